"""Model extensions at the schema level: add nonlinear terms to any representation.

``diagnose`` extends a baseline model with the structure that matches a physical cause.
Two mechanisms cover every representation, so an identifier plugin needs no change:

- **terms** (friction, stiffness, gravity): :func:`extend_with_terms` refits the model with
  extra regressors Θ over *past* outputs (lag >= 1) and inputs.  ARX: least squares on the
  ARX regressors plus Θ.  Sparse map (SINDYc): least squares on the active library terms plus
  Θ.  State space: ``A`` and ``C`` are kept, ``B``, ``D``, ``E`` and the initial states are
  re-estimated by output-error least squares with Θ computed from the measured outputs.  An
  ARX or a sparse map with blocks is regressed on what its representation sees: the inputs
  after its input blocks, the outputs before its output blocks (:func:`driven_outputs`).
- **blocks** (delay, dead zone, saturation, play, lag): the data are transformed, the baseline
  identifier is run again and the block is attached (:func:`transform_inputs`,
  :func:`drop_samples`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from ..dataset import Dataset, Experiment
from ..errors import SchemaError
from ..regression import scaled_lstsq, term_columns_of
from ..schema import ARX, Block, Model, SparseMap, StateSpace
from ..simulate import (
    aligned,
    apply_block,
    block_inputs,
    curve_inverse,
    divergence,
    inner_outputs,
    simulate,
    simulate_dataset,
    transform_inputs,
    unit_responses,
)
from ..terms import Term

FloatArray = NDArray[np.float64]


def _signals(model: Model, e: Experiment) -> dict[str, FloatArray]:
    return {
        **{n: e.u[:, j] for j, n in enumerate(model.input_names)},
        **{n: e.y[:, j] for j, n in enumerate(model.output_names)},
    }


def driven_outputs(model: Model, data: Dataset) -> Dataset:
    """``data`` (as measured: raw inputs) with its outputs taken back through ``model``'s
    output blocks: the signal the representation produces, on which a regression of it is
    fitted.

    The blocks are undone from the last to the first.  A polynomial curve is inverted
    (:func:`~tendonkit.simulate.curve_inverse`).  Any other block ``B`` is undone
    approximately: the signal before it is ``z + (ŝ - B(ŝ))``, ``z`` the signal after it and
    ``ŝ`` the noise-free simulation entering it (the representation, started from the
    outputs taken back through the curves, run through the blocks before ``B``) — for a play
    the side of the gap in contact, as the backlash effect builds its candidates
    (``plugins/effects_blocks.py``), for a clip the excess on the samples it clips.  Where
    that simulation is not finite (a diverged model), the outputs taken back through the
    curves stand in for it.
    """
    blocks = model.output_blocks
    if not blocks:
        return data
    names = model.output_names
    inner = data.with_experiments(
        [dataclasses.replace(e, y=inner_outputs(model, e.y)) for e in data.experiments]
    )
    if all(b.kind == "polynomial" for b in blocks):
        return inner  # curves only: inverted, no simulation needed
    sims = simulate_dataset(model.replace(output_blocks=()), inner)
    exps = []
    for e, e_in, sim in zip(data.experiments, inner.experiments, sims, strict=True):
        entering = block_inputs(blocks, names, np.where(np.isfinite(sim), sim, e_in.y))
        z = np.array(e.y, dtype=float)
        for b, x in zip(reversed(blocks), reversed(entering), strict=True):
            j = names.index(b.signal)
            if b.kind == "polynomial":
                z[:, j] = curve_inverse(b, z[:, j])
            else:
                z[:, j] = z[:, j] + (x - apply_block(b, x))
        exps.append(dataclasses.replace(e, y=z))
    return data.with_experiments(exps)


def with_note(model: Model, text: str) -> Model:
    """``model`` with ``text`` appended to its provenance notes."""
    prov = dataclasses.replace(
        model.provenance,
        notes=(model.provenance.notes + "; " if model.provenance.notes else "") + text,
    )
    return model.replace(provenance=prov)


def extend_with_terms(
    model: Model,
    data: Dataset,
    terms: Sequence[Term],
    note: str = "",
    refit: Callable[[Dataset], Model] | None = None,
) -> Model:
    """Refit ``model`` on ``data`` with the extra regressors ``terms`` (see module docstring).

    Terms are written in output-equation time: they read outputs and inputs with lag >= 1.
    Existing terms of the model are kept and refitted, and its blocks kept: an ARX or a sparse
    map is regressed on the inputs passed through its input blocks and on its own outputs,
    before its output blocks (:func:`driven_outputs`); a state space on the measured outputs.
    For a state-space model, ``refit`` (the baseline's identifier) is run with Θ — computed
    from the measured outputs — as extra inputs, so ``A``, ``B`` and ``E`` are estimated
    together; without it, ``A`` and ``C`` are kept and ``B``, ``D``, ``E``, ``x0`` are
    refitted by output-error least squares.
    """
    data = aligned(model, data)
    terms = tuple(terms)
    rep = model.representation
    if model.output_blocks and isinstance(rep, ARX | SparseMap):
        # The regressors are what the representation sees: its own outputs, before the
        # model's output blocks (read from its simulation of the raw inputs) ...
        data = driven_outputs(model, data)
    if model.input_blocks and isinstance(rep, ARX | SparseMap):
        # ... and the inputs after its input blocks (an extension of an already extended
        # model, e.g. the next step of a diagnosis).
        data = transform_inputs(data, model.input_blocks)
    if isinstance(rep, ARX):
        new = _extend_arx(model, rep, data, terms)
    elif isinstance(rep, SparseMap):
        new = _extend_sparse(model, rep, data, terms)
    elif refit is not None:
        new = _extend_ss_by_refit(model, rep, data, terms, refit)
    else:
        new = _extend_ss(model, rep, data, terms)
    return with_note(new, note) if note else new


def _extend_ss_by_refit(
    model: Model,
    rep: StateSpace,
    data: Dataset,
    terms: tuple[Term, ...],
    refit: Callable[[Dataset], Model],
) -> Model:
    """Identify again with Θ(measured y) as extra inputs; their input columns become ``E``."""
    all_terms = (*rep.terms, *(shift_term(t) for t in terms))
    nu = len(model.inputs)
    names = tuple(f"_theta{i}" for i in range(len(all_terms)))
    exps = []
    for e in data.experiments:
        sig = {**_signals(model, e)}
        theta = term_columns_of(all_terms, sig, e.n_samples)
        exps.append(dataclasses.replace(e, u=np.hstack([e.u, theta])))
    augmented = Dataset(
        inputs=data.inputs + names, outputs=data.outputs, experiments=tuple(exps), dt=data.dt
    )
    fitted = refit(augmented)
    frep = fitted.representation
    if not isinstance(frep, StateSpace) or frep.terms:
        return _extend_ss(model, rep, data, terms)
    y0 = frep.y0
    E = frep.B[:, nu:].copy()
    if frep.u0 is not None and np.any(frep.u0[nu:] != 0):
        # An operating point of Θ (an identifier that removes the means) is a constant state
        # input b = -E θ0: with x' = x - (I - A)⁻¹ b the model is x'⁺ = A x' + B(u - u0) + Eθ,
        # y = C x' + D(u - u0) + y0 + C (I - A)⁻¹ b, the same outputs (the initial state is
        # estimated), so b moves into the output's operating point.
        try:
            shift = np.linalg.solve(np.eye(frep.A.shape[0]) - frep.A, -E @ frep.u0[nu:])
        except np.linalg.LinAlgError:  # an integrator: no steady state to move b to
            return _extend_ss(model, rep, data, terms)
        y0 = (np.zeros(frep.C.shape[0]) if y0 is None else y0) + frep.C @ shift
    return model.replace(
        representation=StateSpace(
            A=frep.A,
            B=frep.B[:, :nu].copy(),
            C=frep.C,
            D=frep.D[:, :nu].copy(),
            x0=None,
            K=None,
            terms=all_terms,
            E=E,
            u0=None if frep.u0 is None else frep.u0[:nu].copy(),
            y0=y0,
        )
    )


# -- ARX ------------------------------------------------------------------------------------------


def _extend_arx(model: Model, rep: ARX, data: Dataset, terms: tuple[Term, ...]) -> Model:
    ny, nu = len(model.outputs), len(model.inputs)
    all_terms = (*rep.terms, *terms)
    nk = list(rep.nk)
    lag = max([rep.na, *[k + rep.nb - 1 for k in nk], *[t.max_lag for t in all_terms], 1])
    rows, targets = [], []
    for e in data.experiments:
        n = e.n_samples
        if n <= lag:
            continue
        cols = [-e.y[lag - i : n - i] for i in range(1, rep.na + 1)]
        for j in range(rep.nb):
            for m in range(nu):
                d = nk[m] + j
                cols.append(e.u[lag - d : n - d, m : m + 1])
        if rep.offset is not None:
            cols.append(np.ones((n - lag, 1)))
        cols.append(term_columns_of(all_terms, _signals(model, e), n)[lag:])
        rows.append(np.hstack(cols))
        targets.append(e.y[lag:])
    theta = scaled_lstsq(np.vstack(rows), np.vstack(targets))
    A = tuple(theta[i * ny : (i + 1) * ny].T.copy() for i in range(rep.na))
    pos = rep.na * ny
    B = []
    for _ in range(rep.nb):
        B.append(theta[pos : pos + nu].T.copy())
        pos += nu
    offset = None
    if rep.offset is not None:
        offset = theta[pos].copy()
        pos += 1
    coef = theta[pos:].copy()
    return model.replace(
        representation=ARX(
            A=A, B=tuple(B), nk=rep.nk, offset=offset, terms=all_terms, term_coefficients=coef
        )
    )


# -- sparse map -----------------------------------------------------------------------------------


def shift_term(term: Term, rename: dict[str, str] | None = None) -> Term:
    """Rewrite an output-equation term for a state update.

    Extension terms are written in output-equation time (they affect ``y[k]`` and read
    ``y[k-l]``, ``u[k-l]`` with ``l >= 1``).  A state update ``x[k+1] = f(·[k])`` affects
    ``y[k+1]``, so every lag drops by one; ``rename`` maps output names to state names.
    """
    rename = rename or {}
    factors = []
    for f in term.factors:
        if f.lag < 1:
            raise SchemaError(f"term {term.label}: extension terms must read lag >= 1.")
        factors.append(
            dataclasses.replace(
                f,
                signal=rename.get(f.signal, f.signal),
                minus=rename.get(f.minus, f.minus),
                lag=f.lag - 1,
            )
        )
    return Term(tuple(factors))


def to_map_term(model: Model, term: Term) -> Term:
    """:func:`shift_term` for a sparse map, with outputs renamed to their states."""
    rep = model.representation
    assert isinstance(rep, SparseMap)
    out_to_state = {
        model.output_names[j]: model.states[i].name for j, i in enumerate(rep.output_states)
    }
    return shift_term(term, out_to_state)


def _extend_sparse(model: Model, rep: SparseMap, data: Dataset, terms: tuple[Term, ...]) -> Model:
    if sorted(rep.output_states) != list(range(rep.n_states)):
        raise SchemaError("Extending a sparse_map needs every state measured (states = outputs).")
    active = np.any(rep.coefficients != 0, axis=1)
    base_terms = tuple(t for t, a in zip(rep.terms, active) if a)
    all_terms = (*base_terms, *(to_map_term(model, t) for t in terms))
    state_names = [s.name for s in model.states]
    order = list(rep.output_states)
    rows, targets = [], []
    lag = max((t.max_lag for t in all_terms), default=0)
    for e in data.experiments:
        x = np.empty((e.n_samples, rep.n_states))
        for j, i in enumerate(order):
            x[:, i] = e.y[:, j]
        sig = {
            **{n: x[:, i] for i, n in enumerate(state_names)},
            **{n: e.u[:, j] for j, n in enumerate(model.input_names)},
        }
        cols = term_columns_of(all_terms, sig, e.n_samples)
        rows.append(cols[lag:-1])
        targets.append(x[lag + 1 :])
    coef = scaled_lstsq(np.vstack(rows), np.vstack(targets), ridge=1e-10)
    return model.replace(
        representation=dataclasses.replace(rep, terms=all_terms, coefficients=coef)
    )


# -- state space ----------------------------------------------------------------------------------


def _extend_ss(model: Model, rep: StateSpace, data: Dataset, terms: tuple[Term, ...]) -> Model:
    all_terms = (*rep.terms, *(shift_term(t) for t in terms))
    nx, ny, nu = rep.n_states, rep.C.shape[0], len(model.inputs)
    estimate_d = bool(np.any(rep.D != 0))
    blocks, targets = [], []
    n_exp = len(data.experiments)
    # the linear part acts on deviations from the operating point; Θ reads the raw signals
    u0, y0 = rep.operating_point
    for ei, e in enumerate(data.experiments):
        theta = term_columns_of(all_terms, _signals(model, e), e.n_samples)
        du = e.u - u0
        sig = np.hstack([du, theta])
        resp = unit_responses(rep.A, rep.C, sig)  # (N, ny, nx*nc)
        N = e.n_samples
        parts = [resp.reshape(N * ny, -1)]
        if estimate_d:
            Dcols = np.zeros((N, ny, ny * nu))
            for j in range(ny):
                Dcols[:, j, j * nu : (j + 1) * nu] = du
            parts.append(Dcols.reshape(N * ny, -1))
        X0 = np.zeros((N * ny, nx * n_exp))
        M = rep.C.copy()
        for k in range(N):
            X0[k * ny : (k + 1) * ny, ei * nx : (ei + 1) * nx] = M
            M = M @ rep.A
        parts.append(X0)
        blocks.append(np.hstack(parts))
        targets.append((e.y - y0).reshape(-1, 1))
    theta_hat = scaled_lstsq(np.vstack(blocks), np.vstack(targets))[:, 0]
    nc = nu + len(all_terms)
    G = theta_hat[: nx * nc].reshape(nx, nc)
    pos = nx * nc
    D = rep.D
    if estimate_d:
        D = theta_hat[pos : pos + ny * nu].reshape(ny, nu)
        pos += ny * nu
    x0 = theta_hat[pos : pos + nx]
    return model.replace(
        representation=dataclasses.replace(
            rep, B=G[:, :nu].copy(), D=D, E=G[:, nu:].copy(), terms=all_terms, x0=x0, K=None
        )
    )


# -- data transforms for block-based extensions ---------------------------------------------------


def with_output_curves(inner: Model, data: Dataset, degree: int = 3) -> Model:
    """``inner`` followed by a ``polynomial`` block per output (a Wiener model), fitted by
    least squares.

    ``inner`` is simulated on every experiment of ``data`` (its initial state estimated); each
    output's curve maps that simulated signal to the measured output (powers of the signal
    scaled to unit spread for the fit, the coefficients then written for the raw signal).

    Raises
    ------
    ValueError
        ``inner`` diverges on the data.
    """
    if not 1 <= degree <= 3:
        raise ValueError(f"a polynomial block is at most cubic, found degree {degree}")
    data = aligned(inner, data)
    x = np.vstack([simulate(inner, e.u, y=e.y, initial="estimate") for e in data.experiments])
    if divergence(x, data.y) is not None:  # non-finite, or finite but far beyond the data
        raise ValueError("the inner model diverges on the data")
    blocks = []
    for j, name in enumerate(inner.output_names):
        mu = float(x[:, j].mean())
        sd = float(x[:, j].std()) or 1.0
        V = np.vander((x[:, j] - mu) / sd, degree + 1, increasing=True)
        a = np.linalg.lstsq(V, data.y[:, j], rcond=None)[0]
        # sum a_i ((s - mu) / sd)^i written as a polynomial of s
        coef = np.polynomial.Polynomial(a)(np.polynomial.Polynomial([-mu / sd, 1.0 / sd])).coef
        c = np.zeros(4)
        c[: coef.size] = coef
        blocks.append(Block("polynomial", name, {f"c{i}": float(c[i]) for i in range(4)}))
    return inner.replace(output_blocks=(*inner.output_blocks, *blocks))


#: Rounds of :func:`fit_wiener`'s alternating least squares.
WIENER_ROUNDS = 2


def fit_wiener(
    refit: Callable[[Dataset], Model], data: Dataset, rounds: int = WIENER_ROUNDS
) -> Model:
    """A structure with a cubic curve after each output (a Wiener model), by least squares.

    A curve after the dynamics bends the measured output, and a linear part fitted to the
    bent output is biased; so the fit alternates: the curve by least squares from the
    simulated inner signal (:func:`with_output_curves`), then the linear part by ``refit``
    (the structure's identifier) on the measured outputs taken back through the curve
    (:func:`tendonkit.simulate.inner_outputs`), ``rounds`` times.
    """
    model = with_output_curves(refit(data), data)
    data = aligned(model, data)
    for _ in range(rounds):
        inner_data = data.with_experiments(
            [dataclasses.replace(e, y=inner_outputs(model, e.y)) for e in data.experiments]
        )
        model = with_output_curves(refit(inner_data), data)
    return model


def transform_outputs(data: Dataset, fn: Callable[[FloatArray], FloatArray]) -> Dataset:
    """Replace every experiment's outputs by ``fn(y)``."""
    return data.with_experiments(
        [dataclasses.replace(e, y=fn(e.y.copy())) for e in data.experiments]
    )


def drop_samples(
    data: Dataset, mask_fn: Callable[[Experiment], FloatArray], min_length: int
) -> Dataset:
    """Split experiments where ``mask_fn`` marks samples to drop; keep segments >= min_length."""
    exps = []
    for e in data.experiments:
        drop = np.asarray(mask_fn(e), dtype=bool)
        keep = ~drop
        edges = np.flatnonzero(np.diff(np.concatenate([[0], keep.astype(int), [0]])))
        for a, b in zip(edges[::2], edges[1::2]):
            if b - a >= min_length:
                s = slice(a, b)
                exps.append(
                    Experiment(
                        t=e.t[s],
                        u=e.u[s],
                        y=e.y[s],
                        name=f"{e.name}[{a}:{b}]",
                        extra={k: v[s] for k, v in e.extra.items()},
                    )
                )
    return data.with_experiments(exps)


def refit_with_input_blocks(
    refit: Callable[[Dataset], Model], blocks: Sequence[Block]
) -> Callable[[Dataset], Model]:
    """A builder that identifies on inputs passed through ``blocks`` and attaches the blocks.

    ``refit`` is the baseline's identifier (``identify(dataset) -> Model``); the returned
    function maps training data to the extended model, for every representation.
    """

    def build(data: Dataset) -> Model:
        model = refit(transform_inputs(data, blocks))
        return model.replace(input_blocks=(*blocks, *model.input_blocks))

    return build

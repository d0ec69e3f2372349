"""Simulation-error refinement of any model: terms, blocks and all (output-error PEM).

Identifiers that regress (ARX, the extensions ``diagnose`` makes, SINDYc) minimise an
*equation* error; the model is then judged — and used — in free-run simulation, where that
estimate is biased whenever the noise is not equation noise or the structure is only an
approximation (Ljung, *System Identification*, 2nd ed., §7.3).  :func:`refine` re-estimates
every continuous parameter of a model by its simulation error, starting from the model as
given, by scipy's trust-region-reflective least squares (Jacobian-scaled, through the compiled
simulation; the Jacobian of an ARX's coefficients exact by forward sensitivities,
:func:`tendonkit._kernel.arx_sensitivity` — through terms with a memory and clipped states
tied to ``A``, :func:`tendonkit._kernel.arx_sensitivity_terms` — passed through its output
blocks by :func:`block_tangent`, the trust-region subproblem from a tall QR:
:func:`_tall_trust_region`; everything else by forward differences and
:func:`scipy.optimize.least_squares`):

- ``state_space``: ``A``, ``B``, ``C``, the non-zero ``D``, the term matrix ``E``, ``u0`` and
  ``y0`` where set;
- ``arx``: every coefficient of ``A``, the non-zero ``B``, the offset and the term
  coefficients (a clipped-state term's follow ``A``: :func:`tied_terms`);
- ``sparse_map``: the non-zero coefficients (the sparsity pattern stays);
- blocks: every parameter but a delay's (a fractional delay's samples are continuous, but a
  change of its integer part is a change of structure) — dead-zone thresholds and centres,
  saturation limits, play widths, lag poles, rate limits;
- the shapes of the operators with a memory in the terms (a ``play``'s half-width, a
  ``bouc_wen`` operator's ``param`` and ``param2``, a ``slew_lag``'s gain, largest step and
  loop weight — shared by the lags of one operator: :func:`_shapes`).

The initial state is estimated from each experiment's data at every evaluation (as
``simulate(..., initial="estimate")``).  The model as given is returned when no lower
simulation error is found, so refining never makes a model worse on the data it is refined
on.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from ._kernel import arx_sensitivity, arx_sensitivity_terms, flatten, follow_index
from ._simulate_arx import arx_max_lag
from .dataset import Dataset
from .errors import SchemaError
from .identification import training_fit
from .regression import r_factor
from .schema import ARX, Block, Model, SparseMap, StateSpace
from .simulate import (
    _apply_blocks,
    _simulate_checked,
    aligned,
    apply_block,
    block_inputs,
    compiled_engine,
    curve_slope,
    initial_span,
    inner_outputs,
    input_history,
)
from .terms import CompiledTerms, Term

FloatArray = NDArray[np.float64]

#: Block parameters that stay fixed (their change is a change of structure).
FIXED_BLOCK_PARAMS = {("delay", "samples")}
#: Admissible ranges of block parameters (the schema's), kept by clipping.
BLOCK_BOUNDS = {
    ("dead_zone", "threshold"): (0.0, np.inf),
    ("play", "width"): (0.0, np.inf),
    ("first_order_lag", "pole"): (0.0, 1.0 - 1e-9),
    ("rate_limit", "rate"): (1e-12, np.inf),
}


def tied_terms(rep: ARX, outputs: Sequence[str]) -> list[tuple[int, int, int, float]]:
    """Clipped-state terms of an ARX model: ``(term index, lag, output index, sign)``.

    ``relu`` of a past output ``j`` at lag ``i`` whose coefficients are exactly ``±A_i[:, j]``
    is how a state clipped inside the recursion is written (``Σ A_i clip(y[k-i])``, the
    ``saturation`` effect); the refinement keeps those coefficients equal to ``A``'s so that
    the clip stays a clip.
    """
    out: list[tuple[int, int, int, float]] = []
    coef = rep.term_coefficients
    if coef is None:
        return out
    names = list(outputs)
    for t, term in enumerate(rep.terms):
        if len(term.factors) != 1:
            continue
        f = term.factors[0]
        if f.fn != "relu" or f.minus or f.signal not in names or not 1 <= f.lag <= rep.na:
            continue
        j = names.index(f.signal)
        col = rep.A[f.lag - 1][:, j]
        sign = 1.0 if f.scale > 0 else -1.0
        if np.any(col) and np.allclose(coef[t], sign * col, rtol=0, atol=1e-12):
            out.append((t, f.lag, j, sign))
    return out


def _shapes(terms: Sequence[Term]) -> list[tuple[list[tuple[int, int]], str]]:
    """The shapes of the operators with a memory in ``terms``, as ``(places, key)``.

    A play's half-width, a Bouc-Wen operator's two shapes, a slew lag's gain, largest step and
    (in a loop) the weight of its second signal.  The slew lags of one signal with equal
    shapes are one actuator read at several lags (``R[k-1]``, ``R[k-2]``, …: its state
    entering the dynamics through each input lag), so they share their parameters (each
    factor still runs its own copy of the state, from its own first sample): a key's
    ``places`` are every ``(term, factor)`` it sets.
    """
    out: list[tuple[list[tuple[int, int]], str]] = []
    lags: dict[tuple[Any, ...], list[tuple[int, int]]] = {}
    for t, term in enumerate(terms):
        for j, f in enumerate(term.factors):
            if not f.stateful:
                continue
            keys: tuple[str, ...]
            if f.fn != "slew_lag":
                keys = ("param",) if f.fn == "play" else ("param", "param2")
                out += [([(t, j)], key) for key in keys]
                continue
            group = (f.signal, f.minus, f.diff, f.scale, f.offset, f.param, f.param2, f.weight)
            if group in lags:
                lags[group].append((t, j))
                continue
            lags[group] = [(t, j)]
            keys = ("param", "param2", "weight") if f.minus else ("param", "param2")
            out += [(lags[group], key) for key in keys]
    return out


def _codec(model: Model, blocks: bool = True) -> tuple[FloatArray, Callable[[FloatArray], Model]]:
    """The free parameters of ``model`` as a vector, and the map back to a model."""
    rep = model.representation
    parts: list[tuple[str, Any, NDArray[np.bool_]]] = []  # (name, array, mask of free entries)
    if isinstance(rep, StateSpace):
        for key in ("A", "B", "C", "D", "E", "u0", "y0"):
            arr = getattr(rep, key)
            if arr is None or np.size(arr) == 0:
                continue
            arr = np.asarray(arr, dtype=float)
            mask = arr != 0 if key == "D" else np.ones(arr.shape, bool)
            parts.append((key, arr, mask))
    elif isinstance(rep, ARX):
        for i, a in enumerate(rep.A):
            parts.append((f"A{i}", np.asarray(a, float), np.ones(a.shape, bool)))
        for j, b in enumerate(rep.B):
            parts.append((f"B{j}", np.asarray(b, float), np.asarray(b) != 0))
        if rep.offset is not None:
            off = np.asarray(rep.offset, float)
            parts.append(("offset", off, np.ones(off.shape, bool)))
        tied = tied_terms(rep, model.output_names)
        if rep.term_coefficients is not None:
            tc = np.asarray(rep.term_coefficients, float)
            free = np.ones(tc.shape, bool)
            free[[t for t, *_ in tied]] = False
            parts.append(("terms", tc, free))
    else:
        co = np.asarray(rep.coefficients, float)
        parts.append(("coefficients", co, co != 0))
    free_blocks = [
        (side, i, name)
        for side, chain in (("in", model.input_blocks), ("out", model.output_blocks))
        for i, b in enumerate(chain)
        for name in sorted(b.params)
        if blocks
        and (b.kind, name) not in FIXED_BLOCK_PARAMS
        # a one-sided clip writes its open end as ±1e300: no limit, not a parameter
        and abs(b.params[name]) < 1e299
    ]
    shapes = _shapes(rep.terms)
    theta0 = np.concatenate(
        [arr[mask] for _, arr, mask in parts]
        + [
            np.array(
                [
                    (model.input_blocks if s == "in" else model.output_blocks)[i].params[n]
                    for s, i, n in free_blocks
                ],
                dtype=float,
            ),
            np.array(
                [getattr(rep.terms[at[0][0]].factors[at[0][1]], key) for at, key in shapes],
                dtype=float,
            ),
        ]
    )

    def decode(theta: FloatArray) -> Model:
        pos = 0
        new: dict[str, Any] = {}
        for name, arr, mask in parts:
            k = int(mask.sum())
            out = arr.copy()
            out[mask] = theta[pos : pos + k]
            pos += k
            new[name] = out
        new_terms: tuple[Term, ...] = tuple(rep.terms)
        if shapes:
            terms = [list(term.factors) for term in rep.terms]
            for k, (at, key) in enumerate(shapes):
                value = float(theta[len(theta) - len(shapes) + k])
                fn = terms[at[0][0]][at[0][1]].fn
                if not np.isfinite(value):  # a step the solver cannot take: the start's value
                    value = float(theta0[len(theta0) - len(shapes) + k])
                if fn == "play":
                    value = abs(value)  # a half-width
                elif fn == "slew_lag" and key == "param2":
                    value = max(abs(value), 1e-12)  # a largest step: > 0, as the schema asks
                elif fn == "slew_lag" and key == "param":
                    value = min(max(value, 1e-6), 1.0)  # a gain per sample, in (0, 1]
                for t, j in at:
                    f = terms[t][j]
                    if key == "param":
                        terms[t][j] = dataclasses.replace(f, param=value)
                    elif key == "param2":
                        terms[t][j] = dataclasses.replace(f, param2=value)
                    else:
                        terms[t][j] = dataclasses.replace(f, weight=value)
            new_terms = tuple(Term(tuple(fs)) for fs in terms)
        if isinstance(rep, StateSpace):
            r: Any = dataclasses.replace(rep, **new)
        elif isinstance(rep, ARX):
            A = tuple(new[f"A{i}"] for i in range(len(rep.A)))
            coef: FloatArray | None = new.get("terms")
            if coef is not None:
                for t, lag, j, sign in tied:  # a clipped state stays a clip of the state
                    coef[t] = sign * A[lag - 1][:, j]
            r = dataclasses.replace(
                rep,
                A=A,
                B=tuple(new[f"B{j}"] for j in range(len(rep.B))),
                offset=new.get("offset"),
                term_coefficients=coef,
            )
        else:
            assert isinstance(rep, SparseMap)
            r = dataclasses.replace(rep, coefficients=new["coefficients"])
        if shapes:
            r = dataclasses.replace(r, terms=new_terms)
        ins, outs = list(model.input_blocks), list(model.output_blocks)
        for s, i, n in free_blocks:
            chain = ins if s == "in" else outs
            b = chain[i]
            lo, hi = BLOCK_BOUNDS.get((b.kind, n), (-np.inf, np.inf))
            params = {**b.params, n: float(np.clip(theta[pos], lo, hi))}
            chain[i] = Block(b.kind, b.signal, params)
            pos += 1
        for chain in (ins, outs):  # saturation limits stay ordered
            for i, b in enumerate(chain):
                if b.kind == "saturation" and b.params["lower"] > b.params["upper"]:
                    mid = 0.5 * (b.params["lower"] + b.params["upper"])
                    chain[i] = Block(b.kind, b.signal, {"lower": mid, "upper": mid})
        return model.replace(representation=r, input_blocks=tuple(ins), output_blocks=tuple(outs))

    return theta0, decode


def free_parameters(model: Model, blocks: bool = True) -> int:
    """How many parameters :func:`refine` re-estimates in ``model``."""
    return int(_codec(model, blocks)[0].size)


def refine(
    model: Model,
    data: Dataset,
    *,
    max_nfev: int = 100,
    tol: float = 1e-6,
    initial: Literal["estimate", "model", "zero"] = "estimate",
    blocks: bool = True,
    analytic: bool = True,
) -> Model:
    """Re-estimate every continuous parameter of ``model`` by its free-run simulation error.

    Parameters
    ----------
    model : Model
        Any model; its current parameters are the start.
    data : Dataset
        Data with the model's inputs and outputs (all experiments are used).
    max_nfev : int
        Cap on the optimiser's iterations; each costs one simulation per parameter.
    tol : float
        Relative tolerance on the cost and the step.
    initial : str
        How each experiment's initial state is obtained at every evaluation
        (``"estimate"``: from the data, as the benchmarks; ``"model"`` or ``"zero"``).
    blocks : bool
        Also refine the blocks' parameters; ``False`` keeps them as the caller chose them.
    analytic : bool
        For an ARX model (initial state from the data): the Jacobian of the coefficients by
        forward sensitivities (:func:`tendonkit._kernel.arx_sensitivity`; with terms that
        hold a state — plays, Bouc-Wen operators, slew lags — or a clipped state tied to
        ``A``, :func:`tendonkit._kernel.arx_sensitivity_terms`: exact, one pass) passed
        through the output blocks (:func:`block_tangent`), an output curve's coefficients
        exactly; the blocks' other parameters and the operators' shapes by forward
        differences.  ``False``, and every other model: forward differences throughout (one
        simulation per parameter).

    Returns
    -------
    Model
        The refined model (its provenance notes say by how much), or ``model`` itself when
        no lower simulation error was found.
    """
    # lazy: heavy (scipy.optimize)
    from scipy.optimize import least_squares

    data = aligned(model, data)
    theta0, decode = _codec(model, blocks)
    if theta0.size == 0:
        return model
    scale = np.std(data.y, axis=0)
    scale[~(scale > 0)] = 1.0

    n_res = sum(e.y.size for e in data.experiments)
    # an ARX's delayed inputs before the record (simulate's steady state at the measured
    # start) are held at the start model's: the objective then depends on the parameters
    # through the simulation alone, as the exact Jacobian says
    history = [input_history(model, e.u, e.y, initial) for e in data.experiments]

    last: dict[str, Any] = {}

    def run(theta: FloatArray) -> tuple[list[FloatArray] | None, FloatArray]:
        """The simulations (None: not a model) and residuals at ``theta``.  The last
        evaluation is kept: the Jacobian at an accepted step reuses its simulations."""
        if "theta" in last and np.array_equal(last["theta"], theta):
            return last["sims"], last["r"]
        sims, r = None, np.full(n_res, np.inf)  # inf: a step that left the domain
        m = None
        if np.all(np.isfinite(theta)):
            try:
                m = decode(theta)
            except SchemaError:  # e.g. a saturation whose limits crossed: step back
                m = None
        if m is not None:
            fast = compiled_engine()
            with np.errstate(all="ignore"):
                sims = [
                    _simulate_checked(m, e.u, e.y, initial, fast, None, h)
                    for e, h in zip(data.experiments, history, strict=True)
                ]
            # a diverged simulation is not finite, which makes the optimiser shorten its step
            r = np.concatenate(
                [
                    ((e.y - sim) / scale).ravel()
                    for e, sim in zip(data.experiments, sims, strict=True)
                ]
            )
        last.update(theta=np.array(theta, dtype=float), sims=sims, r=r)
        return sims, r

    def residuals(theta: FloatArray) -> FloatArray:
        return run(theta)[1].copy()

    r0 = residuals(theta0)
    cost0 = float(r0 @ r0)
    if not np.isfinite(cost0):
        return model
    jac: Any = "2-point"
    if analytic and _arx_sensitivity_applies(model, initial):
        jac = _arx_jacobian(model, data, decode, run, scale, history)
    with np.errstate(all="ignore"):  # trial steps may diverge; the optimiser steps back
        if callable(jac):
            x, fun, nfev = _tall_trust_region(
                residuals, jac, theta0, ftol=tol, xtol=tol, max_nfev=max_nfev
            )
        else:
            sol = least_squares(
                residuals, theta0, jac=jac, x_scale="jac", ftol=tol, xtol=tol, max_nfev=max_nfev
            )
            x, fun, nfev = sol.x, sol.fun, sol.nfev
    cost = float(fun @ fun)
    if not np.isfinite(cost) or not cost < cost0:
        return model
    refined = decode(x)
    own = [input_history(refined, e.u, e.y, initial) for e in data.experiments]
    if own != history:
        # the objective held the start model's delayed inputs before the record; the refined
        # model is simulated from its own (input_history): its cost is that simulation's
        history = own
        last.clear()
        cost = float(np.sum(run(x)[1] ** 2))
        if not np.isfinite(cost) or not cost < cost0:
            return model
    n = r0.size
    note = (
        f"refined by simulation error: normalised RMS {np.sqrt(cost0 / n):.4g} -> "
        f"{np.sqrt(cost / n):.4g} ({theta0.size} parameters, {nfev} evaluations)"
    )
    prov = refined.provenance
    notes = "; ".join(x for x in (prov.notes, note) if x)
    fit = training_fit(refined, data) if prov.training_fit else prov.training_fit
    return refined.replace(provenance=dataclasses.replace(prov, notes=notes, training_fit=fit))


#: Machine epsilon (the trust-region subproblem's rank test, as scipy's).
_EPS = float(np.finfo(float).eps)


def _tall_trust_region(
    fun: Callable[[FloatArray], FloatArray],
    jac: Callable[[FloatArray], FloatArray],
    x0: FloatArray,
    *,
    ftol: float,
    xtol: float,
    gtol: float = 1e-8,
    max_nfev: int,
) -> tuple[FloatArray, FloatArray, int]:
    """``(x, residuals, evaluations)``: scipy's ``least_squares(method="trf", x_scale="jac")``
    without bounds, step for step, for a tall Jacobian.

    scipy factors the whole ``m × n`` scaled Jacobian ``J_h`` by an SVD at every step.  For a
    simulation error ``m`` is the record's length times the outputs (10⁴–10⁵) and ``n`` a few
    hundred at most, so those SVDs cost much of a refinement (the tutorial's diagnosis: 48 SVDs
    of 16 000 × 256, 0.26–0.32 s each).  The subproblem needs only ``J_h``'s singular values,
    its right singular vectors and ``Uᵀf``; they are taken from the triangular factor of
    ``[J_h | f]`` (:func:`tendonkit.regression.r_factor`, a blocked TSQR: orthogonal, so
    nothing of the accuracy is lost) and the SVD of its ``n × n`` block — about a third of the
    time.  The trust-region subproblem (Moré 1977), the Jacobian scaling, the radius updates,
    the treatment of a non-finite trial (radius quartered) and the termination tests are
    scipy's, so the steps are its steps (a test compares the two).
    """
    x = np.array(x0, dtype=float)
    f = fun(x)
    nfev = 1
    J = jac(x)
    m, n = J.shape
    cost = 0.5 * float(f @ f)
    g = J.T @ f
    scale_inv = np.linalg.norm(J, axis=0)
    scale_inv[scale_inv == 0] = 1.0
    Delta = float(np.linalg.norm(x * scale_inv)) or 1.0
    alpha = 0.0
    while True:
        if np.linalg.norm(g, ord=np.inf) < gtol or nfev >= max_nfev:
            break
        d = 1.0 / scale_inv
        J_h = J * d
        R = r_factor(np.hstack([J_h, f[:, None]]))
        U, sv, VT = np.linalg.svd(np.triu(R[:n, :n]))
        uf, V = U.T @ R[:n, n], VT.T
        full_rank = m >= n and sv[-1] > _EPS * m * sv[0]
        actual_reduction = -1.0
        done = False
        while actual_reduction <= 0 and nfev < max_nfev:
            step_h, alpha = _tr_step(sv, V, uf, Delta, alpha, full_rank)
            Js = J_h @ step_h
            predicted_reduction = -float((d * g) @ step_h + 0.5 * Js @ Js)
            step = d * step_h
            x_new = x + step
            f_new = fun(x_new)
            nfev += 1
            step_h_norm = float(np.linalg.norm(step_h))
            if not np.all(np.isfinite(f_new)):
                Delta = 0.25 * step_h_norm
                continue
            cost_new = 0.5 * float(f_new @ f_new)
            actual_reduction = cost - cost_new
            if predicted_reduction > 0:
                ratio = actual_reduction / predicted_reduction
            else:
                ratio = 1.0 if predicted_reduction == actual_reduction == 0 else 0.0
            Delta_new = Delta
            if ratio < 0.25:
                Delta_new = 0.25 * step_h_norm
            elif ratio > 0.75 and step_h_norm > 0.95 * Delta:
                Delta_new = 2.0 * Delta
            step_norm = float(np.linalg.norm(step))
            ftol_ok = actual_reduction < ftol * cost and ratio > 0.25
            xtol_ok = step_norm < xtol * (xtol + float(np.linalg.norm(x)))
            if ftol_ok or xtol_ok:
                done = True
                break
            alpha *= Delta / Delta_new
            Delta = Delta_new
        if actual_reduction > 0:
            x, f, cost = x_new, f_new, cost_new
            if not done:  # the Jacobian of the next step
                J = jac(x)
                g = J.T @ f
                scale_inv = np.maximum(scale_inv, np.linalg.norm(J, axis=0))
        if done:
            break
    return x, f, nfev


def _tr_step(
    s: FloatArray, V: FloatArray, uf: FloatArray, Delta: float, alpha: float, full_rank: bool
) -> tuple[FloatArray, float]:
    """The trust-region step ``p`` (scaled variables) and its Levenberg–Marquardt parameter
    ``α``: ``(JᵀJ + α I) p = -Jᵀf`` with ``‖p‖ ≤ Δ``, from ``J = U diag(s) Vᵀ`` and ``uf = Uᵀf``
    (Moré 1977; scipy's ``solve_lsq_trust_region``, whose steps these are)."""
    suf = s * uf
    if full_rank:
        p = -V @ (uf / s)
        if np.linalg.norm(p) <= Delta:
            return p, 0.0

    def phi(a: float) -> tuple[float, float]:
        denom = s**2 + a
        p_norm = float(np.linalg.norm(suf / denom))
        return p_norm - Delta, -float(np.sum(suf**2 / denom**3)) / p_norm

    upper = float(np.linalg.norm(suf)) / Delta
    if full_rank:
        value, slope = phi(0.0)
        lower = -value / slope
    else:
        lower = 0.0
    if not full_rank and alpha == 0:
        alpha = max(0.001 * upper, (lower * upper) ** 0.5)
    for _ in range(10):
        if alpha < lower or alpha > upper:
            alpha = max(0.001 * upper, (lower * upper) ** 0.5)
        value, slope = phi(alpha)
        if value < 0:
            upper = alpha
        ratio = value / slope
        lower = max(lower, alpha - ratio)
        alpha -= (value + Delta) * ratio / Delta
        if abs(value) < 0.01 * Delta:
            break
    p = -V @ (suf / (s**2 + alpha))
    return p * (Delta / float(np.linalg.norm(p))), alpha


def block_tangent(block: Block, x: FloatArray, T: FloatArray) -> FloatArray:
    """How a block passes derivatives: ``T`` (N, P), the derivatives of its input signal
    ``x`` (N,) with respect to P parameters, mapped to those of its output (the block's own
    parameters held).

    A curve scales them by its slope, a clip and a dead zone pass them where the signal is
    inside the limits and outside the zone, a play and a rate limit pass those of the sample
    their output last followed (:func:`tendonkit._kernel.follow_index`), and the linear blocks
    (delays, lags, sections) filter them as they filter the signal.  At a kink (the signal
    exactly at a limit, a play exactly at its gap's edge) the one-sided derivative.
    """
    p = block.params
    if block.kind == "polynomial":
        return np.asarray(curve_slope(p, x))[:, None] * T
    if block.kind == "saturation":
        return ((x > p["lower"]) & (x < p["upper"]))[:, None] * T
    if block.kind == "dead_zone":
        return (np.abs(x - p["center"]) > p["threshold"])[:, None] * T
    if block.kind in ("play", "rate_limit"):
        if not x.shape[0]:
            return T.copy()
        width, rate = (p["width"], -1.0) if block.kind == "play" else (0.0, p["rate"])
        return T[follow_index(np.ascontiguousarray(x, dtype=float), float(width), float(rate))]
    # delay, first_order_lag, second_order_section: linear in the signal
    if not T.shape[1]:
        return T.copy()
    return np.column_stack([apply_block(block, T[:, q]) for q in range(T.shape[1])])


def exact_jacobian(model: Model) -> bool:
    """Whether :func:`refine` computes ``model``'s Jacobian by forward sensitivities (one pass,
    whatever the number of coefficients) rather than by a simulation per parameter."""
    return _arx_sensitivity_applies(model, "estimate")


def _arx_sensitivity_applies(model: Model, initial: str) -> bool:
    # blocks after the model: the chain rule through each (:func:`block_tangent`); terms of
    # every kind, tied or with a memory (:func:`tendonkit._kernel.arx_sensitivity_terms`)
    return isinstance(model.representation, ARX) and initial == "estimate"


def _arx_jacobian(
    model: Model,
    data: Dataset,
    decode: Callable[[FloatArray], Model],
    run: Callable[[FloatArray], tuple[list[FloatArray] | None, FloatArray]],
    scale: FloatArray,
    history: list[dict[int, float]] | None = None,
) -> Callable[[FloatArray], FloatArray]:
    """The Jacobian of :func:`refine`'s residuals for an ARX model (see ``analytic``).

    ``history``: per experiment, the delayed inputs before the record ``run`` holds
    (:func:`tendonkit.simulate.input_history` of ``model``, the default).

    The coefficients come first in the parameter vector (``_codec``: ``A``, the non-zero
    ``B``, the offset, the term coefficients but those tied to ``A``), the blocks' parameters
    after them, then the shapes of the terms' operators with a memory.  ``run``
    gives the simulations and residuals at a parameter vector (those of the step just taken).
    """
    rep0 = model.representation
    assert isinstance(rep0, ARX)
    if history is None:
        history = [input_history(model, e.u, e.y) for e in data.experiments]
    outputs, inputs = list(model.output_names), list(model.input_names)
    ny, nu, nt = len(outputs), len(inputs), len(rep0.terms)
    # The structure is fixed (only coefficients change; an operator's shape is a parameter
    # of forward differences): which coefficient multiplies what, and where the terms read
    # past outputs, is known once.
    b_entries = [
        (lag, i, j) for lag, b in enumerate(rep0.B) for i, j in zip(*np.nonzero(b), strict=True)
    ]
    tied = tied_terms(rep0, outputs)
    n_terms_free = (nt - len(tied)) * ny if rep0.term_coefficients is not None else 0
    n_lin = (
        sum(a.size for a in rep0.A) + len(b_entries) + (0 if rep0.offset is None else ny)
    ) + n_terms_free
    n_shapes = len(_shapes(rep0.terms))
    L = arx_max_lag(rep0, nu)
    # Terms with a memory, or tied to A: every term evaluated with its tangent along the
    # simulation (:func:`tendonkit._kernel.arx_sensitivity_terms`); memoryless terms alone:
    # their derivatives at each sample (:func:`tendonkit._kernel.arx_sensitivity`).
    general = rep0.term_coefficients is not None and (
        bool(tied) or any(t.stateful for t in rep0.terms)
    )
    in_index = {n: j for j, n in enumerate(inputs)}
    out_index = {n: j for j, n in enumerate(outputs)}
    tcol = np.full((nt, ny), -1, dtype=np.int64)
    tsign = np.ones(nt)
    if general:
        first_term = n_lin - n_terms_free
        tied_rows = {t for t, *_ in tied}
        free_rows = [t for t in range(nt) if t not in tied_rows]
        for rank, t in enumerate(free_rows):
            tcol[t] = first_term + rank * ny + np.arange(ny)
        a_start = np.cumsum([0] + [a.size for a in rep0.A])
        for t, lag, j, sign in tied:  # its coefficients are sign·A[lag-1][:, j]
            tcol[t] = a_start[lag - 1] + np.arange(ny) * ny + j
            tsign[t] = sign
    ct = (
        CompiledTerms(rep0.terms)
        if nt and rep0.term_coefficients is not None and not general
        else None
    )
    qs = [q for q, (n, _) in enumerate(ct.keys) if n in outputs] if ct is not None else []
    qcol = np.array([outputs.index(ct.keys[q][0]) for q in qs] if ct else [], dtype=np.int64)
    qlag = np.array([ct.keys[q][1] for q in qs] if ct else [], dtype=np.int64)

    def regressors(rep: ARX, Up: FloatArray, Yp: FloatArray, N: int) -> tuple[Any, Any]:
        """Φ (N, ny, n_lin): each coefficient's regressor on the simulated outputs, and the
        terms' derivatives with respect to their readings of past outputs (nt, nq, N)."""
        ks = np.arange(N) + L
        Phi = np.zeros((N, ny, n_lin))
        p = 0
        for w, a in enumerate(rep.A):
            for i, j in np.ndindex(a.shape):
                Phi[:, i, p] = -Yp[ks - 1 - w, j]
                p += 1
        for lag, i, j in b_entries:
            Phi[:, i, p] = Up[ks - lag - rep.nk[j], j]
            p += 1
        if rep.offset is not None:
            Phi[:, range(ny), range(p, p + ny)] = 1.0
            p += ny
        J = np.zeros((nt, 0, N))
        if ct is not None:
            src = {n: (Up, j) for j, n in enumerate(inputs)}
            src.update({n: (Yp, j) for j, n in enumerate(outputs)})
            values = np.array([src[n][0][ks - lag, src[n][1]] for n, lag in ct.keys])
            values = values.reshape(len(ct.keys), N)
            theta_t = np.broadcast_to(ct.evaluate(values), (nt, N))  # constants: (nt,)
            for t in range(nt):
                Phi[:, range(ny), range(p, p + ny)] = theta_t[t][:, None]
                p += ny
            if qs:
                J = np.ascontiguousarray(ct.jacobian(values)[:, qs, :])
        return Phi, J

    # The parameter vector after the coefficients (``_codec``): the input blocks' free
    # parameters, then the output blocks' (both in the vector only when blocks are refined),
    # then the operators' shapes (forward differences).
    # A curve's c0..c3 have exact columns (``d f / d c_i = x^i``), every other block parameter
    # forward differences.
    def free(b: Block) -> list[str]:
        return [
            name
            for name in sorted(b.params)
            if (b.kind, name) not in FIXED_BLOCK_PARAMS and abs(b.params[name]) < 1e299
        ]

    n_in = sum(len(free(b)) for b in model.input_blocks)
    curve_at: dict[int, int] = {}  # output block -> its c0's place among the blocks' parameters
    n_out = 0
    for k, b in enumerate(model.output_blocks):
        if b.kind == "polynomial":
            curve_at[k] = n_out
        n_out += len(free(b))
    exact_out = sorted(q for c in curve_at.values() for q in range(c, c + 4))

    def jac(theta: FloatArray) -> FloatArray:
        m = decode(theta)
        with_blocks = theta.size == n_lin + n_in + n_out + n_shapes  # blocks=True
        rep = m.representation
        assert isinstance(rep, ARX)
        sims, r0 = run(theta)
        if sims is None:
            return np.zeros((r0.size, theta.size))
        coef = np.zeros((nt, ny)) if rep.term_coefficients is None else rep.term_coefficients
        A = np.array(rep.A).reshape(len(rep.A), ny, ny) if rep.A else np.zeros((0, ny, ny))
        linear: list[FloatArray] = []
        block_cols: list[FloatArray] = []
        chain = [(outputs.index(b.signal), b) for b in m.output_blocks]
        inner = m.replace(output_blocks=()) if chain else m
        # the terms as flat arrays, once for every experiment (their shapes move with theta)
        flat = flatten(rep.terms, in_index, out_index) if general else None
        with np.errstate(all="ignore"):
            for e, ys, hist in zip(data.experiments, sims, history, strict=True):
                N = e.u.shape[0]
                start = min(L, N)
                ub = _apply_blocks(m.input_blocks, m.input_names, e.u, True, hist)
                Up = np.vstack([np.repeat(ub[:1], L, axis=0), ub])
                y_meas = e.y
                if chain:  # the inner signal, started from the outputs taken back
                    y_meas = inner_outputs(m, e.y, initial_span(m))
                    ys = _simulate_checked(inner, e.u, y_meas, "estimate", True, None, hist)
                Yp = np.vstack([np.repeat(y_meas[:1], L, axis=0), ys])
                Phi, J = regressors(rep, Up, Yp, N)
                Phi[:start] = 0.0  # the measured history does not depend on the parameters
                if flat is not None:
                    S = arx_sensitivity_terms(
                        Phi, A, np.ascontiguousarray(coef, dtype=float), tcol, tsign,
                        np.ascontiguousarray(Up, dtype=float),
                        np.ascontiguousarray(Yp, dtype=float), start, L, flat.ptr, flat.src,
                        flat.col, flat.lag, flat.diff, flat.src2, flat.col2, flat.code,
                        flat.power, flat.scale, flat.offset, flat.param, flat.param2,
                        flat.weight,
                    )  # fmt: skip
                else:
                    S = arx_sensitivity(
                        Phi, A, np.ascontiguousarray(coef, dtype=float), J, qcol, qlag, start, L
                    )
                Sx = S[L:]
                Bx = np.zeros((N, ny, n_out if with_blocks else 0))
                entering = block_inputs(m.output_blocks, outputs, ys)
                for k, ((j, b), x) in enumerate(zip(chain, entering, strict=True)):
                    Sx[:, j, :] = block_tangent(b, x, Sx[:, j, :])
                    if with_blocks:
                        Bx[:, j, :] = block_tangent(b, x, Bx[:, j, :])
                        if k in curve_at:  # d f / d c_i = x^i
                            Bx[:, j, curve_at[k] : curve_at[k] + 4] = np.vander(x, 4, True)
                linear.append((-Sx / scale[None, :, None]).reshape(N * ny, -1))
                block_cols.append((-Bx / scale[None, :, None]).reshape(N * ny, -1))
        out = np.zeros((r0.size, theta.size))
        out[:, :n_lin] = np.vstack(linear)
        fd = list(range(n_lin, theta.size))
        if with_blocks and exact_out:  # the output blocks' after the input blocks' (``_codec``)
            first = n_lin + n_in
            out[:, [first + q for q in exact_out]] = np.vstack(block_cols)[:, exact_out]
            fd = [p for p in fd if p - first not in exact_out]
        for p in fd:  # the other blocks' parameters: forward differences
            h = 1.4901161193847656e-08 * max(1.0, abs(float(theta[p])))
            step = theta.copy()
            step[p] += h
            out[:, p] = (run(step)[1] - r0) / h
        return np.where(np.isfinite(out), out, 0.0)

    return jac

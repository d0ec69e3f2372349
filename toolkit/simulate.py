"""Free-run simulation for every representation of the schema (prediction: :mod:`tendonkit.predict`).

Initial-state policy (``initial=``):

- ``"zero"``: every state and every pre-sample signal is zero;
- ``"model"``: the model's stored ``x0`` (zero when it has none);
- ``"estimate"`` (default when measured outputs are given): state space: least-squares fit of
  ``x0`` to the first ``max(10·n, 50)`` samples; ARX and sparse maps: the first samples of the
  measured outputs seed the recursion (the simulated output equals the measurement there),
  and an ARX's delayed inputs before the record are those of its steady state at the measured
  start where its equation gives it (:func:`_input_history`; otherwise every input before the
  record is its first sample);
- an array: the initial state itself (``state_space``, ``sparse_map``).

Input blocks are applied to the input sequence before the dynamics, output blocks to the
simulated outputs after them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from . import _kernel
from ._representations import section_gain
from ._response import (
    Initial,
    delay_taps,
    fractional_delay,
    split_delay,
    ss_response,
)
from ._simulate_arx import _arx_parts, _sim_arx, arx_max_lag
from .dataset import Dataset
from .errors import DataError, SimulationError
from .realize import fold_offsets
from .schema import ARX, Block, Model, SparseMap, StateSpace
from .terms import CompiledTerms, Term, series_getter

FloatArray = NDArray[np.float64]


def apply_block(
    block: Block, s: FloatArray, compiled: bool = True, before: float | None = None
) -> FloatArray:
    """Apply one block to a signal sequence ``s`` (n,) and return the new sequence.

    ``compiled=False`` runs the reference (pure numpy/Python) form of the play and rate-limit
    loops instead of the compiled kernel.  ``before``: a delay's signal before the first sample
    (default ``s[0]``).
    """
    p = block.params
    if block.kind == "delay":
        return fractional_delay(s, float(p["samples"]), before)
    if block.kind == "dead_zone":
        c, th = p["center"], p["threshold"]
        z = s - c
        return np.sign(z) * np.maximum(np.abs(z) - th, 0.0) + c
    if block.kind == "saturation":
        return np.clip(s, p["lower"], p["upper"])
    if block.kind == "play":
        if compiled and s.shape[0]:
            return np.asarray(
                _kernel.play_loop(np.ascontiguousarray(s, dtype=float), float(p["width"]), s[0])
            )
        return play_operator(s, p["width"])
    if block.kind == "first_order_lag":
        # lazy: heavy (scipy)
        from scipy.signal import lfilter

        a = p["pole"]
        out = lfilter([0.0, 1.0 - a], [1.0, -a], s - s[0]) + s[0]
        return np.asarray(out)
    if block.kind == "rate_limit":
        if compiled and s.shape[0]:
            return np.asarray(
                _kernel.rate_loop(np.ascontiguousarray(s, dtype=float), float(p["rate"]))
            )
        return rate_limiter(s, p["rate"])
    if block.kind == "polynomial":
        return np.asarray(curve_value(p, s))
    if block.kind == "second_order_section":
        # lazy: heavy (scipy)
        from scipy.signal import lfilter

        if not s.shape[0]:
            return s.astype(float)
        num, den = [1.0, p["b1"], p["b2"]], [1.0, p["a1"], p["a2"]]
        return np.asarray(lfilter(num, den, s - s[0]) + section_gain(p) * s[0])
    raise SimulationError(f"Unknown block kind {block.kind!r}.")  # pragma: no cover


def rate_limiter(s: FloatArray, rate: float) -> FloatArray:
    """Follow ``s`` with at most ``rate`` change per sample, starting at ``s[0]``."""
    out = np.empty_like(s, dtype=float)
    v = s[0]
    for k, x in enumerate(s):
        v += min(max(x - v, -rate), rate)
        out[k] = v
    return out


def unit_responses(A: FloatArray, C: FloatArray, signals: FloatArray) -> FloatArray:
    """Output responses to each signal entering each state: shape ``(N, ny, nx * n_signals)``.

    Column ``i * n_signals + c`` is the output ``y = C x`` of ``x⁺ = A x + e_i s_c[k]`` from
    rest: every signal of ``signals`` (N, n_signals) entering every state in turn — the
    regressors of an output-error least-squares fit with ``A`` and ``C`` fixed (the compiled
    :func:`tendonkit._kernel.unit_response_loop`).
    """
    return np.asarray(
        _kernel.unit_response_loop(
            np.ascontiguousarray(A, dtype=float),
            np.ascontiguousarray(C, dtype=float),
            np.ascontiguousarray(signals, dtype=float),
        )
    )


def play_operator(s: FloatArray, width: float, start: float | None = None) -> FloatArray:
    """Backlash (play) operator of half-width ``width``: output follows when pushed past the gap."""
    out = np.empty_like(s, dtype=float)
    v = s[0] if start is None else start
    lo, hi = -width, width
    for k, x in enumerate(s):
        if x - v > hi:
            v = x - hi
        elif x - v < lo:
            v = x - lo
        out[k] = v
    return out


def flat_terms(
    terms: Sequence[Term], first: Mapping[str, int], second: Mapping[str, int]
) -> _kernel.FlatTerms:
    """``terms`` as the flat per-factor arrays the compiled kernels read — and the C runtime
    of model FMUs: a signal named in ``first`` reads buffer 0 at that column, any other buffer
    1 at its column in ``second``."""
    return _kernel.flatten(terms, first, second)


def transform_inputs(data: Dataset, blocks: Sequence[Block]) -> Dataset:
    """Apply input blocks to every experiment's inputs (what a model with them sees)."""
    exps = []
    for e in data.experiments:
        u = e.u.copy()
        for b in blocks:
            j = data.inputs.index(b.signal)
            u[:, j] = apply_block(b, u[:, j])
        exps.append(dataclasses.replace(e, u=u))
    return data.with_experiments(exps)


def _apply_blocks(
    blocks: tuple[Block, ...],
    names: list[str],
    arr: FloatArray,
    compiled: bool = True,
    before: dict[int, float] | None = None,
) -> FloatArray:
    """``before``: a delayed signal's value before the record, per column (default: its
    first sample; :func:`input_history`)."""
    if not blocks:
        return arr
    out = arr.copy()
    held = before or {}
    for b in blocks:
        j = names.index(b.signal)
        out[:, j] = apply_block(b, out[:, j], compiled, held.get(j))
    return out


def _input_history(model: Model, rep: ARX, u: FloatArray, y: FloatArray) -> dict[int, float]:
    """Inputs before the record, for an ARX model whose inputs pass delay blocks.

    The first samples of a delayed input come from before the record, which the data do not
    hold.  Held at the first sample (``u[0]``), a plant started at rest with its input
    switched on at once is simulated with a step that never happened: on a dead time of 30
    samples the free run fitted 85.6 % where the same model written as an ARX with ``nk =
    30`` (which copies its first outputs) fitted 98.8 %, and diagnose named a false friction
    from that start.  The ARX's own history is the measured start held before the record
    (``y[0]``); the delayed inputs are chosen to agree with it — the steady state of the
    ARX, ``A(1) y[0] = offset + G(1) u + Σ c_t θ_t(y[0])`` (its terms of the outputs held at
    ``y[0]``), solved for the delayed inputs nearest ``u[0]`` (least squares), each within the
    range of its record.  Where that equation is not the model's steady state — an input
    passes another block (a dead zone, a filter), a term reads an input (a Hammerstein curve,
    a bilinear gain) or has a memory — the inputs stay held at ``u[0]``, as before.
    """
    nu = u.shape[1]
    delayed = sorted({model.input_names.index(b.signal) for b in model.input_blocks})
    if u.shape[0] == 0 or y.shape[0] == 0:
        return {}
    Acat, G, off = _arx_parts(model, rep)
    ny = y.shape[1]
    A1 = np.eye(ny) + (Acat.reshape(ny, -1, ny).sum(axis=1) if Acat.size else 0.0)
    G1 = np.sum(G, axis=0).reshape(ny, nu)
    u0 = u[0].astype(float)
    r = A1 @ y[0] - off - G1 @ u0
    if rep.terms and rep.term_coefficients is not None:
        inputs = set(model.input_names)
        ct = CompiledTerms(rep.terms)
        if any(t.signals & inputs for t in rep.terms) or ct.stateful:
            return {}
        outputs = list(model.output_names)
        at_rest = np.array([y[0, outputs.index(name)] for name, _ in ct.keys], dtype=float)
        theta = ct.evaluate(at_rest.reshape(len(ct.keys), 1))[:, 0]
        r = r - theta @ rep.term_coefficients
    GJ = G1[:, delayed]
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(GJ))) or not np.any(GJ):
        return {}
    delta = np.linalg.lstsq(GJ, r, rcond=1e-8)[0]
    lo, hi = u[:, delayed].min(axis=0), u[:, delayed].max(axis=0)
    pre = np.clip(u0[delayed] + delta, lo, hi)
    return {j: float(v) for j, v in zip(delayed, pre)}


def block_inputs(blocks: Sequence[Block], names: Sequence[str], s: FloatArray) -> list[FloatArray]:
    """The signal entering each of ``blocks`` (its own column of ``s`` (n, len(names)), the
    blocks before it applied in order): what a block's derivative or its undoing is taken at."""
    out = np.array(s, dtype=float)
    entering = []
    for b in blocks:
        j = list(names).index(b.signal)
        entering.append(out[:, j].copy())
        out[:, j] = apply_block(b, out[:, j])
    return entering


def curve_value(p: Mapping[str, float], s: Any) -> Any:
    """A ``polynomial`` block's curve ``c0 + c1 s + c2 s^2 + c3 s^3`` (scalar or array)."""
    return p["c0"] + s * (p["c1"] + s * (p["c2"] + s * p["c3"]))


def curve_slope(p: Mapping[str, float], s: Any) -> Any:
    """The curve's derivative ``c1 + 2 c2 s + 3 c3 s^2``."""
    return p["c1"] + s * (2.0 * p["c2"] + 3.0 * p["c3"] * s)


def curve_inverse(block: Block, y: FloatArray, iterations: int = 60) -> FloatArray:
    """The inner signal ``s`` that a ``polynomial`` block maps to ``y``, sample by sample.

    Levenberg–Marquardt on ``(f(s) - y)^2`` from ``s = y``, every step accepted only where it
    lowers the misfit: the solution of ``f(s) = y`` reached downhill from the identity where
    there are several, the curve's extremum where ``y`` lies beyond it.  The measured outputs
    of a Wiener model taken back to its inner signal, from which the representation's initial
    state is estimated.
    """
    p = {k: float(v) for k, v in block.params.items()}
    y = np.asarray(y, dtype=float)
    s = y.copy()
    r = curve_value(p, s) - y
    damping = np.full(s.shape, 1e-3 * max(p["c1"] ** 2 + p["c2"] ** 2 + p["c3"] ** 2, 1e-300))
    with np.errstate(over="ignore", invalid="ignore"):
        for _ in range(iterations):
            d = curve_slope(p, s)
            trial = s - r * d / (d * d + damping)
            r_trial = curve_value(p, trial) - y
            better = np.abs(r_trial) < np.abs(r)
            s = np.where(better, trial, s)
            r = np.where(better, r_trial, r)
            damping = np.where(better, damping * 0.1, damping * 10.0)
            if np.all(np.abs(r) <= 1e-13 * (np.abs(y) + 1.0)):
                break  # every sample on the curve (otherwise: on to the extremum)
    return np.asarray(s)


def inner_outputs(model: Model, y: FloatArray, samples: int | None = None) -> FloatArray:
    """Measured outputs taken back through the output blocks' static curves (the others as
    they are: a clip or a play leaves the signal it passes unchanged).

    ``samples``: only the first ones (those an initial state is estimated from); the rest are
    returned as measured.
    """
    out = np.array(y, dtype=float)
    names = model.output_names
    n = out.shape[0] if samples is None else min(samples, out.shape[0])
    for b in reversed(model.output_blocks):
        if b.kind == "polynomial":
            j = names.index(b.signal)
            out[:n, j] = curve_inverse(b, out[:n, j])
    return out


def read_whole(model: Model, n_samples: int, initial: str = "estimate") -> str | None:
    """Why ``model`` reproduces a record of ``n_samples`` from its own measured outputs, which
    would score 100 % with nothing left to score; None when it does not.

    An ARX started from the measured outputs copies its first lags (a simulation, and a
    prediction: ``initial="predict"``); a state space's initial state estimated from a record
    holding no more output values than it has states matches them exactly.
    """
    rep = model.representation
    if isinstance(rep, ARX) and initial in ("estimate", "predict"):
        lags = initial_span(model)
        if n_samples <= lags:
            return f"starts from the first {lags} measured samples of each record"
    elif isinstance(rep, StateSpace) and initial == "estimate":
        if n_samples * len(model.outputs) <= rep.n_states:
            return f"fits its {rep.n_states} initial states to each record's outputs"
    return None


def initial_span(model: Model, window: int | None = None) -> int:
    """How many leading output samples ``initial="estimate"`` reads (at most)."""
    rep = model.representation
    if isinstance(rep, StateSpace):
        return window or max(10 * rep.n_states, 50)
    if isinstance(rep, ARX):
        return arx_max_lag(rep, len(model.inputs))
    return max(window or 1, 1)


def _check_u(model: Model, u: Any, y: Any) -> tuple[FloatArray, FloatArray | None]:
    u = np.asarray(u, dtype=float)
    if u.ndim == 1 and len(model.inputs) == 1:
        u = u[:, None]
    problems = []
    if u.ndim != 2 or u.shape[1] != len(model.inputs):
        problems.append(
            f"inputs must have shape (n_samples, {len(model.inputs)}) for {model.input_names}; "
            f"found {u.shape}."
        )
    if y is not None:
        y = np.asarray(y, dtype=float)
        if y.ndim == 1 and len(model.outputs) == 1:
            y = y[:, None]
        if y.ndim != 2 or y.shape[1] != len(model.outputs) or y.shape[0] != u.shape[0]:
            problems.append(
                f"measured outputs must have shape ({u.shape[0]}, {len(model.outputs)}); "
                f"found {y.shape}."
            )
    if u.size and not np.all(np.isfinite(u)):
        problems.append("inputs contain NaN or infinite values.")
    if problems:
        raise DataError(f"Cannot simulate model {model.name!r}:", problems)
    return u, y


#: Default simulation engine of :func:`simulate`: ``"compiled"`` or ``"reference"``.
ENGINE = "compiled"


def simulate(
    model: Model,
    u: FloatArray,
    *,
    y: FloatArray | None = None,
    initial: Initial | None = None,
    engine: str | None = None,
    init_window: int | None = None,
) -> FloatArray:
    """Free-run simulation of ``model`` driven by inputs ``u`` (n, nu).

    Parameters
    ----------
    model : Model
        Any representation.
    u : array (n, nu)
        Inputs, columns in the order of ``model.inputs``.
    y : array (n, ny), optional
        Measured outputs, used only by ``initial="estimate"``.
    initial : {"zero", "model", "estimate"} or array, optional
        Initial-state policy (module docstring).  Default: ``"estimate"`` when ``y`` is given,
        otherwise ``"model"``.
    engine : {"compiled", "reference"}, optional
        ``"compiled"`` runs the per-sample loops in the numba kernel (:mod:`tendonkit._kernel`);
        ``"reference"`` runs the numpy implementation it is tested against (equal to 1e-12).
        Default: :data:`ENGINE` (``"compiled"``; benchmarks set it to time whole workflows
        such as ``diagnose`` on either).
    init_window : int, optional
        With ``initial="estimate"``: use at most the first ``init_window`` samples of ``y``
        (the benchmarks' official protocol: the initial state from an initialisation window,
        the score on the rest).  State space: the least-squares initial state from that
        window (default ``max(10 n, 50)`` samples); ARX: the measured outputs as history for
        at most that many samples (default: the model's lag); sparse maps use ``y[0]``.

    Returns
    -------
    array (n, ny)
        Simulated outputs.

    Examples
    --------
    >>> import numpy as np
    >>> from tendonkit.schema import Model, Signal, StateSpace
    >>> m = Model("m", 1.0, (Signal("u"),), (Signal("y"),),
    ...           StateSpace(np.array([[0.5]]), np.array([[1.0]]), np.array([[1.0]]), np.zeros((1, 1))))
    >>> simulate(m, np.ones((3, 1)))[:, 0].tolist()
    [0.0, 1.0, 1.5]
    """
    u, y = _check_u(model, u, y)
    if initial is None:
        initial = "estimate" if y is not None else "model"
    if isinstance(initial, str) and initial == "estimate" and y is None:
        raise DataError("initial='estimate' needs the measured outputs y.")
    if isinstance(initial, str) and initial not in ("zero", "model", "estimate"):
        raise DataError(
            f"initial must be 'zero', 'model', 'estimate' or an array, found {initial!r}."
        )
    engine = ENGINE if engine is None else engine
    if engine not in ("compiled", "reference"):
        raise DataError(f"engine must be 'compiled' or 'reference', found {engine!r}.")
    if init_window is not None and (
        isinstance(init_window, bool) or not isinstance(init_window, int) or init_window < 1
    ):
        raise DataError(f"init_window must be a positive number of samples, found {init_window!r}.")
    return _simulate_checked(model, u, y, initial, engine == "compiled", init_window)


def compiled_engine() -> bool:
    """Whether :data:`ENGINE` (read when called: benchmarks set it) is the compiled one."""
    return ENGINE == "compiled"


def input_history(
    model: Model, u: FloatArray, y: FloatArray | None, initial: Initial | None = "estimate"
) -> dict[int, float]:
    """The delayed inputs before the record that :func:`simulate` starts ``model`` from
    (:func:`_input_history`; empty unless an ARX with ``initial="estimate"``), by input
    index.  :func:`tendonkit.output_error.refine` holds them at its start model's."""
    if y is None or not _starts_delays(model, initial):
        return {}
    if any(b.kind == "polynomial" for b in model.output_blocks):
        y = inner_outputs(model, y, initial_span(model))
    return _history(model, np.asarray(u, dtype=float), np.asarray(y, dtype=float))


def _starts_delays(model: Model, initial: Initial | None) -> bool:
    """Whether :func:`_input_history` applies: an ARX started from its measured outputs whose
    input blocks are delays only (nothing else stands between them and its equation)."""
    blocks = model.input_blocks
    return (
        isinstance(model.representation, ARX)
        and isinstance(initial, str)
        and initial == "estimate"
        and bool(blocks)
        and all(b.kind == "delay" for b in blocks)
    )


def _history(model: Model, u: FloatArray, y: FloatArray) -> dict[int, float]:
    rep = model.representation
    assert isinstance(rep, ARX)
    with np.errstate(all="ignore"):
        return _input_history(model, rep, u, y)


def _simulate_checked(
    model: Model,
    u: FloatArray,
    y: FloatArray | None,
    initial: Initial,
    fast: bool,
    init_window: int | None,
    before: Mapping[int, float] | None = None,
) -> FloatArray:
    """:func:`simulate` after its checks; ``before``: the delayed inputs before the record
    (default: :func:`input_history`)."""
    if y is not None and any(b.kind == "polynomial" for b in model.output_blocks):
        y = inner_outputs(model, y, initial_span(model, init_window))
    rep = model.representation
    if before is None and y is not None and _starts_delays(model, initial):
        before = _history(model, u, y)  # y taken back through the curves above
    ub = _apply_blocks(model.input_blocks, model.input_names, u, fast, dict(before or {}))
    # A diverging simulation overflows on its way to NaN; that is reported through the NaN
    # outputs (and a fit of -inf), not through floating-point warnings.
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        if isinstance(rep, StateSpace) and rep.terms:
            ys = _sim_ss_terms(model, rep, ub, y, initial, fast, init_window)
        elif isinstance(rep, StateSpace):
            ys = _sim_ss(rep, ub, y, initial, init_window)
        elif isinstance(rep, ARX):
            ys = _sim_arx(model, rep, ub, y, initial, fast, init_window)
        else:
            ys = _sim_sparse(model, rep, ub, y, initial, fast)
    # Diverged (or an output curve overflowed): nothing from the first non-finite sample on is
    # meaningful, also after an output block (a play would otherwise hold its last finite value).
    bad = _first_non_finite(ys)
    ys[bad:] = np.nan
    with np.errstate(over="ignore", invalid="ignore"):
        out = _apply_blocks(model.output_blocks, model.output_names, ys, fast)
    out[min(bad, _first_non_finite(out)) :] = np.nan
    return out


def _first_non_finite(a: FloatArray) -> int:
    """Index of the first row of ``a`` with a non-finite entry (``len(a)`` if none)."""
    rows = ~np.all(np.isfinite(a), axis=1)
    return int(np.argmax(rows)) if rows.any() else a.shape[0]


def simulate_dataset(
    model: Model, data: Dataset, *, initial: Initial | None = "estimate"
) -> list[FloatArray]:
    """Simulate every experiment of ``data`` (inputs selected by the model's input names)."""
    data = aligned(model, data)
    return [simulate(model, e.u, y=e.y, initial=initial) for e in data.experiments]


#: Relative difference of sample times beyond which a model and data do not belong together.
DT_TOLERANCE = 0.01


def check_sample_time(model: Model, dt: float, what: str = "the data") -> None:
    """Raise :class:`DataError` unless ``dt`` is the model's sample time (within 1 %)."""
    if abs(float(dt) - model.dt) > DT_TOLERANCE * model.dt:
        raise DataError(
            f"Model {model.name!r} has sample time {model.dt:g} s but {what} are sampled at "
            f"{float(dt):g} s: a discrete-time model only holds at its own sample time "
            "(resample the data, or identify a model at this rate)."
        )


def check_units(model: Model, units: Mapping[str, str], what: str = "the data") -> None:
    """Raise :class:`DataError` listing every signal whose unit differs between model and data.

    A unit that either side does not know (``""``) is not checked: a CSV without units in its
    header (``q1 [rad]``) meets any model.
    """
    clash = [
        f"{s.name}: the model's is {s.unit!r}, {what} give {units[s.name]!r}"
        for s in (*model.inputs, *model.outputs)
        if s.unit and units.get(s.name) and units[s.name] != s.unit
    ]
    if clash:
        raise DataError(
            f"Model {model.name!r} and {what} disagree on units (convert the data, or fix the "
            "units in the CSV header):",
            clash,
        )


def divergence(y: FloatArray, reference: FloatArray, factor: float = 1e6) -> int | None:
    """First sample where a free run left ``factor`` × the reference's range, or None.

    A simulated output that turns non-finite or exceeds ``factor`` times the span of the
    measured (or expected) outputs around their mean has diverged: the model is unstable on
    these inputs, and numbers past that sample are meaningless.
    """
    ref = np.asarray(reference, dtype=float)
    y = np.asarray(y, dtype=float)
    finite = ref[np.isfinite(ref).all(axis=1)] if ref.ndim == 2 else ref[np.isfinite(ref)]
    if finite.size == 0:
        span, centre = np.ones(y.shape[1:]), np.zeros(y.shape[1:])
    else:
        span = np.maximum(np.ptp(finite, axis=0), np.abs(finite).max(axis=0))
        span = np.where(span > 0, span, 1.0)
        centre = finite.mean(axis=0)
    with np.errstate(invalid="ignore", over="ignore"):
        bad = ~np.isfinite(y) | (np.abs(y - centre) > factor * span)
    rows = bad.any(axis=1) if bad.ndim == 2 else bad
    return int(np.argmax(rows)) if rows.any() else None


def aligned(model: Model, data: Dataset) -> Dataset:
    """The dataset with the model's inputs and outputs in the model's order.

    Raises
    ------
    DataError
        A signal of the model is not in the data, the data are sampled at another rate than
        the model (more than :data:`DT_TOLERANCE` apart), or a signal's unit in the data is not
        the model's (:func:`check_units`): a model meeting data of another sample time or in
        other units gives a wrong answer, never an error of its own.
    """
    missing = [n for n in (*model.input_names, *model.output_names) if n not in data.columns]
    if missing:
        raise DataError(
            f"The data lack signals of model {model.name!r}: {', '.join(missing)}. "
            f"Columns: {', '.join(data.columns)}."
        )
    check_sample_time(model, data.dt)
    check_units(model, data.units)
    if (tuple(model.input_names), tuple(model.output_names)) == (data.inputs, data.outputs):
        return data
    return data.select(model.input_names, model.output_names)


# -- state space --------------------------------------------------------------------------------


def _ss_x0(
    rep: StateSpace,
    u: FloatArray,
    y: FloatArray | None,
    initial: Initial,
    model: Model | None = None,
    window: int | None = None,
) -> FloatArray:
    n = rep.n_states
    if isinstance(initial, np.ndarray) or not isinstance(initial, str):
        return np.asarray(initial, dtype=float).reshape(n)
    if initial == "zero":
        return np.zeros(n)
    if initial == "model":
        return np.zeros(n) if rep.x0 is None else rep.x0
    assert y is not None
    if rep.terms and rep.E is not None and model is not None:
        # Θ from the measured outputs acts as a known extra input for the initial-state fit,
        # which reads the first ``window`` samples only: Θ is causal (a lag repeats the first
        # sample, an operator with a memory runs from it), so it is evaluated on those alone.
        N = _x0_samples(n, u.shape[0], window)
        u, y = u[:N], y[:N]
        theta = ss_theta_measured(model, u, y)
        nt = rep.E.shape[1]
        lin = StateSpace(
            rep.A,
            np.hstack([rep.B, rep.E]),
            rep.C,
            np.hstack([rep.D, np.zeros((rep.C.shape[0], nt))]),
            u0=None if rep.u0 is None else np.concatenate([rep.u0, np.zeros(nt)]),
            y0=rep.y0,
        )
        return estimate_x0(lin, np.hstack([u, theta]), y, window)
    return estimate_x0(rep, u, y, window)


def _sim_ss(
    rep: StateSpace,
    u: FloatArray,
    y: FloatArray | None,
    initial: Initial,
    window: int | None = None,
) -> FloatArray:
    x0 = _ss_x0(rep, u, y, initial, window=window)
    if not rep.has_offsets:
        return ss_response(rep.A, rep.B, rep.C, rep.D, u, x0)
    du, y0 = _deviations(rep, u)
    return ss_response(rep.A, rep.B, rep.C, rep.D, du, x0) + y0


def _deviations(rep: StateSpace, u: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``u - u0`` and ``y0`` of a state-space model (zeros where the offset is unset)."""
    u0, y0 = rep.operating_point
    return u - u0, y0


def ss_theta_measured(model: Model, u: FloatArray, y: FloatArray) -> FloatArray:
    """The terms of a model evaluated on measured signals (series-parallel), shape (n, n_terms)."""
    rep = model.representation
    assert isinstance(rep, StateSpace | ARX)
    ct = CompiledTerms(rep.terms)
    sig = {
        **{n: u[:, j] for j, n in enumerate(model.input_names)},
        **{n: y[:, j] for j, n in enumerate(model.output_names)},
    }
    get = series_getter(sig)
    if not ct.keys:
        return np.ones((u.shape[0], ct.n_terms))
    return ct.evaluate(np.array([get(n, lag) for n, lag in ct.keys])).T


def _sim_ss_terms(
    model: Model,
    rep: StateSpace,
    u: FloatArray,
    y: FloatArray | None,
    initial: Initial,
    compiled: bool = True,
    window: int | None = None,
) -> FloatArray:
    """State space with nonlinear terms of past outputs: a loop over samples."""
    assert rep.E is not None
    x = _ss_x0(rep, u, y, initial, model, window).copy()
    if rep.has_offsets:  # the loop below steps raw signals: the offsets ride on a constant state
        rep = fold_offsets(rep)
        x = np.append(x, 1.0)
    assert rep.E is not None
    ct = CompiledTerms(rep.terms)
    N, ny, nu = u.shape[0], rep.C.shape[0], u.shape[1]
    L = max((t.max_lag for t in rep.terms), default=1)
    Y = np.zeros((N + L, ny))
    U = np.zeros((N + L, nu))
    U[L:] = u
    U[:L] = u[0] if N else 0.0
    hist = {
        **{n: U[:, j] for j, n in enumerate(model.input_names)},
        **{n: Y[:, j] for j, n in enumerate(model.output_names)},
    }
    if y is not None and isinstance(initial, str) and initial == "estimate":
        Y[:L] = y[0]
    if compiled:
        flat = _kernel.flatten(
            rep.terms,
            {n: j for j, n in enumerate(model.input_names)},
            {n: j for j, n in enumerate(model.output_names)},
        )
        c = np.ascontiguousarray
        _kernel.run_terms(
            _kernel.ss_terms_loop,
            U,
            Y,
            c(u, dtype=float),
            c(x, dtype=float),
            *(c(m, dtype=float) for m in (rep.A, rep.B, rep.C, rep.D, rep.E)),
            L,
            flat=flat,
        )
        return Y[L:]
    keys = ct.keys
    for k in range(N):
        kk = k + L
        Y[kk] = rep.C @ x + rep.D @ u[k]
        vals = np.array([hist[name][kk - lag] for name, lag in keys])
        x = rep.A @ x + rep.B @ u[k] + rep.E @ ct.evaluate(vals)
        if not np.all(np.isfinite(x)):
            Y[kk + 1 :] = np.nan
            break
    return Y[L:]


def _x0_samples(n: int, available: int, window: int | None) -> int:
    """How many samples :func:`estimate_x0` fits an ``n``-state initial state on."""
    return min(available, window or max(10 * n, 50))


def estimate_x0(
    rep: StateSpace, u: FloatArray, y: FloatArray, window: int | None = None
) -> FloatArray:
    """Least-squares initial state from the first ``window`` samples (default ``max(10 n, 50)``).

    A model with an operating point (``u0``, ``y0``) is fitted on the deviations from it.
    """
    n = rep.n_states
    N = _x0_samples(n, u.shape[0], window)
    du, y0 = _deviations(rep, u[:N])
    forced = ss_response(rep.A, rep.B, rep.C, rep.D, du, np.zeros(n)) + y0
    ny = rep.C.shape[0]
    obs = np.empty((N * ny, n))
    M = rep.C.copy()
    for k in range(N):
        obs[k * ny : (k + 1) * ny] = M
        M = M @ rep.A
    rhs = (y[:N] - forced).reshape(-1)
    if not (np.all(np.isfinite(obs)) and np.all(np.isfinite(rhs))):
        return np.zeros(n)  # an unstable model's free response overflows: nothing to fit
    x0, *_ = np.linalg.lstsq(obs, rhs, rcond=None)
    return np.asarray(x0)


# -- sparse map -----------------------------------------------------------------------------------


def sparse_map_recursion(
    terms: Sequence[Term],
    coefficients: FloatArray,
    U: FloatArray,
    X: FloatArray,
    start: int,
    inputs: Sequence[str],
    states: Sequence[str],
) -> None:
    """Run ``x[k+1] = Ξᵀ Θ(k)`` in the compiled kernel, in place, from row ``start`` on.

    The building block of sparse-map simulation for callers that hold their own histories
    (the nonlinear MPC's rollout): ``U`` and ``X`` are buffers of equal length whose rows
    before and at ``start`` are given (``Θ(k)`` reads ``U[k - lag]`` and ``X[k - lag]``);
    rows ``start + 1`` to the end of ``X`` are written, NaN from the first that is not
    finite.

    Parameters
    ----------
    terms : sequence of Term
        Θ over ``inputs`` and ``states`` (an input name wins over a state of that name).
    coefficients : ndarray
        Ξ, ``(len(terms), len(states))``.
    U, X : ndarray
        ``(n, len(inputs))`` and ``(n, len(states))``; ``X`` is written.
    start : int
        The first row whose successor is computed; rows ``0..start`` must cover every lag.
    inputs, states : sequence of str
        Column names of ``U`` and ``X``.
    """
    flat = _kernel.flatten(
        terms, {n: j for j, n in enumerate(inputs)}, {n: j for j, n in enumerate(states)}
    )
    _kernel.run_terms(
        _kernel.sparse_loop,
        np.ascontiguousarray(U, dtype=float),
        X,
        np.ascontiguousarray(coefficients, dtype=float),
        start,
        flat=flat,
    )


def _sim_sparse(
    model: Model,
    rep: SparseMap,
    u: FloatArray,
    y: FloatArray | None,
    initial: Initial,
    compiled: bool = True,
) -> FloatArray:
    nx = rep.n_states
    N = u.shape[0]
    ct = CompiledTerms(rep.terms)
    L = max((t.max_lag for t in rep.terms), default=0) + 1
    X = np.zeros((N + L, nx))
    U = np.zeros((N + L, len(model.inputs)))
    U[L:] = u
    U[:L] = u[0] if N else 0.0
    if isinstance(initial, str):
        if initial == "zero":
            x0 = np.zeros(nx)
        elif initial == "model":
            x0 = np.zeros(nx) if rep.x0 is None else rep.x0.copy()
        else:
            assert y is not None
            x0 = np.zeros(nx) if rep.x0 is None else rep.x0.copy()
            x0[list(rep.output_states)] = y[0]
    else:
        x0 = np.asarray(initial, dtype=float).reshape(nx)
    X[: L + 1] = x0
    hist: dict[str, FloatArray] = {}
    for j, s in enumerate(model.states):
        hist[s.name] = X[:, j]
    for j, name in enumerate(model.input_names):
        hist[name] = U[:, j]
    coef = rep.coefficients
    if compiled:
        flat = _kernel.flatten(
            rep.terms,
            {n: j for j, n in enumerate(model.input_names)},
            {s.name: j for j, s in enumerate(model.states)},
        )
        _kernel.run_terms(
            _kernel.sparse_loop, U, X, np.ascontiguousarray(coef, dtype=float), L, flat=flat
        )
        return X[L:, list(rep.output_states)]
    keys = ct.keys
    for k in range(N - 1):
        kk = k + L
        vals = np.array([hist[name][kk - lag] for name, lag in keys])
        X[kk + 1] = ct.evaluate(vals) @ coef
        if not np.all(np.isfinite(X[kk + 1])):
            X[kk + 1 :] = np.nan
            break
    return X[L:, list(rep.output_states)]


__all__ = [
    "DT_TOLERANCE",
    "ENGINE",
    "aligned",
    "apply_block",
    "arx_max_lag",
    "check_sample_time",
    "check_units",
    "delay_taps",
    "divergence",
    "estimate_x0",
    "fractional_delay",
    "play_operator",
    "rate_limiter",
    "read_whole",
    "simulate",
    "simulate_dataset",
    "sparse_map_recursion",
    "split_delay",
    "ss_response",
    "ss_theta_measured",
    "transform_inputs",
    "unit_responses",
]

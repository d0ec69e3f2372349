"""The clip detector: is a signal piled up at its extreme value because something clipped it?

:func:`atom_test` is the direct test of the ``saturation`` effect's signature on validation data
(docs/diagnose.md, "Direct evidence: a clipped output"): a clip makes the signal sit at exactly
one level far more often than a peak, a rest or dwelling would, arriving there at speed while the
inputs and the baseline's simulation keep moving.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class AtomTest:
    """Test that a signal piles up at a level at the end of its range (a clip).

    Attributes
    ----------
    p_value : float
        ``P(X >= count / run)`` for ``X ~ Poisson(expected / run)``; 1 when the level is not
        a candidate clip (a sample past it, no interior to compare with, a rest).
    count : int
        Samples at the level (within the tolerance).
    expected : float
        The most samples the level could hold without a clip (see :func:`atom_test`).
    run : float
        Typical length of a run of repeated values inside the range (1 for a noisy signal).
    beyond : int
        Samples past the level (a clip allows none).
    level : float
        The level tested.
    side : str
        ``"upper"`` or ``"lower"``.
    motion : float or None
        Standard deviation of the reference (the model's output without a clip) over the
        samples at the level, relative to its standard deviation over the record (None
        without a reference).
    past : float or None
        Share of the samples at the level where the reference lies past it (None without a
        reference).
    input_motion : float or None
        The same as ``motion`` for the inputs (the largest over them; None without inputs).
    arrival : float or None
        Median speed ``|y[k-1] - y[k-2]|`` at which the signal arrives at the level (``k``
        the first sample of a run there), relative to the median of the non-zero ``|Δy|``.
    reason : str
        Why the p-value is 1 without a test, else ``""``.
    """

    p_value: float
    count: int
    expected: float
    run: float
    beyond: int
    level: float
    side: str
    motion: float | None = None
    past: float | None = None
    input_motion: float | None = None
    arrival: float | None = None
    reason: str = ""

    def to_dict(self) -> dict[str, float | int | str | None]:
        """Plain data."""
        return dataclasses.asdict(self)


#: The reference and the inputs must move at the level (:func:`atom_test`): their standard
#: deviation over the samples there, relative to the record's.
MIN_MOTION = 0.25
#: The reference tells a clip from a rest only if it fits the signal at least this well
#: (percent): a poor model drifts where it is wrong.
MIN_JUDGE_FIT = 50.0
#: The signal must arrive at the level moving (:func:`atom_test`): the median speed of its
#: arrivals relative to its median non-zero step.
MIN_ARRIVAL = 0.5


def _runs(same: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """``(start, stop)`` of the runs of True in ``same``."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], same.astype(np.int8), [0]])))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist()))


def atom_test(
    y: FloatArray,
    level: float,
    side: str,
    *,
    reference: FloatArray | None = None,
    reference_fit: float | None = None,
    u: FloatArray | None = None,
    window: float = 0.01,
) -> AtomTest:
    """Is ``level`` an atom at the end of ``y``'s range, more samples than no clip puts there?

    A clipped signal stays at its limit while the signal behind it would have gone past it.
    The null hypothesis is "no clip", and three things other than a clip repeat a value:

    - **a peak.** A peak ``y ≈ c - a t^(2m)`` puts ``N(d) ∝ d^(1/2m)`` samples within ``d`` of
      its top.  The bound takes ``m = 2`` (peaks flat to fourth order, such as a flattened
      periodic wave): a bin of width ``h`` at the top holds ``N_w r / (1 - r)``,
      ``r = (h / w)^(1/4)``, if ``N_w`` samples lie in the rest of a window ``w`` below it;
    - **a held level** (a quantised or noise-free signal at rest) anywhere in the range: the
      level may hold as many samples as the busiest value inside the range (not at either end,
      which may be clipped too);
    - **dwelling**: where repeated values come in runs (a quantised signal that moves slowly),
      samples are not independent.  Counts are divided by the typical run length inside the
      range (``Σ L² / Σ L`` over the runs of equal consecutive values; 1 for a noisy signal),
      and the test is a Poisson tail of ``count / run`` at mean ``expected / run``, where
      ``expected`` is the larger of the two bounds above and 1.

    A rest at the top of the range — a step test held longest at its highest level — is not a
    clip either, and only a model of the output tells it apart: with ``reference``, what the
    output would do without a clip (the baseline's free-run simulation: it responds to the
    inputs that matter, with their delays), must go past the level on at least half of the
    samples there or move while the output stays (its standard deviation over the samples at
    the level at least :data:`MIN_MOTION` of its standard deviation over the record); and it
    is a judge only if it fits the signal by at least :data:`MIN_JUDGE_FIT` (``reference_fit``):
    a poor model drifts where it is wrong (a stuck drive at its end positions).  The inputs ``u``
    must move too (the largest of them, by :data:`MIN_MOTION`): a model alone can drift, the
    inputs alone move where the output lags them or does not depend on them.  A clip reached
    at rest is therefore not detected.  Without a model, the way the signal arrives tells most
    rests from clips: a clip cuts a moving signal, a system settles into a rest with a speed
    that vanishes.  The median speed one step before each arrival must be at least
    :data:`MIN_ARRIVAL` of the signal's median non-zero step.  The p-value is also 1 when a
    sample lies past the level or fewer than 10 samples lie inside the range.

    Parameters
    ----------
    y : array (n,)
        The signal.
    level : float
        The level (the clip's value).
    side : {"upper", "lower"}
        Which end of the range.
    reference : array (n,), optional
        What the output would be without a clip, at the same samples.
    reference_fit : float, optional
        The reference's fit to the signal (percent).
    u : array (n, m), optional
        The inputs at the same samples.
    window : float
        ``w`` as a fraction of the signal's range.

    Returns
    -------
    AtomTest
    """
    # lazy: heavy (scipy)
    from scipy import stats

    if side not in ("upper", "lower"):
        raise ValueError(f"side must be 'upper' or 'lower', found {side!r}")
    v = np.asarray(y, dtype=float)
    ok = np.isfinite(v)
    ref = None if reference is None else np.asarray(reference, dtype=float).reshape(-1)
    v = v[ok]
    c = float(level)
    if side == "lower":
        v, c = -v, -c
    span = float(np.ptp(v)) if v.size else 0.0

    def untested(
        count: int,
        beyond: int,
        reason: str,
        motion: float | None = None,
        inp: float | None = None,
        arrival: float | None = None,
        past: float | None = None,
    ) -> AtomTest:
        return AtomTest(
            1.0,
            count,
            float(count),
            1.0,
            beyond,
            float(level),
            side,
            motion,
            past,
            inp,
            arrival,
            reason,
        )

    if span == 0:
        return untested(int(v.size), 0, "the signal is constant")
    tol = 1e-6 * span
    at = np.abs(v - c) <= tol
    count = int(np.sum(at))
    beyond = int(np.sum(v > c + tol))
    if beyond or count == 0:
        return untested(count, beyond, "samples lie past the level" if beyond else "no sample")
    inside = ~at & (v > float(np.min(v)) + tol)
    if int(np.sum(inside)) < 10:
        return untested(count, beyond, "fewer than 10 samples inside the range")
    steps = np.abs(np.diff(v))
    typical = float(np.median(steps[steps > tol])) if np.any(steps > tol) else 0.0
    starts = np.flatnonzero(at[2:] & ~at[1:-1]) + 2
    arrival = float(np.median(steps[starts - 2]) / typical) if starts.size and typical > 0 else 0.0
    if arrival < MIN_ARRIVAL:
        return untested(
            count, beyond, "the signal settles there (a rest, not a clip)", arrival=arrival
        )
    motion = past = None
    if ref is not None:
        if len(ref) != len(ok):
            raise ValueError(f"reference has {len(ref)} samples, the signal {len(ok)}")
        r_ok = ref[ok] if side == "upper" else -ref[ok]
        sd = float(np.std(r_ok[np.isfinite(r_ok)])) if np.any(np.isfinite(r_ok)) else 0.0
        at_ref = r_ok[at]
        finite = bool(np.all(np.isfinite(at_ref)))
        motion = float(np.std(at_ref) / sd) if sd > 0 and count > 1 and finite else 0.0
        past = float(np.mean(at_ref > c)) if finite else 0.0
        if reference_fit is not None and not reference_fit >= MIN_JUDGE_FIT:
            why = f"the model fits {reference_fit:.0f} %: too poor to tell a clip from a rest"
            return untested(count, beyond, why, motion, arrival=arrival, past=past)
        if past < 0.5 and motion < MIN_MOTION:
            why = "the model rests there too (not a clip)"
            return untested(count, beyond, why, motion, arrival=arrival, past=past)
    input_motion = None
    if u is not None:
        inputs = np.asarray(u, dtype=float).reshape(len(ok), -1)[ok]
        sd_u = np.std(inputs, axis=0)
        live = sd_u > 0
        input_motion = (
            float(np.max(np.std(inputs[at][:, live], axis=0) / sd_u[live]))
            if np.any(live) and count > 1
            else 0.0
        )
        if input_motion < MIN_MOTION:
            return untested(
                count,
                beyond,
                "the inputs rest there too (not a clip)",
                motion,
                input_motion,
                arrival,
                past,
            )
    values, counts = np.unique(v[inside], return_counts=True)
    busiest = float(counts.max())
    gaps = np.diff(values)
    gaps = gaps[gaps > tol]
    h = max(2.0 * tol, float(np.min(gaps)) if gaps.size else 0.0)
    w = max(window * span, 16.0 * h)
    n_w = float(np.sum((v < c - tol) & (v > c - w)))
    r = (h / w) ** 0.25
    expected = max(1.0, n_w * r / (1.0 - r), busiest)
    # Runs of equal consecutive values inside the range (a run ends at either end level).
    same = np.zeros(len(v), dtype=bool)
    same[1:] = (np.abs(np.diff(v)) <= tol) & inside[1:] & inside[:-1]
    lengths = np.array([b - a + 1 for a, b in _runs(same)], dtype=float)
    singles = float(np.sum(inside)) - float(lengths.sum())
    run = float((np.sum(lengths**2) + singles) / (lengths.sum() + singles))
    p = float(stats.poisson.sf(math.ceil(count / run) - 1, expected / run))
    return AtomTest(
        p, count, expected, run, beyond, float(level), side, motion, past, input_motion, arrival
    )

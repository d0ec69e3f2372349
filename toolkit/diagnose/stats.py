"""Statistics of model comparison: is one model's validation loss really lower than another's?

Used by :func:`tendonkit.diagnose.diagnose` (the reasoning and the calibration are in
``docs/diagnose.md``): :func:`loss_test` compares per-sample losses over contiguous batches
sized by the :func:`autocorrelation_time` of their difference, and :func:`holm` adjusts the
p-values of several such tests (optionally weighted).  :func:`atom_test` is a direct test of
one signature, a signal piled up at its extreme value (a clip).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class LossTest:
    """One-sided test that an alternative model's validation loss is lower than a reference's.

    Attributes
    ----------
    p_value : float
        One-sided p-value of ``H0: E[log((1 - margin) L_ref,b / L_alt,b)] <= 0`` over batches b.
    log_ratio : float
        Mean over batches of ``log(L_ref,b / L_alt,b)`` (0 = no change; 0.1 ≈ 10 % less
        error energy in a typical batch).
    std_error : float
        Its standard error from the batches.
    n_batches, batch_length : int
        The batches.
    tau : float
        Integrated autocorrelation time of the loss difference, in samples.
    """

    p_value: float
    log_ratio: float
    std_error: float
    n_batches: int
    batch_length: int
    tau: float

    def to_dict(self) -> dict[str, float]:
        """Plain data."""
        return dataclasses.asdict(self)


def autocorrelation_time(d: FloatArray, c: float = 5.0) -> float:
    """Integrated autocorrelation time ``1 + 2 Σ ρ_k`` with Sokal's automatic window.

    The sum runs to the smallest lag ``M >= c·τ(M)``; white noise gives 1, an AR(1) process
    with coefficient ``a`` gives about ``(1 + a) / (1 - a)``.
    """
    d = np.asarray(d, dtype=float) - np.mean(d)
    n = len(d)
    if n < 4:
        return 1.0
    f = np.fft.rfft(d, 2 * n)
    ac = np.fft.irfft(f * np.conj(f))[:n]
    if ac[0] <= 0:
        return 1.0
    rho = ac / ac[0]
    tau = 1.0
    for m in range(1, n // 2):
        tau += 2.0 * rho[m]
        if m >= c * tau:
            break
    return float(max(tau, 1.0))


def loss_test(
    reference: FloatArray,
    alternative: FloatArray,
    *,
    margin: float = 0.0,
    k: float = 4.0,
    min_batches: int = 5,
    max_batches: int = 50,
) -> LossTest:
    """Test that ``alternative`` has lower loss than ``reference`` by more than ``margin``.

    Both are per-sample losses on the same validation samples.  Simulation errors are
    strongly autocorrelated and their size changes along a record by orders of magnitude
    (a large circle against a small one), so the test works on contiguous batches:

    1. the batch length is ``k`` integrated autocorrelation times of the loss difference
       (:func:`autocorrelation_time`), so that batch statistics are nearly independent; the
       number of batches is clamped to ``[min_batches, max_batches]``;
    2. per batch, ``r_b = log((1 - margin)·mean(reference_b)) - log(mean(alternative_b))``,
       the log of the batch's error-energy ratio: scale-free, so a batch of large motion does
       not outweigh every other batch;
    3. a one-sided t-test of ``mean(r_b) > 0`` with ``n_batches - 1`` degrees of freedom.

    The null hypothesis is "the alternative does not remove more than ``margin`` of the
    reference's error energy in a typical stretch of the record".  Pure noise and an
    extension without structure give symmetric ``r_b`` around ``log(1 - margin) <= 0``.

    Parameters
    ----------
    reference, alternative : array (n,)
        Per-sample losses (non-negative).
    margin : float
        Smallest relative reduction of the error energy that counts, in [0, 1).
    k : float
        Batch length in autocorrelation times.
    min_batches, max_batches : int
        Range of the number of batches.

    Returns
    -------
    LossTest
    """
    from scipy import stats

    ref = np.asarray(reference, dtype=float)
    alt = np.asarray(alternative, dtype=float)
    n = len(ref)
    if n < 2 * min_batches or not (np.all(np.isfinite(ref)) and np.all(np.isfinite(alt))):
        return LossTest(1.0, float("nan"), float("nan"), 0, 0, float("nan"))
    with np.errstate(over="ignore", invalid="ignore"):
        tau = autocorrelation_time(ref - alt)
    if not math.isfinite(tau):
        return LossTest(1.0, float("nan"), float("nan"), 0, 0, float("nan"))
    length = math.ceil(k * tau)
    b = int(np.clip(n // max(length, 1), min_batches, max_batches))
    tiny = 1e-12 * max(float(np.mean(ref)), float(np.mean(alt)), 1e-300)
    mr = np.array([c.mean() for c in np.array_split(ref, b)]) + tiny
    ma = np.array([c.mean() for c in np.array_split(alt, b)]) + tiny
    r = np.log(mr / ma)
    mean = float(r.mean())
    se = float(r.std(ddof=1)) / math.sqrt(b)
    shifted = mean + math.log(1.0 - margin)
    if se == 0:
        p = 0.0 if shifted > 0 else 1.0
    else:
        p = float(stats.t.sf(shifted / se, df=b - 1))
    return LossTest(p, mean, se, b, n // b, tau)


def holm(p_values: Sequence[float], weights: Sequence[float] | None = None) -> list[float]:
    """Holm–Bonferroni adjusted p-values, optionally weighted (Holm 1979).

    With weights ``w_i`` (non-negative, normalised here) hypothesis ``i`` is tested at
    ``α·w_i / Σ_{remaining} w``; equal weights give the ordinary Holm procedure.  A zero
    weight never rejects.  The family-wise error rate stays at ``α`` for any weights fixed
    before the p-values are seen.
    """
    m = len(p_values)
    if m == 0:
        return []
    w = np.ones(m) if weights is None else np.clip(np.asarray(weights, dtype=float), 0.0, None)
    if not np.any(w > 0):
        w = np.ones(m)
    w = w / w.sum()
    ratio = [p_values[i] / w[i] if w[i] > 0 else math.inf for i in range(m)]
    order = sorted(range(m), key=lambda i: ratio[i])
    out = [1.0] * m
    running = 0.0
    remaining = 1.0
    for i in order:
        running = max(running, 1.0 if math.isinf(ratio[i]) else min(1.0, remaining * ratio[i]))
        out[i] = running
        remaining -= w[i]
    return out


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

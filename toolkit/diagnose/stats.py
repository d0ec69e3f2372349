"""Statistics of model comparison: is one model's validation loss really lower than another's?

Used by :func:`tendonkit.diagnose.diagnose` (the reasoning and the calibration are in
``docs/diagnose.md``): :func:`loss_test` compares per-sample losses over batches (every window)
sized by the :func:`autocorrelation_time` of their difference, and :func:`holm` adjusts the
p-values of several such tests (optionally weighted).   The direct test of a clipped
signal is :mod:`tendonkit.diagnose.clip`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


#: Batch length of :func:`loss_test`, in integrated autocorrelation times.
BATCH_TAUS = 4.0
#: Most batches :func:`loss_test` cuts a record into.
MAX_BATCHES = 50


@dataclass(frozen=True)
class LossTest:
    """One-sided test that an alternative model's validation loss is lower than a reference's.

    Attributes
    ----------
    p_value : float
        One-sided p-value of ``H0: E[log((1 - margin) L_ref,b / L_alt,b)] <= 0`` over batches b.
    log_ratio : float
        Mean over every window of the batch length (overlapping) of ``log(L_ref,b /
        L_alt,b)`` (0 = no change; 0.1 ≈ 10 % less error energy in a typical batch).
    std_error : float
        Its standard error (overlapping batch means).
    n_batches, batch_length : int
        The batches the record is cut into: ``batch_length`` is the windows' length; there
        are ``n - batch_length + 1`` windows, and the degrees of freedom are
        :func:`obm_dof`'s.
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
    k: float = BATCH_TAUS,
    min_batches: int = 5,
    max_batches: int = MAX_BATCHES,
) -> LossTest:
    """Test that ``alternative`` has lower loss than ``reference`` by more than ``margin``.

    Both are per-sample losses on the same validation samples.  Simulation errors are
    strongly autocorrelated and their size changes along a record by orders of magnitude
    (a large circle against a small one), so the test works on contiguous batches:

    1. the batch length is ``k`` integrated autocorrelation times of the loss difference
       (:func:`autocorrelation_time`), so that batch statistics are nearly independent; the
       number of batches ``b`` is clamped to ``[min_batches, max_batches]``;
    2. per batch, ``r_b = log((1 - margin)·mean(reference_b)) - log(mean(alternative_b))``,
       the log of the batch's error-energy ratio: scale-free, so a batch of large motion does
       not outweigh every other batch — for every window of the batch length, overlapping
       (overlapping batch means, Meketon & Schmeiser 1984);
    3. a one-sided t-test of ``mean(r_b) > 0`` with the overlapping-batch-means variance and
       its :func:`obm_dof` degrees of freedom (``1.5 (b - 1)``, with ``b`` no more than the
       batches of ``k`` τ the record holds).

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
    # lazy: heavy (scipy)
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
    size = n // b
    tiny = 1e-12 * max(float(np.mean(ref)), float(np.mean(alt)), 1e-300)
    # every window of the batch length, overlapping (Meketon & Schmeiser 1984)
    mr = _window_means(ref, size) + tiny
    ma = _window_means(alt, size) + tiny
    r = np.log(mr / ma)
    mean = float(r.mean())
    # Var(mean) ≈ size · Σ (r_j - mean)² / ((n - size + 1)(n - size)), the OBM estimator of
    # the variance of a plain mean over the n samples; the mean of the windows counts the
    # record's first and last samples less (weights w_i ∝ the windows holding sample i), so
    # its variance is n · Σ w_i² times that (1.14 at five batches)
    m = len(r)
    i = np.arange(n)
    held = np.minimum.reduce([i + 1, np.full(n, size), n - i, np.full(n, m)]).astype(float)
    w = held / held.sum()
    obm = size * float(np.sum((r - mean) ** 2)) / (m * (n - size))
    se = math.sqrt(obm * n * float(np.sum(w**2)))
    shifted = mean + math.log(1.0 - margin)
    if se == 0:
        p = 0.0 if shifted > 0 else 1.0
    else:
        p = float(stats.t.sf(shifted / se, df=obm_dof(n, size, k * tau)))
    return LossTest(p, mean, se, b, size, tau)


def obm_dof(n: int, size: int, batch_span: float) -> float:
    """Degrees of freedom of the overlapping-batch-means variance: ``1.5 (b - 1)``
    (Meketon & Schmeiser 1984; Welch 1987), half as many again as the same record cut into
    ``b`` non-overlapping batches — with ``b`` the number of batches of length
    ``batch_span`` (``k`` autocorrelation times) the record holds, where it holds fewer than
    the clamp's minimum: batches made shorter than that are not independent, and counting
    them overstated the evidence (the null's rejection rate at α = 1 % rose to 3.5–5.5 % on
    records of 1–5 τ, 16.5 % on one shorter than 4 τ). At least one."""
    return max(1.0, 1.5 * (min(n / size, n / max(batch_span, 1.0)) - 1.0))


def _window_means(x: FloatArray, size: int) -> FloatArray:
    """Means of every window of ``size`` consecutive samples (``len(x) - size + 1`` of them).

    From prefix and suffix sums within blocks of ``size``: a window is the end of one block
    plus the start of the next, so no sum is subtracted from another — a running sum minus
    an earlier one loses every loss below its rounding step once a diverged stretch (10¹² a
    sample) has passed.
    """
    n = len(x)
    nb = n // size + 1
    blocks = np.pad(np.asarray(x, dtype=float), (0, nb * size - n)).reshape(nb, size)
    starts = blocks.cumsum(axis=1)  # sum of the first j + 1 samples of each block
    ends = blocks[:, ::-1].cumsum(axis=1)[:, ::-1]  # sum of samples j.. of each block
    # window starting at sample j of block b: ends[b, j] + starts[b + 1, j - 1]
    head = np.hstack([np.zeros((nb - 1, 1)), starts[1:, :-1]])
    return np.asarray((ends[:-1] + head).ravel()[: n - size + 1] / size, dtype=float)


def routes_p_value(
    reference: Sequence[FloatArray | None],
    alternative: Sequence[FloatArray | None],
    *,
    margin: float = 0.0,
) -> float:
    """One-sided p-value that ``alternative`` is better, over several routes of evidence.

    Each route is a pair of per-sample losses on the same samples (the free-run simulation,
    a prediction); a route missing on either side (None) is skipped.  The routes'
    :func:`loss_test` p-values are combined by Bonferroni, ``k · min(p)``, which keeps the
    level whatever their dependence.
    """
    ps = [
        loss_test(r, a, margin=margin).p_value
        for r, a in zip(reference, alternative)
        if r is not None and a is not None
    ]
    return min(1.0, len(ps) * min(ps)) if ps else 1.0


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

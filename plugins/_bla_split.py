"""The first filter of a Wiener–Hammerstein structure, from a split of a linear model's dynamics.

A Wiener–Hammerstein system ``y = G2(f(G1(u)))`` has a best linear approximation (BLA) whose
poles and zeros are those of ``G1`` and ``G2`` together (Schoukens et al.).  Which belong to
the first filter is not in the linear model: every split of its poles and zeros is a
candidate, and the data decide.  For each split ``(G1, G2)`` the inner signal ``x = G1 u`` is
formed, and ``y ≈ Σ_i c_i G2(x^i)`` (``i`` = 0…3) is fitted by least squares — linear in the
``c_i`` with ``G1`` and ``G2`` fixed, a free-run simulation (no output is fed back), so its
residual is the split's simulation error.  The split with the smallest error gives ``G1`` as
``second_order_section`` blocks (the brute-force scan of Sjöberg, Lauwers & Schoukens,
"Identification of Wiener–Hammerstein models: two algorithms based on the best split of a
linear model applied to the SYSID'09 benchmark problem", Control Engineering Practice 20,
2012; the refinement by simulation error that follows every named extension then moves the
filter freely).

Only a *linear* model is split, because only a linear model is a best linear approximation:
after a cause is named (a later step of a diagnosis), the model's linear part is the rest of a
nonlinear model, not the BLA, and its poles and zeros are not the two filters'.  Single-input
single-output ARX models only.
"""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tendonkit.dataset import Dataset
from tendonkit.schema import ARX, Block, Model
from tendonkit.simulate import transform_inputs

FloatArray = NDArray[np.float64]

#: Largest number of pole groups (a real pole or a complex pair) in the first filter.
MAX_GROUPS = 2
#: Zeros farther from the origin than this stay in the second filter (a zero far outside the
#: unit circle is a small leading coefficient of the ARX numerator, a near-delay).
MAX_ZERO_RADIUS = 1.5
#: Degree of the curve with which every split is scored.
SPLIT_DEGREE = 3


def _groups(roots: Any) -> list[list[complex]]:
    """Roots grouped into real roots and conjugate pairs."""
    out: list[list[complex]] = []
    left = list(np.asarray(roots, dtype=complex))
    while left:
        r = left.pop(0)
        if abs(r.imag) <= 1e-9 * max(1.0, abs(r)) or not left:
            out.append([complex(r.real, 0.0)])
            continue
        k = int(np.argmin([abs(x - np.conj(r)) for x in left]))
        out.append([r, left.pop(k)])
    return out


def arx_polynomials(rep: ARX) -> tuple[FloatArray, FloatArray, int] | None:
    """``(a, b, nk)`` of a SISO ARX: ``a = [1, a1 …]``, ``b = [b1 …]`` read at lag ``nk``."""
    if rep.A and np.shape(rep.A[0]) != (1, 1):
        return None
    if not rep.B or np.shape(rep.B[0]) != (1, 1) or len(rep.nk) != 1:
        return None
    a = np.concatenate([[1.0], [float(x[0, 0]) for x in rep.A]])
    b = np.array([float(x[0, 0]) for x in rep.B])
    return a, b, int(rep.nk[0])


def _poly(roots: list[complex]) -> FloatArray:
    return np.real(np.poly(roots)) if roots else np.ones(1)


def sections(zeros: list[complex], poles: list[complex], signal: str) -> list[Block]:
    """``G1 = Π(q - z) / Π(q - p)`` as monic ``second_order_section`` blocks (its gain dropped:
    the curve after it carries it)."""
    # lazy: heavy (scipy)
    from scipy.signal import zpk2sos

    sos = zpk2sos(np.asarray(zeros, complex), np.asarray(poles, complex), 1.0)
    out = []
    for b0, b1, b2, _a0, a1, a2 in sos:  # zpk2sos pads missing zeros at the origin: b0 = 1
        params = {"b1": b1 / b0, "b2": b2 / b0, "a1": a1, "a2": a2}
        out.append(Block("second_order_section", signal, {k: float(v) for k, v in params.items()}))
    return out


def best_split(model: Model, data: Dataset) -> tuple[list[Block], dict[str, Any]] | None:
    """The first filter of the split of ``model``'s dynamics that best explains ``data``.

    Returns the filter's sections (on the model's one input) and a record of the choice, or
    None where the model is not a linear SISO ARX with stable poles to split.
    """
    # lazy: heavy (scipy)
    from scipy.signal import lfilter

    rep = model.representation
    if not isinstance(rep, ARX) or len(model.inputs) != 1 or len(model.outputs) != 1:
        return None
    if not model.is_linear:
        return None
    polys = arx_polynomials(rep)
    if polys is None:
        return None
    a, b, nk = polys
    poles = np.roots(a)
    if poles.size == 0 or np.any(np.abs(poles) >= 1.0):
        return None
    b_trim = np.trim_zeros(b, "f")
    lead = len(b) - len(b_trim)
    zeros = np.roots(b_trim) if b_trim.size > 1 else np.zeros(0)
    pg = _groups(poles)
    zg_all = _groups(zeros)
    zg = [g for g in zg_all if max(abs(z) for z in g) <= MAX_ZERO_RADIUS]
    far = [g for g in zg_all if max(abs(z) for z in g) > MAX_ZERO_RADIUS]
    data = transform_inputs(data, model.input_blocks)
    exps = [(e.u[:, 0] - e.u[:, 0].mean(), e.y[:, 0]) for e in data.experiments]
    best: tuple[float, list[complex], list[complex]] | None = None
    n_tried = 0
    for k in range(1, min(MAX_GROUPS, len(pg)) + 1):
        for pi in itertools.combinations(range(len(pg)), k):
            p1 = [p for i in pi for p in pg[i]]
            p2 = [p for i in range(len(pg)) if i not in pi for p in pg[i]]
            for kz in range(0, min(MAX_GROUPS, len(zg)) + 1):
                for zi in itertools.combinations(range(len(zg)), kz):
                    z1 = [z for i in zi for z in zg[i]]
                    if len(z1) > len(p1):
                        continue
                    z2 = [z for g in far + [zg[i] for i in range(len(zg)) if i not in zi]
                          for z in g]  # fmt: skip
                    b1, a1 = _poly(z1), _poly(p1)
                    b2 = np.concatenate([np.zeros(nk + lead), _poly(z2)])
                    a2 = _poly(p2)
                    xs = [lfilter(b1, a1, u) for u, _ in exps]
                    # the inner signal in units of its spread: powers of comparable size
                    scale = float(np.std(np.concatenate(xs)))
                    if not scale > 0:
                        continue
                    cols, ys = [], []
                    for x, (_, y) in zip(xs, exps, strict=True):
                        x = x / scale
                        cols.append(
                            np.column_stack(
                                [lfilter(b2, a2, x**i) for i in range(SPLIT_DEGREE + 1)]
                            )
                        )
                        ys.append(y)
                    X, Y = np.vstack(cols), np.concatenate(ys)
                    if not np.all(np.isfinite(X)):
                        continue
                    c, *_ = np.linalg.lstsq(X, Y, rcond=None)
                    err = float(np.sqrt(np.mean((Y - X @ c) ** 2)))
                    n_tried += 1
                    if best is None or err < best[0]:
                        best = (err, z1, p1)
    if best is None:
        return None
    err, z1, p1 = best
    blocks = sections(z1, p1, model.input_names[0])
    record = {
        "splits_tried": n_tried,
        "first_filter_poles": [str(np.round(p, 4)) for p in p1],
        "first_filter_zeros": [str(np.round(z, 4)) for z in z1],
        "split_rms": err,
    }
    return blocks, record

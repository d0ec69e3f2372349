"""N4SID: subspace identification of a discrete state-space model (Van Overschee & De Moor).

The model is the innovation form ``x[k+1] = A x + B u + K e``, ``y = C x + D u + e``.

Algorithm (numerics in :mod:`tendonkit.plugins._subspace`):

1. Signals are scaled to unit RMS.  For each experiment the Gram matrix of its block-Hankel
   data matrix (``i`` past and ``i`` future block rows of inputs and outputs) is computed from
   lagged products of the signals, and the Gram matrices of all experiments are summed — the
   Hankel *columns* of the experiments are concatenated, never the signals.  Time and memory
   are linear in the number of samples; no ``N × N`` matrix, nor the ``2i(nu+ny) × N`` Hankel
   matrix itself, is ever formed.
2. The L factor of the LQ factorisation of the data matrix is the Cholesky factor of that
   Gram matrix.  Forming a Gram matrix squares the condition number, which is harmless here:
   the data matrix of a persistently excited record is well conditioned up to the noise
   level, and noise-free data (an exactly rank-deficient Gram matrix) are handled by a
   diagonal shift of a few ulps.  Noise-free systems are still recovered to ~1e-12
   (see the tests).  A Householder QR of the data matrix would cost ``O(N (2i(nu+ny))²)``,
   about 100 times more at the sizes of interest.
3. The oblique projection of the future outputs on the past data, weighted by the projection
   orthogonal to the future inputs ("robust" N4SID weighting), is decomposed by SVD.  The
   order is given, or chosen at the largest gap of the log singular values.
4. ``A`` and ``C`` come from the least-squares fit of the shifted Kalman-filter state
   sequences (Van Overschee & De Moor 1996, Fig. 4.8); the residual covariances give the
   innovation gain ``K`` through the Riccati equation.
5. If ``A`` is unstable and ``stable`` is set, its unstable eigenvalues are reflected into the
   unit circle (``λ → λ/|λ|²``).
6. ``B``, ``D`` (zero unless ``feedthrough``) and the initial state of every experiment are
   fitted by linear least squares on the *simulation* error with ``A`` and ``C`` fixed.  This
   gives a much better free-run fit than the subspace ``B``, ``D`` and is still linear: the
   regressors are the states of the dual system ``(Aᵀ, c_p)`` driven by each input.  They are
   never formed: within a block of 16 samples they are fixed linear functions of the dual
   state at the block start and the block's inputs, so the normal equations follow from the
   Gram matrix of one short row per block (block-start states by a nested-block recursion,
   inputs, outputs), accumulated over time chunks.

The initial state fitted for the *first* experiment is stored as ``x0`` (used by
``simulate(..., initial="model")``); ``initial="estimate"`` re-estimates it from any data.

References
----------
P. Van Overschee, B. De Moor, "N4SID: Subspace algorithms for the identification of combined
deterministic-stochastic systems", Automatica 30(1), 75–93, 1994; *Subspace Identification for
Linear Systems*, Kluwer, 1996.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from tendonkit.dataset import Dataset
from tendonkit.errors import DataError, OptionError
from tendonkit.hookspecs import hookimpl
from tendonkit.identification import build_model, is_int, one_blas_thread, require_samples
from tendonkit.plugins import _modal
from tendonkit.plugins import _subspace as sub
from tendonkit.schema import Model, StateSpace

FloatArray = NDArray[np.float64]

#: Largest eigenvalue modulus after stabilisation.
STABLE_RADIUS = _modal.STABLE_RADIUS
#: Smallest default horizon (block rows); 10 gives fits within 0.01 points of the truth on the
#: 4-input 2-output order-8 test system at 1 % noise (5 loses 2 points, 20 gains nothing).
MIN_HORIZON = 10


@dataclass(frozen=True, kw_only=True)
class N4SID:
    """Options of the N4SID identifier.

    Parameters
    ----------
    order : int or None
        Number of states; ``None`` chooses it at the largest gap of the log singular values
        (the paper used 8).
    horizon : int or None
        Block rows ``i`` of the past and of the future Hankel matrices (>= 2).  Default:
        ``max(10, 2·ceil(order/ny) + 2)``, or ``max(10, ceil(max_order/ny) + 2)`` when the order
        is chosen automatically.  It must satisfy ``(horizon - 1)·ny >= order``.
    max_order : int
        Largest order considered by the automatic choice.
    stable : bool
        Reflect unstable eigenvalues of ``A`` into the unit circle.
    feedthrough : bool
        Estimate ``D``; otherwise ``D = 0`` (the robot has no direct feedthrough).
    estimate_x0 : bool
        Fit the initial state of every experiment together with ``B`` and ``D`` and store the
        first one as ``x0``; otherwise ``x0`` is zero in the fit and not stored.
    refine : bool
        Refine ``A``, ``B``, ``C`` (``D`` with ``feedthrough``) and every experiment's initial
        state by their free-run simulation error (output-error / prediction-error refinement,
        MATLAB's ``pem`` on an ``n4sid`` start): Levenberg–Marquardt-type trust-region least
        squares on the output-normalised errors, keeping ``A`` stable; the subspace model is kept if the refinement does not
        lower the error.  The Kalman gain stays the subspace one (in the refined coordinates).
        The refinement is ``pem``'s (:func:`tendonkit.plugins._modal.refine`): the refined
        model is in real modal form.
    offset : bool
        Identify the dynamics of the deviations from the mean input and output and store
        that operating point in the model (``u0``, ``y0``: undone in simulation); otherwise
        the signals are used as they are (a level the dynamics do not produce is then fitted
        by the initial state only).  For integrating plants use ``pem``.

    Examples
    --------
    >>> from tendonkit.testsystems import random_state_space, simulate_truth
    >>> data, _ = simulate_truth(random_state_space(4, 2, 1, seed=3), 2000, noise=0.0)
    >>> model = N4SID(order=4).identify(data)
    >>> model.representation.n_states, round(model.provenance.training_fit["y1"], 6)
    (4, 100.0)
    """

    name: ClassVar[str] = "n4sid"
    description: ClassVar[str] = (
        "N4SID subspace identification (Van Overschee & De Moor), LQ via Hankel Gram matrix, "
        "B/D/x0 by simulation-error least squares, Kalman gain; paper: order 8."
    )

    order: int | None = None
    horizon: int | None = None
    max_order: int = 20
    stable: bool = True
    feedthrough: bool = False
    estimate_x0: bool = True
    refine: bool = False
    offset: bool = False

    def __post_init__(self) -> None:
        p: list[str] = []
        if self.order is not None and (not is_int(self.order) or self.order < 1):
            p.append(f"order must be an integer >= 1 or None (automatic), found {self.order!r}.")
        if self.horizon is not None and (not is_int(self.horizon) or self.horizon < 2):
            p.append(
                f"horizon must be an integer >= 2 or None (automatic), found {self.horizon!r}."
            )
        if not is_int(self.max_order) or self.max_order < 1:
            p.append(f"max_order must be an integer >= 1, found {self.max_order!r}.")
        for key in ("stable", "feedthrough", "estimate_x0", "refine", "offset"):
            if not isinstance(getattr(self, key), bool | np.bool_):
                p.append(f"{key} must be true or false, found {getattr(self, key)!r}.")
        if p:
            raise OptionError("Invalid options for n4sid:", p)

    def block_rows(self, ny: int) -> int:
        """The horizon ``i`` used for ``ny`` outputs (the option, or its default)."""
        if self.horizon is not None:
            return int(self.horizon)
        if self.order is not None:
            return max(MIN_HORIZON, 2 * _ceil_div(self.order, ny) + 2)
        return max(MIN_HORIZON, _ceil_div(self.max_order, ny) + 2)

    def identify(self, dataset: Dataset) -> Model:
        """Identify a state-space model from ``dataset`` (all experiments)."""
        with one_blas_thread():
            return self._identify(dataset)

    def _identify(self, dataset: Dataset) -> Model:
        nu, ny = dataset.nu, dataset.ny
        i = self.block_rows(ny)
        if self.order is not None and (i - 1) * ny < self.order:
            raise OptionError(
                f"n4sid: horizon {i} is too short for order {self.order} with {ny} output(s); "
                f"(horizon - 1)·ny must be >= order, so use horizon >= {_ceil_div(self.order, ny) + 1}."
            )
        rows = 2 * i * (nu + ny)
        require_samples(
            dataset, 2 * i + 1, f"n4sid (horizon {i}: 2·{i} + 1 samples per experiment)"
        )
        columns = sum(e.n_samples - 2 * i + 1 for e in dataset.experiments)
        if columns < rows:
            raise DataError(
                f"Too few samples for n4sid: the Hankel matrices have {columns} columns but "
                f"{rows} rows (2·horizon·(inputs + outputs)); at least {rows} columns are needed."
            )
        exps = [(e.u, e.y) for e in dataset.experiments]
        u0 = y0 = None
        if self.offset:  # deviations from the operating point (the means of all experiments)
            u0 = np.mean(np.vstack([u for u, _ in exps]), axis=0)
            y0 = np.mean(np.vstack([y for _, y in exps]), axis=0)
            exps = [(u - u0, y - y0) for u, y in exps]
        su = _rms([u for u, _ in exps], nu)
        sy = _rms([y for _, y in exps], ny)

        L = sub.lq_factor(_gram(exps, su, sy, i) / columns)
        U, sv = sub.singular_values_and_basis(L, nu, ny, i)
        cap = (i - 1) * ny
        if self.order is not None:
            n, how = self.order, "given"
        else:
            n = sub.select_order(sv, min(self.max_order, cap))
            how = "chosen at the largest singular-value gap"
        space = sub.system_matrices(L, U, sv, nu, ny, i, n)

        A = space.A
        notes = [f"order {n} ({how}); horizon {i}"]
        if self.stable and sub.spectral_radius(A) >= STABLE_RADIUS:
            notes.append(f"unstable A (spectral radius {sub.spectral_radius(A):.6g}) stabilised")
            A = sub.stabilize(A, STABLE_RADIUS)
        C = space.C * sy[:, None]
        A_sub, T = A, np.eye(n)  # the subspace A (for the Kalman gain), and the refinement's basis
        if sub.spectral_radius(A) < 1.0:
            B, D, x0s = sub.fit_input_matrices(
                A, C, exps, feedthrough=self.feedthrough, estimate_x0=self.estimate_x0
            )
            if self.refine:
                A, B, C, D, x0s, T, note = _refine(A, B, C, D, x0s, exps, sy, self.feedthrough)
                notes.append(note)
            x0 = x0s[0] if self.estimate_x0 else None
        else:
            Bs, Ds = sub.subspace_input_matrices(L, A, space.C, nu, ny, i)
            B = Bs / su[None, :]
            D = (sy[:, None] * Ds / su[None, :]) if self.feedthrough else np.zeros((ny, nu))
            x0 = None
            notes.append("A is unstable: B and D from the subspace step, no x0")
        Ks = sub.kalman_gain(space, A_sub)
        K = None if Ks is None else T @ Ks / sy[None, :]
        if K is None:
            notes.append("no Kalman gain (singular noise covariance)")
        notes.append("singular values " + " ".join(f"{v:.4g}" for v in sv[: min(len(sv), n + 4)]))
        rep = StateSpace(A=A, B=B, C=C, D=D, x0=x0, K=K, u0=u0, y0=y0)
        details = {"singular_values": [float(v) for v in sv], "order": int(n)}
        return build_model(self, dataset, rep, notes="; ".join(notes), details=details)


def _refine(
    A: FloatArray,
    B: FloatArray,
    C: FloatArray,
    D: FloatArray,
    x0s: list[FloatArray],
    exps: list[tuple[FloatArray, FloatArray]],
    sy: FloatArray,
    feedthrough: bool,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, list[FloatArray], FloatArray, str]:
    """Simulation-error refinement of a stable state-space model (see ``N4SID.refine``).

    The same refinement as ``pem``'s (:func:`tendonkit.plugins._modal.refine`, modal
    coordinates, exact Jacobian, poles bounded by ``STABLE_RADIUS``).  Also returns the state
    transformation ``T`` into the refined model's coordinates (``x_new = T x``), so that the
    subspace Kalman gain can follow (``K_new = T K``); the identity when the subspace model
    is kept.
    """
    n = A.shape[0]
    x0s = [np.zeros(n) if x is None else np.asarray(x, dtype=float) for x in x0s]
    while len(x0s) < len(exps):
        x0s.append(np.zeros(n))
    kw = {
        "integrators": 0, "feedthrough": feedthrough, "output_offset": False,
        "input_offset": False, "y0": np.zeros(C.shape[0]), "u0": np.zeros(B.shape[1]),
        "radius": STABLE_RADIUS,
    }  # fmt: skip
    layout, theta = _modal.from_state_space(A, B, C, D, x0s, **kw)
    theta, before, after, nfev = _modal.refine(layout, theta, exps, sy, 60, 1e-8)
    if not after < before:
        msg = "refinement kept the subspace model (no lower simulation error)"
        return A, B, C, D, x0s, np.eye(n), msg
    Am, Bm, Cm, Dm, zs, _, _ = _modal.to_state_space(layout, theta)
    # the modal coordinates of the unit initial states are the columns of T
    unit = [np.eye(n)[:, k] for k in range(n)]
    basis, theta_basis = _modal.from_state_space(A, B, C, D, unit, **kw)
    T = np.column_stack(_modal.to_state_space(basis, theta_basis)[4])
    note = (
        f"refined by simulation error: normalised RMS {before:.4g} -> {after:.4g} "
        f"({nfev} evaluations)"
    )
    return Am, Bm, Cm, Dm if feedthrough else D, zs, T, note


def _gram(
    exps: list[tuple[FloatArray, FloatArray]], su: FloatArray, sy: FloatArray, i: int
) -> FloatArray:
    """Summed Hankel Gram matrix, rows ordered ``[U_past; U_future; Y_past; Y_future]``."""
    nu, ny = su.size, sy.size
    m, s = nu + ny, 2 * i
    G = np.zeros((s * m, s * m))
    for u, y in exps:
        z = np.empty((u.shape[0], m))  # scaled signals side by side, without temporaries
        np.divide(u, su, out=z[:, :nu])
        np.divide(y, sy, out=z[:, nu:])
        G += sub.hankel_gram(z, s)
    a = np.arange(s)[:, None] * m
    order = np.concatenate([(a + np.arange(nu)).ravel(), (a + nu + np.arange(ny)).ravel()])
    return G[np.ix_(order, order)]


def _rms(parts: list[FloatArray], k: int) -> FloatArray:
    """Root-mean-square of every column over all experiments (1 where it is zero)."""
    if k == 0:
        return np.ones(0)
    total = sum(np.einsum("ij,ij->j", x, x) for x in parts)
    count = sum(x.shape[0] for x in parts)
    r = np.sqrt(np.asarray(total) / count)
    r[~(r > 0)] = 1.0
    return np.asarray(r)


def _ceil_div(a: int, b: int) -> int:
    return -(-a // b)


@hookimpl
def tendonkit_register_identifiers(registry):  # type: ignore[no-untyped-def]
    """Register the N4SID identifier."""
    registry.add(N4SID)

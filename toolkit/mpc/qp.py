"""The MPC tracking QP: written once in cvxpy, solved by cvxpy or by the solver directly.

:class:`TrackingQP` states the problem of every tendonkit MPC controller in cvxpy with
parameters (DPP), over the horizon ``j = 1..N``::

    minimise   sum_{j<N} |y_j - r_j|²_Q + |y_N - r_N|²_Qf + sum_{j<N} |Δu_j|²_R
               + sum_{j<N} |u_j - u_target|²_S + rho_1 sum(s) + rho_2 |s|²
    subject to x_1     = x1 + B_0 u_0
               x_{j+1} = A_j x_j + B_j u_j + w_j
               y_j     = C x_j + D u_{j-1} + yoff
               u_min <= u_j <= u_max,   |Δu_j| <= du_max (where finite)
               y_min - s_j <= y_j <= y_max + s_j,   s >= 0

with ``Δu_0 = u_0 - u_prev``.  The dynamics are either time invariant (``A``, ``B`` constant:
only vectors change between steps) or time varying (``A_j``, ``B_j`` are parameters, for
successive linearisation).

Two ways to solve the same problem:

- the *design path* sets the parameter values and calls ``problem.solve`` (cvxpy re-uses the
  compiled parameter-affine map, DPP);
- the *fast path* (:class:`_DirectSolver`) reads that parameter-affine map once from
  ``problem.get_problem_data`` (cvxpy's ``ParamConeProg.apply_parameters``, probed one
  parameter entry at a time, which is exact because the map is affine) and at every step only
  forms ``q``, ``b`` (and the changing entries of ``A``) by a sparse product with the parameter
  vector, then updates a persistent Clarabel or OSQP solver in place (``update``, warm start).
  Both paths hand the same numbers to the same solver.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import OptionError

FloatArray = NDArray[np.float64]

#: Solvers the MPC controllers can use, and cvxpy's names for them.
SOLVERS = {"clarabel": "CLARABEL", "osqp": "OSQP"}

#: Settings both paths pass to Clarabel.  In-place updates need presolve off and structural
#: zeros kept.  Iterative refinement of the KKT solves is off: it costs about a third of the
#: solve time on these small, scaled QPs and changed the applied inputs by < 1e-7 N on
#: minimal 8- and 16-state models (3e-2 N on a non-minimal 48-state ARX realisation) in
#: benchmarks/bench_mpc_solvers.py; pass ``iterative_refinement_enable=True`` to restore it.
CLARABEL_DEFAULTS: dict[str, Any] = {
    "verbose": False,
    "presolve_enable": False,
    "input_sparse_dropzeros": False,
    "iterative_refinement_enable": False,
}
#: Settings both paths pass to OSQP (cvxpy's tolerances; a fixed rho-adaptation interval so
#: that runs are repeatable).
OSQP_DEFAULTS: dict[str, Any] = {
    "verbose": False,
    "eps_abs": 1e-5,
    "eps_rel": 1e-5,
    "max_iter": 10000,
    "polishing": True,
    "adaptive_rho_interval": 25,
    "warm_starting": True,
}


@dataclass(frozen=True)
class QPResult:
    """Outcome of one QP solve: status text, success flag and the optimal trajectories."""

    status: str
    ok: bool
    U: FloatArray | None = None
    Y: FloatArray | None = None
    X: FloatArray | None = None


@dataclass(frozen=True)
class QPSpec:
    """Sizes, weights and bounds of the tracking QP (already validated).

    ``A`` and ``B`` are the constant dynamics, or ``None`` for time-varying ones.  The solver
    works on scaled inputs ``v = (u - u_center) / u_scale`` (about [-1, 1] between bounds).  ``Lq``,
    ``Lqf``, ``Lr`` and ``Ls`` are square roots of the weights (``Q = Lqᵀ Lq``; ``Ls`` is None
    without an input target).  ``du_max`` (None or inf: none) bounds the input moves.  Output
    bounds may be infinite; outputs without any finite bound get no slack variable.
    """

    n: int
    nu: int
    ny: int
    horizon: int
    A: FloatArray | None
    B: FloatArray | None
    C: FloatArray
    D: FloatArray
    Lq: FloatArray
    Lqf: FloatArray
    Lr: FloatArray
    u_min: FloatArray
    u_max: FloatArray
    u_center: FloatArray
    u_scale: FloatArray
    y_min: FloatArray
    y_max: FloatArray
    slack_weight: tuple[float, float]
    Ls: FloatArray | None = None
    u_target: FloatArray | None = None
    du_max: FloatArray | None = None


class TrackingQP:
    """The parametric tracking QP of :mod:`tendonkit.mpc` (see the module docstring).

    Parameters
    ----------
    spec : QPSpec
        Sizes, weights, bounds; ``spec.A is None`` selects time-varying dynamics.
    solver : {"clarabel", "osqp"}
        The QP solver.
    fast : bool
        Solve through the direct solver interface (True) or through ``problem.solve``.
    solver_options : mapping, optional
        Extra solver settings, given to both paths.
    formulation : {"sparse", "condensed"}
        Keep the states as variables with the dynamics as equality constraints, or eliminate
        them (time-invariant dynamics only): ``y = Gu u + Gx1 x1 + Gw w``.
    """

    def __init__(
        self,
        spec: QPSpec,
        solver: str = "clarabel",
        fast: bool = True,
        solver_options: Mapping[str, Any] | None = None,
        formulation: str = "sparse",
    ) -> None:
        # lazy: heavy (cvxpy)
        import cvxpy as cp

        if formulation not in ("sparse", "condensed"):
            raise OptionError(
                f"formulation must be 'sparse' or 'condensed', found {formulation!r}."
            )
        if formulation == "condensed" and spec.A is None:
            raise OptionError("The condensed formulation needs time-invariant dynamics.")
        self.spec = spec
        self.solver = solver
        self.fast = fast
        self.formulation = formulation
        self.time_varying = spec.A is None
        defaults = CLARABEL_DEFAULTS if solver == "clarabel" else OSQP_DEFAULTS
        self.options = {**defaults, **dict(solver_options or {})}
        n, nu, ny, N = spec.n, spec.nu, spec.ny, spec.horizon
        nw = max(N - 1, 1)
        p: dict[str, Any] = {
            "x1": cp.Parameter(n, name="x1"),
            "w": cp.Parameter((n, nw) if self.time_varying else (n, 1), name="w"),
            "yoff": cp.Parameter((ny, 1), name="yoff"),
            "r": cp.Parameter((ny, N), name="r"),
            "u_prev": cp.Parameter(nu, name="u_prev"),
        }
        if self.time_varying:
            p["A"] = [cp.Parameter((n, n), name=f"A{j}") for j in range(1, N)]
            p["B"] = [cp.Parameter((n, nu), name=f"B{j}") for j in range(N)]
        self.params = p
        V = cp.Variable((nu, N), name="v")  # scaled inputs: u = u_center + u_scale * v
        U = cp.multiply(spec.u_scale[:, None], V) + spec.u_center[:, None] @ np.ones((1, N))
        self._V = V
        cons: list[Any] = []
        if formulation == "condensed":
            self._maps = _prediction_matrices(spec)
            Gu, Gx1, Gw = self._maps
            y = Gu @ cp.vec(U, order="F") + Gx1 @ p["x1"] + Gw @ p["w"][:, 0]
            Y = cp.reshape(y, (ny, N), order="F") + p["yoff"] @ np.ones((1, N))
            variables = [V]
        else:
            X = cp.Variable((n, N), name="x")
            B0 = p["B"][0] if self.time_varying else spec.B
            cons.append(X[:, 0] == p["x1"] + B0 @ U[:, 0])
            if N > 1 and self.time_varying:
                cons += [
                    X[:, j] == p["A"][j - 1] @ X[:, j - 1] + p["B"][j] @ U[:, j] + p["w"][:, j - 1]
                    for j in range(1, N)
                ]
            elif N > 1:
                w = p["w"] @ np.ones((1, N - 1))
                cons.append(X[:, 1:] == spec.A @ X[:, :-1] + spec.B @ U[:, 1:] + w)
            Y = spec.C @ X + spec.D @ U + p["yoff"] @ np.ones((1, N))
            variables = [V, X]
        for i in range(nu):  # hard input bounds, on the scaled inputs
            if np.isfinite(spec.u_min[i]):
                cons.append(V[i, :] >= (spec.u_min[i] - spec.u_center[i]) / spec.u_scale[i])
            if np.isfinite(spec.u_max[i]):
                cons.append(V[i, :] <= (spec.u_max[i] - spec.u_center[i]) / spec.u_scale[i])
        if spec.du_max is not None and np.any(np.isfinite(spec.du_max)):
            rows = [i for i in range(nu) if np.isfinite(spec.du_max[i])]
            dU = cp.hstack(
                [cp.reshape(U[:, 0] - p["u_prev"], (nu, 1), order="F"), U[:, 1:] - U[:, :-1]]
            )
            lim = (spec.du_max[rows] / spec.u_scale[rows])[:, None] @ np.ones((1, N))
            dV = cp.multiply(1.0 / spec.u_scale[rows][:, None], dU[rows, :])
            cons += [dV <= lim, dV >= -lim]  # rate limits, on the scaled inputs
        E = Y - p["r"]
        cost = cp.sum_squares(spec.Lqf @ E[:, N - 1])
        if N > 1:
            cost += cp.sum_squares(spec.Lq @ E[:, : N - 1])
        du0 = cp.reshape(U[:, 0] - p["u_prev"], (nu, 1), order="F")
        cost += cp.sum_squares(spec.Lr @ cp.hstack([du0, U[:, 1:] - U[:, :-1]]))
        if spec.Ls is not None and np.any(spec.Ls):
            target = np.zeros(nu) if spec.u_target is None else spec.u_target
            cost += cp.sum_squares(spec.Ls @ (U - target[:, None] @ np.ones((1, N))))
        soft = [i for i in range(ny) if np.isfinite(spec.y_min[i]) or np.isfinite(spec.y_max[i])]
        if soft:  # soft output bounds with one slack per output and step
            S = cp.Variable((len(soft), N), name="slack")
            cons.append(S >= 0)
            for row, i in enumerate(soft):
                if np.isfinite(spec.y_max[i]):
                    cons.append(Y[i, :] <= spec.y_max[i] + S[row, :])
                if np.isfinite(spec.y_min[i]):
                    cons.append(Y[i, :] >= spec.y_min[i] - S[row, :])
            rho1, rho2 = spec.slack_weight
            cost += rho1 * cp.sum(S) + rho2 * cp.sum_squares(S)
        self.problem = cp.Problem(cp.Minimize(cost), cons)
        self._variables = variables
        self._direct: _DirectSolver | None = None
        self._values: dict[str, Any] = {}
        if fast:
            self._direct = _DirectSolver(self.problem, self.solver, self.options, variables)

    @property
    def setup_time_s(self) -> float:
        """Time spent reading cvxpy's problem data and setting up the solver (fast path)."""
        return 0.0 if self._direct is None else self._direct.setup_time_s

    # -- parameters ---------------------------------------------------------------------
    def set_parameters(
        self,
        *,
        x1: FloatArray,
        w: FloatArray,
        yoff: FloatArray,
        r: FloatArray,
        u_prev: FloatArray,
        A: list[FloatArray] | None = None,
        B: list[FloatArray] | None = None,
    ) -> None:
        """Give every parameter its value for the next solve.

        Parameters
        ----------
        x1 : array (n,)
            Free part of the first predicted state (``x_1 = x1 + B_0 u_0``).
        w : array (n,) or (n, N-1)
            Additive term of the dynamics: constant (time-invariant dynamics) or one column
            per step ``j = 1..N-1`` (time-varying dynamics).
        yoff : array (ny,)
            Constant output offset (disturbance estimate, model offset).
        r : array (N, ny)
            Reference for ``y_1..y_N``.
        u_prev : array (nu,)
            The input applied at the previous step.
        A, B : list of arrays, optional
            Time-varying dynamics ``A_1..A_{N-1}`` and ``B_0..B_{N-1}``.
        """
        p = self.params
        vals: dict[str, Any] = {
            "x1": np.asarray(x1, dtype=float),
            "w": np.asarray(w, dtype=float).reshape(p["w"].shape),
            "yoff": np.asarray(yoff, dtype=float).reshape(-1, 1),
            "r": np.asarray(r, dtype=float).T,
            "u_prev": np.asarray(u_prev, dtype=float),
        }
        if self.time_varying:
            assert A is not None and B is not None
            vals["A"], vals["B"] = list(A), list(B)
        self._values = vals
        if self._direct is not None:
            # The fast path reads the raw arrays: cvxpy's Parameter.value setter validates
            # every entry (about 50 µs per parameter, a fifth of a whole step).
            by_id = {p[k].id: vals[k] for k in ("x1", "w", "yoff", "r", "u_prev")}
            if self.time_varying:
                for key in ("A", "B"):
                    by_id.update((par.id, v) for par, v in zip(p[key], vals[key]))
            self._direct.values = by_id
            return
        for key in ("x1", "w", "yoff", "r", "u_prev"):
            p[key].value = vals[key]
        if self.time_varying:
            for key in ("A", "B"):
                for par, val in zip(p[key], vals[key]):
                    par.value = val

    # -- solving ------------------------------------------------------------------------
    def solve(self) -> QPResult:
        """Solve with the current parameter values (design or fast path)."""
        if self._direct is not None:
            status, ok, vals = self._direct.solve()
        else:
            status, ok = self._solve_cvxpy()
            vals = [np.asarray(v.value) for v in self._variables] if ok else []
        if not ok:
            return QPResult(status, False)
        spec, p = self.spec, self._values
        U = spec.u_center[:, None] + spec.u_scale[:, None] * vals[0]
        if self.formulation == "condensed":
            Gu, Gx1, Gw = self._maps
            y = Gu @ U.ravel(order="F") + Gx1 @ p["x1"] + Gw @ p["w"][:, 0]
            Y = y.reshape((spec.ny, spec.horizon), order="F") + p["yoff"]
        else:
            Y = spec.C @ vals[1] + spec.D @ U + p["yoff"]
        X = None if self.formulation == "condensed" else np.asarray(vals[1])
        return QPResult(status, True, U=np.asarray(U), Y=np.asarray(Y), X=X)

    def _solve_cvxpy(self) -> tuple[str, bool]:
        # lazy: heavy (cvxpy)
        import cvxpy as cp

        try:
            self.problem.solve(solver=SOLVERS[self.solver], warm_start=True, **self.options)
        except cp.error.SolverError as exc:
            return f"solver error: {exc}", False
        status = str(self.problem.status)
        ok = status in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE)
        ok = ok and all(v.value is not None for v in self._variables)
        return status, ok


class _DirectSolver:
    """Persistent Clarabel/OSQP solver fed from cvxpy's parameter-affine problem data."""

    def __init__(
        self, problem: Any, solver: str, options: dict[str, Any], variables: list[Any]
    ) -> None:
        # lazy: heavy (cvxpy); heavy (scipy)
        import cvxpy as cp
        import scipy.sparse as sp

        t0 = time.perf_counter()
        data, _, _ = problem.get_problem_data(SOLVERS[solver])
        prog = data[cp.settings.PARAM_PROB]
        self.solver = solver
        self.options = options
        dims = prog.cone_dims
        if dims.soc or dims.psd or dims.exp or getattr(dims, "p3d", None):
            raise OptionError("The MPC problem compiled to cones other than a QP's.")
        self.n_eq, self.n_ineq = int(dims.zero), int(dims.nonneg)
        self._params = [p for p in prog.parameters]
        self._sizes = [int(p.size) for p in self._params]
        #: Raw parameter values by parameter id (set by :meth:`TrackingQP.set_parameters`);
        #: a parameter missing here is read from its cvxpy ``value``.
        self.values: dict[int, Any] = {}
        size = sum(self._sizes)
        self._param_vec = np.zeros(size)

        def apply(values: dict[int, FloatArray], zero_offset: bool) -> tuple[Any, ...]:
            return tuple(
                prog.apply_parameters(
                    values, zero_offset=zero_offset, keep_zeros=True, quad_obj=True
                )
            )

        zeros = {p.id: np.zeros(p.shape) for p in self._params}
        P0, q0, _, A0, b0 = apply(zeros, zero_offset=False)
        probes: list[tuple[FloatArray, FloatArray, Any]] = []
        for p in self._params:
            for k in range(int(p.size)):
                e = np.zeros(int(p.size))
                e[k] = 1.0
                vals = dict(zeros)
                vals[p.id] = e.reshape(p.shape, order="F")
                Pk, qk, _, Ak, bk = apply(vals, zero_offset=True)
                if sp.csc_array(Pk).count_nonzero():
                    raise OptionError("A parameter of the MPC problem enters its quadratic cost.")
                probes.append((np.asarray(qk), np.asarray(bk), sp.coo_array(Ak)))
        A0 = sp.coo_array(A0)
        # Union sparsity pattern of the constraint matrix, in CSC order.
        rows = np.concatenate([A0.row] + [pr[2].row for pr in probes]).astype(np.int64)
        cols = np.concatenate([A0.col] + [pr[2].col for pr in probes]).astype(np.int64)
        m, nx = A0.shape
        key = np.unique(cols * m + rows)
        self._rows, self._cols_a = key % m, key // m
        indptr = np.searchsorted(self._cols_a, np.arange(nx + 1))
        self._A_pattern = (self._rows.astype(np.int32), indptr.astype(np.int32), (m, nx))
        A0csr = A0.tocsr()
        a0 = np.asarray(A0csr[self._rows, self._cols_a]).ravel()
        Ta, Tq, Tb = [], [], []
        for qk, bk, Ak in probes:
            Ta.append(np.asarray(Ak.tocsr()[self._rows, self._cols_a]).ravel())
            Tq.append(qk)
            Tb.append(bk)
        nprobe = len(probes)
        self._a0, self._q0, self._b0 = a0, np.asarray(q0, dtype=float), np.asarray(b0, dtype=float)
        self._Ta: Any = sp.csr_array(np.array(Ta).T) if nprobe else None
        self._Tq: Any = sp.csr_array(np.array(Tq).T) if nprobe else None
        self._Tb: Any = sp.csr_array(np.array(Tb).T) if nprobe else None
        self._a_varies = bool(self._Ta is not None and self._Ta.count_nonzero())
        P = sp.csc_matrix(sp.triu(sp.csc_array(P0)), dtype=float)
        P.indices, P.indptr = P.indices.astype(np.int32), P.indptr.astype(np.int32)
        self._P = P
        self._var_slices = []
        for v in variables:
            c = int(prog.var_id_to_col[v.id])
            self._var_slices.append((slice(c, c + int(v.size)), v.shape))
        self._solver: Any = None
        self._setup(self._q0, self._b0, self._a0)
        self.setup_time_s = time.perf_counter() - t0

    # -- data of the current parameter values ---------------------------------------------
    def _vector(self) -> FloatArray:
        vec, values = self._param_vec, self.values
        pos = 0
        for p, s in zip(self._params, self._sizes):
            v = values.get(p.id) if values else None
            vec[pos : pos + s] = np.ravel(p.value if v is None else v, order="F")
            pos += s
        return vec

    def _data(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        vec = self._vector()
        if self._Tq is None:
            return self._q0, self._b0, self._a0
        q = self._q0 + self._Tq @ vec
        b = self._b0 + self._Tb @ vec
        a = self._a0 + self._Ta @ vec if self._a_varies else self._a0
        return q, b, a

    def _matrix(self, values: FloatArray) -> Any:
        # lazy: heavy (scipy)
        import scipy.sparse as sp

        indices, indptr, shape = self._A_pattern
        return sp.csc_matrix((values, indices, indptr), shape=shape)

    # -- solving -------------------------------------------------------------------------
    def solve(self) -> tuple[str, bool, list[FloatArray]]:
        """Solve for the current parameter values: (status, ok, [variable values])."""
        q, b, a = self._data()
        if self.solver == "clarabel":
            status, ok, x = self._solve_clarabel(q, b, a)
        else:
            status, ok, x = self._solve_osqp(q, b, a)
        if not ok or x is None:
            return status, False, []
        vals = [np.reshape(x[sl], shape, order="F") for sl, shape in self._var_slices]
        return status, True, vals

    def _setup(self, q: FloatArray, b: FloatArray, a: FloatArray) -> None:
        """Create the persistent solver (factorisation structures) once."""
        if self.solver == "clarabel":
            # lazy: heavy (clarabel)
            import clarabel

            settings = clarabel.DefaultSettings()
            for k, v in self.options.items():
                setattr(settings, k, v)
            cones = []
            if self.n_eq:
                cones.append(clarabel.ZeroConeT(self.n_eq))
            if self.n_ineq:
                cones.append(clarabel.NonnegativeConeT(self.n_ineq))
            self._solver = clarabel.DefaultSolver(self._P, q, self._matrix(-a), b, cones, settings)
        else:
            # lazy: heavy (osqp)
            import osqp

            self._solver = osqp.OSQP()
            lower, upper = self._bounds(b)
            self._solver.setup(self._P, q, self._matrix(a), lower, upper, **self.options)

    def _bounds(self, b: FloatArray) -> tuple[FloatArray, FloatArray]:
        upper = np.concatenate([-b[: self.n_eq], np.full(self.n_ineq, np.inf)])
        return -b, upper

    def _solve_clarabel(
        self, q: FloatArray, b: FloatArray, a: FloatArray
    ) -> tuple[str, bool, FloatArray | None]:
        if self._a_varies:
            self._solver.update(q=q, b=b, A=-a)
        else:
            self._solver.update(q=q, b=b)
        sol = self._solver.solve()
        status = str(sol.status)
        ok = status in ("Solved", "AlmostSolved")
        return status, ok, np.asarray(sol.x) if ok else None

    def _solve_osqp(
        self, q: FloatArray, b: FloatArray, a: FloatArray
    ) -> tuple[str, bool, FloatArray | None]:
        # lazy: heavy (osqp)
        import osqp

        lower, upper = self._bounds(b)
        if self._a_varies:
            self._solver.update(q=q, l=lower, u=upper, Ax=a)
        else:
            self._solver.update(q=q, l=lower, u=upper)
        res = self._solver.solve(raise_error=False)
        code = res.info.status_val
        ok = code in (osqp.SolverStatus.OSQP_SOLVED, osqp.SolverStatus.OSQP_SOLVED_INACCURATE)
        ok = ok and res.x is not None and bool(np.all(np.isfinite(res.x)))
        if not ok:  # do not warm-start the next solve from a failed iterate
            self._solver.warm_start(x=np.zeros(self._P.shape[0]), y=np.zeros(lower.size))
        return str(res.info.status), ok, np.asarray(res.x) if ok else None


def _prediction_matrices(spec: QPSpec) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Condensed maps ``vec(Y) = Gu vec(U) + Gx1 x1 + Gw w`` (column-major, constant ``w``)."""
    assert spec.A is not None and spec.B is not None
    A, B, C, D = spec.A, spec.B, spec.C, spec.D
    n, nu, ny, N = spec.n, spec.nu, spec.ny, spec.horizon
    powers = [np.eye(n)]
    for _ in range(N):
        powers.append(A @ powers[-1])
    Gu = np.zeros((ny * N, nu * N))
    Gx1 = np.zeros((ny * N, n))
    Gw = np.zeros((ny * N, n))
    for j in range(N):  # y_{j+1} = C x_{j+1} + D u_j
        rows = slice(j * ny, (j + 1) * ny)
        Gx1[rows] = C @ powers[j]
        Gu[rows, j * nu : (j + 1) * nu] += D
        for i in range(j + 1):  # x_{j+1} gets A^{j-i} B u_i
            Gu[rows, i * nu : (i + 1) * nu] += C @ powers[j - i] @ B
        for i in range(1, j + 1):  # and A^{j-i} w (w drives x_{i+1} for i >= 1)
            Gw[rows] += C @ powers[j - i]
    return Gu, Gx1, Gw

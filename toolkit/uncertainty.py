"""Parameter uncertainty and the confidence band of a simulated output (MATLAB ``simsd``).

An identifier that refines its parameters by least squares can store their covariance in the
model's provenance, ``details["covariance"]`` = ``{"parameters": [names], "matrix": [[...]]}``,
the names addressing entries of the state-space representation (``"A[0,1]"``, ``"B[2,0]"``,
``"C[0,0]"``, ``"D[0,0]"``, ``"K[0,0]"``, ``"u0[0]"``, ``"y0[0]"``; the Kalman gain ``K`` of a
model fitted by its prediction error does not move a simulation, so its entries add nothing
to the band).  The covariance is the Gauss–Newton one,
``λ (JᵀJ)⁺`` with ``J`` the Jacobian of the normalised simulation errors (or, for a model
fitted by its prediction error, prediction errors) at the optimum and
``λ`` their variance (Ljung, *System Identification*, 2nd ed., §9.3): it describes the scatter
of the estimate under the noise seen in the residuals, not the error of a wrong structure.

:func:`simulate_band` propagates it to the outputs to first order: the output's sensitivity
to every listed parameter (central differences at the scale of that parameter's own standard
deviation, the initial state held at its nominal estimate) gives ``var ŷ[k] = s_kᵀ Σ s_k``.
"""

from __future__ import annotations

import dataclasses
import re
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .errors import SchemaError
from .schema import Model, StateSpace
from .simulate import estimate_x0, simulate

FloatArray = NDArray[np.float64]

_NAME = re.compile(r"^(A|B|C|D|K|u0|y0)\[(\d+)(?:,(\d+))?\]$")


def covariance(model: Model) -> tuple[list[str], FloatArray] | None:
    """The stored parameter covariance ``(names, matrix)``, or ``None`` when there is none."""
    raw = model.provenance.details.get("covariance")
    if not raw:
        return None
    names = [str(n) for n in raw["parameters"]]
    matrix = np.asarray(raw["matrix"], dtype=float)
    if matrix.shape != (len(names), len(names)) or not all(_NAME.match(n) for n in names):
        raise SchemaError(f"Model {model.name!r}: its stored covariance is malformed.")
    return names, matrix


def with_parameters(rep: StateSpace, names: list[str], values: FloatArray) -> StateSpace:
    """``rep`` with the named entries set to ``values``."""
    mats: dict[str, Any] = {
        k: None if getattr(rep, k) is None else np.array(getattr(rep, k), dtype=float)
        for k in ("A", "B", "C", "D", "K", "u0", "y0")
    }
    for name, v in zip(names, values, strict=True):
        m = _NAME.match(name)
        assert m is not None
        key, i, j = m.group(1), int(m.group(2)), m.group(3)
        if mats[key] is None:
            if key == "K":
                mats[key] = np.zeros((rep.n_states, rep.C.shape[0]))
            else:
                mats[key] = np.zeros(rep.B.shape[1] if key == "u0" else rep.C.shape[0])
        if j is None:
            mats[key][i] = v
        else:
            mats[key][i, int(j)] = v
    return dataclasses.replace(rep, **mats)


def parameter_values(rep: StateSpace, names: list[str]) -> FloatArray:
    """The named entries of ``rep``."""
    out = []
    for name in names:
        m = _NAME.match(name)
        assert m is not None
        key, i, j = m.group(1), int(m.group(2)), m.group(3)
        arr = getattr(rep, key)
        out.append(0.0 if arr is None else float(arr[i] if j is None else arr[i, int(j)]))
    return np.asarray(out)


def simulate_band(
    model: Model,
    u: FloatArray,
    y: FloatArray | None = None,
    *,
    initial: str = "estimate",
    init_window: int | None = None,
    level: float = 0.99,
) -> tuple[FloatArray, FloatArray]:
    """Simulated outputs and the half-width of their ``level`` confidence band.

    Returns ``(y_hat, half_width)``, both ``(n, ny)``; the band is ``y_hat ± half_width``.

    Raises
    ------
    SchemaError
        If the model stores no covariance or is not a state-space model without terms.
    """
    # lazy: heavy (scipy.stats)
    from scipy.stats import norm

    stored = covariance(model)
    rep = model.representation
    if stored is None or not isinstance(rep, StateSpace) or rep.terms:
        raise SchemaError(
            f"Model {model.name!r} has no parameter covariance (identify it with pem)."
        )
    names, cov = stored
    # the Kalman gain does not move a simulation: its sensitivities are zero
    moves = [i for i, n in enumerate(names) if not n.startswith("K[")]
    names, cov = [names[i] for i in moves], cov[np.ix_(moves, moves)]
    u = np.asarray(u, dtype=float)
    yy = None if y is None else np.asarray(y, dtype=float)
    if initial == "estimate":
        if yy is None:
            raise SchemaError("initial='estimate' needs the measured outputs y.")
        x0 = estimate_x0(rep, u, yy, init_window)
    elif initial == "model" and rep.x0 is not None:
        x0 = np.asarray(rep.x0, dtype=float)
    else:
        x0 = np.zeros(rep.n_states)
    nominal = simulate(model, u, initial=x0)
    theta = parameter_values(rep, names)
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    S = np.zeros((*nominal.shape, len(names)))
    for i in range(len(names)):
        h = sd[i] if sd[i] > 0 else 1e-8 * max(abs(theta[i]), 1.0)
        out = []
        for sign in (1.0, -1.0):
            th = theta.copy()
            th[i] += sign * h
            m = model.replace(representation=with_parameters(rep, names, th))
            out.append(simulate(m, u, initial=x0))
        S[:, :, i] = (out[0] - out[1]) / (2 * h)
    var = np.einsum("kjp,pq,kjq->kj", S, cov, S)
    z = float(norm.ppf(0.5 + level / 2.0))
    return nominal, z * np.sqrt(np.clip(var, 0.0, None))

"""The parts of a model that the schema is built from: signals, blocks, representations, provenance.

A private module below :mod:`tendonkit.schema` (which re-exports every name here), so that the
parser (:mod:`tendonkit._schema_io`) and the realisations (:mod:`tendonkit.realize`) depend on the
parts without depending on :class:`~tendonkit.schema.Model`, and the schema can use both.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from .terms import Term

SCHEMA_VERSION = 1
FloatArray = NDArray[np.float64]

#: Kinds of :class:`Block` (static or hysteretic operators on one signal).
BLOCK_KINDS: dict[str, tuple[str, ...]] = {
    "delay": ("samples",),
    "dead_zone": ("threshold", "center"),
    "saturation": ("lower", "upper"),
    "play": ("width",),
    "first_order_lag": ("pole",),
    "rate_limit": ("rate",),
    "polynomial": ("c0", "c1", "c2", "c3"),
    "second_order_section": ("b1", "b2", "a1", "a2"),
}
#: The block kinds that are linear (a model whose blocks are all of these has a state-space form).
LINEAR_BLOCKS = frozenset({"delay", "first_order_lag", "second_order_section"})


def section_gain(p: dict[str, float]) -> float:
    """Static gain ``(1 + b1 + b2) / (1 + a1 + a2)`` of a ``second_order_section`` block's
    parameters (the C runtime of model FMUs computes it in the same order)."""
    return float((1.0 + p["b1"] + p["b2"]) / (1.0 + p["a1"] + p["a2"]))


def section_is_stable(a1: float, a2: float) -> bool:
    """Whether ``1 + a1 q⁻¹ + a2 q⁻²`` has both roots strictly inside the unit circle."""
    return bool(abs(a2) < 1.0 and abs(a1) < 1.0 + a2)


@dataclass(frozen=True)
class Signal:
    """A named signal with a unit (SI, free text such as ``"rad"`` or ``"N"``)."""

    name: str
    unit: str = ""


@dataclass(frozen=True)
class Block:
    """An operator applied to one input before, or one output after, the representation.

    Kinds and parameters (see :data:`BLOCK_KINDS`):

    - ``delay``: ``samples`` >= 0; with ``n = floor(samples)`` and ``α = samples - n``,
      ``v[k] = (1-α) s[k-n] + α s[k-n-1]`` (a fractional part is the frame average of a
      zero-order-held signal delayed by a fraction of a sample);
    - ``dead_zone``: ``threshold`` >= 0 around ``center``: ``v = sign(s-c)·max(|s-c|-th, 0) + c``;
    - ``saturation``: clip to [``lower``, ``upper``];
    - ``play``: backlash/play operator of half-width ``width`` (stateful, starts at the signal);
    - ``first_order_lag``: ``v[k+1] = p v[k] + (1-p) s[k]``, ``pole`` in [0, 1);
    - ``rate_limit``: ``v[k] = v[k-1] + clip(s[k] - v[k-1], -rate, rate)``, ``rate`` > 0 per sample;
    - ``polynomial``: a static curve ``v = c0 + c1 s + c2 s^2 + c3 s^3`` (on an output: a Wiener
      model's curve or a sensor's; on an input: a Hammerstein model's);
    - ``second_order_section``: a linear filter ``(1 + b1 q⁻¹ + b2 q⁻²) / (1 + a1 q⁻¹ + a2 q⁻²)``
      (a monic numerator: the gain is the next block's or the representation's), stable
      (``|a2| < 1``, ``|a1| < 1 + a2``); it starts at rest at its first input sample, ``v[0] =
      g s[0]`` with ``g`` its static gain.  A cascade of sections is any rational filter: the
      first filter of a Wiener–Hammerstein model, before a ``polynomial`` curve or terms.
    """

    kind: str
    signal: str
    params: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """Plain-data form."""
        return {"kind": self.kind, "signal": self.signal, "params": dict(self.params)}


@dataclass(frozen=True, eq=False)
class StateSpace:
    """Discrete-time state space ``x[k+1] = A x + B u``, ``y = C x + D u``.

    An optional operating point ``u0`` (length nu) and ``y0`` (length ny) makes the model act
    on deviations: ``x[k+1] = A x + B (u - u0)``, ``y = C x + D (u - u0) + y0`` (MATLAB's
    ``InputOffset``/``OutputOffset``).  ``u0`` is what keeps an integrating model from drifting;
    ``y0`` is a level the dynamics do not produce (a sensor offset).  Simulation, initial-state
    estimation and prediction work on the deviations; consumers that step the model without
    estimating states (the stepper, FMUs, MPC) use :func:`tendonkit.realize.fold_offsets`,
    which carries them in one constant state.

    ``K`` is an optional innovation (Kalman) gain, ``x[k+1] = A x + B u + K e``, used for
    k-step prediction and state estimation.  Optional nonlinear ``terms`` Θ[k] over outputs and
    inputs (lag >= 0; ``y[k]`` is known before ``x[k+1]``) enter the state update through ``E``
    (n × n_terms): ``x[k+1] = A x + B u + E Θ`` (model extensions made by ``diagnose``).
    """

    A: FloatArray
    B: FloatArray
    C: FloatArray
    D: FloatArray
    x0: FloatArray | None = None
    K: FloatArray | None = None
    terms: tuple[Term, ...] = ()
    E: FloatArray | None = None
    u0: FloatArray | None = None
    y0: FloatArray | None = None
    kind: Literal["state_space"] = "state_space"

    @property
    def n_states(self) -> int:
        """Number of states."""
        return int(self.A.shape[0])

    @property
    def operating_point(self) -> tuple[FloatArray, FloatArray]:
        """``(u0, y0)`` as arrays, zeros where unset."""
        nu, ny = self.B.shape[1], self.C.shape[0]
        u0 = np.zeros(nu) if self.u0 is None else np.asarray(self.u0, dtype=float)
        y0 = np.zeros(ny) if self.y0 is None else np.asarray(self.y0, dtype=float)
        return u0, y0

    @property
    def has_offsets(self) -> bool:
        """Whether a non-zero operating point ``u0`` or ``y0`` is set."""
        return any(v is not None and bool(np.any(np.asarray(v) != 0)) for v in (self.u0, self.y0))


@dataclass(frozen=True, eq=False)
class ARX:
    """MIMO ARX model.

    ``y[k] + sum_i A[i-1] y[k-i] = sum_j B[j-1] u_nk[k-j+1] + offset``, where input ``m`` is
    delayed by ``nk[m]`` samples: ``u_nk[k][m] = u[k - nk[m]][m]``.  ``A`` has ``na`` matrices
    of shape ``(ny, ny)`` (outputs may couple), ``B`` has ``nb`` matrices ``(ny, nu)``; orders
    that differ per input are zero columns.  Optional nonlinear regressors ``terms`` enter with
    coefficients ``term_coefficients`` of shape ``(n_terms, ny)`` (NARX extensions).
    """

    A: tuple[FloatArray, ...]
    B: tuple[FloatArray, ...]
    nk: tuple[int, ...]
    offset: FloatArray | None = None
    terms: tuple[Term, ...] = ()
    term_coefficients: FloatArray | None = None
    kind: Literal["arx"] = "arx"

    @property
    def na(self) -> int:
        """Number of output lags."""
        return len(self.A)

    @property
    def nb(self) -> int:
        """Number of input lags (after the delay)."""
        return len(self.B)


@dataclass(frozen=True, eq=False)
class SparseMap:
    """Sparse nonlinear map ``x[k+1] = Ξᵀ Θ(x[k], u[k])``, ``y = x[output_states]``.

    ``terms`` is Θ as structured :class:`~tendonkit.terms.Term` objects over the model's state
    and input names; ``coefficients`` is Ξ with shape ``(n_terms, n_states)``.
    """

    terms: tuple[Term, ...]
    coefficients: FloatArray
    output_states: tuple[int, ...]
    x0: FloatArray | None = None
    kind: Literal["sparse_map"] = "sparse_map"

    @property
    def n_states(self) -> int:
        """Number of states."""
        return int(self.coefficients.shape[1])


Representation = StateSpace | ARX | SparseMap


@dataclass(frozen=True)
class Provenance:
    """Where a model came from: identifier, its version and options, data hash, training fit.

    ``details`` holds machine-readable results of the identification that are not options
    (plain JSON data: e.g. the threshold a sweep chose, the singular values behind an order).
    """

    identifier: str = ""
    version: str = ""
    options: dict[str, Any] = field(default_factory=dict)
    dataset_hash: str = ""
    training_fit: dict[str, float] = field(default_factory=dict)
    notes: str = ""
    details: dict[str, Any] = field(default_factory=dict)

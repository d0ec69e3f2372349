"""Structured nonlinear terms: the vocabulary of ``sparse_map`` models and model extensions.

A :class:`Term` is a product of :class:`Factor` objects; each factor applies one function from
a closed set to one named signal, possibly delayed (``lag``) or differenced (``diff``).  Terms
are plain data, so a model file that contains them can be loaded without evaluating any code,
and their derivatives are known in closed form (used by nonlinear MPC).

Examples
--------
>>> import numpy as np
>>> t = Term((Factor("x1", power=2), Factor("u1")))
>>> t.label
'x1^2*u1'
>>> get = series_getter({"x1": np.array([2.0]), "u1": np.array([3.0])})
>>> float(t.evaluate(get)[0])
12.0
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ._kernel import CODES, MAX_PRODUCT_POWER, hysteresis_record
from .errors import SchemaError

#: The closed set of functions a factor may apply (``z`` is the scaled, shifted signal).
FUNCTIONS: dict[str, str] = {
    "pow": "z**power",
    "sin": "sin(z)",
    "cos": "cos(z)",
    "tanh": "tanh(z)",
    "sign": "sign(z)",
    "abs": "|z|",
    "dead_zone": "sign(z)*max(|z|-param, 0)",
    "sat": "clip(z, -param, param)",
    "relu": "max(z-param, 0)",
    "play": "play operator of half-width param along time (stateful)",
    "bouc_wen": "Bouc-Wen state h += dz - param*|dz|*h - param2*dz*|h| along time (stateful)",
    "slew_lag": "r += clip(param*(z - r), -param2, param2) along time (stateful)",
}
#: Functions with a memory: their value at a sample depends on the factor's earlier samples.
#: They are hysteresis operators, run along time from the first sample a simulator evaluates
#: (play and slew lag: from ``z`` itself; Bouc-Wen: from ``h = 0``); see :meth:`Factor.value`.
STATEFUL = frozenset({"play", "bouc_wen", "slew_lag"})

_FN_CODES = {name: i for i, name in enumerate(FUNCTIONS)}
assert tuple(FUNCTIONS) == CODES, "the compiled kernel's function codes follow FUNCTIONS"
FloatArray = NDArray[np.float64]
#: ``get(name, lag)`` returns signal ``name`` delayed by ``lag`` samples.
Getter = Callable[[str, int], Any]


@dataclass(frozen=True)
class Factor:
    """One factor ``fn((s[k-lag] - offset) * scale)`` of a term.

    Parameters
    ----------
    signal : str
        Name of a model state, output or input.
    fn : str
        One of :data:`FUNCTIONS`.
    power : int
        Exponent for ``fn="pow"`` (ignored otherwise), >= 1.
    lag : int
        Delay in samples, >= 0.
    diff : int
        0 for the signal itself; ``m >= 1`` for the difference over ``m`` samples,
        ``s[k-lag] - s[k-lag-m]`` (a velocity estimate that averages noise for larger ``m``).
    minus : str
        Empty for the signal itself; the name of a second signal ``r`` for the difference
        ``s - weight·r`` (with ``diff``: ``(s[k-lag] - s[k-lag-m]) - weight·(r[k-lag] -
        r[k-lag-m])``) — a coupling *between two bodies*: the stretch of the spring or the play
        between them, or their relative velocity; or a loop closed through the second signal
        (an actuator whose force also follows the load's position: ``weight`` its stiffness).
    weight : float
        The ``minus`` signal's weight (1 for a difference between two bodies).
    scale, offset : float
        Affine normalisation applied before ``fn``.
    param : float
        Width of a dead zone, level of a saturation, knee of a relu, half-width of a play,
        the first shape parameter of a Bouc-Wen operator.
    param2 : float
        The second shape parameter of a Bouc-Wen operator, the largest step of a slew lag
        (unused by the other functions).

    Notes
    -----
    ``play``, ``bouc_wen`` and ``slew_lag`` are operators with a memory (:data:`STATEFUL`;
    the first two hysteresis operators): their value at a sample depends on the factor's past,
    so a simulator carries their state from step to step and a whole-record evaluation runs
    them along the record.  The play follows ``z`` with a
    lag of at most ``param`` (backlash; a sum of plays of several widths is a
    Prandtl-Ishlinskii operator); the Bouc-Wen state obeys the discretised
    ``dh = dz - param·|dz|·h - param2·dz·|h|`` (Bouc-Wen with exponent 1 and unit initial
    stiffness; ``h`` saturates at ``±1/(param + param2)`` when that is positive).  The slew
    lag is a first-order lag of pole ``1 - param`` whose step is at most ``param2`` (a
    rate-limited actuator: ``r += clip(param·(z - r), ±param2)``, its value ``r`` after the
    step), started at ``z``.
    """

    signal: str
    fn: str = "pow"
    power: int = 1
    lag: int = 0
    diff: int = 0
    scale: float = 1.0
    offset: float = 0.0
    param: float = 0.0
    param2: float = 0.0
    minus: str = ""
    weight: float = 1.0

    @property
    def stateful(self) -> bool:
        """Whether this factor is a hysteresis operator with a memory (:data:`STATEFUL`)."""
        return self.fn in STATEFUL

    @property
    def label(self) -> str:
        """Readable form, e.g. ``sin(x1)`` or ``u2[k-3]^2``."""
        name = self.signal if self.lag == 0 else f"{self.signal}[k-{self.lag}]"
        if self.minus:
            other = self.minus if self.lag == 0 else f"{self.minus}[k-{self.lag}]"
            sign = "+" if self.weight < 0 else "-"
            if abs(self.weight) != 1.0:
                other = f"{abs(self.weight):g}*{other}"
            name = f"({name}{sign}{other})"
        if self.diff:
            name = f"Δ{name}" if self.diff == 1 else f"Δ{self.diff}{name}"
        if self.scale != 1.0 or self.offset != 0.0:
            name = (
                f"({name}-{self.offset:g})*{self.scale:g}"
                if self.offset
                else f"{self.scale:g}*{name}"
            )
        if self.fn == "pow":
            return name if self.power == 1 else f"{name}^{self.power}"
        if self.fn in ("dead_zone", "sat", "relu", "play"):
            return f"{self.fn}({name};{self.param:g})"
        if self.fn in ("bouc_wen", "slew_lag"):
            return f"{self.fn}({name};{self.param:g},{self.param2:g})"
        return f"{self.fn}({name})"

    @property
    def max_lag(self) -> int:
        """Oldest sample this factor reads, in samples back from ``k``."""
        return self.lag + self.diff

    @property
    def signals(self) -> tuple[str, ...]:
        """The signals this factor reads: its own, and the one it is taken relative to."""
        return (self.signal, self.minus) if self.minus else (self.signal,)

    def _z(self, get: Getter) -> FloatArray:
        def at(name: str) -> FloatArray:  # the signal at the lag (minus it `diff` further back)
            v = np.asarray(get(name, self.lag), dtype=float)
            return v - np.asarray(get(name, self.lag + self.diff), dtype=float) if self.diff else v

        s = at(self.signal) - self.weight * at(self.minus) if self.minus else at(self.signal)
        return (s - self.offset) * self.scale

    def value(self, z: FloatArray) -> FloatArray:
        """Apply the function to the normalised signal ``z``.

        A hysteresis operator (:attr:`stateful`) reads ``z`` as a record along its first axis
        and runs from its first sample.
        """
        if self.stateful:
            return _run_stateful(self.fn, np.asarray(z, dtype=float), self.param, self.param2)[0]
        return _apply(
            _FN_CODES[self.fn],
            np.asarray(z, dtype=float),
            float(self.power),
            np.asarray(self.param),
            deriv=False,
        )

    def derivative(self, z: FloatArray) -> FloatArray:
        """Derivative of :meth:`value` with respect to ``z`` (almost everywhere for kinks).

        For a hysteresis operator: with respect to the current sample of ``z``, the past held.
        """
        if self.stateful:
            return _run_stateful(self.fn, np.asarray(z, dtype=float), self.param, self.param2)[1]
        return _apply(
            _FN_CODES[self.fn],
            np.asarray(z, dtype=float),
            float(self.power),
            np.asarray(self.param),
            deriv=True,
        )

    def evaluate(self, get: Getter) -> FloatArray:
        """Evaluate with ``get(name, lag)`` returning the signal ``name`` delayed by ``lag``."""
        return self.value(self._z(get))

    def to_dict(self) -> dict[str, Any]:
        """Plain-data form; defaults are left out to keep files short."""
        out: dict[str, Any] = {"signal": self.signal, "fn": self.fn}
        for key, default in (
            ("power", 1),
            ("lag", 0),
            ("diff", 0),
            ("scale", 1.0),
            ("offset", 0.0),
            ("param", 0.0),
            ("param2", 0.0),
            ("minus", ""),
            ("weight", 1.0),
        ):
            val = getattr(self, key)
            if val != default:
                out[key] = val
        return out


def series_getter(signals: Mapping[str, FloatArray]) -> Getter:
    """Accessor over whole time series: ``get(name, lag)[k] = signals[name][k - lag]``.

    Samples before the start repeat the first sample (edge padding); callers that need exact
    regressors discard the first :attr:`Term.max_lag` rows.
    """

    def get(name: str, lag: int) -> FloatArray:
        s = np.asarray(signals[name], dtype=float)
        if lag == 0:
            return s
        if lag >= s.shape[0]:
            return np.full_like(s, s[0])
        return np.concatenate([np.full(lag, s[0]), s[:-lag]])

    return get


@dataclass(frozen=True)
class Term:
    """A product of factors; the empty product is the constant 1."""

    factors: tuple[Factor, ...] = field(default_factory=tuple)

    @property
    def label(self) -> str:
        """Readable form such as ``x1*u2`` or ``1``."""
        return "*".join(f.label for f in self.factors) if self.factors else "1"

    @property
    def max_lag(self) -> int:
        """Oldest sample any factor reads."""
        return max((f.max_lag for f in self.factors), default=0)

    @property
    def signals(self) -> set[str]:
        """Names of the signals this term reads."""
        return {s for f in self.factors for s in f.signals}

    @property
    def stateful(self) -> bool:
        """Whether a factor is a hysteresis operator (its value has a memory)."""
        return any(f.stateful for f in self.factors)

    def evaluate(self, get: Getter, shape: tuple[int, ...] = ()) -> FloatArray:
        """Evaluate the product; ``shape`` is used for the constant term."""
        if not self.factors:  # the constant term
            return np.ones(shape)
        out: FloatArray | float = 1.0
        for f in self.factors:
            out = out * f.evaluate(get)
        # not ``isinstance(out, float)``: a scalar product is a numpy float, which is a float
        return np.asarray(out)

    def gradient(self, get: Getter) -> dict[str, FloatArray]:
        """Partial derivatives with respect to the current (lag 0, undifferenced) signals.

        Returns a mapping ``signal name -> dTerm/dsignal[k]``.  Factors on delayed signals are
        constants here; a differenced factor depends on ``s[k]`` with derivative ``+1 * scale``,
        a relative one on its ``minus`` signal with ``-weight * scale``.
        """
        values = [f.evaluate(get) for f in self.factors]
        grads: dict[str, FloatArray] = {}
        for i, f in enumerate(self.factors):
            if f.lag != 0:
                continue
            dz = f.derivative(f._z(get)) * f.scale
            rest: FloatArray | float = 1.0
            for j, v in enumerate(values):
                if j != i:
                    rest = rest * v
            g = np.asarray(dz * rest)
            for name, gi in zip(f.signals, (g, -f.weight * g)):
                grads[name] = grads[name] + gi if name in grads else gi
        return grads

    def to_dict(self) -> dict[str, Any]:
        """Plain-data form."""
        return {"factors": [f.to_dict() for f in self.factors]}


def term_matrix(terms: Sequence[Term], get: Getter, n: int) -> FloatArray:
    """Evaluate every term and stack the results as columns, shape ``(n, n_terms)``."""
    out = np.empty((n, len(terms)))
    for j, t in enumerate(terms):
        out[:, j] = np.broadcast_to(t.evaluate(get, (n,)), (n,))
    return out


_FACTOR_KEYS = {
    "signal", "fn", "power", "lag", "diff", "scale", "offset", "param", "param2", "minus",
    "weight",
}  # fmt: skip
#: Bounds on a factor read from a file: lags as a delay's (100,000 samples), powers to 64.
MAX_TERM_LAG = 100_000
MAX_POWER = 64


def _finite(value: int | float) -> bool:
    try:
        return bool(np.isfinite(float(value)))
    except OverflowError:
        return False


def factor_from_dict(data: Any, where: str, problems: list[str]) -> Factor | None:
    """Parse a factor, appending every problem found to ``problems``."""
    if not isinstance(data, dict):
        problems.append(f"{where}: expected an object, found {type(data).__name__}.")
        return None
    unknown = set(data) - _FACTOR_KEYS
    if unknown:
        problems.append(f"{where}: unknown keys {sorted(unknown)}; allowed {sorted(_FACTOR_KEYS)}.")
    ok = True
    signal = data.get("signal")
    if not isinstance(signal, str) or not signal:
        problems.append(f"{where}.signal: expected a signal name, found {signal!r}.")
        ok = False
    minus = data.get("minus", "")
    if not isinstance(minus, str) or (minus and minus == signal):
        problems.append(
            f"{where}.minus: expected the name of another signal (or none), found {minus!r}."
        )
        ok = False
    fn = data.get("fn", "pow")
    if not isinstance(fn, str) or fn not in FUNCTIONS:
        problems.append(f"{where}.fn: {fn!r} is not one of {sorted(FUNCTIONS)}.")
        ok = False
    ints = {}
    for key, default, low, high in (
        ("power", 1, 1, MAX_POWER),
        ("lag", 0, 0, MAX_TERM_LAG),
        ("diff", 0, 0, MAX_TERM_LAG),
    ):
        val = data.get(key, default)
        if isinstance(val, bool) or not isinstance(val, int) or not low <= val <= high:
            problems.append(
                f"{where}.{key}: expected an integer from {low} to {high}, found {val!r}."
            )
            ok = False
        else:
            ints[key] = val
    floats: dict[str, float] = {}
    for key, fdefault in (
        ("scale", 1.0),
        ("offset", 0.0),
        ("param", 0.0),
        ("param2", 0.0),
        ("weight", 1.0),
    ):
        val = data.get(key, fdefault)
        if isinstance(val, bool) or not isinstance(val, int | float) or not _finite(val):
            problems.append(f"{where}.{key}: expected a finite number, found {val!r}.")
            ok = False
        else:
            floats[key] = float(val)
    if ok and fn == "play" and floats["param"] < 0:
        problems.append(
            f"{where}.param: a play's half-width must be >= 0, found {floats['param']!r}."
        )
        ok = False
    if ok and not minus and floats["weight"] != 1.0:
        problems.append(
            f"{where}.weight: weighs the second signal (minus), and this factor has none; "
            f"found {floats['weight']!r}."
        )
        ok = False
    if ok and fn == "slew_lag" and not (0.0 < floats["param"] <= 1.0 and floats["param2"] > 0):
        problems.append(
            f"{where}: a slew lag's param (its gain per sample) must be in (0, 1] and its param2 "
            f"(its largest step) > 0, found {floats['param']!r} and {floats['param2']!r}."
        )
        ok = False
    if not ok:
        return None
    return Factor(signal=signal, fn=fn, minus=minus, **ints, **floats)  # type: ignore[arg-type]


def term_from_dict(data: Any, where: str, problems: list[str]) -> Term | None:
    """Parse a term, appending every problem found to ``problems``."""
    if not isinstance(data, dict) or not isinstance(data.get("factors", None), list):
        problems.append(f"{where}: expected an object with a 'factors' list.")
        return None
    factors = [
        factor_from_dict(f, f"{where}.factors[{i}]", problems)
        for i, f in enumerate(data["factors"])
    ]
    if any(f is None for f in factors):
        return None
    return Term(tuple(f for f in factors if f is not None))


@functools.lru_cache(maxsize=512)
def _compiled_structure(terms: tuple[Term, ...]) -> dict[str, Any]:
    """The read-only attributes of a :class:`CompiledTerms` for ``terms`` (cached; not the
    terms themselves, which each instance keeps as it was given them)."""
    keys: set[tuple[str, int]] = set()
    for t in terms:
        for f in t.factors:
            for name in f.signals:
                keys.add((name, f.lag))
                if f.diff:
                    keys.add((name, f.lag + f.diff))
    ordered = tuple(sorted(keys, key=lambda k: (k[1], k[0])))
    index = {k: i for i, k in enumerate(ordered)}
    nt = len(terms)
    mf = max((len(t.factors) for t in terms), default=0) or 1
    out: dict[str, Any] = {"keys": ordered}
    for name in ("_cur", "_prev", "_cur2", "_prev2"):
        out[name] = np.zeros((nt, mf), dtype=int)
    for name in ("_hasdiff", "_hasminus", "_active"):
        out[name] = np.zeros((nt, mf), dtype=bool)
    out["_code"] = np.full((nt, mf), -1, dtype=int)
    for name, fill in (("_power", 1.0), ("_scale", 1.0), ("_offset", 0.0), ("_param", 0.0),
                       ("_param2", 0.0), ("_weight", 1.0)):  # fmt: skip
        out[name] = np.full((nt, mf), fill)
    for i, t in enumerate(terms):
        for j, f in enumerate(t.factors):
            out["_cur"][i, j] = index[(f.signal, f.lag)]
            if f.diff:
                out["_prev"][i, j] = index[(f.signal, f.lag + f.diff)]
                out["_hasdiff"][i, j] = True
            if f.minus:  # the ``minus`` signal's keys (current and differenced)
                out["_cur2"][i, j] = index[(f.minus, f.lag)]
                out["_prev2"][i, j] = index[(f.minus, f.lag + f.diff)]
                out["_hasminus"][i, j] = True
            out["_active"][i, j] = True
            out["_code"][i, j] = _FN_CODES[f.fn]
            for name, value in (("_power", f.power), ("_scale", f.scale), ("_offset", f.offset),
                                ("_param", f.param), ("_param2", f.param2),
                                ("_weight", f.weight)):  # fmt: skip
                out[name][i, j] = value
    out["_anydiff"], out["_anyminus"] = bool(out["_hasdiff"].any()), bool(out["_hasminus"].any())
    code_of, power = out["_code"], out["_power"]
    stateful_codes = [_FN_CODES[name] for name in STATEFUL]
    # one group per function (and per exponent for powers: evaluating a group of equal
    # exponents needs no search for them at every step)
    groups: dict[tuple[int, float | None], tuple[NDArray[np.intp], ...]] = {}
    for code in np.unique(code_of):
        if code < 0 or code in stateful_codes:
            continue
        mask = code_of == code
        if code == _FN_CODES["pow"]:
            for p in np.unique(power[mask]):
                groups[int(code), float(p)] = np.nonzero(mask & (power == p))
        else:
            groups[int(code), None] = np.nonzero(mask)
    out["_groups"] = groups
    # (term, factor) positions of the hysteresis operators, and their function names
    out["_memory"] = tuple(
        (i, j, t.factors[j].fn)
        for i, t in enumerate(terms)
        for j in range(len(t.factors))
        if t.factors[j].stateful
    )
    for value in out.values():  # shared by every instance: read only
        if isinstance(value, np.ndarray):
            value.flags.writeable = False
    return out


class CompiledTerms:
    """Vectorised evaluator for a fixed list of terms.

    The terms read a fixed set of *keys* ``(signal, lag)``; callers provide their values as an
    array ``values`` of shape ``(n_keys, *batch)`` in the order of :attr:`keys`.  Evaluation
    costs a handful of numpy calls whatever the number of terms, so simulators can call it once
    per time step, and regression code once for a whole record (batch = samples).
    """

    terms: tuple[Term, ...]
    keys: tuple[tuple[str, int], ...]
    _cur: NDArray[np.int_]
    _prev: NDArray[np.int_]
    _cur2: NDArray[np.int_]
    _prev2: NDArray[np.int_]
    _hasdiff: NDArray[Any]
    _hasminus: NDArray[Any]
    _active: NDArray[np.bool_]
    _code: NDArray[np.int_]
    _power: FloatArray
    _scale: FloatArray
    _offset: FloatArray
    _param: FloatArray
    _param2: FloatArray
    _weight: FloatArray
    _anydiff: bool
    _anyminus: bool
    _groups: dict[tuple[int, float | None], tuple[NDArray[np.intp], ...]]
    _memory: tuple[tuple[int, int, str], ...]

    def __init__(self, terms: Sequence[Term]) -> None:
        # The index arrays depend on the terms alone and are only read: a search of candidate
        # extensions compiles the same terms thousands of times, so they are built once
        # (:func:`_compiled_structure`); each instance holds its own operators' state, and its
        # own terms (equal terms share the arrays: 0.0 and -0.0, 3 and 3.0 compare equal).
        self.terms = tuple(terms)
        self.__dict__.update(_compiled_structure(self.terms))
        self.reset()

    @property
    def stateful(self) -> bool:
        """Whether a term holds a hysteresis operator (:data:`STATEFUL`)."""
        return bool(self._memory)

    def reset(self) -> None:
        """Forget the hysteresis operators' past: the next step is their first.

        :attr:`state`, shape ``(n_terms, max factors, 2)``, holds every operator's state
        (NaN before its first step); saving and restoring it resumes a simulation exactly.
        """
        self.state = np.full((len(self.terms), self._cur.shape[1], 2), np.nan)

    def _memory_values(
        self, z: FloatArray, out: FloatArray, der: FloatArray | None, commit: bool
    ) -> None:
        """Fill the hysteresis operators' entries of ``out`` (and ``der``) in place.

        One step (``z`` of shape ``(nt, mf)``) continues from the held state, which is
        advanced when ``commit``; a record (``(nt, mf, n)``) runs from its first sample.
        """
        if z.ndim > 3:
            raise SchemaError(
                "Operators with a memory (play, bouc_wen, slew_lag) are evaluated one step or one record at "
                f"a time, not on a batch of shape {z.shape[2:]}."
            )
        for i, j, fn in self._memory:
            p, p2 = float(self._param[i, j]), float(self._param2[i, j])
            if z.ndim == 2:
                v, d, new = _step_stateful(fn, float(z[i, j]), self.state[i, j], p, p2)
                if commit:
                    self.state[i, j] = new
            else:
                v, d = _run_stateful(fn, z[i, j], p, p2)  # type: ignore[assignment]
            out[i, j] = v
            if der is not None:
                der[i, j] = d

    @property
    def n_terms(self) -> int:
        """Number of terms."""
        return len(self.terms)

    def _z(self, values: FloatArray) -> FloatArray:
        # the compiled kernel's order of operations: (s - s_prev) - (r - r_prev), then the
        # offset and the scale
        z = values[self._cur]
        if self._anydiff:
            z = z - np.where(_expand(self._hasdiff, z), values[self._prev], 0.0)
        if self._anyminus:
            r = values[self._cur2]
            if self._anydiff:
                r = r - np.where(_expand(self._hasdiff, r), values[self._prev2], 0.0)
            z = z - np.where(_expand(self._hasminus, z), _expand(self._weight, r) * r, 0.0)
        return (z - _expand(self._offset, z)) * _expand(self._scale, z)

    def evaluate(self, values: FloatArray, commit: bool = True) -> FloatArray:
        """Term values, shape ``(n_terms, *batch)``.

        With hysteresis operators (:attr:`stateful`) ``values`` is one time step (shape
        ``(n_keys,)``; the operators' state advances unless ``commit`` is false) or one whole
        record (``(n_keys, n)``, run from its first sample; the held state is not used).
        """
        values = np.asarray(values, dtype=float)
        batch = values.shape[1:]
        if self.n_terms == 0:
            return np.zeros((0, *batch))
        if not self.keys:  # only constant terms
            return np.ones((self.n_terms, *batch))
        z = self._z(values)
        out = np.ones_like(z)
        for (code, p), idx in self._groups.items():
            out[idx] = _apply(code, z[idx], p, self._param[idx], deriv=False)
        if self._memory:
            self._memory_values(z, out, None, commit)
        return np.prod(out, axis=1)

    def jacobian(self, values: FloatArray) -> FloatArray:
        """Derivatives of every term with respect to every key, shape ``(n_terms, n_keys, *batch)``.

        Differenced factors contribute ``+scale`` to their current key and ``-scale`` to their
        previous one; a relative factor (``minus``) the opposite, times its ``weight``, to its
        second signal's keys.
        ``sign`` and the kinks of ``abs``, ``dead_zone``, ``sat`` and ``relu`` use their
        derivative almost everywhere.
        """
        values = np.asarray(values, dtype=float)
        batch = values.shape[1:]
        nt, mf = self._cur.shape
        jac = np.zeros((nt, len(self.keys), *batch))
        if nt == 0 or not self.keys:
            return jac
        z = self._z(values)
        val = np.ones_like(z)
        der = np.zeros_like(z)
        for (code, p), idx in self._groups.items():
            val[idx] = _apply(code, z[idx], p, self._param[idx], deriv=False)
            der[idx] = _apply(code, z[idx], p, self._param[idx], deriv=True)
        if self._memory:  # with respect to the current sample, the operators' past held
            self._memory_values(z, val, der, commit=False)
        for j in range(mf):
            others = (
                np.prod(np.delete(val, j, axis=1), axis=1) if mf > 1 else np.ones_like(val[:, 0])
            )
            d = der[:, j] * _expand(self._scale[:, j], der[:, j]) * others
            rows = np.nonzero(self._active[:, j])[0]
            for r in rows:
                jac[r, self._cur[r, j]] += d[r]
                if self._hasdiff[r, j]:
                    jac[r, self._prev[r, j]] -= d[r]
                if self._hasminus[r, j]:
                    w = self._weight[r, j]
                    jac[r, self._cur2[r, j]] -= w * d[r]
                    if self._hasdiff[r, j]:
                        jac[r, self._prev2[r, j]] += w * d[r]
        return jac


def _step_stateful(
    fn: str, z: float, state: Sequence[float], param: float, param2: float
) -> tuple[float, float, tuple[float, float]]:
    """One sample of a hysteresis operator: ``(value, d value / d z, new state)``.

    The state is two numbers, NaN before the first sample: the play's or the slew lag's
    output (and nothing), or the Bouc-Wen operator's previous ``z`` and its ``h``.
    """
    z, a, b = float(z), float(state[0]), float(state[1])
    if fn == "play":
        if math.isnan(a):
            return z, 1.0, (z, 0.0)
        p = min(max(a, z - param), z + param)
        return p, float(p != a), (p, 0.0)
    if fn == "slew_lag":
        if math.isnan(a):
            return z, 1.0, (z, 0.0)
        step = param * (z - a)
        r = a + min(max(step, -param2), param2)
        return r, param if abs(step) < param2 else 0.0, (r, 0.0)
    if math.isnan(a):  # bouc_wen: starts from h = 0
        return 0.0, 1.0, (z, 0.0)
    d = z - a
    h = b + d - param * abs(d) * b - param2 * d * abs(b)
    sd = 1.0 if d > 0 else (-1.0 if d < 0 else 0.0)
    return h, 1.0 - param * sd * b - param2 * abs(b), (z, h)


def _run_stateful(
    fn: str, z: FloatArray, param: float, param2: float
) -> tuple[FloatArray, FloatArray]:
    """A hysteresis operator run along the first axis of ``z``: values and derivatives."""
    if z.shape[0] == 0:
        return z.copy(), z.copy()
    flat = np.ascontiguousarray(z.reshape(z.shape[0], -1).T, dtype=float)
    val, der = np.empty_like(flat), np.empty_like(flat)
    for c in range(flat.shape[0]):  # compiled: what _step_stateful does, sample by sample
        val[c], der[c] = hysteresis_record(_FN_CODES[fn], flat[c], float(param), float(param2))
    return val.T.reshape(z.shape), der.T.reshape(z.shape)


def _expand(a: FloatArray, like: FloatArray) -> FloatArray:
    return a.reshape(a.shape + (1,) * (like.ndim - a.ndim))


def _product_power(z: Any, p: int) -> Any:
    """``z ** p`` as ``((z·z)·z)…`` for ``p`` >= 1 (a new array for an array ``z``), in the
    order of the compiled kernel's ``_fn``, so both give the same number."""
    out = +z
    for _ in range(p - 1):
        out = out * z
    return out


def _pow(z: FloatArray, p: float, deriv: bool) -> FloatArray:
    """``z ** p`` or its derivative ``p · z ** (p - 1)``; integer exponents up to
    :data:`MAX_PRODUCT_POWER` by repeated products."""
    e = p - 1 if deriv else p
    if e == 0:
        v = np.ones_like(z)
    elif 1 <= e <= MAX_PRODUCT_POWER and e == int(e):
        v = _product_power(z, int(e))
    else:
        v = z**e
    return p * v if deriv else v


def _apply(
    code: int, z: FloatArray, power: float | None, param: FloatArray, deriv: bool
) -> FloatArray:
    """Function ``code`` (its derivative when ``deriv``) of ``z``; ``power`` is the exponent of
    ``pow`` (one for all of ``z``), unused by the other functions."""
    fn = list(FUNCTIONS)[code]
    if fn == "pow":
        assert power is not None
        return _pow(np.asarray(z, dtype=float), power, deriv)
    param = _expand(param, z)
    if fn == "sin":
        return np.cos(z) if deriv else np.sin(z)
    if fn == "cos":
        return -np.sin(z) if deriv else np.cos(z)
    if fn == "tanh":
        return 1.0 - np.tanh(z) ** 2 if deriv else np.tanh(z)
    if fn == "sign":
        return np.zeros_like(z) if deriv else np.sign(z)
    if fn == "abs":
        return np.sign(z) if deriv else np.abs(z)
    if fn == "dead_zone":
        if deriv:
            return (np.abs(z) > param).astype(float)
        return np.sign(z) * np.maximum(np.abs(z) - param, 0.0)
    if fn == "sat":
        return (np.abs(z) < param).astype(float) if deriv else np.clip(z, -param, param)
    if fn == "relu":
        return (z > param).astype(float) if deriv else np.maximum(z - param, 0.0)
    raise SchemaError(f"Unknown factor function {fn!r}.")  # pragma: no cover


def scalar_evaluator(ct: CompiledTerms) -> Callable[..., list[float]]:
    """A pure-Python evaluator for one time step: ``f(values) -> term values``.

    ``values`` lists the current value of every key of ``ct`` (same order as ``ct.keys``).
    Hysteresis operators keep their state in ``ct.state`` (``ct.reset()`` starts them again).
    For the few terms of an extended model this is several times faster per step than the
    vectorised :meth:`CompiledTerms.evaluate`, which pays numpy's call overhead.
    """

    spec = []
    slot = 0
    where: list[tuple[int, int]] = []  # the operators' places in ct.state
    for i, t in enumerate(ct.terms):
        factors = []
        for j, f in enumerate(t.factors):
            prev = int(ct._prev[i, j]) if ct._hasdiff[i, j] else -1
            cur2 = int(ct._cur2[i, j]) if ct._hasminus[i, j] else -1
            prev2 = int(ct._prev2[i, j]) if ct._hasminus[i, j] and ct._hasdiff[i, j] else -1
            mem = -1
            if f.stateful:
                mem, slot = slot, slot + 1
                where.append((i, j))
            factors.append(
                (
                    int(ct._cur[i, j]),
                    prev,
                    cur2,
                    prev2,
                    f.weight,
                    f.fn,
                    f.power,
                    f.scale,
                    f.offset,
                    f.param,
                    f.param2,
                    mem,
                )
            )
        spec.append(tuple(factors))

    def value(fn: str, z: float, power: int, param: float) -> float:
        if fn == "pow":
            if 1 < power <= MAX_PRODUCT_POWER and power == int(power):  # as the kernel
                return float(_product_power(z, int(power)))
            return z**power
        if fn == "sin":
            return math.sin(z)
        if fn == "cos":
            return math.cos(z)
        if fn == "tanh":
            return math.tanh(z)
        if fn == "sign":
            return (z > 0) - (z < 0)
        if fn == "abs":
            return abs(z)
        if fn == "dead_zone":
            return math.copysign(max(abs(z) - param, 0.0), z)
        if fn == "sat":
            return min(max(z, -param), param)
        return max(z - param, 0.0)  # relu

    def evaluate(v: Sequence[float], commit: bool = True) -> list[float]:
        """Term values for one step; hysteresis operators advance unless ``commit`` is false."""
        out = []
        for factors in spec:
            prod = 1.0
            for (
                cur,
                prev,
                cur2,
                prev2,
                weight,
                fn,
                power,
                scale,
                offset,
                param,
                param2,
                mem,
            ) in factors:
                z = v[cur] - v[prev] if prev >= 0 else v[cur]
                if cur2 >= 0:
                    z = z - weight * (v[cur2] - v[prev2] if prev2 >= 0 else v[cur2])
                if mem >= 0:
                    st = ct.state[where[mem]]
                    val, _, new = _step_stateful(fn, (z - offset) * scale, st, param, param2)
                    if commit:
                        st[:] = new
                    prod *= val
                else:
                    prod *= value(fn, (z - offset) * scale, power, param)
            out.append(prod)
        return out

    return evaluate

"""Step-wise evaluation of a model: one sample at a time, as an FMU or a controller needs it.

:class:`Stepper` has the semantics of :func:`tendonkit.simulate.simulate` with
``initial="model"``, sample by sample, for every representation of the schema and every block
kind.  Over a whole sequence, ``[stepper.step(u[k]) for k in ...]`` equals
``simulate(model, u, initial="model")`` to rounding.  The conventions it follows:

* input blocks act on the inputs before the dynamics, output blocks on the modelled outputs
  after them, in their listed order; a ``delay`` is padded with its first input sample,
  ``play``, ``rate_limit``, ``first_order_lag`` and ``second_order_section`` start at their
  first input sample (a section at rest: ``v[0] = g s[0]``, ``g`` its static gain);
* ``state_space``: ``y = C x + D u`` then ``x ← A x + B u (+ E Θ)`` from the stored ``x0``;
  the terms' histories hold the first input sample and zero outputs before the start;
* ``arx``: the histories before the start are zero (inputs and outputs);
* ``sparse_map``: ``y = x[output_states]`` then ``x ← Ξᵀ Θ``; states before the start are
  ``x0``, inputs the first input sample;
* once an output is not finite, every later output is NaN (before the output blocks).

Each step splits into :meth:`Stepper.outputs` (the outputs at the current instant for the
current inputs; no state change) and :meth:`Stepper.advance` (commit the inputs and move one
sample on), which is what an FMI co-simulation slave with direct feedthrough needs.

Examples
--------
>>> import numpy as np
>>> from tendonkit.schema import Model, Signal, StateSpace
>>> ss = StateSpace(np.array([[0.5]]), np.array([[1.0]]), np.array([[1.0]]), np.array([[0.0]]))
>>> s = Stepper(Model("m", 1.0, (Signal("u"),), (Signal("y"),), ss))
>>> [float(s.step([1.0])[0]) for _ in range(3)]
[0.0, 1.0, 1.5]
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ._representations import section_gain
from .errors import DataError
from .realize import arx_lag_matrices, fold_offsets
from .schema import ARX, Block, Model, SparseMap, StateSpace
from .simulate import arx_max_lag, curve_value, split_delay
from .terms import CompiledTerms, scalar_evaluator

__all__ = ["Stepper", "feedthrough", "history_length"]

FloatArray = NDArray[np.float64]


class _BlockState:
    """One block on one signal, evaluated sample by sample (see :func:`simulate.apply_block`)."""

    def __init__(self, block: Block) -> None:
        self.kind = block.kind
        self.p = {k: float(v) for k, v in block.params.items()}
        self.started = False
        self.fifo: deque[float] = deque()
        self.v = 0.0  # play / rate_limit: current output; first_order_lag: deviation
        self.s0 = 0.0  # first_order_lag, second_order_section: first input sample
        self.w = [0.0, 0.0]  # second_order_section: transposed direct form II state
        self.gain = section_gain(self.p) if self.kind == "second_order_section" else 1.0

    def value(self, s: float) -> float:
        """Block output for input ``s`` at the current sample (no state change)."""
        kind, p = self.kind, self.p
        if kind == "dead_zone":
            z = s - p["center"]
            return float(np.sign(z) * max(abs(z) - p["threshold"], 0.0) + p["center"])
        if kind == "saturation":
            return min(max(s, p["lower"]), p["upper"])
        if kind == "delay":
            n, a = split_delay(p["samples"])
            if (n == 0 and a == 0) or not self.started:
                return s
            # fifo = [s[k-n-1], ..., s[k-1]]
            return (1.0 - a) * (self.fifo[1] if n else s) + a * self.fifo[0]
        if kind == "play":
            v = self.v if self.started else s
            w = p["width"]
            if s - v > w:
                v = s - w
            elif s - v < -w:
                v = s + w
            return v
        if kind == "first_order_lag":
            return s if not self.started else self.v + self.s0
        if kind == "polynomial":
            return float(curve_value(p, s))
        if kind == "second_order_section":
            if not self.started:
                return self.gain * s
            # lfilter's order of operations (y = w0 + b0·x), then the start's level
            return (self.w[0] + (s - self.s0)) + self.gain * self.s0
        # rate_limit
        v = self.v if self.started else s
        r = p["rate"]
        return v + min(max(s - v, -r), r)

    def commit(self, s: float) -> float:
        """Output for ``s`` and advance one sample."""
        out = self.value(s)
        kind, p = self.kind, self.p
        if kind == "delay":
            n, a = split_delay(p["samples"])
            if n or a:
                if not self.started:
                    self.fifo.extend([s] * (n + 1))
                self.fifo.append(s)
                self.fifo.popleft()
        elif kind in ("play", "rate_limit"):
            self.v = out
        elif kind == "first_order_lag":
            a = p["pole"]
            if not self.started:
                self.s0, self.v = s, 0.0
            # The next output of lfilter([0, 1-a], [1, -a], s - s0): z = b1 x - a1 y.
            self.v = (s - self.s0) * (1.0 - a) - self.v * (-a)
        elif kind == "second_order_section":
            if not self.started:
                self.s0, self.w = s, [0.0, 0.0]
            # lfilter([1, b1, b2], [1, a1, a2], s - s0) in transposed direct form II, its
            # operations in scipy's order, so that the two agree to the last bit
            x = s - self.s0
            z = self.w[0] + x
            self.w = [(self.w[1] + x * p["b1"]) - z * p["a1"], x * p["b2"] - z * p["a2"]]
        self.started = True
        return out


class _Chain:
    """The blocks of a model on inputs or outputs, grouped by signal, in model order."""

    def __init__(self, blocks: Sequence[Block], names: Sequence[str]) -> None:
        self.items = [(list(names).index(b.signal), _BlockState(b)) for b in blocks]

    def value(self, x: FloatArray) -> FloatArray:
        if not self.items:
            return x
        out = x.copy()
        for j, state in self.items:
            out[j] = state.value(float(out[j]))
        return out

    def commit(self, x: FloatArray) -> FloatArray:
        if not self.items:
            return x
        out = x.copy()
        for j, state in self.items:
            out[j] = state.commit(float(out[j]))
        return out


class Stepper:
    """Evaluate ``model`` one sample at a time (module docs give the conventions).

    Parameters
    ----------
    model : Model
        Any representation, with any blocks.

    Attributes
    ----------
    time_index : int
        Samples advanced since :meth:`reset`.
    """

    def __init__(self, model: Model) -> None:
        self.model = model
        self.nu, self.ny = len(model.inputs), len(model.outputs)
        rep = model.representation
        if isinstance(rep, StateSpace):
            rep = fold_offsets(rep)  # an operating point rides on a constant state
        self._rep = rep
        self._lag = history_length(model)
        if isinstance(rep, StateSpace) and rep.terms:
            assert rep.E is not None
            self._ct = CompiledTerms(rep.terms)
        elif isinstance(rep, ARX):
            self._G = arx_lag_matrices(rep, self.nu) if rep.B else [np.zeros((self.ny, self.nu))]
            self._acat = np.hstack(rep.A) if rep.A else np.zeros((self.ny, 0))
            self._off = np.zeros(self.ny) if rep.offset is None else rep.offset
            coef = rep.term_coefficients
            self._terms = bool(rep.terms) and coef is not None
            if self._terms:
                assert coef is not None
                self._ct = CompiledTerms(rep.terms)
                self._eval = scalar_evaluator(self._ct)
                self._coef_t = coef.T.copy()
        elif isinstance(rep, SparseMap):
            self._ct = CompiledTerms(rep.terms)
            self._states = [s.name for s in model.states]
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Return to the model's initial state (``initial="model"``)."""
        model, rep = self.model, self._rep
        self.time_index = 0
        self._dead = False
        if getattr(self, "_ct", None) is not None:  # hysteresis operators start afresh
            self._ct.reset()
        self._in_blocks = _Chain(model.input_blocks, model.input_names)
        self._out_blocks = _Chain(model.output_blocks, model.output_names)
        if isinstance(rep, StateSpace):
            self._x = np.zeros(rep.n_states) if rep.x0 is None else np.array(rep.x0, dtype=float)
        elif isinstance(rep, SparseMap):
            self._x = np.zeros(rep.n_states) if rep.x0 is None else np.array(rep.x0, dtype=float)
        # Histories, newest last; filled on the first advance (they need the first input).
        self._u_hist: deque[FloatArray] = deque()
        self._y_hist: deque[FloatArray] = deque()
        self._x_hist: deque[FloatArray] = deque()
        # Where a term's signal lives; later entries win, as in simulate's history dicts
        # (state space: inputs then outputs; sparse map: states then inputs).
        self._sources: dict[str, tuple[deque[FloatArray], int]] = {}
        if isinstance(rep, SparseMap):
            self._sources.update((n, (self._x_hist, j)) for j, n in enumerate(self._states))
            self._sources.update((n, (self._u_hist, j)) for j, n in enumerate(model.input_names))
        else:
            self._sources.update((n, (self._u_hist, j)) for j, n in enumerate(model.input_names))
            self._sources.update((n, (self._y_hist, j)) for j, n in enumerate(model.output_names))

    def get_state(self) -> dict[str, Any]:
        """The whole evaluation state as plain data (JSON-serialisable; NaN as ``None``).

        :meth:`set_state` with it returns this stepper, or another one of the same model, to
        exactly this sample: what an FMU's ``fmi2GetFMUstate`` and serialisation need.
        """

        def arr(a: Any) -> list[Any]:
            return [None if not np.isfinite(v) else float(v) for v in np.ravel(a)]

        blocks = [
            {"started": b.started, "fifo": list(b.fifo), "v": b.v, "s0": b.s0, "w": list(b.w)}
            for chain in (self._in_blocks, self._out_blocks)
            for _, b in chain.items
        ]
        return {
            "time_index": self.time_index,
            "dead": self._dead,
            "x": arr(self._x) if hasattr(self, "_x") else [],
            "u_hist": [arr(a) for a in self._u_hist],
            "y_hist": [arr(a) for a in self._y_hist],
            "x_hist": [arr(a) for a in self._x_hist],
            "blocks": blocks,
            "hysteresis": arr(self._ct.state) if getattr(self, "_ct", None) is not None else [],
        }

    def set_state(self, state: Mapping[str, Any]) -> None:
        """Return to a state taken by :meth:`get_state` (of a stepper of the same model).

        Raises
        ------
        DataError
            The state does not belong to this model (other sizes or block count).
        """

        def arr(values: Sequence[Any], n: int, what: str) -> FloatArray:
            out = np.array([np.nan if v is None else float(v) for v in values], dtype=float)
            if out.shape != (n,):
                raise DataError(f"A saved state of another model: {what} has {out.size} values.")
            return out

        try:
            blocks = list(state["blocks"])
            chains = [b for chain in (self._in_blocks, self._out_blocks) for _, b in chain.items]
            if len(blocks) != len(chains):
                raise DataError("A saved state of another model: the blocks differ.")
            nx = len(self._x) if hasattr(self, "_x") else 0
            x = arr(state["x"], nx, "x")
            hists = [
                [arr(a, n, name) for a in state[name]]
                for name, n in (("u_hist", self.nu), ("y_hist", self.ny), ("x_hist", nx))
            ]
            ct = getattr(self, "_ct", None)
            memory = None
            if ct is not None:  # states saved before hysteresis operators existed have none
                saved = state.get("hysteresis") or [None] * ct.state.size
                memory = arr(saved, ct.state.size, "hysteresis").reshape(ct.state.shape)
            self.time_index = int(state["time_index"])
            self._dead = bool(state["dead"])
        except (KeyError, TypeError, ValueError) as exc:
            raise DataError(f"Not a saved stepper state: {exc}.") from exc
        if nx:
            self._x = x
        if memory is not None:
            self._ct.state[...] = memory
        for target, values in zip((self._u_hist, self._y_hist, self._x_hist), hists, strict=True):
            target.clear()  # the same deques: the term sources keep pointing at them
            target.extend(values)
        for b, saved in zip(chains, blocks, strict=True):
            b.started = bool(saved["started"])
            b.fifo = deque(float(v) for v in saved["fifo"])
            b.v, b.s0 = float(saved["v"]), float(saved["s0"])
            b.w = [float(v) for v in saved.get("w", (0.0, 0.0))]

    # ------------------------------------------------------------------ public
    def outputs(self, u: Sequence[float] | FloatArray) -> FloatArray:
        """Outputs at the current sample for inputs ``u`` (no state change).

        Parameters
        ----------
        u : array_like
            Inputs ``(nu,)`` in the order of ``model.inputs``.

        Returns
        -------
        numpy.ndarray
            ``(ny,)`` outputs in the order of ``model.outputs``.
        """
        ub = self._in_blocks.value(self._check(u))
        with np.errstate(over="ignore", invalid="ignore"):
            y = self._out_blocks.value(self._raw_output(ub))
        return y if np.all(np.isfinite(y)) else np.full(self.ny, np.nan)  # a curve overflowed

    def advance(self, u: Sequence[float] | FloatArray) -> FloatArray:
        """Commit inputs ``u`` at the current sample, move one sample on, return the outputs.

        The returned outputs are those of the sample just left (what :meth:`outputs` gave).
        """
        ub = self._in_blocks.commit(self._check(u))
        y = self._raw_output(ub, commit=True)
        if not self._dead:
            self._update(ub, y)
        self.time_index += 1
        with np.errstate(over="ignore", invalid="ignore"):
            out = self._out_blocks.commit(y)
        if np.all(np.isfinite(out)):
            return out
        self._dead = True  # an output curve overflowed: diverged from here, as in simulate
        return np.full(self.ny, np.nan)

    def step(self, u: Sequence[float] | FloatArray) -> FloatArray:
        """Outputs at the current sample for inputs ``u``, then advance (see :meth:`advance`)."""
        return self.advance(u)

    # ------------------------------------------------------------------ internals
    def _check(self, u: Sequence[float] | FloatArray) -> FloatArray:
        arr = np.asarray(u, dtype=float).reshape(-1)
        if arr.shape != (self.nu,):
            raise DataError(
                f"Model {self.model.name!r} takes {self.nu} inputs "
                f"({', '.join(self.model.input_names)}); found {arr.shape[0]}."
            )
        if not np.all(np.isfinite(arr)):
            raise DataError(f"Inputs must be finite; found {arr.tolist()}.")
        return arr

    def _raw_output(self, ub: FloatArray, commit: bool = False) -> FloatArray:
        """Modelled outputs before the output blocks (NaN once diverged).

        ``commit``: this sample is being left, so hysteresis operators in an ARX's terms advance.
        """
        if self._dead:
            return np.full(self.ny, np.nan)
        rep = self._rep
        if isinstance(rep, StateSpace):
            y = rep.C @ self._x + rep.D @ ub
        elif isinstance(rep, SparseMap):
            y = self._x[list(rep.output_states)].copy()
        else:
            y = self._arx_output(rep, ub, commit)
        if not np.all(np.isfinite(y)):
            self._dead = True
            return np.full(self.ny, np.nan)
        return np.asarray(y, dtype=float)

    def _histories(self, ub: FloatArray) -> None:
        """Before the first sample: pad the histories as :func:`simulate` does."""
        if self.time_index or self._u_hist:
            return
        rep, lag = self._rep, self._lag
        if isinstance(rep, ARX):
            pad_u, pad_y = np.zeros(self.nu), np.zeros(self.ny)
        else:
            pad_u, pad_y = ub.copy(), np.zeros(self.ny)
        for _ in range(lag):
            self._u_hist.append(pad_u)
            self._y_hist.append(pad_y)
            if isinstance(rep, SparseMap):
                self._x_hist.append(self._x.copy())

    def _arx_output(self, rep: ARX, ub: FloatArray, commit: bool = False) -> FloatArray:
        self._histories(ub)
        u_h, y_h = self._u_hist, self._y_hist
        acc = np.zeros(self.ny) + self._off
        for lag, g in enumerate(self._G):
            if np.any(g):
                acc = acc + g @ (ub if lag == 0 else u_h[-lag])
        if rep.na:
            past = np.concatenate([y_h[-i] for i in range(1, rep.na + 1)])
            acc = acc - self._acat @ past
        if self._terms:
            names_u, names_y = self.model.input_names, self.model.output_names
            reads = []
            for name, lag in self._ct.keys:
                if name in names_u:
                    src = ub if lag == 0 else u_h[-lag]
                    reads.append(float(src[names_u.index(name)]))
                else:
                    reads.append(float(y_h[-lag][names_y.index(name)]))
            try:
                theta = self._eval(reads, commit)
            except (OverflowError, ValueError):
                return np.full(self.ny, np.nan)
            acc = acc + self._coef_t @ theta
        return np.asarray(acc, dtype=float)

    def _update(self, ub: FloatArray, y: FloatArray) -> None:
        """Advance the representation's state with inputs ``ub`` and outputs ``y``."""
        rep = self._rep
        if isinstance(rep, StateSpace) and not rep.terms:
            self._x = rep.A @ self._x + rep.B @ ub  # divergence shows in the outputs
            return
        if isinstance(rep, StateSpace):
            assert rep.E is not None
            self._histories(ub)
            self._u_hist.append(ub)
            self._y_hist.append(y)
            vals = np.array([self._key(name, lag) for name, lag in self._ct.keys])
            self._x = rep.A @ self._x + rep.B @ ub + rep.E @ self._ct.evaluate(vals)
            self._trim()
        elif isinstance(rep, ARX):
            self._histories(ub)
            self._u_hist.append(ub)
            self._y_hist.append(y)
            self._trim()
            return
        else:
            self._histories(ub)
            self._u_hist.append(ub)
            self._x_hist.append(self._x.copy())
            vals = np.array([self._key(name, lag) for name, lag in self._ct.keys])
            self._x = self._ct.evaluate(vals) @ rep.coefficients
            self._trim()
        if not np.all(np.isfinite(self._x)):
            self._dead = True

    def _key(self, name: str, lag: int) -> float:
        """Signal ``name`` ``lag`` samples back; the newest history entry is the current one."""
        source, j = self._sources[name]
        return float(source[-1 - lag][j])

    def _trim(self) -> None:
        keep = self._lag + 1
        for hist in (self._u_hist, self._y_hist, self._x_hist):
            while len(hist) > keep:
                hist.popleft()


def history_length(model: Model) -> int:
    """Samples of history the stepper pads before the first one (0: none kept).

    State space: the oldest sample its terms read (none without terms); ARX: its largest
    lag (:func:`tendonkit.simulate.arx_max_lag`); sparse map: the oldest sample its terms read,
    plus one.  The C runtime of model FMUs sizes its ring buffers with it.
    """
    rep = model.representation
    if isinstance(rep, StateSpace):
        return max((t.max_lag for t in rep.terms), default=1) if rep.terms else 0
    if isinstance(rep, ARX):
        return arx_max_lag(rep, len(model.inputs))
    return max((t.max_lag for t in rep.terms), default=0) + 1


def _chain_passes(blocks: Sequence[Block], signal: str, initial: bool) -> bool:
    """Whether the current value of ``signal`` reaches the end of its block chain."""
    for b in blocks:
        if b.signal != signal:
            continue
        if b.kind == "first_order_lag" and not initial:
            return False
        if b.kind == "delay" and int(b.params["samples"]) > 0 and not initial:
            return False
    return True


def feedthrough(model: Model, initial: bool = False) -> dict[str, list[str]]:
    """Which inputs each output depends on directly, at the same sample.

    Parameters
    ----------
    model : Model
    initial : bool
        At the first sample instead of later ones: a ``delay`` (padded with the first input)
        and a ``first_order_lag`` (starting at it) pass the current input only there.

    Returns
    -------
    dict
        Output name -> input names (structural: a non-zero coefficient or a block path).

    Examples
    --------
    >>> import numpy as np
    >>> from tendonkit.schema import Model, Signal, StateSpace
    >>> ss = StateSpace(np.eye(1), np.eye(1), np.eye(1), np.array([[2.0]]))
    >>> feedthrough(Model("m", 1.0, (Signal("u"),), (Signal("y"),), ss))
    {'y': ['u']}
    """
    rep = model.representation
    nu, ny = len(model.inputs), len(model.outputs)
    direct = np.zeros((ny, nu), dtype=bool)
    if isinstance(rep, StateSpace):
        direct |= rep.D != 0
    elif isinstance(rep, ARX):
        if rep.B:
            direct |= arx_lag_matrices(rep, nu)[0] != 0
        coef = rep.term_coefficients
        if rep.terms and coef is not None:
            for i, term in enumerate(rep.terms):
                for f in term.factors:
                    if f.lag:
                        continue
                    for name in f.signals:
                        if name in model.input_names:
                            direct[:, model.input_names.index(name)] |= coef[i] != 0
    out: dict[str, list[str]] = {}
    for j, y_name in enumerate(model.output_names):
        passes_out = _chain_passes(model.output_blocks, y_name, initial)
        out[y_name] = [
            u_name
            for m, u_name in enumerate(model.input_names)
            if direct[j, m] and passes_out and _chain_passes(model.input_blocks, u_name, initial)
        ]
    return out

"""The model schema: one plain-data contract shared by every identifier and every consumer.

A :class:`Model` holds signal names and units, the sample time, exactly one representation
from a closed set (:class:`StateSpace`, :class:`ARX`, :class:`SparseMap`), optional static or
hysteretic blocks on its inputs and outputs (:class:`Block`, used by model extensions), and
provenance.  It serialises to JSON and back exactly; loading validates everything and never
evaluates code from the file.

Examples
--------
>>> import numpy as np
>>> ss = StateSpace(A=np.array([[0.9]]), B=np.array([[1.0]]), C=np.array([[1.0]]),
...                 D=np.array([[0.0]]))
>>> m = Model(name="first order", dt=0.03, inputs=(Signal("u"),), outputs=(Signal("y"),),
...           representation=ss)
>>> Model.from_json(m.to_json()) == m
True
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ._representations import (
    ARX,
    BLOCK_KINDS,
    LINEAR_BLOCKS,
    SCHEMA_VERSION,
    Block,
    FloatArray,
    Provenance,
    Representation,
    Signal,
    SparseMap,
    StateSpace,
    section_is_stable,
)
from ._schema_io import model_fields
from .errors import SchemaError
from .files import atomic_write, check_input_file
from .realize import to_state_space
from .terms import Term


@dataclass(frozen=True, eq=False)
class Model:
    """A dynamic model in tendonkit's schema.

    Parameters
    ----------
    name : str
        Free text.
    dt : float
        Sample time in seconds.
    inputs, outputs : tuple of Signal
        Input and output signals, in order.
    representation : StateSpace, ARX or SparseMap
        The dynamics.
    states : tuple of Signal
        State names (``sparse_map`` terms refer to them; optional otherwise).
    input_blocks, output_blocks : tuple of Block
        Operators applied to named inputs before, and to named outputs after, the dynamics.
    provenance : Provenance
        Identifier, options, data hash and training fit.
    """

    name: str
    dt: float
    inputs: tuple[Signal, ...]
    outputs: tuple[Signal, ...]
    representation: Representation
    states: tuple[Signal, ...] = ()
    input_blocks: tuple[Block, ...] = ()
    output_blocks: tuple[Block, ...] = ()
    provenance: Provenance = field(default_factory=Provenance)
    schema_version: int = SCHEMA_VERSION

    def __post_init__(self) -> None:
        problems = _check_model(self)
        if problems:
            raise SchemaError("The model is not consistent with the schema:", problems)

    # -- convenience --------------------------------------------------------------------
    @property
    def kind(self) -> str:
        """The representation kind: ``state_space``, ``arx`` or ``sparse_map``."""
        return self.representation.kind

    @property
    def input_names(self) -> list[str]:
        """Input names in order."""
        return [s.name for s in self.inputs]

    @property
    def output_names(self) -> list[str]:
        """Output names in order."""
        return [s.name for s in self.outputs]

    @property
    def is_wiener(self) -> bool:
        """True when the model has output blocks and every one is a static curve
        (``polynomial``): a Wiener model, whose representation's own output is not measured."""
        return bool(self.output_blocks) and all(b.kind == "polynomial" for b in self.output_blocks)

    @property
    def is_linear(self) -> bool:
        """True for a linear representation without nonlinear blocks or terms (input delays,
        first-order lags and second-order sections are linear)."""
        rep = self.representation
        if isinstance(rep, SparseMap):
            return False
        if isinstance(rep, ARX | StateSpace) and rep.terms:
            return False
        return all(b.kind in LINEAR_BLOCKS for b in self.input_blocks) and not self.output_blocks

    def replace(self, **changes: Any) -> Model:
        """A copy with fields replaced (models are immutable)."""
        return replace(self, **changes)

    def to_control(self) -> Any:
        """The model as a discrete python-control ``StateSpace`` (linear models only).

        ARX models are realised in observable canonical form with one block per output lag;
        input delay blocks are realised as extra states.
        """
        # lazy: heavy (control)
        import control

        if not self.is_linear:
            raise SchemaError(
                f"Model {self.name!r} ({self.kind}) is nonlinear; to_control() needs a linear "
                "state_space or arx model without nonlinear blocks."
            )
        ss = to_state_space(self)
        return control.ss(
            ss.A,
            ss.B,
            ss.C,
            ss.D,
            self.dt,
            inputs=self.input_names,
            outputs=self.output_names,
            name=self.name or None,
        )

    # -- serialisation ------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-compatible data (nested lists of floats, no objects)."""
        return {
            "schema_version": self.schema_version,
            "name": self.name,
            "dt": self.dt,
            "inputs": [_sig(s) for s in self.inputs],
            "outputs": [_sig(s) for s in self.outputs],
            "states": [_sig(s) for s in self.states],
            "representation": _rep_to_dict(self.representation),
            "input_blocks": [b.to_dict() for b in self.input_blocks],
            "output_blocks": [b.to_dict() for b in self.output_blocks],
            "provenance": {
                "identifier": self.provenance.identifier,
                "version": self.provenance.version,
                "options": self.provenance.options,
                "dataset_hash": self.provenance.dataset_hash,
                "training_fit": self.provenance.training_fit,
                "notes": self.provenance.notes,
                "details": self.provenance.details,
            },
        }

    def to_json(self, indent: int | None = 1) -> str:
        """JSON text; floats are written with ``repr`` so the round trip is exact."""
        return json.dumps(self.to_dict(), indent=indent, allow_nan=False)

    def save(self, path: str | Path) -> Path:
        """Write the model as JSON to ``path``, atomically (:func:`tendonkit.files.atomic_write`)."""
        text = self.to_json()
        return atomic_write(path, lambda p: p.write_text(text, encoding="utf-8"))

    @classmethod
    def from_dict(cls, data: Any, source: str = "model") -> Model:
        """Build and validate a model from plain data, listing every problem found."""
        fields = model_fields(data, source)
        try:
            return cls(**fields)
        except SchemaError as exc:
            raise SchemaError(f"{source} is not a valid tendonkit model:", exc.problems) from None

    @classmethod
    def from_json(cls, text: str, source: str = "model") -> Model:
        """Parse JSON text (never evaluates code), within :data:`MAX_JSON_BYTES` and
        :data:`MAX_JSON_DEPTH`."""
        if len(text) > MAX_JSON_BYTES:
            raise SchemaError(
                f"{source} has {len(text)} characters; a model file holds at most "
                f"{MAX_JSON_BYTES} (it is read into memory whole)."
            )
        depth = json_depth(text)
        if depth > MAX_JSON_DEPTH:
            raise SchemaError(
                f"{source} nests {depth} levels deep; a model is at most {MAX_JSON_DEPTH} deep."
            )
        try:
            data = json.loads(text, parse_constant=_refuse_constant)
        except (json.JSONDecodeError, ValueError, RecursionError) as exc:
            raise SchemaError(f"{source} is not valid JSON: {exc}") from None
        return cls.from_dict(data, source)

    @classmethod
    def load(cls, path: str | Path) -> Model:
        """Read a model JSON file."""
        path = Path(path)
        problems: list[str] = []
        if not check_input_file(path, problems, what="model file") and path.exists():
            raise SchemaError(problems[0])
        try:
            if path.stat().st_size > 4 * MAX_JSON_BYTES:
                raise SchemaError(f"Model file {str(path)!r} is larger than any model file can be.")
            text = path.read_text(encoding="utf-8")
        except FileNotFoundError:
            raise SchemaError(f"Model file {str(path)!r} does not exist.") from None
        except (OSError, UnicodeDecodeError) as exc:
            raise SchemaError(f"Model file {str(path)!r} cannot be read: {exc}") from None
        return cls.from_json(text, source=str(path))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Model):
            return NotImplemented
        return self.to_dict() == other.to_dict()

    __hash__ = None  # type: ignore[assignment]


#: Largest model file read (characters): a model of 10 million numbers fits with room to spare.
MAX_JSON_BYTES = 256 * 1024 * 1024
#: Deepest JSON nesting of a model file: the schema needs 6 (matrices in a list in an object).
MAX_JSON_DEPTH = 32


def json_depth(text: str) -> int:
    """Deepest ``[``/``{`` nesting of JSON text (strings skipped), without parsing it."""
    depth = deepest = 0
    in_string = escaped = False
    for ch in text:
        if in_string:
            if escaped:
                escaped = False
            elif ch == "\\":
                escaped = True
            elif ch == '"':
                in_string = False
        elif ch == '"':
            in_string = True
        elif ch in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif ch in "]}":
            depth -= 1
    return deepest


def _refuse_constant(name: str) -> float:
    raise ValueError(f"non-finite number {name} is not allowed")


def _sig(s: Signal) -> dict[str, str]:
    return {"name": s.name, "unit": s.unit}


def _arr(a: FloatArray | None) -> Any:
    return None if a is None else np.asarray(a, dtype=float).tolist()


def _rep_to_dict(rep: Representation) -> dict[str, Any]:
    if isinstance(rep, StateSpace):
        return {
            "kind": rep.kind,
            "A": _arr(rep.A),
            "B": _arr(rep.B),
            "C": _arr(rep.C),
            "D": _arr(rep.D),
            "x0": _arr(rep.x0),
            "K": _arr(rep.K),
            "terms": [t.to_dict() for t in rep.terms],
            "E": _arr(rep.E),
            "u0": _arr(rep.u0),
            "y0": _arr(rep.y0),
        }
    if isinstance(rep, ARX):
        return {
            "kind": rep.kind,
            "A": [_arr(a) for a in rep.A],
            "B": [_arr(b) for b in rep.B],
            "nk": list(rep.nk),
            "offset": _arr(rep.offset),
            "terms": [t.to_dict() for t in rep.terms],
            "term_coefficients": _arr(rep.term_coefficients),
        }
    return {
        "kind": rep.kind,
        "terms": [t.to_dict() for t in rep.terms],
        "coefficients": _arr(rep.coefficients),
        "output_states": list(rep.output_states),
        "x0": _arr(rep.x0),
    }


def _check_model(m: Model) -> list[str]:
    """Consistency checks on a constructed model (shapes, names, finiteness)."""
    p: list[str] = []
    if m.schema_version != SCHEMA_VERSION:
        p.append(f"schema_version {m.schema_version} is not supported (expected {SCHEMA_VERSION}).")
    if not (isinstance(m.dt, int | float) and np.isfinite(m.dt) and m.dt > 0):
        p.append(f"dt must be a positive number of seconds, found {m.dt!r}.")
    nu, ny = len(m.inputs), len(m.outputs)
    if ny == 0:
        p.append("a model needs at least one output.")
    names = [s.name for s in (*m.inputs, *m.outputs)]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        p.append(f"signal names must be unique across inputs and outputs; repeated: {dup}.")
    rep = m.representation
    if isinstance(rep, StateSpace):
        n = rep.A.shape[0] if rep.A.ndim == 2 else -1
        _shape(p, "A", rep.A, (n, n))
        _shape(p, "B", rep.B, (n, nu))
        _shape(p, "C", rep.C, (ny, n))
        _shape(p, "D", rep.D, (ny, nu))
        if rep.x0 is not None:
            _shape(p, "x0", rep.x0, (n,))
        if rep.K is not None:
            _shape(p, "K", rep.K, (n, ny))
        if rep.terms and rep.E is None:
            p.append("state_space terms need the matrix E.")
        if rep.E is not None:
            _shape(p, "E", rep.E, (n, len(rep.terms)))
        if rep.u0 is not None:
            _shape(p, "u0", rep.u0, (nu,))
        if rep.y0 is not None:
            _shape(p, "y0", rep.y0, (ny,))
        _term_signals(p, rep.terms, set(m.input_names) | set(m.output_names))
    elif isinstance(rep, ARX):
        for i, a in enumerate(rep.A):
            _shape(p, f"A[{i}]", a, (ny, ny))
        for j, b in enumerate(rep.B):
            _shape(p, f"B[{j}]", b, (ny, nu))
        if len(rep.nk) != nu or any(int(k) != k or k < 0 for k in rep.nk):
            p.append(f"nk must list one integer >= 0 per input ({nu}), found {list(rep.nk)}.")
        if rep.offset is not None:
            _shape(p, "offset", rep.offset, (ny,))
        nt = len(rep.terms)
        if nt and rep.term_coefficients is None:
            p.append("ARX terms need term_coefficients.")
        if rep.term_coefficients is not None:
            _shape(p, "term_coefficients", rep.term_coefficients, (nt, ny))
        allowed = set(m.input_names) | set(m.output_names)
        _term_signals(p, rep.terms, allowed)
        _past_outputs(p, rep.terms, set(m.output_names))
        if not rep.B and not rep.A and not rep.terms:
            p.append("an ARX model needs at least one A or B matrix.")
    elif isinstance(rep, SparseMap):
        nx = len(m.states)
        _shape(p, "coefficients", rep.coefficients, (len(rep.terms), nx))
        if nx == 0:
            p.append("a sparse_map model must name its states.")
        if len(rep.output_states) != ny or any(not 0 <= i < nx for i in rep.output_states):
            p.append(
                f"output_states must give one state index in [0, {nx}) per output ({ny}), "
                f"found {list(rep.output_states)}."
            )
        if rep.x0 is not None:
            _shape(p, "x0", rep.x0, (nx,))
        _term_signals(p, rep.terms, {s.name for s in m.states} | set(m.input_names))
    else:
        p.append(f"unknown representation {type(rep).__name__}.")
    for where, blocks, allowed_names in (
        ("input_blocks", m.input_blocks, set(m.input_names)),
        ("output_blocks", m.output_blocks, set(m.output_names)),
    ):
        for i, block in enumerate(blocks):
            p.extend(_check_block(f"{where}[{i}]", block, allowed_names))
    return p


def _check_block(where: str, b: Block, allowed: set[str]) -> list[str]:
    p: list[str] = []
    if b.kind not in BLOCK_KINDS:
        return [f"{where}: kind {b.kind!r} is not one of {sorted(BLOCK_KINDS)}."]
    if b.signal not in allowed:
        p.append(f"{where}: signal {b.signal!r} is not one of {sorted(allowed)}.")
    need = set(BLOCK_KINDS[b.kind])
    if set(b.params) != need:
        p.append(
            f"{where}: a {b.kind} block takes parameters {sorted(need)}, found {sorted(b.params)}."
        )
        return p
    vals = b.params
    if not all(np.isfinite(float(v)) for v in vals.values()):
        p.append(f"{where}: parameters must be finite, found {vals}.")
    elif b.kind == "delay" and not vals["samples"] >= 0:
        p.append(f"{where}: delay samples must be >= 0, found {vals['samples']}.")
    elif (
        b.kind in ("dead_zone", "play") and min(vals.get("threshold", 0), vals.get("width", 0)) < 0
    ):
        p.append(f"{where}: {b.kind} width must be >= 0, found {vals}.")
    elif b.kind == "saturation" and vals["lower"] >= vals["upper"]:
        p.append(f"{where}: saturation needs lower < upper, found {vals}.")
    elif b.kind == "rate_limit" and not vals["rate"] > 0:
        p.append(f"{where}: rate_limit rate must be > 0, found {vals['rate']}.")
    elif b.kind == "first_order_lag" and not 0.0 <= vals["pole"] < 1.0:
        p.append(f"{where}: first_order_lag pole must be in [0, 1), found {vals['pole']}.")
    elif b.kind == "second_order_section" and not section_is_stable(vals["a1"], vals["a2"]):
        p.append(
            f"{where}: a second_order_section must be stable (|a2| < 1, |a1| < 1 + a2), "
            f"found a1 = {vals['a1']}, a2 = {vals['a2']}."
        )
    return p


def _term_signals(p: list[str], terms: tuple[Term, ...], allowed: set[str]) -> None:
    for i, t in enumerate(terms):
        unknown = t.signals - allowed
        if unknown:
            p.append(f"term {i} ({t.label}) reads unknown signals {sorted(unknown)}.")


def _past_outputs(p: list[str], terms: tuple[Term, ...], outputs: set[str]) -> None:
    for i, t in enumerate(terms):
        if any(s in outputs and f.lag < 1 for f in t.factors for s in f.signals):
            p.append(f"term {i} ({t.label}) must read outputs with lag >= 1 (no algebraic loop).")


def _shape(p: list[str], name: str, a: Any, shape: tuple[int, ...]) -> None:
    arr = np.asarray(a)
    if arr.shape != shape:
        p.append(f"{name} must have shape {shape}, found {arr.shape}.")
    elif not np.all(np.isfinite(arr)):
        p.append(f"{name} contains NaN or infinite values.")

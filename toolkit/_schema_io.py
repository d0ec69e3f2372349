"""Strict parsing of model files into the fields of :class:`~tendonkit.schema.Model` (no code is evaluated).

:meth:`tendonkit.schema.Model.from_dict` builds the model from :func:`model_fields`, so this module
needs only the model's parts (:mod:`tendonkit._representations`), never the schema itself.
"""

from __future__ import annotations

import json
import math
import re
from typing import Any

import numpy as np

from ._representations import (
    ARX,
    SCHEMA_VERSION,
    Block,
    Provenance,
    Signal,
    SparseMap,
    StateSpace,
)
from .errors import SchemaError
from .terms import Term, term_from_dict

#: Largest delay, lag or ARX input delay (samples) a model file may state: 100,000 samples is
#: 50 minutes at the robot's 30 ms; a larger one would make every simulation allocate and loop
#: over a history no data set has.
MAX_LAG = 100_000
#: Most lag matrices (ARX ``na``/``nb``) a model file may state.
MAX_ORDER = 1_000
#: Most numbers in one matrix of a model file (memory, not precision, is the limit).
MAX_ELEMENTS = 10_000_000
#: Signal names: a letter or underscore, then letters, digits, ``_`` or ``.`` — names survive a
#: CSV header and an FMU variable list unquoted (no separators, quotes or control characters).
NAME_PATTERN = re.compile(r"[^\W\d]\w*(?:\.\w+)*")


def is_number(value: Any) -> bool:
    """A JSON number that is a finite double (not a bool, not a too-large integer)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return False
    try:
        return math.isfinite(float(value))
    except OverflowError:
        return False


def _found(value: Any) -> str:
    text = json.dumps(value) if isinstance(value, str | bool) or value is None else repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


_TOP_KEYS = {
    "schema_version",
    "name",
    "dt",
    "inputs",
    "outputs",
    "states",
    "representation",
    "input_blocks",
    "output_blocks",
    "provenance",
}
_REP_KEYS = {
    "state_space": {"kind", "A", "B", "C", "D", "x0", "K", "terms", "E", "u0", "y0"},
    "arx": {"kind", "A", "B", "nk", "offset", "terms", "term_coefficients"},
    "sparse_map": {"kind", "terms", "coefficients", "output_states", "x0"},
}


def model_fields(data: Any, source: str = "model") -> dict[str, Any]:
    """Validate plain data into the keyword arguments of ``Model``; every problem at once."""
    p: list[str] = []
    if not isinstance(data, dict):
        raise SchemaError(f"{source}: expected a JSON object, found {type(data).__name__}.")
    version = data.get("schema_version")
    if type(version) is not int or version != SCHEMA_VERSION:
        raise SchemaError(
            f"{source}: schema_version {version!r} is not supported; this tendonkit reads "
            f"version {SCHEMA_VERSION}."
        )
    unknown = set(data) - _TOP_KEYS
    if unknown:
        p.append(f"unknown top-level keys {sorted(unknown)}.")
    for key in ("name", "dt", "inputs", "outputs", "representation"):
        if key not in data:
            p.append(f"missing key {key!r}.")
    name = data.get("name", "")
    if not isinstance(name, str):
        p.append(f"name: expected text, found {name!r}.")
    dt = data.get("dt")
    if not is_number(dt) or not float(dt) > 0:  # type: ignore[arg-type]
        p.append(f"dt: expected a positive number of seconds, found {_found(dt)}.")
    inputs = _signals(data.get("inputs", []), "inputs", p)
    outputs = _signals(data.get("outputs", []), "outputs", p)
    states = _signals(data.get("states", []), "states", p)
    rep = _representation(data.get("representation"), p)
    in_blocks = _blocks(data.get("input_blocks", []), "input_blocks", p)
    out_blocks = _blocks(data.get("output_blocks", []), "output_blocks", p)
    prov = _provenance(data.get("provenance", {}), p)
    if p or rep is None:
        raise SchemaError(f"{source} is not a valid tendonkit model:", p or ["bad representation"])
    return {
        "name": name,
        "dt": float(dt),  # type: ignore[arg-type]
        "inputs": inputs,
        "outputs": outputs,
        "states": states,
        "representation": rep,
        "input_blocks": in_blocks,
        "output_blocks": out_blocks,
        "provenance": prov,
    }


def _signals(raw: Any, where: str, p: list[str]) -> tuple[Signal, ...]:
    if not isinstance(raw, list):
        p.append(f"{where}: expected a list of {{name, unit}} objects.")
        return ()
    out = []
    for i, s in enumerate(raw):
        if (
            not isinstance(s, dict)
            or not isinstance(s.get("name"), str)
            or not s["name"]
            or not isinstance(s.get("unit", ""), str)
            or set(s) - {"name", "unit"}
        ):
            p.append(f"{where}[{i}]: expected {{'name': text, 'unit': text}}, found {_found(s)}.")
            continue
        if not NAME_PATTERN.fullmatch(s["name"]):
            p.append(
                f"{where}[{i}].name: {_found(s['name'])} is not a signal name (a letter or _, "
                "then letters, digits, _ or .; no separators, spaces or control characters)."
            )
            continue
        if not s.get("unit", "").isprintable():
            p.append(f"{where}[{i}].unit: control characters in {_found(s['unit'])}.")
            continue
        out.append(Signal(s["name"], s.get("unit", "")))
    return tuple(out)


def _leaves(raw: Any, where: str, depth: int, p: list[str]) -> tuple[int, ...] | None:
    """Shape of a nested list of numbers, or None after reporting the first problem."""
    if depth == 0:
        if not is_number(raw):
            p.append(f"{where}: expected a number, found {_found(raw)}.")
            return None
        return ()
    if not isinstance(raw, list):
        p.append(f"{where}: expected a list, found {_found(raw)}.")
        return None
    shapes = []
    for i, item in enumerate(raw):
        s = _leaves(item, f"{where}[{i}]", depth - 1, p)
        if s is None:
            return None
        shapes.append(s)
    if any(s != shapes[0] for s in shapes):
        p.append(f"{where}: rows of different lengths.")
        return None
    return (len(raw), *(shapes[0] if shapes else (0,) * (depth - 1)))


def _matrix(raw: Any, where: str, p: list[str], ndim: int = 2) -> np.ndarray | None:
    if raw is None:
        return None
    shape = _leaves(raw, where, ndim, p)
    if shape is None:
        return None
    if math.prod(shape) > MAX_ELEMENTS:
        p.append(f"{where}: {math.prod(shape)} numbers; at most {MAX_ELEMENTS} are accepted.")
        return None
    arr = np.array(raw, dtype=float).reshape(shape)
    if arr.size == 0 and ndim == 2:
        arr = arr.reshape(0, 0) if arr.ndim != 2 else arr
    return arr


def _required(raw: dict[str, Any], key: str, where: str, p: list[str], ndim: int = 2) -> Any:
    if key not in raw or raw[key] is None:
        p.append(f"{where}.{key}: missing.")
        return None
    return _matrix(raw[key], f"{where}.{key}", p, ndim)


def _terms(raw: Any, where: str, p: list[str]) -> tuple[Term, ...]:
    if not isinstance(raw, list):
        p.append(f"{where}: expected a list of terms.")
        return ()
    parsed = [term_from_dict(t, f"{where}[{i}]", p) for i, t in enumerate(raw)]
    return tuple(t for t in parsed if t is not None)


def _representation(raw: Any, p: list[str]) -> StateSpace | ARX | SparseMap | None:
    where = "representation"
    if not isinstance(raw, dict):
        p.append(f"{where}: expected an object.")
        return None
    kind = raw.get("kind")
    if not isinstance(kind, str) or kind not in _REP_KEYS:
        p.append(f"{where}.kind: {kind!r} is not one of {sorted(_REP_KEYS)}.")
        return None
    unknown = set(raw) - _REP_KEYS[kind]
    if unknown:
        p.append(f"{where}: unknown keys {sorted(unknown)} for kind {kind!r}.")
    n0 = len(p)
    if kind == "state_space":
        mats = {k: _required(raw, k, where, p) for k in "ABCD"}
        x0 = _matrix(raw.get("x0"), f"{where}.x0", p, 1)
        K = _matrix(raw.get("K"), f"{where}.K", p, 2)
        sterms = _terms(raw.get("terms", []), f"{where}.terms", p)
        E = _matrix(raw.get("E"), f"{where}.E", p, 2)
        u0 = _matrix(raw.get("u0"), f"{where}.u0", p, 1)
        y0 = _matrix(raw.get("y0"), f"{where}.y0", p, 1)
        if len(p) > n0:
            return None
        return StateSpace(
            A=mats["A"], B=mats["B"], C=mats["C"], D=mats["D"], x0=x0, K=K, terms=sterms, E=E,
            u0=u0, y0=y0,
        )  # fmt: skip
    if kind == "arx":
        A = _matrix_list(raw.get("A"), f"{where}.A", p)
        B = _matrix_list(raw.get("B"), f"{where}.B", p)
        nk = raw.get("nk")
        if not isinstance(nk, list) or not all(
            isinstance(k, int) and not isinstance(k, bool) and 0 <= k <= MAX_LAG for k in nk
        ):
            p.append(
                f"{where}.nk: expected a list of integers from 0 to {MAX_LAG} (samples), "
                f"found {_found(nk)}."
            )
            nk = []
        offset = _matrix(raw.get("offset"), f"{where}.offset", p, 1)
        terms = _terms(raw.get("terms", []), f"{where}.terms", p)
        tc = _matrix(raw.get("term_coefficients"), f"{where}.term_coefficients", p, 2)
        if len(p) > n0:
            return None
        return ARX(
            A=tuple(A), B=tuple(B), nk=tuple(nk), offset=offset, terms=terms, term_coefficients=tc
        )
    terms = _terms(raw.get("terms"), f"{where}.terms", p)
    coef = _required(raw, "coefficients", where, p)
    outs = raw.get("output_states")
    if not isinstance(outs, list) or not all(
        isinstance(i, int) and not isinstance(i, bool) and 0 <= i < MAX_ELEMENTS for i in outs
    ):
        p.append(f"{where}.output_states: expected a list of state indices, found {_found(outs)}.")
        outs = []
    x0 = _matrix(raw.get("x0"), f"{where}.x0", p, 1)
    if len(p) > n0:
        return None
    return SparseMap(terms=terms, coefficients=coef, output_states=tuple(outs), x0=x0)


def _matrix_list(raw: Any, where: str, p: list[str]) -> list[np.ndarray]:
    if not isinstance(raw, list):
        p.append(f"{where}: expected a list of matrices.")
        return []
    if len(raw) > MAX_ORDER:
        p.append(f"{where}: {len(raw)} lag matrices; at most {MAX_ORDER} are accepted.")
        return []
    out = []
    for i, m in enumerate(raw):
        arr = _matrix(m, f"{where}[{i}]", p)
        if arr is not None:
            out.append(arr)
    return out


def _blocks(raw: Any, where: str, p: list[str]) -> tuple[Block, ...]:
    if not isinstance(raw, list):
        p.append(f"{where}: expected a list.")
        return ()
    out = []
    for i, b in enumerate(raw):
        if (
            not isinstance(b, dict)
            or set(b) != {"kind", "signal", "params"}
            or not isinstance(b["kind"], str)
            or not isinstance(b["signal"], str)
            or not isinstance(b["params"], dict)
            or not all(is_number(v) for v in b["params"].values())
        ):
            p.append(
                f"{where}[{i}]: expected {{kind, signal, params: {{name: number}}}}, "
                f"found {_found(b)}."
            )
            continue
        samples = b["params"].get("samples", 0)
        if b["kind"] == "delay" and not 0 <= samples <= MAX_LAG:
            p.append(
                f"{where}[{i}].params.samples: a delay from 0 to {MAX_LAG} samples, found {samples}."
            )
            continue
        out.append(Block(b["kind"], b["signal"], {k: float(v) for k, v in b["params"].items()}))
    return tuple(out)


def _provenance(raw: Any, p: list[str]) -> Provenance:
    if not isinstance(raw, dict):
        p.append("provenance: expected an object.")
        return Provenance()
    fit = raw.get("training_fit", {})
    if not isinstance(fit, dict) or not all(is_number(v) for v in fit.values()):
        p.append("provenance.training_fit: expected {output: finite number}.")
        fit = {}
    opts = raw.get("options", {})
    if not isinstance(opts, dict):
        p.append("provenance.options: expected an object.")
        opts = {}
    details = raw.get("details", {})
    if not isinstance(details, dict):
        p.append("provenance.details: expected an object.")
        details = {}
    texts = {}
    for key in ("identifier", "version", "dataset_hash", "notes"):
        val = raw.get(key, "")
        if not isinstance(val, str):
            p.append(f"provenance.{key}: expected text, found {_found(val)}.")
            val = ""
        texts[key] = val
    return Provenance(
        options=opts, training_fit={k: float(v) for k, v in fit.items()}, details=details, **texts
    )

"""Model FMUs that need no Python: a generic C runtime and the model as a numeric resource.

The C backend of ``tendonkit export`` (the default).  One C runtime (``fmu/c``: the FMI 2.0 and
FMI 3.0 co-simulation interfaces, ring-buffer histories, the blocks, the terms, the joint
reconstruction and the forward kinematics, a few hundred lines) evaluates every model of the
schema the way :class:`tendonkit.stepper.Stepper` does.  It is compiled once per platform and
cached; each export writes the model as ``resources/model.tkm`` (a flat array of
little-endian float64, :func:`model_resource`) beside a copy of the binary named after the
model.  So exporting never needs a compiler per model, and the archive runs in any FMI
importer — Simulink, Dymola, OpenModelica, a test rig — with no Python on the target.

Binaries are built where they can be built here: the host platform with the system C compiler
when there is one, the others (and the host, when there is none) with the ``ziglang`` package's
clang, which cross-compiles to linux64, win64 and darwin64 without a system toolchain.  The
Windows binary imports only ``msvcrt.dll`` and ``kernel32.dll``.  The archive also carries the
C sources and headers (``sources/``; FMI 2.0 ``SourceFiles``, FMI 3.0 ``buildDescription.xml``)
so that any importer can rebuild it, e.g. ``fmpy.build.build_platform_binary``.
"""

from __future__ import annotations

import contextlib
import datetime
import fcntl
import functools
import hashlib
import importlib.util
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import uuid
import xml.etree.ElementTree as ET
import zipfile
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tendonkit import __version__
from tendonkit.errors import FMUError
from tendonkit.realize import arx_lag_matrices, fold_offsets
from tendonkit.robot import RobotParameters
from tendonkit.schema import ARX, Block, Model, SparseMap, StateSpace
from tendonkit.simulate import flat_terms, split_delay
from tendonkit.stepper import history_length
from tendonkit.terms import Term

__all__ = [
    "PLATFORMS",
    "CBuild",
    "c_problems",
    "model_resource",
    "runtime_binaries",
    "write_c_fmu",
]

_HERE = Path(__file__).resolve().parent
SOURCES = ("tendonkit_fmu.c", "tendonkit_runtime.c")
HEADERS = ("tendonkit_runtime.h",)
FMI_HEADERS = (
    "fmi2Functions.h",
    "fmi2FunctionTypes.h",
    "fmi2TypesPlatform.h",
    "fmi3Functions.h",
    "fmi3FunctionTypes.h",
    "fmi3PlatformTypes.h",
)
RESOURCE = "model.tkm"
MAGIC, FORMAT = 7318.2026, 5.0  # tendonkit_runtime.h
_LIMIT = 100_000  # the runtime's bound on counts and lags
#: Part of the binaries' cache key: change it with the compiler commands of :func:`_compile`.
_BUILD_RECIPE = "2"

#: FMI 2.0 platform -> (FMI 3.0 platform tuple, zig target, shared-library suffix).
PLATFORMS: dict[str, tuple[str, str, str]] = {
    "linux64": ("x86_64-linux", "x86_64-linux-gnu.2.17", ".so"),
    "win64": ("x86_64-windows", "x86_64-windows-gnu", ".dll"),
    "darwin64": ("x86_64-darwin", "x86_64-macos", ".dylib"),
}
_BLOCK_CODES = {
    "delay": 0,
    "dead_zone": 1,
    "saturation": 2,
    "play": 3,
    "first_order_lag": 4,
    "rate_limit": 5,
    "polynomial": 6,
    "second_order_section": 7,
}
#: The factor functions the C runtime implements (``fn()`` in tendonkit_runtime.c).
C_FUNCTIONS = (
    "pow", "sin", "cos", "tanh", "sign", "abs", "dead_zone", "sat", "relu", "play", "bouc_wen",
    "slew_lag",
)  # fmt: skip
#: Functions msvcrt.dll provides to the Windows build (no mingw runtime is linked).
_MSVCRT = (
    "calloc cos fclose fopen fread free fseek ftell malloc memcpy memmove memset pow sin "
    "_snprintf strlen strncmp strtol tanh _vsnprintf floor"
).split()


# ------------------------------------------------------------------------------- the model
def c_problems(model: Model) -> list[str]:
    """Why the C runtime cannot evaluate ``model`` (empty when it can).

    Every representation, block and factor function of the schema has a C form; a model
    fails here only if a plugin added a factor function the runtime lacks, or its sizes and
    lags exceed the runtime's bounds.
    """
    problems = []
    rep = model.representation
    unknown = sorted({f.fn for t in rep.terms for f in t.factors} - set(C_FUNCTIONS))
    if unknown:
        problems.append(f"factor functions {', '.join(unknown)} have no C form")
    kinds = sorted(
        {b.kind for b in (*model.input_blocks, *model.output_blocks)} - set(_BLOCK_CODES)
    )
    if kinds:
        problems.append(f"blocks {', '.join(kinds)} have no C form")
    if history_length(model) > _LIMIT:
        problems.append(f"the model reads more than {_LIMIT} samples back")
    # an ARX term reading an output at lag 0 cannot reach here: the schema refuses the model
    return problems


def _blocks(blocks: Sequence[Block], names: Sequence[str]) -> list[float]:
    out: list[float] = [float(len(blocks))]
    for b in blocks:
        p = b.params
        params: tuple[float, ...]
        if b.kind == "delay":
            n, a = split_delay(float(p["samples"]))
            params = (float(n), float(a))
        elif b.kind == "dead_zone":
            params = (float(p["threshold"]), float(p["center"]))
        elif b.kind == "saturation":
            params = (float(p["lower"]), float(p["upper"]))
        elif b.kind == "polynomial":
            params = (float(p["c0"]), float(p["c1"]), float(p["c2"]), float(p["c3"]))
        elif b.kind == "second_order_section":
            params = (float(p["b1"]), float(p["b2"]), float(p["a1"]), float(p["a2"]))
        else:
            params = (
                float(p[{"play": "width", "first_order_lag": "pole"}.get(b.kind, "rate")]),
                0.0,
            )
        params = (*params, 0.0, 0.0)[:4]  # every block row: signal, kind and four numbers
        out += [float(list(names).index(b.signal)), float(_BLOCK_CODES[b.kind]), *params]
    return out


def _factors(model: Model, terms: Sequence[Term]) -> tuple[list[float], list[float], int]:
    """``ptr`` and the factor rows, 13 numbers each in the order ``tk_load`` reads them (src,
    col, lag, diff, src2, col2, code, power, scale, offset, param, param2, weight): the arrays of the
    compiled kernels (:func:`tendonkit.simulate.flat_terms`), sources as the stepper resolves
    names — a sparse map's states, then inputs (an input name wins); an ARX's inputs, then
    outputs (an output name wins)."""
    ins, outs = list(model.input_names), list(model.output_names)
    if isinstance(model.representation, SparseMap):
        states = [s.name for s in model.states]
        first, second = [n for n in states if n not in ins], ins
        index = {n: i for i, n in enumerate(states)}
    else:
        first, second = [n for n in ins if n not in outs], outs
        index = {n: i for i, n in enumerate(ins)}
    flat = flat_terms(terms, {n: index[n] for n in first}, {n: i for i, n in enumerate(second)})
    cols = (flat.src, flat.col, flat.lag, flat.diff, flat.src2, flat.col2, flat.code,
            flat.power, flat.scale, flat.offset, flat.param, flat.param2, flat.weight)  # fmt: skip
    rows = np.column_stack(cols).ravel() if len(flat.src) else np.zeros(0)
    return [float(v) for v in flat.ptr], [float(v) for v in rows], len(flat.src)


def model_resource(
    model: Model,
    *,
    kinematics: bool,
    ratios: Sequence[float],
    robot: RobotParameters,
    start: Sequence[float],
) -> bytes:
    """``model.tkm``: the model as the flat float64 array the C runtime reads (``tk_load``).

    Parameters
    ----------
    model : Model
    kinematics : bool
        Append q3..q6 and the end effector (needs outputs ``q1`` and ``q2``).
    ratios : sequence of 4 float
        Start values of the ratios q3/q1, q4/q2, q5/q1, q6/q2.
    robot : RobotParameters
        Geometry of the forward kinematics.
    start : sequence of float
        Input start values (the operating point).
    """
    rep = model.representation
    if isinstance(rep, StateSpace) and rep.has_offsets:
        # the runtime has no operating point: it rides on a constant state
        rep = fold_offsets(rep)
        model = model.replace(representation=rep)
    nu, ny = len(model.inputs), len(model.outputs)
    terms = rep.terms
    ptr, rows, nf = _factors(model, terms)
    nx = rep.n_states if isinstance(rep, StateSpace | SparseMap) else 0
    outs = list(model.output_names)
    iq = (outs.index("q1"), outs.index("q2")) if kinematics else (0, 0)
    head = [
        MAGIC,
        FORMAT,
        {"state_space": 0, "arx": 1, "sparse_map": 2}[rep.kind],
        nu,
        ny,
        nx,
        len(terms),
        nf,
        float(model.dt),
        history_length(model),
        float(kinematics),
        *iq,
        *[float(r) for r in ratios],
        *[float(r) for r in robot.R],
        float(robot.link_pitch),
        float(robot.tool_offset),
        *[float(v) for v in start],
    ]
    body: list[np.ndarray] = [
        np.asarray(head, dtype=float),
        np.asarray(_blocks(model.input_blocks, model.input_names)),
        np.asarray(_blocks(model.output_blocks, model.output_names)),
        np.asarray(ptr),
        np.asarray(rows),
    ]
    if isinstance(rep, StateSpace):
        E = rep.E if rep.E is not None and terms else np.zeros((nx, len(terms)))
        x0 = np.zeros(nx) if rep.x0 is None else np.asarray(rep.x0, dtype=float)
        body += [rep.A, rep.B, rep.C, rep.D, x0, E]
    elif isinstance(rep, ARX):
        G = arx_lag_matrices(rep, nu) if rep.B else [np.zeros((ny, nu))]
        acat = np.hstack(rep.A) if rep.A else np.zeros((ny, 0))
        off = np.zeros(ny) if rep.offset is None else rep.offset
        coef = rep.term_coefficients
        coef_t = coef.T if terms and coef is not None else np.zeros((ny, len(terms)))
        body += [np.asarray([len(G), rep.na], dtype=float), np.stack(G), acat, off, coef_t]
    else:
        x0 = np.zeros(nx) if rep.x0 is None else np.asarray(rep.x0, dtype=float)
        body += [rep.coefficients, np.asarray(rep.output_states, dtype=float), x0]
    body.append(np.asarray([MAGIC]))
    flat = np.concatenate([np.ascontiguousarray(b, dtype=float).ravel() for b in body])
    return flat.astype("<f8").tobytes()


# ------------------------------------------------------------------------------- compiling
@dataclass(frozen=True)
class CBuild:
    """Binaries of the runtime per FMI 2.0 platform, and why the others are missing."""

    binaries: dict[str, Path]
    missing: dict[str, str]


def _fmi_headers() -> Path:
    import fmpy  # lazy: fmpy ships the FMI 2.0 and 3.0 headers

    return Path(fmpy.__file__).resolve().parent / "c-code"


def _host_platform() -> str | None:
    machine = platform.machine().lower()
    if machine not in ("x86_64", "amd64"):
        return None
    return {"linux": "linux64", "win32": "win64", "darwin": "darwin64"}.get(sys.platform)


def _zig() -> list[str] | None:
    if importlib.util.find_spec("ziglang") is None:
        return None
    return [sys.executable, "-m", "ziglang"]


def _zig_include() -> Path:
    """The Windows (mingw) headers inside the ziglang package."""
    spec = importlib.util.find_spec("ziglang")
    assert spec is not None and spec.origin is not None
    return Path(spec.origin).parent / "lib" / "libc" / "include" / "any-windows-any"


def _system_cc() -> str | None:
    for name in (os.environ.get("CC", ""), "cc", "gcc", "clang"):
        if name and shutil.which(name):
            return shutil.which(name)
    return None


@functools.cache
def _source_digest() -> str:
    digest = hashlib.sha256()
    for name in (*SOURCES, *HEADERS):
        digest.update((_HERE / "c" / name).read_bytes())
    for name in FMI_HEADERS:
        digest.update((_fmi_headers() / name).read_bytes())
    digest.update(" ".join(_MSVCRT).encode())
    digest.update(_BUILD_RECIPE.encode())
    return digest.hexdigest()[:16]


@contextlib.contextmanager
def _locked(folder: Path) -> Iterator[None]:
    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / ".lock", "w") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def _compile(plat: str, out: Path, tmp: Path) -> str | None:
    """Build the runtime for ``plat`` into ``out``; the reason when it cannot be built."""
    include = ["-I", str(_HERE / "c"), "-I", str(_fmi_headers())]
    sources = [str(_HERE / "c" / s) for s in SOURCES]
    common = ["-std=c99", "-O2", "-shared", "-s", *include]
    zig = _zig()
    cc = _system_cc() if plat == _host_platform() else None
    env = dict(os.environ)  # zig keeps its own cache (~/.cache/zig unless ZIG_GLOBAL_CACHE_DIR)
    if cc is not None and plat != "win64":
        cmd = [cc, *common, "-fPIC", "-o", str(out), *sources]
        cmd += ["-lm"] if plat == "linux64" else []
    elif zig is None:
        return "no C compiler: install the ziglang package (pip install ziglang)"
    elif plat == "win64":
        # msvcrt.dll only: an import library from a definition file, no mingw runtime
        (tmp / "msvcrt.def").write_text("LIBRARY msvcrt.dll\nEXPORTS\n" + "\n".join(_MSVCRT))
        lib = tmp / "libmsvcrt.a"
        err = _run([*zig, "dlltool", "-d", str(tmp / "msvcrt.def"), "-l", str(lib),
                    "-m", "i386:x86-64"], env)  # fmt: skip
        if err:
            return err
        cmd = [*zig, "cc", "-target", PLATFORMS[plat][1], *common, "-nostdlib", "-DTK_NO_CRT",
               "-isystem", str(_zig_include()), "-o", str(out), *sources, str(lib)]  # fmt: skip
    else:
        cmd = [
            *zig,
            "cc",
            "-target",
            PLATFORMS[plat][1],
            *common,
            "-fPIC",
            "-o",
            str(out),
            *sources,
        ]
        cmd += ["-lm"] if plat == "linux64" else []
    return _run(cmd, env, cwd=tmp)


def _run(cmd: list[str], env: Mapping[str, str], cwd: Path | None = None) -> str | None:
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, env=dict(env), cwd=cwd, timeout=600)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return f"{Path(cmd[0]).name} failed: {exc}"
    if r.returncode != 0:
        return f"{' '.join(cmd[:4])} ... failed: {(r.stderr or r.stdout).strip()[-800:]}"
    return None


def _cache_root() -> Path:
    from tendonkit.fmu.build import _cache_root as root  # lazy: build imports this module

    return root()


def runtime_binaries(platforms: Sequence[str] | None = None) -> CBuild:
    """The runtime compiled for ``platforms`` (default: all of :data:`PLATFORMS`), cached.

    A binary is built once per machine and source version (``$TENDONKIT_CACHE/c-runtime``);
    concurrent callers wait for each other.  Platforms that cannot be built here are listed
    with the reason in :attr:`CBuild.missing`.
    """
    wanted = list(platforms) if platforms is not None else list(PLATFORMS)
    unknown = [p for p in wanted if p not in PLATFORMS]
    if unknown:
        raise FMUError(f"Unknown platforms {unknown}; known: {', '.join(PLATFORMS)}.")
    folder = _cache_root() / "c-runtime" / _source_digest()
    binaries: dict[str, Path] = {}
    missing: dict[str, str] = {}
    with _locked(folder):
        for plat in wanted:
            target = folder / f"tendonkit_fmu_{plat}{PLATFORMS[plat][2]}"
            failed = folder / f"{plat}.failed"
            if not target.is_file() and not failed.is_file():
                with tempfile.TemporaryDirectory(prefix="tendonkit_cc_") as tmp:
                    out = Path(tmp) / target.name
                    why = _compile(plat, out, Path(tmp))
                    if why is None and out.is_file():
                        os.replace(out, target)
                    else:
                        failed.write_text(why or "the compiler wrote no binary")
            if target.is_file():
                binaries[plat] = target
            else:
                missing[plat] = failed.read_text()
    return CBuild(binaries, missing)


# ------------------------------------------------------------------------------- the archive
def model_identifier(name: str) -> str:
    """A C identifier from a model name (the binaries' file name)."""
    ident = re.sub(r"[^0-9A-Za-z_]", "_", name) or "model"
    return ident if not ident[0].isdigit() else f"m_{ident}"


@dataclass(frozen=True)
class Variables:
    """The FMU's variables in value-reference order, with what the description needs."""

    inputs: list[str]
    outputs: list[str]
    parameters: list[str]
    start: dict[str, float]
    units: dict[str, str]
    descriptions: dict[str, str]
    outputs_deps: dict[str, list[str]]
    initial_deps: dict[str, list[str]]


def write_c_fmu(
    path: Path,
    model: Model,
    variables: Variables,
    *,
    fmi: int,
    resource: bytes,
    build: CBuild,
    description: str,
) -> None:
    """Write the archive (atomically): description, resource, sources and binaries."""
    ident = model_identifier(model.name)
    md = (_description2 if fmi == 2 else _description3)(model, variables, ident, description)
    entries: dict[str, bytes] = {
        "modelDescription.xml": md,
        f"resources/{RESOURCE}": resource,
    }
    for name in (*SOURCES, *HEADERS):
        entries[f"sources/{name}"] = (_HERE / "c" / name).read_bytes()
    for name in FMI_HEADERS:
        entries[f"sources/{name}"] = (_fmi_headers() / name).read_bytes()
    if fmi == 3:
        entries["sources/buildDescription.xml"] = _build_description(ident)
    for plat, binary in build.binaries.items():
        folder = plat if fmi == 2 else PLATFORMS[plat][0]
        entries[f"binaries/{folder}/{ident}{PLATFORMS[plat][2]}"] = binary.read_bytes()
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as zf:
            for name, data in entries.items():
                zf.writestr(name, data)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def _root(fmi: int, model: Model, ident: str, description: str) -> ET.Element:
    attrib = {
        "fmiVersion": "2.0" if fmi == 2 else "3.0",
        "modelName": model.name,
        "description": description,
        "author": "tendonkit",
        "version": __version__,
        "generationTool": f"tendonkit {__version__} (C backend)",
        "generationDateAndTime": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "variableNamingConvention": "structured"
        if all(
            re.match(r"^[A-Za-z_][A-Za-z0-9_]*$", n)
            for n in [*model.input_names, *model.output_names]
        )
        else "flat",
    }
    token = "{" + str(uuid.uuid5(uuid.NAMESPACE_URL, f"tendonkit:{ident}:{model.to_json()}")) + "}"
    attrib["guid" if fmi == 2 else "instantiationToken"] = token
    if fmi == 2:
        attrib["numberOfEventIndicators"] = "0"
    return ET.Element("fmiModelDescription", attrib)


def _units(root: ET.Element, variables: Variables) -> None:
    from tendonkit.fmu._model_description import _unit_definitions  # lazy: a sibling

    used = []
    for name in [*variables.inputs, *variables.outputs, *variables.parameters]:
        unit = variables.units.get(name)
        if unit and unit not in used:
            used.append(unit)
    if used:
        root.append(_unit_definitions(used))
    cats = ET.SubElement(root, "LogCategories")
    ET.SubElement(cats, "Category", {"name": "logStatusError", "description": "errors"})
    ET.SubElement(cats, "Category", {"name": "logAll", "description": "all messages"})


def _experiment(root: ET.Element, model: Model) -> None:
    dt = float(model.dt)
    ET.SubElement(
        root,
        "DefaultExperiment",
        {"startTime": "0.0", "stopTime": repr(dt * 1000), "stepSize": repr(dt)},
    )


def _xml(root: ET.Element) -> bytes:
    ET.indent(root, space="  ")
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True)


def _variables(v: Variables) -> Iterator[tuple[str, str, dict[str, str]]]:
    """``(name, causality, attributes)`` of every variable in value-reference order."""
    vr = 0
    for names, causality in (
        (v.inputs, "input"),
        (v.outputs, "output"),
        (v.parameters, "parameter"),
    ):
        for name in names:
            yield (
                name,
                causality,
                {
                    "name": name,
                    "valueReference": str(vr),
                    "description": v.descriptions.get(name, ""),
                    "causality": causality,
                    "variability": "tunable" if causality == "parameter" else "continuous",
                },
            )
            vr += 1


def _start_and_unit(v: Variables, name: str) -> dict[str, str]:
    out = {}
    if name in v.start:
        out["start"] = repr(float(v.start[name]))
    if v.units.get(name):
        out["unit"] = v.units[name]
    return out


def _description2(model: Model, v: Variables, ident: str, description: str) -> bytes:
    root = _root(2, model, ident, description)
    cs = ET.SubElement(
        root,
        "CoSimulation",
        {
            "modelIdentifier": ident,
            "needsExecutionTool": "false",
            "canHandleVariableCommunicationStepSize": "false",
            "canInterpolateInputs": "false",
            "maxOutputDerivativeOrder": "0",
            "canRunAsynchronuously": "false",
            "canBeInstantiatedOnlyOncePerProcess": "false",
            "canNotUseMemoryManagementFunctions": "true",
            "canGetAndSetFMUstate": "true",
            "canSerializeFMUstate": "true",
            "providesDirectionalDerivative": "false",
        },
    )
    files = ET.SubElement(cs, "SourceFiles")
    for name in SOURCES:
        ET.SubElement(files, "File", {"name": name})
    _units(root, v)
    _experiment(root, model)
    mvs = ET.SubElement(root, "ModelVariables")
    index: dict[str, int] = {}
    for name, causality, attrib in _variables(v):
        if causality == "output":
            attrib["initial"] = "calculated"
        elif causality == "parameter":
            attrib["initial"] = "exact"
        sv = ET.SubElement(mvs, "ScalarVariable", attrib)
        ET.SubElement(sv, "Real", _start_and_unit(v, name))
        index[name] = len(index)
    structure = ET.SubElement(root, "ModelStructure")
    outs = ET.SubElement(structure, "Outputs")
    for name in v.outputs:
        deps = " ".join(str(index[d] + 1) for d in v.outputs_deps[name])
        ET.SubElement(outs, "Unknown", {"index": str(index[name] + 1), "dependencies": deps})
    init = ET.SubElement(structure, "InitialUnknowns")
    for name in v.outputs:
        deps = " ".join(
            str(index[d] + 1) for d in sorted(v.initial_deps[name], key=index.__getitem__)
        )
        ET.SubElement(init, "Unknown", {"index": str(index[name] + 1), "dependencies": deps})
    return _xml(root)


def _description3(model: Model, v: Variables, ident: str, description: str) -> bytes:
    root = _root(3, model, ident, description)
    ET.SubElement(
        root,
        "CoSimulation",
        {
            "modelIdentifier": ident,
            "needsExecutionTool": "false",
            "canBeInstantiatedOnlyOncePerProcess": "false",
            "canGetAndSetFMUState": "true",
            "canSerializeFMUState": "true",
            "providesDirectionalDerivatives": "false",
            "providesAdjointDerivatives": "false",
            "providesPerElementDependencies": "false",
            "canHandleVariableCommunicationStepSize": "false",
            "fixedInternalStepSize": repr(float(model.dt)),
            "maxOutputDerivativeOrder": "0",
            "providesIntermediateUpdate": "false",
            "mightReturnEarlyFromDoStep": "false",
            "canReturnEarlyAfterIntermediateUpdate": "false",
            "hasEventMode": "false",
            "providesEvaluateDiscreteStates": "false",
        },
    )
    _units(root, v)
    _experiment(root, model)
    mvs = ET.SubElement(root, "ModelVariables")
    vr: dict[str, int] = {}
    for name, _, attrib in _variables(v):
        ET.SubElement(mvs, "Float64", {**attrib, **_start_and_unit(v, name)})
        vr[name] = len(vr)
    taken = {*v.inputs, *v.outputs, *v.parameters}
    clock = next(n for n in ("time", "time_", "tendonkit_time") if n not in taken)
    ET.SubElement(
        mvs,
        "Float64",
        {
            "name": clock,
            "valueReference": str(len(vr)),
            "causality": "independent",
            "variability": "continuous",
            "description": "simulation time",
        },
    )
    structure = ET.SubElement(root, "ModelStructure")
    for name in v.outputs:
        ET.SubElement(
            structure,
            "Output",
            {"valueReference": str(vr[name]), "dependencies": _deps3(v.outputs_deps[name], vr)},
        )
    for name in v.outputs:
        ET.SubElement(
            structure,
            "InitialUnknown",
            {"valueReference": str(vr[name]), "dependencies": _deps3(v.initial_deps[name], vr)},
        )
    return _xml(root)


def _deps3(names: Sequence[str], vr: Mapping[str, int]) -> str:
    return " ".join(str(vr[n]) for n in sorted(names, key=vr.__getitem__))


def _build_description(ident: str) -> bytes:
    root = ET.Element("fmiBuildDescription", {"fmiVersion": "3.0"})
    config = ET.SubElement(root, "BuildConfiguration", {"modelIdentifier": ident})
    files = ET.SubElement(config, "SourceFileSet", {"language": "C99"})
    for name in SOURCES:
        ET.SubElement(files, "SourceFile", {"name": name})
    return _xml(root)

"""Build the plant FMU and model FMUs with pythonfmu, then make their modelDescription.xml complete.

pythonfmu writes a valid archive but an incomplete model description: no units, an empty
``InitialUnknowns``, no output dependencies and capability flags that do not match a fixed-step
slave.  :func:`finalize_model_description` rewrites ``modelDescription.xml`` inside the archive
so that :func:`fmpy.validation.validate_fmu` reports no problem:

* ``UnitDefinitions`` for every unit used (SI base-unit exponents for the known ones);
* ``unit`` on every Real variable that has one;
* ``ModelStructure/Outputs`` with explicit ``dependencies`` (empty = no direct feedthrough);
* ``ModelStructure/InitialUnknowns`` for every calculated output;
* ``DefaultExperiment`` with the fixed step and ``canHandleVariableCommunicationStepSize="false"``.

Plant FMUs built for the same parameters are cached (:func:`cached_plant_fmu`), keyed by the
parameters and the slave source.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.metadata
import json
import os
import re
import shutil
import sys
import tempfile
import zipfile
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tendonkit import __version__
from tendonkit.errors import FMUError, OptionError, raise_if
from tendonkit.fmu._config import (
    PARAMETER_RANGES,
    PRESETS,
    PlantConfig,
    config_from_dict,
    config_to_dict,
)
from tendonkit.fmu._model_description import UNIT_BASES, finalize_model_description
from tendonkit.robot import PAPER_RATIOS, RobotParameters
from tendonkit.schema import Model
from tendonkit.stepper import feedthrough

__all__ = [
    "BACKENDS",
    "EFFECT_SWITCHES",
    "PARAMETER_RANGES",
    "UNIT_BASES",
    "ExportResult",
    "build_model_fmu",
    "build_plant_fmu",
    "cached_plant_fmu",
    "export_model_fmu",
    "finalize_model_description",
    "model_fmu_problems",
    "plant_parameters",
]

_HERE = Path(__file__).resolve().parent
_IDENTIFIER = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")

#: Short effect switches of ``--effect`` (plant spec §10): letter -> (switch, primary parameter).
#: A bare letter turns the effect on at its spec defaults; ``LETTER=VALUE`` also sets the
#: primary parameter (``G`` takes a mount name and defaults to ``horiz_tilt``).
EFFECT_SWITCHES: dict[str, tuple[str | None, str]] = {
    "A": ("friction_on", "friction_mu_k"),
    "B": ("backlash_on", "backlash_b"),
    "D": ("delay_on", "delay_s"),
    "Z": ("deadzone_on", "deadzone_T"),
    "F": ("forcelag_on", "forcelag_tau"),
    "G": (None, "mount"),
    "K": ("hardening_on", "hardening_k3"),
    "N": ("noise_on", "noise_sigma_q"),
    "L": ("camera_on", "camera_fc"),
}
_MU_S_OVER_MU_K = PlantConfig().friction_mu_s / PlantConfig().friction_mu_k


# ------------------------------------------------------------------------------- parameters
def plant_parameters(
    effects: Iterable[str] | Mapping[str, Any] | None = None,
    preset: str = "nominal",
    base: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Resolve ``--effect`` items and a preset into validated flat plant parameters.

    Parameters
    ----------
    effects : iterable of str or mapping, optional
        Items ``NAME=VALUE`` (flat names of :func:`~tendonkit.fmu.plant.config_to_dict`) or
        short switches ``A``, ``B``, ``D``, ``Z``, ``F``, ``G``, ``K``, ``N``, ``L`` with an
        optional value for the effect's primary parameter (:data:`EFFECT_SWITCHES`); or a
        mapping ``name -> value`` of either kind.
    preset : str
        Base configuration, ``"nominal"`` or ``"paper_like"``.
    base : mapping, optional
        Flat parameters to start from instead of the preset (e.g. an FMU's start values).

    Returns
    -------
    dict
        The complete flat parameter set (every name, validated).

    Raises
    ------
    OptionError
        Listing every problem: unknown names (with the valid ones), malformed items, values
        out of range and inconsistent combinations.

    Examples
    --------
    >>> p = plant_parameters(["A", "D=0.12"])
    >>> p["friction_on"], p["delay_on"], p["delay_s"]
    (True, True, 0.12)
    """
    problems: list[str] = []
    if preset not in PRESETS:
        problems.append(f"unknown preset {preset!r}; presets: {', '.join(PRESETS)}")
        preset = "nominal"
    items: list[tuple[str, str | None]] = []
    if isinstance(effects, Mapping):
        items = [(str(k), None if v is None else str(v)) for k, v in effects.items()]
    else:
        for item in effects or []:
            name, sep, text = str(item).partition("=")
            if not name.strip() or (sep and not text.strip()):
                problems.append(f"effect {item!r} is not NAME, NAME=VALUE or a switch letter")
                continue
            items.append((name.strip(), text.strip() if sep else None))
    kinds = config_to_dict(PlantConfig())
    flat_names = tuple(kinds)
    values: dict[str, Any] = {}
    explicit: set[str] = set()
    unknown: list[str] = []
    for key, value in items:
        if key in EFFECT_SWITCHES:
            switch, primary = EFFECT_SWITCHES[key]
            if switch is not None:
                values[switch] = True
            if key == "G":
                values["mount"] = value or "horiz_tilt"
            elif value is not None:
                values[primary] = value
        elif key in flat_names:
            if value is None:
                if key.endswith("_on"):
                    value = "1"
                else:
                    problems.append(f"parameter {key!r} needs a value ({key}=VALUE)")
                    continue
            if key in explicit:
                problems.append(f"parameter {key!r} is given twice")
            values[key] = value
            explicit.add(key)
        else:
            unknown.append(key)
    if unknown:
        problems.append(
            f"unknown effects or parameters: {', '.join(map(repr, unknown))}; "
            f"switches: {', '.join(EFFECT_SWITCHES)}; parameters: {', '.join(flat_names)}"
        )
    for name in list(values):  # convert now so that every range problem is reported too
        try:
            values[name] = _coerce(kinds[name], values[name])
        except (TypeError, ValueError):
            problems.append(f"{name} has an invalid value {values.pop(name)!r}")
    if "friction_mu_k" in values and "friction_mu_s" not in explicit:
        # keep the default static/kinetic ratio unless mu_s is given
        values["friction_mu_s"] = values["friction_mu_k"] * _MU_S_OVER_MU_K
    merged = {**(PRESETS[preset] if base is None else base), **values}
    try:
        config, robot = config_from_dict(merged)
    except OptionError as exc:
        problems.extend(exc.problems or [str(exc)])
    raise_if(problems, OptionError, "Invalid plant effects:")
    return dict(config_to_dict(config, robot))


def _coerce(kind: Any, value: Any) -> Any:
    """Convert a command-line value to the type of the parameter's default ``kind``."""
    if isinstance(kind, bool):
        low = str(value).strip().lower()
        if low in ("1", "true", "yes", "on"):
            return True
        if low in ("0", "false", "no", "off"):
            return False
        raise ValueError(value)
    if isinstance(kind, int):
        number = float(value)
        if not number.is_integer():
            raise ValueError(value)
        return int(number)
    if isinstance(kind, float):
        return float(value)
    return str(value)


# ------------------------------------------------------------------------------- building
def build_plant_fmu(
    path: str | Path,
    config: PlantConfig | None = None,
    robot: RobotParameters | None = None,
) -> Path:
    """Build the plant FMU with ``config`` and ``robot`` as its parameter start values.

    Parameters
    ----------
    path : str or Path
        The ``.fmu`` file to write (written atomically).
    config : PlantConfig, optional
        Hidden effects; nominal by default.
    robot : RobotParameters, optional
        Geometry; nominal by default.

    Returns
    -------
    Path
        ``path``.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> out = build_plant_fmu(pathlib.Path(tempfile.mkdtemp()) / "plant.fmu")
    >>> out.suffix
    '.fmu'
    """
    # lazy: heavy (pythonfmu, through the slave module)
    from tendonkit.fmu import plant_fmu as slave

    params = config_to_dict(config or PlantConfig(), robot)
    resources = {slave.PARAMETER_FILE: json.dumps(params, indent=1)}
    units = {**slave.SIGNAL_UNITS, **slave.PARAMETER_UNITS}
    outputs = {name: () for name in slave.OUTPUTS}  # no direct feedthrough
    parameters = tuple(params)
    return _build(
        _HERE / "plant_fmu.py",
        path,
        resources,
        step_size=slave.STEP,
        stop_time=10.0,
        units=units,
        outputs=outputs,
        initial_unknowns=dict.fromkeys(slave.OUTPUTS, parameters),
    )


def cached_plant_fmu(
    parameters: Mapping[str, Any] | None = None, cache_dir: str | Path | None = None
) -> Path:
    """A plant FMU for ``parameters`` from the cache, built on first use.

    Parameters
    ----------
    parameters : mapping, optional
        Flat plant parameters (e.g. from :func:`plant_parameters`); nominal by default.
    cache_dir : str or Path, optional
        Defaults to ``$TENDONKIT_CACHE`` or ``$XDG_CACHE_HOME/tendonkit`` (``~/.cache/tendonkit``).

    Returns
    -------
    Path
        The cached FMU, keyed by the parameters, the slave source and the pythonfmu version.
    """
    # lazy: heavy (pythonfmu)
    import pythonfmu

    config, robot = config_from_dict(dict(parameters or {}))
    params = config_to_dict(config, robot)
    digest = hashlib.sha256()
    digest.update(json.dumps(params, sort_keys=True).encode())
    digest.update((_HERE / "plant_fmu.py").read_bytes())
    digest.update((_HERE / "build.py").read_bytes())
    digest.update(str(getattr(pythonfmu, "__version__", "")).encode())
    folder = Path(cache_dir) if cache_dir is not None else _cache_root() / "plant"
    target = folder / f"plant-{digest.hexdigest()[:16]}.fmu"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        if not target.is_file():
            build_plant_fmu(target, config, robot)
    except OSError as exc:
        raise FMUError(
            f"Cannot write the plant FMU cache in {str(folder)!r} ({exc}); set TENDONKIT_CACHE "
            "to a writable folder or build one with 'tendonkit plant build'."
        ) from None
    return target


def _cache_root() -> Path:
    if os.environ.get("TENDONKIT_CACHE"):
        return Path(os.environ["TENDONKIT_CACHE"])
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "tendonkit"


@contextlib.contextmanager
def _installed_pythonfmu() -> Iterator[None]:
    """Import the installed pythonfmu for a build, whatever this process imported before.

    A pythonfmu FMU run in this process first (fmpy hosts the slave in-process) leaves the
    copy of pythonfmu bundled in its resources as ``sys.modules["pythonfmu"]``; that copy has
    no builder and no binaries.  Its modules are set aside for the build and put back after,
    so the running slave keeps its own.
    """
    installed = Path(str(importlib.metadata.distribution("pythonfmu").locate_file("pythonfmu")))
    loaded = sys.modules.get("pythonfmu")
    here = Path(getattr(loaded, "__file__", "") or "").parent
    if loaded is None or here.resolve() == installed.resolve():
        yield
        return

    def ours() -> list[str]:
        return [n for n in sys.modules if n == "pythonfmu" or n.startswith("pythonfmu.")]

    aside = {n: sys.modules.pop(n) for n in ours()}
    saved_path = list(sys.path)
    sys.path.insert(0, str(installed.parent))  # the slave's resources folder may come first
    try:
        yield
    finally:
        sys.path[:] = saved_path
        for n in ours():
            del sys.modules[n]
        sys.modules.update(aside)


def _module_file(name: str) -> str:
    module = sys.modules.get(name)
    return str(getattr(module, "__file__", "?"))


def _build(
    script: Path,
    path: str | Path,
    resources: Mapping[str, str | bytes],
    *,
    step_size: float,
    stop_time: float,
    units: Mapping[str, str],
    outputs: Mapping[str, Sequence[str]],
    initial_unknowns: Mapping[str, Sequence[str] | None],
    naming: str = "structured",
    state: bool = False,
    model_name: str | None = None,
    description: str | None = None,
) -> Path:
    """Run pythonfmu on a private copy of ``script`` and finalise the model description."""
    path = Path(path)
    if not path.parent.is_dir():
        raise FMUError(f"The folder of {str(path)!r} does not exist.")
    # The slave module is named after tendonkit's version: an importer loads a slave module
    # once per process by name, so FMUs of two tendonkit versions in one process (a 0.1 and
    # a 0.2 model FMU) would otherwise both run whichever was loaded first.
    module = f"tendonkit_{script.stem}_{re.sub(r'[^0-9A-Za-z]', '_', __version__)}"
    saved_path = list(sys.path)
    had_module = module in sys.modules
    with tempfile.TemporaryDirectory(prefix="tendonkit_fmu_") as tmp:
        src = Path(tmp) / "src"
        src.mkdir()
        shutil.copy2(script, src / f"{module}.py")
        extra = []
        for name, content in resources.items():
            target = src / name
            if isinstance(content, bytes):
                target.write_bytes(content)
            else:
                target.write_text(content, encoding="utf-8")
            extra.append(target)
        built = Path(tmp) / "out.fmu"
        try:
            with _installed_pythonfmu():
                # lazy: heavy (pythonfmu)
                from pythonfmu.builder import FmuBuilder

                FmuBuilder.build_FMU(src / f"{module}.py", dest=built, project_files=extra)
        except Exception as exc:  # pythonfmu raises bare exceptions
            raise FMUError(f"pythonfmu could not build {script.name}: {exc}") from exc
        finally:
            sys.path[:] = saved_path  # pythonfmu leaves the script folder on sys.path
            if not had_module:
                sys.modules.pop(module, None)
        with zipfile.ZipFile(built) as zf:
            binaries = [n for n in zf.namelist() if n.startswith("binaries/")]
        if not binaries:
            raise FMUError(
                f"pythonfmu built {script.name} without binaries: the pythonfmu imported in this "
                f"process ({_module_file('pythonfmu')}) is not an installed pythonfmu (an FMU "
                "that bundles its own copy was loaded first?). Export in a fresh process."
            )
        finalize_model_description(
            built,
            step_size=step_size,
            stop_time=stop_time,
            units=units,
            outputs=outputs,
            initial_unknowns=initial_unknowns,
            naming=naming,
            state=state,
            model_name=model_name,
            description=description,
        )
        fd, tmp_out = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        os.close(fd)
        try:
            shutil.copyfile(built, tmp_out)
            os.replace(tmp_out, path)
        finally:
            if os.path.exists(tmp_out):
                os.unlink(tmp_out)
    return path


def model_fmu_problems(model: Model, kinematics: bool = True) -> list[str]:
    """Why ``model`` cannot be exported (empty when it can).

    Parameters
    ----------
    model : Model
    kinematics : bool
        Whether q3..q6 and the end effector are to be reconstructed, which needs outputs
        named ``q1`` and ``q2`` (pan and tilt base joints, rad).

    Returns
    -------
    list of str
    """
    # lazy: heavy (pythonfmu, through the slave module)
    from tendonkit.fmu.model_fmu import EE, JOINTS, RATIO_NAMES

    problems = []
    if not model.inputs:
        problems.append(f"model {model.name!r} has no inputs; an FMU needs at least one.")
    if kinematics:
        missing = [n for n in ("q1", "q2") if n not in model.output_names]
        if missing:
            problems.append(
                "the kinematic reconstruction needs model outputs named q1 and q2 (the base "
                f"pan and tilt joints, rad); model {model.name!r} has outputs "
                f"{', '.join(model.output_names)}. Rename them or export with --no-kinematics."
            )
        other = [f"{s.name} [{s.unit}]" for s in model.outputs if s.name in ("q1", "q2") and s.unit]
        if any(s.unit not in ("", "rad") for s in model.outputs if s.name in ("q1", "q2")):
            problems.append(
                f"the kinematic reconstruction computes in rad, but model {model.name!r} has "
                f"{', '.join(other)}: identify it from angles in rad, or export with "
                "--no-kinematics."
            )
        taken = sorted(set(model.input_names + model.output_names) & {*JOINTS, *EE, *RATIO_NAMES})
        if taken:
            problems.append(
                f"the model already has signals named {', '.join(taken)}, which the kinematic "
                "reconstruction adds; export with --no-kinematics."
            )
    return problems


@dataclass(frozen=True)
class ExportResult:
    """What :func:`export_model_fmu` wrote.

    Attributes
    ----------
    path : Path
        The FMU.
    backend : str
        ``"c"`` (compiled runtime, no Python needed to run it) or ``"python"`` (pythonfmu).
    fmi : int
        FMI version, 2 or 3.
    platforms : tuple of str
        FMI 2.0 names of the platforms whose binaries are inside (``linux64``, ``win64``,
        ``darwin64``).
    notes : tuple of str
        Why the export fell back to the Python backend, and which platforms are missing.
    """

    path: Path
    backend: str
    fmi: int
    platforms: tuple[str, ...]
    notes: tuple[str, ...] = ()

    def summary(self) -> str:
        """One line for a user: backend, FMI version, platforms."""
        kind = "C, no Python needed" if self.backend == "c" else "Python (pythonfmu)"
        return (
            f"FMI {self.fmi}.0 co-simulation, {kind}, binaries for "
            f"{', '.join(self.platforms) or 'no platform'}"
        )


BACKENDS = ("c", "python")


def export_model_fmu(
    model: Model,
    path: str | Path,
    ratios: Sequence[float] | None = None,
    kinematics: bool = True,
    robot: RobotParameters | None = None,
    *,
    backend: str | None = None,
    fmi: int = 2,
    platforms: Sequence[str] | None = None,
) -> ExportResult:
    """Export ``model`` as a co-simulation FMU (see :mod:`tendonkit.fmu.cfmu`, docs/fmu.md).

    Parameters
    ----------
    model : Model
        Any representation of the schema, with any blocks.
    path : str or Path
        The ``.fmu`` file to write (atomically).
    ratios : sequence of 4 float, optional
        Start values of ``ratio_3..ratio_6`` (q3/q1, q4/q2, q5/q1, q6/q2); the paper's by
        default.
    kinematics : bool
        Add q3..q6 and the end effector (needs outputs ``q1`` and ``q2``).
    robot : RobotParameters, optional
        Geometry of the forward kinematics; the nominal robot by default.
    backend : {"c", "python"}, optional
        ``"c"``: the compiled runtime (no Python on the target); ``"python"``: a pythonfmu
        slave that needs tendonkit in the importer's Python.  By default C, falling back to
        Python (FMI 2.0 only) when the model has a part without a C form or no binary can
        be built here; the result's ``notes`` say why.
    fmi : {2, 3}
        FMI version (3 needs the C backend).
    platforms : sequence of str, optional
        Platforms to put binaries in for (C backend): ``linux64``, ``win64``, ``darwin64``;
        all that can be built here by default.

    Returns
    -------
    ExportResult

    Raises
    ------
    OptionError
        The model cannot be exported as asked (every reason listed).
    """
    # lazy: heavy (pythonfmu, through the slave module)
    from tendonkit.fmu import cfmu
    from tendonkit.fmu import model_fmu as slave

    problems = model_fmu_problems(model, kinematics)
    r = tuple(float(x) for x in (ratios if ratios is not None else PAPER_RATIOS[2:]))
    if len(r) != 4:
        problems.append(f"ratios must hold 4 numbers (q3/q1, q4/q2, q5/q1, q6/q2), found {r}.")
    if backend is not None and backend not in BACKENDS:
        problems.append(f"backend must be one of {', '.join(BACKENDS)}, found {backend!r}.")
    if fmi not in (2, 3):
        problems.append(f"fmi must be 2 or 3, found {fmi!r}.")
    if backend == "python" and fmi == 3:
        problems.append("the Python backend (pythonfmu) writes FMI 2.0 only; use --backend c.")
    unknown = [p for p in (platforms or ()) if p not in cfmu.PLATFORMS]
    if unknown:
        problems.append(f"unknown platforms {unknown}; known: {', '.join(cfmu.PLATFORMS)}.")
    c_why = cfmu.c_problems(model) if backend != "python" else []
    if c_why and (backend == "c" or fmi == 3):
        problems.append(f"the C backend cannot export this model: {'; '.join(c_why)}.")
    raise_if(problems, OptionError, f"Model {model.name!r} cannot be exported:")
    robot = robot or RobotParameters()
    notes: list[str] = []
    build = None
    if backend != "python" and not c_why:
        build = cfmu.runtime_binaries(platforms)
        notes += [f"no {p} binary: {why}" for p, why in build.missing.items()]
        if not build.binaries:
            if backend == "c" or fmi == 3:
                raise FMUError(
                    "No binary of the C runtime could be built here: " + "; ".join(notes)
                )
            c_why = ["no platform binary could be built here"]
    if backend != "python" and c_why:
        notes.insert(0, f"fell back to the Python backend: {'; '.join(c_why)}")
    op = model.provenance.details.get("operating_point", {})
    inputs, outputs, params = slave.export_layout(model, kinematics)
    units = {s.name: s.unit for s in (*model.inputs, *model.outputs) if s.unit}
    if kinematics:
        units.update(dict.fromkeys(slave.JOINTS, "rad"))
        units.update(dict.fromkeys(slave.EE, "m"))
    deps = feedthrough(model)  # after the first sample: inputs only
    first = feedthrough(model, initial=True)  # initialisation: inputs and the ratios
    if kinematics:
        for table, with_ratios in ((deps, False), (first, True)):
            _add_kinematic_dependencies(table, model.input_names, with_ratios)
    description = (
        f"tendonkit {model.kind} model {model.name!r} ({len(model.inputs)} inputs, "
        f"{len(model.outputs)} outputs, step {model.dt:g} s"
        + (", with q3..q6 and the end effector reconstructed" if kinematics else "")
        + f"), exported by tendonkit {__version__}"
    )
    path = Path(path)
    if not path.parent.is_dir():
        raise FMUError(f"The folder of {str(path)!r} does not exist.")
    if build is not None and build.binaries:
        start = [float(op.get(n, 0.0)) if isinstance(op, dict) else 0.0 for n in inputs]
        variables = cfmu.Variables(
            inputs=inputs,
            outputs=outputs,
            parameters=params,
            start={**dict(zip(inputs, start, strict=True)), **dict(zip(params, r, strict=False))},
            units=units,
            descriptions={
                **{n: f"model input {n}" for n in inputs},
                **{
                    n: slave._output_description(n, j < len(model.outputs))
                    for j, n in enumerate(outputs)
                },
                **{
                    n: f"constant joint-angle ratio {slave.JOINTS[i]}/q{1 + i % 2}"
                    for i, n in enumerate(params)
                },
            },
            outputs_deps={name: deps[name] for name in outputs},
            initial_deps={name: first[name] for name in outputs},
        )
        resource = cfmu.model_resource(
            model, kinematics=kinematics, ratios=r, robot=robot, start=start
        )
        cfmu.write_c_fmu(
            path,
            model,
            variables,
            fmi=fmi,
            resource=resource,
            build=build,
            description=description,
        )
        return ExportResult(path, "c", fmi, tuple(build.binaries), tuple(notes))
    config = {
        "kinematics": kinematics,
        "ratios": list(r),
        "robot": robot.to_dict(),
        "tendonkit_version": __version__,
    }
    resources = {slave.MODEL_FILE: model.to_json(), slave.CONFIG_FILE: json.dumps(config)}
    naming = "structured" if all(_IDENTIFIER.match(n) for n in inputs + outputs) else "flat"
    _build(
        _HERE / "model_fmu.py",
        path,
        resources,
        step_size=float(model.dt),
        stop_time=float(model.dt) * 1000,
        units=units,
        outputs={name: deps[name] for name in outputs},
        initial_unknowns={name: first[name] for name in outputs},
        naming=naming,
        state=True,
        model_name=model.name,
        description=description,
    )
    with zipfile.ZipFile(path) as zf:
        plats = sorted(
            {
                n.split("/")[1]
                for n in zf.namelist()
                if n.count("/") >= 2 and n.startswith("binaries/")
            }
        )
    return ExportResult(path, "python", 2, tuple(plats), tuple(notes))


def build_model_fmu(
    model: Model,
    path: str | Path,
    ratios: Sequence[float] | None = None,
    kinematics: bool = True,
    robot: RobotParameters | None = None,
    *,
    backend: str | None = None,
    fmi: int = 2,
    platforms: Sequence[str] | None = None,
) -> Path:
    """Export ``model`` as a co-simulation FMU; :func:`export_model_fmu` without the report.

    Returns
    -------
    Path
        ``path``.
    """
    return export_model_fmu(
        model, path, ratios, kinematics, robot, backend=backend, fmi=fmi, platforms=platforms
    ).path


def _add_kinematic_dependencies(
    table: dict[str, list[str]], inputs: Sequence[str], with_ratios: bool
) -> None:
    """Dependencies of q3..q6 (one ratio times q1 or q2) and of the end effector (all)."""
    # lazy: heavy (pythonfmu, through the slave module)
    from tendonkit.fmu.model_fmu import EE, RATIO_NAMES

    pan, tilt = table["q1"], table["q2"]
    for joint, base, ratio in (("q3", pan, 0), ("q4", tilt, 1), ("q5", pan, 2), ("q6", tilt, 3)):
        table[joint] = [*base, *([RATIO_NAMES[ratio]] if with_ratios else [])]
    both = [name for name in inputs if name in pan or name in tilt]
    for name in EE:
        table[name] = [*both, *(RATIO_NAMES if with_ratios else ())]

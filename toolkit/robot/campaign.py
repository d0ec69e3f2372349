"""Co-simulation campaigns: one controller design checked across many plant variants.

A campaign is a TOML file (docs/campaigns.md).  It names the plant (a preset, effects switched on
in every run, and parameters drawn per run from ranges — by default the plant spec's own, §10),
the controllers (linear or nonlinear MPC on model files, the open-loop kinematic controller, or a
user's controller class), the references and the pass criteria.  :func:`run_campaign` expands it
into runs — plant draws × noise repeats × references × controllers, every random choice taken
from the campaign's seed and the draw's number, never from a worker — and runs each as one
co-simulation with the plant FMU inside its worker (:func:`tendonkit.parallel.run_tasks`: this
process, a local process pool, or a Dask cluster).

Every finished run is appended to ``OUT/runs.jsonl`` at once, so an interrupted campaign resumes
from the rows already written; at the end the rows are sorted into ``OUT/runs.csv``, summarised
(``summary.json``: pass rate, worst cases with their parameters, distributions) and drawn
(``index.html`` with figures).  The columns that do not measure the machine (everything but
``solve_p99_ms``, ``step_p99_ms``, ``deadline_misses``, ``wall_s``, ``worker`` and ``attempts``)
are identical whatever the engine and the number of workers: :data:`DETERMINISTIC`.

Reading a spec executes nothing; a controller of ``kind = "python"`` imports the module it
names, in this process and in every worker — that is what naming it asks for.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib
import inspect
import json
import math
import operator
import os
import re
import sys
import tempfile
import time
import tomllib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

try:
    import fcntl
except ImportError:  # Windows
    fcntl = None  # type: ignore[assignment]

from .. import __version__
from ..errors import OptionError, OutputError, SchemaError, raise_if
from ..files import atomic_write, write_json
from ..identification import is_int
from ..parallel import LOST, Outcome, default_jobs, engine_name, run_tasks, task_problems
from ..schema import Model
from .campaign_report import render, summarise, write_outputs
from .collect import fmu_parameters
from .controllers import ControllerSettings, controller_kind, make_controller
from .cosim import REFERENCES, STEP, CosimResult, Reference, make_reference, run

__all__ = [
    "DETERMINISTIC",
    "METRICS",
    "CampaignResult",
    "CampaignSpec",
    "Criterion",
    "load_spec",
    "metrics_of",
    "plant_items",
    "rerun",
    "run_campaign",
    "spec_from_dict",
]

#: Per-run metrics: name -> description (unit in the name).
METRICS: dict[str, str] = {
    "rms_error_mrad": "RMS of the measured q1, q2 error (both joints), mrad",
    "rms_q1_mrad": "RMS of the measured q1 error, mrad",
    "rms_q2_mrad": "RMS of the measured q2 error, mrad",
    "rms_error_true_mrad": "RMS of the true q1, q2 error (both joints), mrad",
    "rms_true_q1_mrad": "RMS of the true q1 error, mrad",
    "rms_true_q2_mrad": "RMS of the true q2 error, mrad",
    "ee_error_cm": "mean end-effector error, measured, cm",
    "ee_error_true_cm": "mean end-effector error, true, cm",
    "ee_error_true_max_cm": "largest end-effector error, true, cm",
    "solve_p99_ms": "99th percentile of the solve time, ms (NaN: no solver)",
    "step_p99_ms": "99th percentile of the controller's step, ms (NaN: no solver)",
    "deadline_misses": "controller steps longer than the 30 ms frame",
    "fallbacks": "steps that held the previous input (solver failure)",
    "bound_violations": "commands outside [20, 190] N (clipped)",
    "wall_s": "wall time of the co-simulation, s",
}
#: Metrics that measure the machine, not the design (they vary from run to run).
TIMING = ("solve_p99_ms", "step_p99_ms", "deadline_misses", "wall_s")
#: Columns of the table identical whatever the engine and the number of workers.
DETERMINISTIC_BASE = ("run", "draw", "repeat", "controller", "reference", "seed")
DETERMINISTIC = (
    *DETERMINISTIC_BASE,
    *(m for m in METRICS if m not in TIMING),
    "status",
    "error",
)
_OPS: dict[str, Callable[[float, float], bool]] = {
    "<=": operator.le,
    "<": operator.lt,
    ">=": operator.ge,
    ">": operator.gt,
    "==": operator.eq,
    "!=": operator.ne,
}
_CRITERION = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_]*)\s*(<=|>=|==|!=|<|>)\s*(\S+)\s*$")
_CONTROLLER_KINDS = ("mpc", "open_loop", "python")
#: Seconds a run may take before its worker is stopped (``[campaign] timeout_s``).
DEFAULT_TIMEOUT_S = 900.0
_SETTINGS = ("horizon", "Q", "R", "pair_weight", "solver")


# -- the spec ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class Criterion:
    """A pass criterion ``metric OP value`` (e.g. ``rms_error_true_mrad <= 25``)."""

    metric: str
    op: str
    value: float

    def holds(self, row: dict[str, Any]) -> bool:
        """Whether ``row`` meets it (a missing or NaN metric does not)."""
        x = row.get(self.metric)
        if x is None or (isinstance(x, float) and math.isnan(x)):
            return False
        return bool(_OPS[self.op](float(x), self.value))

    def __str__(self) -> str:
        return f"{self.metric} {self.op} {self.value:g}"

    @classmethod
    def parse(cls, text: str) -> Criterion:
        """``"metric OP number"``; ValueError when it is not that (or the number not finite)."""
        m = _CRITERION.match(text)
        if not m or not math.isfinite(value := float(m.group(3))):
            raise ValueError(f"{text!r} is not 'METRIC OP NUMBER'")
        return cls(m.group(1), m.group(2), value)


@dataclass(frozen=True)
class Vary:
    """A plant parameter drawn per run: a range (uniform, or log-uniform) or a list of values."""

    name: str
    low: float | None = None
    high: float | None = None
    values: tuple[Any, ...] | None = None
    log: bool = False
    points: int = 3

    def grid(self) -> list[Any]:
        """The values of a grid campaign."""
        if self.values is not None:
            return list(self.values)
        assert self.low is not None and self.high is not None
        if self.log:
            return [float(v) for v in np.geomspace(self.low, self.high, self.points)]
        return [float(v) for v in np.linspace(self.low, self.high, self.points)]

    def draw(self, rng: np.random.Generator) -> Any:
        """One Monte-Carlo value."""
        if self.values is not None:
            v = self.values[int(rng.integers(len(self.values)))]
            return v.item() if hasattr(v, "item") else v
        assert self.low is not None and self.high is not None
        if self.log:
            return float(np.exp(rng.uniform(np.log(self.low), np.log(self.high))))
        return float(rng.uniform(self.low, self.high))


@dataclass(frozen=True)
class ControllerSpec:
    """A controller of the campaign (``kind``: ``mpc``, ``open_loop`` or ``python``)."""

    name: str
    kind: str
    model: str | None = None
    settings: dict[str, Any] = field(default_factory=dict)
    cls: str | None = None
    path: str | None = None
    options: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class ReferenceSpec:
    """A reference of the campaign (:func:`tendonkit.robot.cosim.make_reference` options)."""

    kind: str
    duration: float | None = None
    speed_cm_s: float = 2.5
    amplitude_cm: float = 9.0
    petals: int = 3

    @property
    def name(self) -> str:
        """Label in the table, e.g. ``petal 60 s`` (other options when not the defaults)."""
        extra = [
            f"{label} {value:g}{unit}"
            for label, value, default, unit in (
                ("speed", self.speed_cm_s, 2.5, " cm/s"),
                ("amplitude", self.amplitude_cm, 9.0, " cm"),
                ("petals", self.petals, 3, ""),
            )
            if value != default
        ]
        head = self.kind + (f" {self.duration:g} s" if self.duration else "")
        return ", ".join([head, *extra])

    def build(self) -> Reference:
        """The reference."""
        return make_reference(
            self.kind,
            duration=self.duration,
            amplitude=self.amplitude_cm / 100.0,
            petals=self.petals,
            speed=self.speed_cm_s / 100.0,
        )


@dataclass(frozen=True)
class CampaignSpec:
    """A validated campaign (from :func:`load_spec` or :func:`spec_from_dict`).

    Attributes
    ----------
    name : str
    seed : int
        Seed of every draw (plant parameters and sensor-noise seeds).
    sampling : {"random", "grid"}
        Monte-Carlo draws, or the product of every parameter's grid.
    draws : int
        Plant draws (random sampling; grid: the size of the product).
    repeats : int
        Sensor-noise seeds per draw.
    preset : str
        The plant's base configuration (``nominal``, ``paper_like``).
    effects : tuple of str
        Effects and parameters set in every run (``A``, ``D=0.09``, ``noise_on=1`` …).
    vary : tuple of Vary
        Parameters drawn per run.
    controllers, references : tuple
    criteria : tuple of Criterion
        A run passes when every criterion holds (and it ran).
    rank_by : str
        The metric that orders the worst cases (larger is worse).
    min_pass_rate : float
        The campaign passes when this fraction of its runs pass.
    timeout_s : float
        A run still going after this many seconds is stopped and reported (local pool).
    base_dir : Path
        Relative paths (models, controller modules) are read from here.
    """

    name: str
    seed: int
    sampling: str
    draws: int
    repeats: int
    preset: str
    effects: tuple[str, ...]
    vary: tuple[Vary, ...]
    controllers: tuple[ControllerSpec, ...]
    references: tuple[ReferenceSpec, ...]
    criteria: tuple[Criterion, ...]
    rank_by: str = "rms_error_true_mrad"
    min_pass_rate: float = 1.0
    base_dir: Path = Path(".")
    timeout_s: float = DEFAULT_TIMEOUT_S

    @property
    def n_draws(self) -> int:
        """Plant draws (grid: every combination)."""
        if self.sampling == "grid":
            return math.prod(len(v.grid()) for v in self.vary)
        return self.draws

    @property
    def n_runs(self) -> int:
        """Runs of the campaign."""
        return self.n_draws * self.repeats * len(self.references) * len(self.controllers)

    def draw(self, d: int) -> dict[str, Any]:
        """The varied parameters of plant draw ``d`` (depends on ``seed`` and ``d`` only)."""
        if self.sampling == "grid":
            out: dict[str, Any] = {}
            for v in reversed(self.vary):  # mixed radix: the last parameter varies fastest
                grid = v.grid()
                d, k = divmod(d, len(grid))
                out[v.name] = grid[k]
            return {v.name: out[v.name] for v in self.vary}
        rng = np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=(d,)))
        return {v.name: v.draw(rng) for v in self.vary}

    def noise_seed(self, d: int, r: int) -> int:
        """The plant's sensor-noise seed of draw ``d``, repeat ``r``."""
        state = np.random.SeedSequence(self.seed, spawn_key=(d, r, 1)).generate_state(1)
        return int(state[0] % (2**31 - 1))

    def runs(self) -> list[dict[str, Any]]:
        """Every run: draw, repeat, reference and controller numbers, parameters, seed."""
        out: list[dict[str, Any]] = []
        for d in range(self.n_draws):
            params = self.draw(d)
            for r in range(self.repeats):
                seed = self.noise_seed(d, r)
                for k in range(len(self.references)):
                    for c in range(len(self.controllers)):
                        out.append(
                            {
                                "run": len(out),
                                "draw": d,
                                "repeat": r,
                                "reference": k,
                                "controller": c,
                                "seed": seed,
                                "varied": params,
                            }
                        )
        return out


def load_spec(path: str | Path, *, check_classes: bool = True) -> CampaignSpec:
    """Read and validate a campaign TOML file (nothing in it is executed but, once everything
    else is valid, the imports of its ``python`` controllers' modules).

    Raises
    ------
    OptionError
        Listing every problem of the file.
    """
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise OptionError(f"Campaign spec {str(p)!r} does not exist.") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise OptionError(f"Campaign spec {str(p)!r} cannot be read: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise OptionError(f"Campaign spec {str(p)!r} is not valid TOML: {exc}") from None
    return spec_from_dict(
        data, base_dir=p.resolve().parent, source=str(p), check_classes=check_classes
    )


def _unknown(
    table: dict[str, Any], allowed: tuple[str, ...], where: str, problems: list[str]
) -> None:
    extra = sorted(set(table) - set(allowed))
    if extra:
        problems.append(
            f"{where}: unknown key(s) {', '.join(extra)}; allowed: {', '.join(allowed)}"
        )


def _number(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


def spec_from_dict(
    data: dict[str, Any],
    base_dir: str | Path = ".",
    source: str = "campaign",
    *,
    check_classes: bool = True,
) -> CampaignSpec:
    """Validate a campaign given as a dictionary (the TOML file's structure, docs/campaigns.md).

    Raises
    ------
    OptionError
        Listing every problem found.
    """
    try:
        return _spec_from_dict(data, Path(base_dir), source, check_classes)
    except (TypeError, AttributeError) as exc:  # a value of a type no check foresaw
        raise OptionError(
            f"Invalid campaign {source}: a value has the wrong type ({exc}); docs/campaigns.md "
            "gives the spec's structure."
        ) from None


def _spec_from_dict(
    data: dict[str, Any], base_dir: Path, source: str, check_classes: bool = True
) -> CampaignSpec:
    # lazy: keeps the robot room off tendonkit.fmu until a campaign is read
    from tendonkit.fmu.build import PARAMETER_RANGES, PRESETS, plant_parameters

    problems: list[str] = []
    base = Path(base_dir)
    if not isinstance(data, dict):
        raise OptionError(f"Invalid campaign {source}: expected a table.")
    _unknown(
        data, ("campaign", "plant", "controllers", "references", "criteria"), "top level", problems
    )
    camp = data.get("campaign", {})
    plant = data.get("plant", {})
    crit = data.get("criteria", {})
    for key, table in (("campaign", camp), ("plant", plant), ("criteria", crit)):
        if not isinstance(table, dict):
            problems.append(f"[{key}] must be a table")
    camp = camp if isinstance(camp, dict) else {}
    plant = plant if isinstance(plant, dict) else {}
    crit = crit if isinstance(crit, dict) else {}
    _unknown(
        camp, ("name", "seed", "sampling", "draws", "repeats", "timeout_s"), "[campaign]", problems
    )
    _unknown(plant, ("preset", "effects", "vary"), "[plant]", problems)
    _unknown(crit, ("require", "rank_by", "min_pass_rate"), "[criteria]", problems)

    name = camp.get("name", re.sub(r"[^A-Za-z0-9_.\- ]", "", Path(source).stem)[:80] or "campaign")
    if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z0-9_.\- ]{1,80}", name):
        problems.append(f"[campaign] name must be 1-80 letters, digits, ' ._-', found {name!r}")
        name = "campaign"
    seed = camp.get("seed", 0)
    if not (is_int(seed) and seed >= 0):
        problems.append(f"[campaign] seed must be a whole number >= 0, found {seed!r}")
        seed = 0
    sampling = camp.get("sampling", "random")
    if sampling not in ("random", "grid"):
        problems.append(f"[campaign] sampling must be 'random' or 'grid', found {sampling!r}")
        sampling = "random"
    draws = camp.get("draws", 1)
    if not (is_int(draws) and 1 <= draws <= 1_000_000):
        problems.append(f"[campaign] draws must be a whole number from 1 to 1e6, found {draws!r}")
        draws = 1
    if sampling == "grid" and "draws" in camp:
        problems.append("[campaign] draws is for random sampling; a grid has every combination")
    repeats = camp.get("repeats", 1)
    if not (is_int(repeats) and 1 <= repeats <= 1000):
        problems.append(
            f"[campaign] repeats must be a whole number from 1 to 1000, found {repeats!r}"
        )
        repeats = 1

    timeout_s = camp.get("timeout_s", DEFAULT_TIMEOUT_S)
    if not (_number(timeout_s) and timeout_s > 0):
        problems.append(
            f"[campaign] timeout_s must be a number of seconds > 0, found {timeout_s!r}"
        )
        timeout_s = DEFAULT_TIMEOUT_S
    preset = plant.get("preset", "nominal")
    if not isinstance(preset, str) or preset not in PRESETS:
        problems.append(f"[plant] preset must be one of {', '.join(PRESETS)}, found {preset!r}")
        preset = "nominal"
    effects = plant.get("effects", [])
    if not (isinstance(effects, list) and all(isinstance(e, str) for e in effects)):
        problems.append(f"[plant] effects must be a list of strings, found {effects!r}")
        effects = []
    fixed = {str(e).partition("=")[0].strip() for e in effects}
    vary = _vary(plant.get("vary", {}), PARAMETER_RANGES, fixed, problems)

    controllers = _controllers(data.get("controllers"), base, problems)
    references = _references(data.get("references"), problems)

    require = crit.get("require", [])
    criteria: list[Criterion] = []
    if not (isinstance(require, list) and all(isinstance(c, str) for c in require)):
        problems.append(f"[criteria] require must be a list of strings, found {require!r}")
        require = []
    for text in require:
        try:
            c = Criterion.parse(text)
        except ValueError:
            problems.append(
                f"[criteria] {text!r} is not 'METRIC OP NUMBER' (OP one of <= < >= > == !=)"
            )
            continue
        if c.metric not in METRICS:
            problems.append(
                f"[criteria] unknown metric {c.metric!r}; metrics: {', '.join(METRICS)}"
            )
        else:
            criteria.append(c)
    rank_by = crit.get("rank_by", "rms_error_true_mrad")
    if not isinstance(rank_by, str) or rank_by not in METRICS:
        problems.append(
            f"[criteria] rank_by must be a metric ({', '.join(METRICS)}), found {rank_by!r}"
        )
        rank_by = "rms_error_true_mrad"
    min_pass = crit.get("min_pass_rate", 1.0)
    if not (_number(min_pass) and 0.0 <= min_pass <= 1.0):
        problems.append(f"[criteria] min_pass_rate must be in [0, 1], found {min_pass!r}")
        min_pass = 1.0

    spec = CampaignSpec(
        name=name,
        seed=seed,
        sampling=sampling,
        draws=draws,
        repeats=repeats,
        preset=preset,
        effects=tuple(effects),
        vary=tuple(vary),
        controllers=tuple(controllers),
        references=tuple(references),
        criteria=tuple(criteria),
        rank_by=rank_by,
        min_pass_rate=float(min_pass),
        base_dir=base,
        timeout_s=float(timeout_s),
    )
    if not problems and spec.n_runs > 1_000_000:
        problems.append(f"the campaign has {spec.n_runs} runs; at most 1,000,000 in one spec")
    if not problems:
        # every draw must be a valid plant: check them all now, not in run 4,127
        try:
            plant_parameters(effects, preset)
        except OptionError as exc:
            problems.extend(f"[plant] effects: {p}" for p in (exc.problems or [str(exc)]))
        else:
            bad: list[str] = []
            for d in range(min(spec.n_draws, 100_000)):
                try:
                    plant_parameters(plant_items(spec.effects, spec.draw(d)), preset)
                except OptionError as exc:
                    bad.append(f"draw {d}: {'; '.join(exc.problems or [str(exc)])}")
                    if len(bad) >= 3:
                        break
            problems.extend(f"[plant] {b}" for b in bad)
    if not problems and check_classes:
        # a user's controller class is imported (its module runs) only once everything else in
        # the spec is valid: a spec with mistakes is read without executing anything
        problems.extend(user_class_problems(spec))
    raise_if(problems, OptionError, f"Invalid campaign {source}:")
    return spec


def user_class_problems(spec: CampaignSpec) -> list[str]:
    """Import each ``python`` controller's class of ``spec`` and check its options against its
    signature (the last check of :func:`load_spec`, for callers that read the spec with
    ``check_classes=False`` and have checks of their own to make first)."""
    problems: list[str] = []
    for c in spec.controllers:
        if c.kind != "python":
            continue
        where, target = f"[[controllers]] {c.name!r}", str(c.cls)
        try:
            cls = _user_class(target, c.path)
            inspect.signature(cls).bind(**c.options)
        except OptionError as exc:
            problems.append(f"{where}: {exc}")
        except TypeError as exc:
            problems.append(f"{where}: options do not fit {target}: {exc}")
        except ValueError:  # no signature to check (a builtin): the runs will tell
            pass
    return problems


def _vary(
    table: Any, ranges: dict[str, tuple[float, float]], fixed: set[str], problems: list[str]
) -> list[Vary]:
    # lazy: keeps the robot room off tendonkit.fmu until a campaign is read
    from tendonkit.fmu.build import plant_parameters

    if not isinstance(table, dict):
        problems.append(f"[plant.vary] must be a table, found {table!r}")
        return []
    names = set(plant_parameters())
    out = []
    for name, item in sorted(table.items()):
        where = f"[plant.vary] {name}"
        if name not in names or name == "seed":
            problems.append(
                f"{where}: not a plant parameter (the noise seed is drawn per repeat); "
                f"parameters: {', '.join(sorted(names - {'seed'}))}"
            )
            continue
        if name in fixed:
            problems.append(f"{where}: also set in [plant] effects; set it in one place")
            continue
        if isinstance(item, str) and item == "spec":
            item = {"range": "spec"}
        if not isinstance(item, dict):
            problems.append(
                f'{where}: expected {{ range = [low, high] }}, {{ range = "spec" }} or {{ values = [...] }}'
            )
            continue
        _unknown(item, ("range", "values", "log", "points"), where, problems)
        log, points = item.get("log", False), item.get("points", 3)
        if not isinstance(log, bool):
            problems.append(f"{where}: log must be true or false")
            log = False
        if not (is_int(points) and 1 <= points <= 1000):
            problems.append(f"{where}: points must be a whole number from 1 to 1000")
            points = 3
        if ("range" in item) == ("values" in item):
            problems.append(f"{where}: give either range or values")
            continue
        if "values" in item:
            vals = item["values"]
            if not (isinstance(vals, list) and vals):
                problems.append(f"{where}: values must be a non-empty list")
                continue
            out.append(Vary(name, values=tuple(vals), points=len(vals)))
            continue
        rng = item["range"]
        if rng == "spec":
            if name not in ranges:
                problems.append(
                    f"{where}: the plant spec gives no range for it; give range = [low, high]"
                )
                continue
            rng = list(ranges[name])
        if not (
            isinstance(rng, list)
            and len(rng) == 2
            and all(_number(x) for x in rng)
            and rng[0] <= rng[1]
        ):
            problems.append(f"{where}: range must be [low, high] with low <= high, found {rng!r}")
            continue
        if name in ranges and not (ranges[name][0] <= rng[0] and rng[1] <= ranges[name][1]):
            lo, hi = ranges[name]
            problems.append(f"{where}: range {rng} leaves the plant's valid range [{lo:g}, {hi:g}]")
            continue
        if log and rng[0] <= 0:
            problems.append(f"{where}: a log range needs low > 0")
            continue
        out.append(Vary(name, float(rng[0]), float(rng[1]), None, log, points))
    return out


def _controllers(items: Any, base: Path, problems: list[str]) -> list[ControllerSpec]:
    """The controller tables; a user class is not imported here (:func:`user_class_problems`)."""
    if not (isinstance(items, list) and items and all(isinstance(i, dict) for i in items)):
        problems.append("[[controllers]]: give at least one controller table")
        return []
    out = []
    for n, item in enumerate(items):
        kind = item.get("kind", "mpc")
        name = item.get("name", f"{kind} {n + 1}")
        where = f"[[controllers]] {name!r}"
        _unknown(
            item, ("name", "kind", "model", "class", "path", "options", *_SETTINGS), where, problems
        )
        if kind not in _CONTROLLER_KINDS:
            problems.append(
                f"{where}: kind must be one of {', '.join(_CONTROLLER_KINDS)}, found {kind!r}"
            )
            continue
        if not isinstance(name, str) or not name.strip():
            problems.append(f"{where}: name must be a non-empty string")
            continue
        settings = {k: item[k] for k in _SETTINGS if k in item}
        options = item.get("options", {})
        if kind == "mpc":
            model_path = item.get("model")
            if not isinstance(model_path, str):
                problems.append(f'{where}: an MPC needs model = "MODEL.json"')
                continue
            full = (base / model_path).resolve()
            try:
                model = Model.load(full)
                controller_kind(model)
                if abs(model.dt - STEP) > 1e-6 * STEP:
                    raise OptionError(
                        f"model {model.name!r} has sample time {model.dt:g} s; the controller runs at {STEP:g} s"
                    )
                make_controller(model, ControllerSettings(**settings))
            except (SchemaError, OptionError, TypeError, ValueError) as exc:
                problems.append(
                    f"{where}: {str(exc).splitlines()[0]} {' '.join(getattr(exc, 'problems', []))}".strip()
                )
                continue
            out.append(ControllerSpec(name, kind, str(full), settings))
        elif kind == "open_loop":
            ignored = sorted(set(item) - {"name", "kind"})
            if ignored:
                problems.append(f"{where}: the open loop takes no {', '.join(ignored)}")
                continue
            out.append(ControllerSpec(name, kind))
        else:
            target = item.get("class")
            path = item.get("path")
            if not (isinstance(target, str) and re.fullmatch(r"[\w.]+:\w+", target)):
                problems.append(f'{where}: class must be "module:Class", found {target!r}')
                continue
            if not isinstance(options, dict):
                problems.append(f"{where}: options must be a table")
                continue
            full_path = str((base / path).resolve()) if isinstance(path, str) else None
            out.append(
                ControllerSpec(name, kind, cls=target, path=full_path, options=dict(options))
            )
    names = [c.name for c in out]
    if len(set(names)) != len(names):
        problems.append(f"[[controllers]]: names must differ, found {names}")
    return out


def _references(items: Any, problems: list[str]) -> list[ReferenceSpec]:
    if items is None:
        return [ReferenceSpec("petal", 60.0)]
    if not (isinstance(items, list) and items and all(isinstance(i, dict) for i in items)):
        problems.append("[[references]]: give reference tables (kind, duration, speed, amplitude)")
        return []
    out = []
    for n, item in enumerate(items):
        where = f"[[references]] {n + 1}"
        _unknown(item, ("kind", "duration", "speed", "amplitude", "petals"), where, problems)
        kind = item.get("kind", "petal")
        duration, petals = item.get("duration"), item.get("petals", 3)
        if duration is not None and not (_number(duration) and duration > 0):
            problems.append(
                f"{where}: duration must be a number of seconds > 0, found {duration!r}"
            )
            continue
        if not (is_int(petals) and 1 <= petals <= 12):
            problems.append(
                f"{where}: petals must be a whole number from 1 to 12, found {petals!r}"
            )
            continue
        if not isinstance(kind, str):
            problems.append(f"{where}: kind must be one of {', '.join(REFERENCES)}, found {kind!r}")
            continue
        ref = ReferenceSpec(
            kind,
            item.get("duration"),
            item.get("speed", 2.5),
            item.get("amplitude", 9.0),
            item.get("petals", 3),
        )
        try:
            for x, what in ((ref.speed_cm_s, "speed"), (ref.amplitude_cm, "amplitude")):
                if not (_number(x) and x > 0):
                    raise OptionError(f"{what} must be a number > 0, found {x!r}")
            if kind not in REFERENCES:
                raise OptionError(f"kind must be one of {', '.join(REFERENCES)}, found {kind!r}")
            ref.build()
        except OptionError as exc:
            problems.append(f"{where}: {' '.join(exc.problems) or str(exc)}")
            continue
        out.append(ref)
    names = [r.name for r in out]
    if len(set(names)) != len(names):
        problems.append(f"[[references]]: two references are the same ({', '.join(names)})")
    return out


def plant_items(effects: Sequence[str], varied: Mapping[str, Any]) -> list[str]:
    """``--effect`` items of one plant: the fixed ``effects``, the ``varied`` parameters, and
    the switches of the effects whose parameters are varied (unless set explicitly)."""
    # lazy: keeps the robot room off tendonkit.fmu until a campaign is read
    from tendonkit.fmu.build import plant_parameters

    names = set(plant_parameters())
    items = list(effects)
    explicit = {e.partition("=")[0].strip() for e in effects} | set(varied)
    for name, value in varied.items():
        items.append(f"{name}={value}")
        switch = name.split("_")[0] + "_on"
        if switch in names and switch not in explicit and not name.endswith("_on"):
            items.append(f"{switch}=1")
            explicit.add(switch)
    return items


# -- one run, in a worker ----------------------------------------------------------------------

_FMU_CACHE: dict[str, Path] = {}
_PRIVATE: list[Path] = []


def _materialise(blob: bytes, sha: str) -> Path:
    """The plant FMU in this worker's temporary folder (written once per process and content)."""
    if sha in _FMU_CACHE and _FMU_CACHE[sha].is_file():
        return _FMU_CACHE[sha]
    if not _PRIVATE:  # this process's own folder (mode 0700): nobody else can swap the FMU
        _PRIVATE.append(Path(tempfile.mkdtemp(prefix="tendonkit-campaign-")))
    path = _PRIVATE[0] / f"plant-{sha[:16]}.fmu"
    path.write_bytes(blob)
    _FMU_CACHE[sha] = path
    return path


def _user_class(target: str, path: str | None) -> type:
    # appended, not prepended: a file in the spec's folder never shadows a library
    if path and path not in sys.path:
        sys.path.append(path)
    module, _, name = target.partition(":")
    try:
        cls = getattr(importlib.import_module(module), name)
    except Exception as exc:  # the user's module: any import failure is reported, not raised
        raise OptionError(f"cannot import {target!r}: {type(exc).__name__}: {exc}") from None
    if not callable(getattr(cls, "step", None)):
        raise OptionError(f"{target!r} has no step(y, r_future) method")
    return cls


@dataclass
class _Step:
    u: Any
    fallback: bool = False
    solve_time_s: float = 0.0
    status: str = "ok"


class _UserController:
    """A user's controller as the co-simulation master needs it (``step`` may return u only)."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.horizon = int(getattr(inner, "horizon", 1))
        self.output_names = list(getattr(inner, "output_names", ["q1", "q2"]))

    def reset(self, u0: Any = None, y0: Any = None) -> None:
        if callable(getattr(self.inner, "reset", None)):
            self.inner.reset(u0=u0, y0=y0)

    def step(self, y_meas: Any, r_future: Any) -> Any:
        res = self.inner.step(y_meas, r_future)
        return res if hasattr(res, "u") else _Step(np.asarray(res, dtype=float))


def _controller(c: dict[str, Any], models: dict[str, str]) -> Any:
    if c["kind"] == "open_loop":
        return None
    if c["kind"] == "mpc":
        model = Model.from_json(models[c["model"]], source=c["model"])
        return make_controller(model, ControllerSettings(**c["settings"]))
    cls = _user_class(c["cls"], c["path"])
    return _UserController(cls(**c["options"]))


def metrics_of(result: CosimResult) -> dict[str, float]:
    """The campaign's per-run metrics (:data:`METRICS`) of one co-simulation."""
    s = result.summary()
    e, et = s["rms_error_rad"], s["rms_error_true_rad"]
    ee_true = np.linalg.norm(result.truth[:, 2:5] - result.reference.ee, axis=1)
    out = {
        "rms_error_mrad": 1e3 * math.sqrt((e["q1"] ** 2 + e["q2"] ** 2) / 2),
        "rms_q1_mrad": 1e3 * e["q1"],
        "rms_q2_mrad": 1e3 * e["q2"],
        "rms_error_true_mrad": 1e3 * math.sqrt((et["q1"] ** 2 + et["q2"] ** 2) / 2),
        "rms_true_q1_mrad": 1e3 * et["q1"],
        "rms_true_q2_mrad": 1e3 * et["q2"],
        "ee_error_cm": s["mean_ee_error_cm"],
        "ee_error_true_cm": s["mean_ee_error_true_cm"],
        "ee_error_true_max_cm": float(100 * np.max(ee_true)),
        "solve_p99_ms": s["solve_time_ms"]["p99"] if "solve_time_ms" in s else math.nan,
        "step_p99_ms": s["step_time_ms"]["p99"] if "step_time_ms" in s else math.nan,
        "deadline_misses": s.get("deadline_misses", 0),
        "fallbacks": s["fallbacks"],
        "bound_violations": s["input_bound_violations"],
        "wall_s": s["wall_time_s"],
    }
    return {k: (float(v) if isinstance(v, float) else int(v)) for k, v in out.items()}


def _simulate(shared: dict[str, Any], payload: dict[str, Any]) -> CosimResult:
    fmu = _materialise(shared["fmu"], shared["fmu_sha"])
    ref = ReferenceSpec(**shared["references"][payload["reference"]]).build()
    c = shared["controllers"][payload["controller"]]
    # lazy: heavy (threadpoolctl); one BLAS thread whatever the engine, for identical numbers
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1):
        controller = _controller(c, shared["models"])
        return run(fmu, ref, controller, parameters=payload["parameters"], name=c["name"])


def _run_task(shared: dict[str, Any], payload: dict[str, Any]) -> dict[str, float]:
    """One run in a worker: the co-simulation's metrics (an exception is the run's error)."""
    return metrics_of(_simulate(shared, payload))


# -- the campaign ------------------------------------------------------------------------------


@dataclass
class CampaignResult:
    """What :func:`run_campaign` produced.

    Attributes
    ----------
    spec : CampaignSpec
    out : Path
        The campaign folder.
    rows : list of dict
        One per run, sorted by run number (the table).
    summary : dict
        Pass rate, per-controller figures, worst cases, retries, timing (``summary.json``).
    resumed : int
        Rows taken from an earlier, interrupted run of the same campaign.
    """

    spec: CampaignSpec
    out: Path
    rows: list[dict[str, Any]]
    summary: dict[str, Any]
    resumed: int = 0

    @property
    def passed(self) -> bool:
        """Whether the pass rate reaches the spec's ``min_pass_rate``."""
        return bool(self.summary["pass_rate"] >= self.spec.min_pass_rate)

    def check(self, min_pass_rate: float | None = None) -> None:
        """Raise AssertionError unless the pass rate reaches ``min_pass_rate`` (default: the spec's).

        The message gives the pass rate per controller and the worst runs with their plants.
        """
        need = self.spec.min_pass_rate if min_pass_rate is None else float(min_pass_rate)
        if self.summary["pass_rate"] < need:
            raise AssertionError(
                f"pass rate {100 * self.summary['pass_rate']:.1f} % < required {100 * need:.1f} %\n"
                + render(self.summary)
            )

    def table(self, deterministic: bool = False) -> list[dict[str, Any]]:
        """The rows; with ``deterministic`` only the columns that do not measure the machine."""
        if not deterministic:
            return [dict(r) for r in self.rows]
        keep = set(DETERMINISTIC) | {v.name for v in self.spec.vary} | {"passed", "failed"}
        return [{k: v for k, v in r.items() if k in keep} for r in self.rows]


def _plant_fmu(spec: CampaignSpec, plant_fmu: str | Path | None) -> Path:
    """The plant FMU given, or the one of the spec's preset (built once, cached)."""
    # lazy: keeps the robot room off tendonkit.fmu until a campaign runs
    from tendonkit.fmu.build import cached_plant_fmu, plant_parameters

    if plant_fmu is not None:
        return Path(plant_fmu)
    return cached_plant_fmu(plant_parameters([], spec.preset))


def _payloads(
    spec: CampaignSpec, fmu_start: dict[str, Any], runs: list[dict[str, Any]] | None = None
) -> list[dict[str, Any]]:
    """What each run's worker needs: its numbers, the plant's overrides, the drawn values."""
    # lazy: keeps the robot room off tendonkit.fmu until a campaign is read
    from tendonkit.fmu.build import plant_parameters

    out = []
    cache: dict[int, dict[str, Any]] = {}
    for r in spec.runs() if runs is None else runs:
        d = r["draw"]
        if d not in cache:
            cache[d] = plant_parameters(plant_items(spec.effects, r["varied"]), spec.preset)
        full = {**cache[d], "seed": r["seed"]}
        overrides = {k: v for k, v in full.items() if fmu_start.get(k) != v}
        payload = {k: r[k] for k in ("run", "draw", "repeat", "reference", "controller", "seed")}
        payload["parameters"] = overrides
        payload["varied"] = r["varied"]
        out.append(payload)
    return out


def _shared(spec: CampaignSpec, fmu: Path) -> dict[str, Any]:
    blob = fmu.read_bytes()
    models = {
        c.model: Path(c.model).read_text(encoding="utf-8")
        for c in spec.controllers
        if c.model is not None
    }
    return {
        "fmu": blob,
        "fmu_sha": hashlib.sha256(blob).hexdigest(),
        "models": models,
        "controllers": [
            {
                "name": c.name,
                "kind": c.kind,
                "model": c.model,
                "settings": c.settings,
                "cls": c.cls,
                "path": c.path,
                "options": c.options,
            }
            for c in spec.controllers
        ],
        "references": [
            {
                "kind": r.kind,
                "duration": r.duration,
                "speed_cm_s": r.speed_cm_s,
                "amplitude_cm": r.amplitude_cm,
                "petals": r.petals,
            }
            for r in spec.references
        ],
    }


def _fingerprint(shared: dict[str, Any], payloads: list[dict[str, Any]]) -> str:
    """What the rows depend on: the plant, models, controllers (a user's source too), runs."""
    h = hashlib.sha256()
    h.update(__version__.encode())
    h.update(shared["fmu_sha"].encode())
    for c in shared["controllers"]:
        if c["kind"] == "python":
            source = inspect.getsourcefile(_user_class(c["cls"], c["path"]))
            if source:
                h.update(Path(source).read_bytes())
    h.update(
        json.dumps(
            {k: v for k, v in shared.items() if k != "fmu"}, sort_keys=True, default=str
        ).encode()
    )
    h.update(json.dumps(payloads, sort_keys=True, default=str).encode())
    return h.hexdigest()


def _row(spec: CampaignSpec, payload: dict[str, Any], rec: dict[str, Any]) -> dict[str, Any]:
    row: dict[str, Any] = {
        "run": payload["run"],
        "draw": payload["draw"],
        "repeat": payload["repeat"],
        "controller": spec.controllers[payload["controller"]].name,
        "reference": spec.references[payload["reference"]].name,
        "seed": payload["seed"],
    }
    row.update(payload["varied"])
    values = rec.get("value") or {}
    for m in METRICS:
        row[m] = values.get(m, math.nan)
    error = rec.get("error")
    finite = all(
        isinstance(row[m], int) or math.isfinite(row[m])
        for m in METRICS
        if m not in ("solve_p99_ms", "step_p99_ms")
    )
    row["status"] = "error" if error else ("ok" if finite else "diverged")
    row["error"] = (error or "").splitlines()[0] if error else ""
    failed = [str(c) for c in spec.criteria if not c.holds(row)]
    row["passed"] = row["status"] == "ok" and not failed
    row["failed"] = "; ".join(failed if row["status"] == "ok" else [row["status"], *failed])
    row["attempts"] = rec.get("attempts", 1)
    row["worker"] = rec.get("worker", "")
    return row


class _Journal:
    """``runs.jsonl``: one line per finished run, flushed and synced as it comes.

    ``OUT/.lock`` (never replaced) is locked first and held until :meth:`close`, so a second
    campaign on the same folder is refused before it reads or touches anything.  On resume,
    rows the machinery lost (a worker that kept dying, a timeout) are run again; rows of runs
    that raised are kept: they would raise again.
    """

    def __init__(self, path: Path, fingerprint: str, n_runs: int, fresh: bool) -> None:
        self.path = path
        self.done: dict[int, dict[str, Any]] = {}
        folder = path.parent
        try:
            self.lock = (folder / ".lock").open("a")
        except OSError as exc:
            raise OutputError(f"Cannot write the campaign folder {str(folder)!r}: {exc}") from None
        if fcntl is not None:  # not POSIX: two writers are the user's business
            try:
                fcntl.flock(self.lock.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                self.lock.close()
                raise OptionError(
                    f"another campaign is writing {str(folder)!r}; wait for it or use another --out"
                ) from None
        try:
            self._open(fingerprint, n_runs, fresh)
        except OSError as exc:
            self.lock.close()
            raise OutputError(f"Cannot write the campaign journal {str(path)!r}: {exc}") from None
        except (OptionError, OutputError):
            self.lock.close()
            raise

    def _open(self, fingerprint: str, n_runs: int, fresh: bool) -> None:
        path = self.path
        manifest = path.with_name("campaign.json")
        if fresh and path.exists():
            stamp = time.strftime("%Y%m%d-%H%M%S")
            path.rename(path.with_name(f"runs-{stamp}.jsonl.old"))
        if path.exists():
            old = {}
            with contextlib.suppress(OSError, ValueError):
                old = json.loads(manifest.read_text())
            if old.get("fingerprint") != fingerprint:
                raise OptionError(
                    f"{str(path.parent)!r} holds the rows of another campaign (its spec, models, "
                    "controllers, plant or tendonkit version differ); use another --out, or "
                    "--fresh to set those rows aside (kept as runs-*.jsonl.old)."
                )
            for line in path.read_text(encoding="utf-8").splitlines():
                with contextlib.suppress(ValueError, KeyError, TypeError):
                    rec = json.loads(line)
                    error = rec.get("error") or ""
                    if error.startswith(LOST):  # the engine lost it: run it again
                        continue
                    self.done[int(rec["run"])] = rec  # a line cut by the interruption is skipped
        write_json(manifest, {"fingerprint": fingerprint, "runs": n_runs, "tendonkit": __version__})
        # rewrite the valid lines only, so a cut line does not end up in the middle
        kept = "".join(json.dumps(r) + "\n" for r in self.done.values())
        atomic_write(path, lambda tmp: tmp.write_text(kept, encoding="utf-8"))
        self.fh = path.open("a", encoding="utf-8")

    def write(self, rec: dict[str, Any]) -> None:
        try:
            self.fh.write(json.dumps(rec, default=float) + "\n")
            self.fh.flush()
            os.fsync(self.fh.fileno())
        except OSError as exc:
            raise OutputError(
                f"Cannot write the campaign journal {str(self.path)!r}: {exc}; the runs written "
                "so far are kept: run the campaign again to resume."
            ) from None
        self.done[int(rec["run"])] = rec

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.fh.close()
        self.lock.close()


def run_campaign(
    spec: CampaignSpec | str | Path,
    out: str | Path,
    *,
    jobs: int | None = None,
    scheduler: str | None = None,
    fresh: bool = False,
    progress: bool = False,
    report: bool = True,
    plant_fmu: str | Path | None = None,
) -> CampaignResult:
    """Run a campaign (or finish an interrupted one) and write its table, summary and report.

    Parameters
    ----------
    spec : CampaignSpec or path
        The campaign, or its TOML file.
    out : path
        Campaign folder (created): ``runs.jsonl`` (written as runs finish), ``runs.csv``,
        ``summary.json``, ``index.html``, ``figures/``.
    jobs : int, optional
        Workers (default: this machine's cores; 1 runs in this process).
    scheduler : str, optional
        ``"local"`` (a dask LocalCluster of ``jobs`` workers) or a dask scheduler address.
    fresh : bool
        Set aside the rows of an earlier run in ``out`` instead of resuming from them.
    progress : bool
        A progress bar with the time left.
    report : bool
        Write the figures and ``index.html`` (the worst runs are simulated again here to draw
        their trajectories).
    plant_fmu : path, optional
        A plant FMU to use instead of the one built for the spec's preset.

    Returns
    -------
    CampaignResult
    """
    if not isinstance(spec, CampaignSpec):
        spec = load_spec(spec)
    raise_if(task_problems(jobs, scheduler), OptionError, f"Campaign {spec.name!r} cannot run:")
    out = Path(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"Cannot create the campaign folder {str(out)!r}: {exc}") from None
    fmu = _plant_fmu(spec, plant_fmu)
    start = fmu_parameters(fmu)
    payloads = _payloads(spec, start)
    shared = _shared(spec, fmu)
    journal = _Journal(out / "runs.jsonl", _fingerprint(shared, payloads), len(payloads), fresh)
    resumed = len(journal.done)
    todo = [p for p in payloads if p["run"] not in journal.done]
    t0 = time.perf_counter()
    n_jobs = jobs if jobs is not None else default_jobs()
    try:
        for o in run_tasks(
            _run_task,
            todo,
            shared=shared,
            jobs=n_jobs,
            scheduler=scheduler,
            progress=progress,
            desc=f"campaign {spec.name}",
            timeout=spec.timeout_s,
        ):
            journal.write(_record(todo[o.index]["run"], o))
    finally:
        journal.close()
    wall = time.perf_counter() - t0
    rows = [_row(spec, p, journal.done[p["run"]]) for p in payloads]
    engine = engine_name(n_jobs, scheduler)
    timing = {
        "engine": engine,
        "workers": 1 if engine == "serial" else n_jobs,
        "scheduler": scheduler,
        "wall_s": wall,
        "runs_now": len(todo),
    }
    summary = summarise(spec, rows, timing, resumed, tuple(METRICS))
    write_outputs(spec, out, rows, summary, shared, payloads, _simulate, report=report)
    return CampaignResult(spec, out, rows, summary, resumed)


def _record(run_number: int, o: Outcome) -> dict[str, Any]:
    return {
        "run": run_number,
        "value": o.value,
        "error": o.error,
        "attempts": o.attempts,
        "worker": o.worker,
        "seconds": o.seconds,
    }


def rerun(
    result: CampaignResult, run_number: int, plant_fmu: str | Path | None = None
) -> CosimResult:
    """Simulate run ``run_number`` of a campaign again, here, with its trajectories.

    Runs are deterministic, so this gives the row's metrics again (timing aside).
    """
    if not (isinstance(run_number, int) and 0 <= run_number < result.spec.n_runs):
        raise OptionError(
            f"run must be a whole number from 0 to {result.spec.n_runs - 1}, found {run_number!r}"
        )
    spec = result.spec
    fmu = _plant_fmu(spec, plant_fmu)
    [payload] = _payloads(spec, fmu_parameters(fmu), [spec.runs()[run_number]])
    return _simulate(_shared(spec, fmu), payload)

"""The plant as an FMI 2.0 co-simulation slave (pythonfmu): :class:`TendonPlant`.

This file is both a module of :mod:`tendonkit.fmu` and the script that pythonfmu packs into the
plant FMU (``tendonkit plant build``; :func:`tendonkit.fmu.build.build_plant_fmu`).  Inside the
FMU it is imported as the top-level module ``plant_fmu`` by the Python interpreter that hosts the
FMU, which must have tendonkit (and so numpy and scipy) installed: the slave only wraps
:class:`tendonkit.fmu.plant.Plant`.

Interface (plant spec §13):

* inputs ``T_cmd1..T_cmd4`` (N), held over the step;
* outputs ``q1..q6`` (rad), ``ee_x, ee_y, ee_z`` (m), ``T1..T4`` (N) as the sensors report them,
  and the truth ``q1_true..q6_true``, ``ee_x_true..ee_z_true``;
* parameters: every flat name of :func:`tendonkit.fmu.plant.config_to_dict` (effects, ``mount``,
  ``seed`` and the robot's geometry), applied when the master leaves initialisation mode.

The communication step is fixed at :data:`STEP` (30 ms).  A ``doStep`` with any other step size is
refused: the slave logs the reason at error level and returns ``False`` (pythonfmu reports that
as ``fmi2Discard``), and the plant does not move, so the master may retry with 30 ms.

A bad parameter combination is reported when the master leaves initialisation mode: every
problem in one message at error level, outputs NaN, and every ``doStep`` refused (``fmi2Discard``)
with the same message.  The slave never raises into pythonfmu: pythonfmu 0.7.0 turns a Python
exception into ``fmi2Fatal`` and releases the Python instance twice afterwards, which aborts the
host process on ``fmi2FreeInstance`` or at exit; it cannot return ``fmi2Error`` at all.  Note that
pythonfmu forwards log messages only when the instance was created with ``loggingOn=true``.

The default parameter values come from ``resources/plant_parameters.json`` (plain JSON written by
the builder, never executed), so one script serves every built configuration.
"""

from __future__ import annotations

import inspect
import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from pythonfmu import Boolean, Fmi2Causality, Fmi2Slave, Integer, Real, String
from pythonfmu.default_experiment import DefaultExperiment
from pythonfmu.enums import Fmi2Initial, Fmi2Status, Fmi2Variability

from tendonkit.fmu.plant import Plant, PlantConfig, config_from_dict, config_to_dict
from tendonkit.robot import RobotParameters

#: Fixed communication step of the plant FMU, s.
STEP = 0.03
#: Name of the resource file holding the parameter start values.
PARAMETER_FILE = "plant_parameters.json"
#: Input variables (commanded tensions, N).
INPUTS = ("T_cmd1", "T_cmd2", "T_cmd3", "T_cmd4")
#: Measured outputs: joint angles (rad), end effector (m), tendon forces (N).
MEASURED = (
    *(f"q{i}" for i in range(1, 7)),
    "ee_x",
    "ee_y",
    "ee_z",
    *(f"T{k}" for k in range(1, 5)),
)
#: Truth outputs (for test oracles): joint angles and end effector without sensor effects.
TRUTH = (*(f"q{i}_true" for i in range(1, 7)), "ee_x_true", "ee_y_true", "ee_z_true")
#: Every output in value-reference order.
OUTPUTS = MEASURED + TRUTH
#: Units of the inputs and outputs.
SIGNAL_UNITS: dict[str, str] = {
    **dict.fromkeys(INPUTS, "N"),
    **{n: "rad" for n in OUTPUTS if n.startswith("q")},
    **{n: "m" for n in OUTPUTS if n.startswith("ee")},
    **{n: "N" for n in OUTPUTS if n.startswith("T")},
}
#: Units of the parameters (dimensionless ones are left out).
PARAMETER_UNITS: dict[str, str] = {
    "settle_s": "s",
    "friction_beta0": "rad",
    "backlash_b": "rad",
    "delay_s": "s",
    "deadzone_T": "N",
    "deadzone_w": "N",
    "forcelag_tau": "s",
    "forcelag_vmax": "m/s",
    "forcelag_kt": "N/m",
    "softening_qs": "rad",
    "noise_sigma_q": "rad",
    "noise_sigma_p": "m",
    "noise_sigma_T": "N",
    "noise_quantum_T": "N",
    "camera_fc": "Hz",
    "link_pitch": "m",
    "tool_offset": "m",
    "rho": "m",
    "R_base": "m",
    "q_cal": "rad",
    "link_mass": "kg",
    "tool_mass": "kg",
    "link_Ixx": "kg.m2",
    "link_Izz": "kg.m2",
    "k_e": "N.m/rad",
    "damping_beta": "s",
    "P_nom": "N",
    "T_min": "N",
    "T_max": "N",
    "gravity": "m/s2",
}
_DESCRIPTIONS = {
    "T_cmd": "commanded tension of tendon {k} (held over the step)",
    "q": "measured angle of joint {k} (backlash, camera filter, noise)",
    "T": "measured force of tendon {k}",
    "q_true": "true angle of joint {k}",
}
_OUTPUT_KEYS = ("q", "ee", "T_meas", "q_true", "ee_true")


def default_parameters() -> dict[str, Any]:
    """The nominal plant's flat parameters (effects off, nominal robot)."""
    return dict(config_to_dict(PlantConfig()))


def read_parameters(resources: str | None) -> dict[str, Any]:
    """Parameter start values: the defaults updated from the FMU's parameter resource file.

    Parameters
    ----------
    resources : str or None
        The FMU's resource folder; ``None`` or a folder without the file gives the defaults.

    Returns
    -------
    dict
        ``name -> value``; unknown names in the file are ignored (they cannot be set anyway).
    """
    params = default_parameters()
    if resources:
        path = Path(resources) / PARAMETER_FILE
        if path.is_file():
            stored = json.loads(path.read_text(encoding="utf-8"))
            params.update((k, v) for k, v in stored.items() if k in params)
    return params


class TendonPlant(Fmi2Slave):
    """FMI 2.0 co-simulation slave of the tendon-driven snake-robot plant (see module docs)."""

    author = "tendonkit"
    description = (
        "Tendon-driven 6-joint rolling-joint snake robot with switchable hidden effects "
        "(tendonkit plant, fixed 30 ms communication step)"
    )
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=10.0, step_size=STEP)

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self._params = read_parameters(self.resources)
        self._plant: Plant | None = None
        self._initialised = False
        self._dirty = True
        self._error: str | None = None
        p_nom = float(self._params["P_nom"])
        # Inputs and outputs live in one flat list indexed by value reference.
        self._io: list[float] = [p_nom] * len(INPUTS) + [0.0] * len(OUTPUTS)
        self._n_in = len(INPUTS)
        self._n_io = len(self._io)
        self._in_vrs = list(range(self._n_in))
        for k, name in enumerate(INPUTS):
            self.register_variable(
                Real(
                    name,
                    causality=Fmi2Causality.input,
                    variability=Fmi2Variability.continuous,
                    description=_DESCRIPTIONS["T_cmd"].format(k=k + 1),
                    getter=self._io_getter(k),
                    setter=self._input_setter(k),
                )
            )
        for j, name in enumerate(OUTPUTS):
            truth = name.endswith("_true")
            self.register_variable(
                Real(
                    name,
                    causality=Fmi2Causality.output,
                    variability=Fmi2Variability.continuous if truth else Fmi2Variability.discrete,
                    initial=Fmi2Initial.calculated,
                    description=_output_description(name),
                    getter=self._io_getter(self._n_in + j, output=True),
                )
            )
        kinds: dict[type, Any] = {bool: Boolean, int: Integer, str: String, float: Real}
        about = parameter_descriptions()
        for name, default in default_parameters().items():
            self.register_variable(
                kinds[type(default)](
                    name,
                    causality=Fmi2Causality.parameter,
                    variability=Fmi2Variability.fixed,
                    initial=Fmi2Initial.exact,
                    description=about.get(name, ""),
                    getter=self._param_getter(name),
                    setter=self._param_setter(name),
                )
            )

    # ------------------------------------------------------------------ accessors
    def _io_getter(self, index: int, output: bool = False) -> Callable[[], float]:
        def get() -> float:
            if output:
                self._ensure_plant()
            return self._io[index]

        return get

    def _input_setter(self, index: int) -> Callable[[float], None]:
        def set_(value: float) -> None:
            self._io[index] = float(value)

        return set_

    def _param_getter(self, name: str) -> Callable[[], Any]:
        return lambda: self._params[name]

    def _param_setter(self, name: str) -> Callable[[Any], None]:
        def set_(value: Any) -> None:
            if self._initialised:
                self.log(
                    f"parameter {name} is fixed: set it before exitInitializationMode; "
                    f"the value {value!r} is ignored",
                    Fmi2Status.error,
                )
                return
            self._params[name] = value
            self._dirty = True

        return set_

    def get_real(self, vrs: list[int]) -> list[float]:
        """Fast path for inputs and outputs (one list lookup per value reference)."""
        if vrs and max(vrs) < self._n_io and min(vrs) >= 0:
            if not self._initialised and max(vrs) >= self._n_in:
                self._ensure_plant()
            io = self._io
            return [io[v] for v in vrs]
        return _guarded(self, super().get_real, vrs, default=math.nan)

    def set_real(self, vrs: list[int], values: list[float]) -> None:
        """Fast path for the four inputs."""
        if vrs == self._in_vrs:
            self._io[: self._n_in] = [float(v) for v in values]
            return
        _guarded(self, super().set_real, vrs, values)

    def get_integer(self, vrs: list[int]) -> list[int]:
        """Integer getter that logs instead of raising (see module docs)."""
        return _guarded(self, super().get_integer, vrs, default=0)

    def get_boolean(self, vrs: list[int]) -> list[bool]:
        """Boolean getter that logs instead of raising (see module docs)."""
        return _guarded(self, super().get_boolean, vrs, default=False)

    def get_string(self, vrs: list[int]) -> list[str]:
        """String getter that logs instead of raising (see module docs)."""
        return _guarded(self, super().get_string, vrs, default="")

    def set_integer(self, vrs: list[int], values: list[int]) -> None:
        """Integer setter that logs instead of raising (see module docs)."""
        _guarded(self, super().set_integer, vrs, values)

    def set_boolean(self, vrs: list[int], values: list[bool]) -> None:
        """Boolean setter that logs instead of raising (see module docs)."""
        _guarded(self, super().set_boolean, vrs, values)

    def set_string(self, vrs: list[int], values: list[str]) -> None:
        """String setter that logs instead of raising (see module docs)."""
        _guarded(self, super().set_string, vrs, values)

    # ------------------------------------------------------------------ FMI life cycle
    def setup_experiment(
        self, start_time: float, stop_time: float | None = None, tolerance: float | None = None
    ) -> None:
        """Nothing to prepare: the plant always starts at rest (plant spec §13)."""

    def exit_initialization_mode(self) -> None:
        """Apply the parameters: build the plant, or log every problem at error level."""
        self._ensure_plant()
        self._initialised = True

    def do_step(self, current_time: float, step_size: float) -> bool:
        """Advance one 30 ms frame with the inputs held; refuse any other step size."""
        plant = self._plant
        if plant is None or self._error is not None:
            self.log(f"cannot step: {self._error}", Fmi2Status.error)
            return False
        if abs(step_size - STEP) > 1e-9:
            self.log(
                f"communication step {step_size!r} s refused: this plant FMU steps at exactly "
                f"{STEP} s (its fixed frame); the state did not change",
                Fmi2Status.error,
            )
            return False
        try:
            # The plant's per-frame path: Plant.step without its dictionary of array copies.
            out = plant._advance(self._io[: self._n_in])
        except Exception as exc:  # never let an exception reach pythonfmu (see module docs)
            self.log(f"step at t = {current_time:g} s failed: {exc}", Fmi2Status.error)
            return False
        self._io[self._n_in :] = (
            out["q"] + out["ee"] + out["T_meas"] + out["q_true"] + out["ee_true"]
        )
        return True

    # ------------------------------------------------------------------ helpers
    def _ensure_plant(self) -> None:
        """(Re)build the plant from the current parameters if they changed.

        A bad parameter set is logged at error level with every problem, the outputs become
        NaN and every later ``doStep`` is refused; nothing is raised (see module docs).
        """
        if not self._dirty:
            return
        self._dirty = False
        try:
            config, robot = config_from_dict(dict(self._params))
            self._plant = Plant(config, robot, h=STEP)
        except Exception as exc:  # OptionError lists every problem
            problems = getattr(exc, "problems", None) or [str(exc)]
            self._plant = None
            self._error = "plant parameters rejected: " + "; ".join(problems)
            self._io[self._n_in :] = [math.nan] * len(OUTPUTS)
            self.log(self._error, Fmi2Status.error)
            return
        self._error = None
        self._io[self._n_in :] = _pack(self._plant.outputs())


def _guarded(
    slave: Fmi2Slave,
    call: Callable[..., Any],
    vrs: list[int],
    values: list[Any] | None = None,
    default: Any = None,
) -> Any:
    """Run a pythonfmu accessor; log a failure at error level instead of raising.

    A failing getter returns ``default`` for every value reference; a failing setter sets
    nothing.
    """
    try:
        return call(vrs) if values is None else call(vrs, values)
    except Exception as exc:  # e.g. a value reference of another type
        slave.log(f"{call.__name__}({vrs}) failed: {exc}", Fmi2Status.error)
        return None if values is not None else [default] * len(vrs)


def _pack(out: dict[str, Any]) -> list[float]:
    """Output values in :data:`OUTPUTS` order from plant outputs (1-D, or one-row 2-D)."""
    values: list[float] = np.concatenate([out[key].ravel() for key in _OUTPUT_KEYS]).tolist()
    return values


def parameter_descriptions() -> dict[str, str]:
    """A description of every plant parameter, from the numpydoc ``Parameters`` sections of
    :class:`PlantConfig` and :class:`RobotParameters` (one source for docs and FMU)."""
    out: dict[str, str] = {}
    for cls in (PlantConfig, RobotParameters):
        doc = inspect.getdoc(cls) or ""
        section = doc.split("Parameters\n----------\n", 1)[-1].split("\n\n", 1)[0]
        names: list[str] = []
        for line in section.splitlines():
            if line and not line.startswith(" "):
                names = [n.strip() for n in line.split(":")[0].split(",")]
                continue
            for n in names:
                out[n] = f"{out.get(n, '')} {line.strip()}".strip()
    for i in range(3, 7):
        out[f"ratio_{i}"] = f"joint-angle ratio q{i}/q{1 + (i + 1) % 2} of the calibration"
    return {k: " ".join(v.replace("``", "").split()) for k, v in out.items()}


def _output_description(name: str) -> str:
    if name.startswith("ee"):
        axis = name[3]
        what = "true" if name.endswith("_true") else "measured"
        return f"{what} end-effector {axis} position in the base frame"
    if name.endswith("_true"):
        return _DESCRIPTIONS["q_true"].format(k=name[1])
    if name.startswith("q"):
        return _DESCRIPTIONS["q"].format(k=name[1])
    return _DESCRIPTIONS["T"].format(k=name[1])

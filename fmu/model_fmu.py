"""An identified model as an FMI 2.0 co-simulation slave (pythonfmu): :class:`TendonModel`.

This file is both a module of :mod:`tendonkit.fmu` and the script that pythonfmu packs into a
model FMU (``tendonkit export``; :func:`tendonkit.fmu.build.build_model_fmu`).  The model itself
travels as the resource ``model.json`` (the schema's JSON, loaded with
:meth:`tendonkit.schema.Model.from_json`, which never evaluates code) and is evaluated by
:class:`tendonkit.stepper.Stepper`, so every representation and block kind of the schema works
without any change here.  The hosting Python needs tendonkit installed; without it the slave
still instantiates, logs why at error level and refuses every step (:data:`MISSING`).

Variables:

* inputs: the model's inputs (start: the operating point of the training data);
* outputs: the model's outputs and, with kinematics, the reconstructed joints
  ``q3 = ratio_3 q1``, ``q4 = ratio_4 q2``, ``q5 = ratio_5 q1``, ``q6 = ratio_6 q2`` and the
  end effector ``ee_x, ee_y, ee_z`` (forward kinematics of the nominal robot);
* tunable parameters ``ratio_3..ratio_6`` (with kinematics).

Step semantics (FMI 2.0 co-simulation).  The slave holds the model state at the current
communication point ``t_k``.  Outputs are computed when read, from that state and the inputs
set *at that point*, so an output with direct feedthrough (``D ≠ 0``, an ARX input with zero
delay, a static input block) reflects the inputs the master has just set: set ``u(t_k)``, read
``y(t_k)``, then ``doStep(t_k, dt)`` commits ``u(t_k)`` and moves the state to ``t_k + dt``.
Read in that order, the outputs equal ``tendonkit.simulate.simulate(model, u, initial="model")``
sample by sample.  ``ModelStructure`` lists these dependencies.  The communication step is fixed
at the model's ``dt``; another step is refused (logged at error level, ``fmi2Discard``, state
unchanged).  Like the plant slave, this slave never raises into pythonfmu (pythonfmu 0.7.0 aborts
the host after an exception); failures are logged at error level and outputs become NaN.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pythonfmu import Fmi2Causality, Fmi2Slave, Real
from pythonfmu.enums import Fmi2Initial, Fmi2Status, Fmi2Variability

#: Why tendonkit cannot be used in this (the importer's) Python, or None.  A slave module that
#: fails to import makes pythonfmu return no instance, and some importers (libcosim, Ecos) then
#: crash; this slave instead instantiates, names the problem in the log and refuses every step.
MISSING: str | None = None
try:
    import numpy as np

    from tendonkit import __version__
    from tendonkit.robot import PAPER_RATIOS, RobotParameters
    from tendonkit.robot.kinematics import expand_joints, forward_kinematics
    from tendonkit.schema import Model
    from tendonkit.stepper import Stepper
except ImportError as _exc:  # pragma: no cover - exercised in a subprocess by the tests
    MISSING = f"{type(_exc).__name__}: {_exc}"

#: Resource holding the model (schema JSON).
MODEL_FILE = "model.json"
#: Resource holding the export options (kinematics, ratios, robot).
CONFIG_FILE = "model_fmu.json"
#: Names of the tunable ratio parameters, in (q3/q1, q4/q2, q5/q1, q6/q2) order.
RATIO_NAMES = ("ratio_3", "ratio_4", "ratio_5", "ratio_6")
#: Reconstructed outputs added by the kinematics.
JOINTS = ("q3", "q4", "q5", "q6")
EE = ("ee_x", "ee_y", "ee_z")


def export_layout(model: Model, kinematics: bool) -> tuple[list[str], list[str], list[str]]:
    """Variable names of the model FMU: ``(inputs, outputs, parameters)`` in value-reference order."""
    outputs = list(model.output_names)
    params: list[str] = []
    if kinematics:
        outputs += [*JOINTS, *EE]
        params = list(RATIO_NAMES)
    return list(model.input_names), outputs, params


def read_resources(resources: str | None) -> tuple[Model, dict[str, Any]]:
    """The model and the export options from the FMU's resource folder (data only)."""
    folder = Path(resources or ".")
    model = Model.from_json((folder / MODEL_FILE).read_text(encoding="utf-8"), MODEL_FILE)
    config_path = folder / CONFIG_FILE
    config = json.loads(config_path.read_text(encoding="utf-8")) if config_path.is_file() else {}
    return model, config


class TendonModel(Fmi2Slave):
    """FMI 2.0 co-simulation slave of an identified tendonkit model (see module docs)."""

    author = "tendonkit"
    description = "tendonkit model (identified dynamics with kinematic reconstruction)"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        if MISSING is not None:
            self._without_tendonkit()
            return
        model, config = read_resources(self.resources)
        self.model = model
        self.description = f"tendonkit {model.kind} model {model.name!r} (step {model.dt:g} s)"
        self._kinematics = bool(config.get("kinematics", False))
        self._ratios = [float(r) for r in config.get("ratios", PAPER_RATIOS[2:])]
        self._robot = RobotParameters.from_dict(config.get("robot", {}))
        self._stepper = Stepper(model)
        exported = config.get("tendonkit_version")
        if exported and exported != __version__:
            self.log(
                f"this FMU was exported by tendonkit {exported}; the host runs tendonkit "
                f"{__version__}: results may differ from the exporter's",
                Fmi2Status.warning,
            )
        self._dt = float(model.dt)
        inputs, outputs, params = export_layout(model, self._kinematics)
        self._n_in, self._n_out = len(inputs), len(outputs)
        self._n_io = self._n_in + self._n_out
        self._in_vrs = list(range(self._n_in))
        # inputs start at the training data's operating point (0 for models without one)
        op = model.provenance.details.get("operating_point", {})
        self._u = [float(op.get(name, 0.0)) if isinstance(op, dict) else 0.0 for name in inputs]
        self._y: list[float] | None = None  # outputs for the current state and inputs
        self._iq = (
            (model.output_names.index("q1"), model.output_names.index("q2"))
            if self._kinematics
            else (0, 0)
        )
        units = {s.name: s.unit for s in (*model.inputs, *model.outputs)}
        for k, name in enumerate(inputs):
            self.register_variable(
                Real(
                    name,
                    causality=Fmi2Causality.input,
                    variability=Fmi2Variability.continuous,
                    description=f"model input {name} [{units.get(name) or '-'}]",
                    getter=self._input_getter(k),
                    setter=self._input_setter(k),
                )
            )
        for j, name in enumerate(outputs):
            self.register_variable(
                Real(
                    name,
                    causality=Fmi2Causality.output,
                    variability=Fmi2Variability.continuous,
                    initial=Fmi2Initial.calculated,
                    description=_output_description(name, j < len(model.outputs)),
                    getter=self._output_getter(j),
                )
            )
        for i, name in enumerate(params):
            self.register_variable(
                Real(
                    name,
                    causality=Fmi2Causality.parameter,
                    variability=Fmi2Variability.tunable,
                    initial=Fmi2Initial.exact,
                    description=f"constant joint-angle ratio {JOINTS[i]}/q{1 + i % 2}",
                    getter=self._ratio_getter(i),
                    setter=self._ratio_setter(i),
                )
            )

    def _without_tendonkit(self) -> None:
        """The variables of the archive (read as plain JSON), all NaN; every step refused."""
        folder = Path(self.resources or ".")
        data = json.loads((folder / MODEL_FILE).read_text(encoding="utf-8"))
        config_path = folder / CONFIG_FILE
        config = (
            json.loads(config_path.read_text(encoding="utf-8")) if config_path.is_file() else {}
        )
        kinematics = bool(config.get("kinematics", False))
        inputs = [s["name"] for s in data["inputs"]]
        outputs = [s["name"] for s in data["outputs"]] + (list(JOINTS + EE) if kinematics else [])
        self._dt = float(data["dt"])
        self._n_in, self._n_out = len(inputs), len(outputs)
        self._n_io = self._n_in + self._n_out
        self._missing = (
            f"this FMU needs tendonkit {config.get('tendonkit_version', '')} in the Python that "
            f"runs it, and it cannot be imported ({MISSING}); install it there "
            "('pip install tendonkit'), or export the model with a backend that needs no Python"
        )
        ignore = lambda value: None  # noqa: E731
        for names, attrs in (
            (inputs, {"causality": Fmi2Causality.input, "setter": ignore}),
            (outputs, {"causality": Fmi2Causality.output, "initial": Fmi2Initial.calculated}),
            (
                RATIO_NAMES if kinematics else (),
                {
                    "causality": Fmi2Causality.parameter,
                    "variability": Fmi2Variability.tunable,
                    "setter": ignore,
                },
            ),
        ):
            for name in names:
                self.register_variable(Real(name, getter=lambda: math.nan, **attrs))
        self.log(self._missing, Fmi2Status.error)

    # ------------------------------------------------------------------ accessors
    def _input_getter(self, k: int) -> Callable[[], float]:
        return lambda: self._u[k]

    def _input_setter(self, k: int) -> Callable[[float], None]:
        def set_(value: float) -> None:
            self._u[k] = float(value)
            self._y = None

        return set_

    def _output_getter(self, j: int) -> Callable[[], float]:
        return lambda: self._outputs()[j]

    def _ratio_getter(self, i: int) -> Callable[[], float]:
        return lambda: self._ratios[i]

    def _ratio_setter(self, i: int) -> Callable[[float], None]:
        def set_(value: float) -> None:
            self._ratios[i] = float(value)
            self._y = None

        return set_

    def get_real(self, vrs: list[int]) -> list[float]:
        """Fast path for inputs and outputs."""
        if MISSING is not None:
            return [math.nan] * len(vrs)
        if vrs and min(vrs) >= 0 and max(vrs) < self._n_io:
            n_in = self._n_in
            y = self._outputs() if max(vrs) >= n_in else []
            u = self._u
            return [u[v] if v < n_in else y[v - n_in] for v in vrs]
        return _guarded(self, super().get_real, vrs, default=math.nan)

    def set_real(self, vrs: list[int], values: list[float]) -> None:
        """Fast path for the inputs."""
        if MISSING is not None:
            return
        if vrs == self._in_vrs:
            self._u = [float(v) for v in values]
            self._y = None
            return
        _guarded(self, super().set_real, vrs, values)

    def get_integer(self, vrs: list[int]) -> list[int]:
        """Integer getter that logs instead of raising (the FMU has no integers)."""
        return _guarded(self, super().get_integer, vrs, default=0)

    def get_boolean(self, vrs: list[int]) -> list[bool]:
        """Boolean getter that logs instead of raising (the FMU has no booleans)."""
        return _guarded(self, super().get_boolean, vrs, default=False)

    def get_string(self, vrs: list[int]) -> list[str]:
        """String getter that logs instead of raising (the FMU has no strings)."""
        return _guarded(self, super().get_string, vrs, default="")

    def set_integer(self, vrs: list[int], values: list[int]) -> None:
        """Integer setter that logs instead of raising."""
        _guarded(self, super().set_integer, vrs, values)

    def set_boolean(self, vrs: list[int], values: list[bool]) -> None:
        """Boolean setter that logs instead of raising."""
        _guarded(self, super().set_boolean, vrs, values)

    def set_string(self, vrs: list[int], values: list[str]) -> None:
        """String setter that logs instead of raising."""
        _guarded(self, super().set_string, vrs, values)

    # ------------------------------------------------------------------ FMI life cycle
    def setup_experiment(
        self, start_time: float, stop_time: float | None = None, tolerance: float | None = None
    ) -> None:
        """Nothing to prepare: the model starts from its stored initial state."""

    def do_step(self, current_time: float, step_size: float) -> bool:
        """Commit the current inputs and advance one model sample; refuse other step sizes."""
        if MISSING is not None:
            self.log(self._missing, Fmi2Status.error)
            return False
        if abs(step_size - self._dt) > 1e-9 * max(1.0, self._dt):
            self.log(
                f"communication step {step_size!r} s refused: this model FMU steps at exactly "
                f"its sample time {self._dt!r} s; the state did not change",
                Fmi2Status.error,
            )
            return False
        try:
            self._stepper.advance(self._u)
        except Exception as exc:  # never let an exception reach pythonfmu (see module docs)
            self.log(f"step at t = {current_time:g} s failed: {exc}", Fmi2Status.error)
            return False
        self._y = None
        return True

    # ------------------------------------------------------------------ FMU state
    def _get_fmu_state(self) -> dict[str, Any]:
        """``fmi2GetFMUstate``: the model's evaluation state, the inputs and the ratios."""
        return {"stepper": self._stepper.get_state(), "u": list(self._u), "ratios": self._ratios}

    def _set_fmu_state(self, state: dict[str, Any]) -> None:
        """``fmi2SetFMUstate``: back to a state of :meth:`_get_fmu_state` (logged if foreign)."""
        try:
            self._stepper.set_state(state["stepper"])
            self._u = [float(v) for v in state["u"]]
            self._ratios = [float(v) for v in state["ratios"]]
        except Exception as exc:  # a state of another FMU: say so, never crash the importer
            self.log(f"FMU state not restored: {exc}", Fmi2Status.error)
        self._y = None

    # ------------------------------------------------------------------ helpers
    def _outputs(self) -> list[float]:
        """Modelled and reconstructed outputs for the current state and inputs (cached)."""
        if self._y is not None:
            return self._y
        try:
            y = self._stepper.outputs(self._u)
        except Exception as exc:
            self.log(f"outputs cannot be computed: {exc}", Fmi2Status.error)
            self._y = [math.nan] * self._n_out
            return self._y
        values = y.tolist()
        if self._kinematics:
            q12 = np.array([y[self._iq[0]], y[self._iq[1]]])
            q = expand_joints(q12, self._ratios)
            values += q[2:].tolist() + forward_kinematics(q, self._robot).tolist()
        self._y = values
        return values


def _guarded(
    slave: Fmi2Slave,
    call: Callable[..., Any],
    vrs: list[int],
    values: list[Any] | None = None,
    default: Any = None,
) -> Any:
    """Run a pythonfmu accessor; log a failure at error level instead of raising."""
    try:
        return call(vrs) if values is None else call(vrs, values)
    except Exception as exc:  # e.g. a value reference of another type
        slave.log(f"{call.__name__}({vrs}) failed: {exc}", Fmi2Status.error)
        return None if values is not None else [default] * len(vrs)


def _output_description(name: str, modelled: bool) -> str:
    if modelled:
        return f"modelled output {name}"
    if name in JOINTS:
        base = "q1" if name in ("q3", "q5") else "q2"
        return f"joint {name[1]} reconstructed as ratio_{name[1]} * {base}"
    return f"end-effector {name[3]} position from the forward kinematics"

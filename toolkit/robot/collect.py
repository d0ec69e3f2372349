"""Data collection: drive a plant FMU through fmpy with one of the paper's protocols.

:func:`collect` plays a :class:`~tendonkit.robot.protocol.Protocol` (the open-loop kinematic
controller's tendon commands) into a plant FMU, one 30 ms frame per command, and logs every
frame like the real experiment.  :class:`PlantSession` is the thin fmpy driver underneath; a
co-simulation master (MPC) can use it to step the plant one frame at a time.

This module only needs an FMU file: building one is the FMU side's job
(``tendonkit plant build`` or :func:`tendonkit.fmu.build.cached_plant_fmu`).

Row k of a recording holds ``t_k``, the command ``u[k]`` issued at ``t_k``, the angles and the
end effector read at ``t_k`` (row 0: the state before the first command) and the force the load
cells read once ``u[k]`` is applied: the tension during frame k (ideal force loop) or, when the
plant's force-loop effect is on (``forcelag_on``), the tension at ``t_k`` — the alignment of
:meth:`tendonkit.fmu.plant.Plant.record`.

Examples
--------
>>> from tendonkit.robot.protocol import circles
>>> rec = collect(circles(radii=[0.02], laps=1), plant="plant.fmu")  # doctest: +SKIP
>>> list(rec.columns)[:6]  # doctest: +SKIP
['t', 'u1', 'u2', 'u3', 'u4', 'T1']
"""

from __future__ import annotations

import ctypes
import dataclasses
import itertools
import math
import shutil
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..dataset import Dataset, write_csv
from ..errors import FMUError, OptionError, raise_if
from .protocol import Protocol

__all__ = [
    "COLUMNS",
    "INPUTS",
    "OUTPUTS",
    "PlantSession",
    "Recording",
    "collect",
    "fmu_parameters",
]

FloatArray = NDArray[np.float64]

#: Input variables of a plant FMU (commanded tensions, N).
INPUTS = ("T_cmd1", "T_cmd2", "T_cmd3", "T_cmd4")
#: Output variables read from a plant FMU, in this order.
OUTPUTS = (
    *(f"q{i}" for i in range(1, 7)),
    "ee_x",
    "ee_y",
    "ee_z",
    *(f"T{k}" for k in range(1, 5)),
    *(f"q{i}_true" for i in range(1, 7)),
    "ee_x_true",
    "ee_y_true",
    "ee_z_true",
)
#: Columns of a recording (and of the CSV ``tendonkit collect`` writes), in order.
COLUMNS = ("t", "u1", "u2", "u3", "u4", *OUTPUTS[9:13], *OUTPUTS[:9], *OUTPUTS[13:])
_FORCES = slice(9, 13)


def _unit(column: str) -> str:
    base = column.removesuffix("_true")
    if base == "t":
        return "s"
    if base[0] in "uT":
        return "N"
    return "m" if base.startswith("ee_") else "rad"


#: Unit of every column (written into the CSV header as ``q1 [rad]``).
UNITS = {c: _unit(c) for c in COLUMNS}


@dataclass(frozen=True, eq=False)
class Recording:
    """The logged frames of one collection run.

    Attributes
    ----------
    columns : dict
        :data:`COLUMNS` -> ``(n,)`` arrays: ``t`` (s), ``u1..u4`` commanded (N), ``T1..T4``
        measured (N), ``q1..q6`` measured (rad), ``ee_x, ee_y, ee_z`` measured (m) and the
        truth ``q1_true..q6_true`` (rad), ``ee_x_true..ee_z_true`` (m).
    protocol : Protocol
        The protocol that was played.
    parameters : dict
        The plant FMU's parameter values for this run (start values and overrides).
    plant : Path
        The plant FMU.
    """

    columns: dict[str, FloatArray]
    protocol: Protocol
    parameters: dict[str, Any] = field(default_factory=dict)
    plant: Path = Path()

    @property
    def n_samples(self) -> int:
        """Number of logged frames."""
        return int(self.columns["t"].shape[0])

    def to_csv(self, path: str | Path) -> Path:
        """Write the columns as CSV (full float precision) and return the path."""
        return write_csv(path, self.columns, UNITS)

    def to_dataset(
        self,
        inputs: Sequence[str] = ("T1", "T2", "T3", "T4"),
        outputs: Sequence[str] = ("q1", "q2"),
    ) -> Dataset:
        """The recording as a :class:`~tendonkit.dataset.Dataset` (other columns as extras).

        Parameters
        ----------
        inputs, outputs : sequence of str
            Column names; by default measured forces -> the two base joints, as in the paper.
        """
        cols = self.columns
        unknown = [n for n in (*inputs, *outputs) if n not in cols]
        if unknown:
            raise OptionError(f"Unknown columns {unknown}. Columns: {', '.join(cols)}.")
        extra = {k: v for k, v in cols.items() if k not in (*inputs, *outputs, "t")}
        ds = Dataset.from_arrays(
            np.column_stack([cols[n] for n in inputs]),
            np.column_stack([cols[n] for n in outputs]),
            dt=self.protocol.h,
            inputs=inputs,
            outputs=outputs,
            name=self.protocol.name,
            extra=extra,
        )
        return dataclasses.replace(ds, units={n: UNITS[n] for n in (*inputs, *outputs)})


#: Message lists of the live sessions, by the key each passes as its componentEnvironment.
_SESSIONS: dict[int, list[tuple[int, str]]] = {}
_SESSION_KEYS = itertools.count(1)
_LOGGER: list[Any] = []


def _session_logger() -> Any:
    """The one FMI 2.0 logger of every session, alive for the whole process.

    fmpy's logger proxy (``fmpy.logging.addLoggerProxy``, which formats printf-style messages)
    keeps only the last logger registered with it, for every FMU of the process.  A logger per
    session would be freed with its session, and the next FMU that logs anything in the
    process — a C model FMU reporting an error, say — would call freed memory.  So all
    sessions share this logger, which finds its session by the ``componentEnvironment`` key
    and prints the messages of other FMUs as fmpy's default logger does.
    """
    if not _LOGGER:
        # lazy: heavy (fmpy)
        from fmpy.fmi2 import fmi2CallbackLoggerTYPE, printLogMessage

        def dispatch(env: Any, name: Any, status: int, category: Any, message: bytes) -> None:
            sink = _SESSIONS.get(int(env or 0))
            if sink is not None:
                sink.append((int(status), message.decode("utf-8", "replace")))
            else:  # another FMU of the process: what fmpy's own logger does
                printLogMessage(env, name, status, category, message)

        _LOGGER.append(fmi2CallbackLoggerTYPE(dispatch))
    return _LOGGER[0]


class PlantSession:
    """One instance of a plant FMU under fmpy, stepped frame by frame.

    Parameters are applied before initialisation; a rejected parameter set, a refused step or
    any other failure raises :class:`~tendonkit.errors.FMUError` with the messages the FMU
    logged.  Use as a context manager (or call :meth:`close`).

    Parameters
    ----------
    fmu : str or Path
        A plant FMU (inputs :data:`INPUTS`, outputs :data:`OUTPUTS`).
    parameters : mapping, optional
        ``name -> value`` overrides of the FMU's parameters (converted to the variable's type).
    instance_name : str
        FMI instance name.

    Attributes
    ----------
    step_size : float
        The FMU's communication step (its default experiment), s.
    outputs : numpy.ndarray
        The current values of :data:`OUTPUTS` (a view that the next :meth:`step` overwrites).
    parameters : dict
        The parameter values in force (start values with the overrides applied).
    """

    def __init__(
        self,
        fmu: str | Path,
        parameters: Mapping[str, Any] | None = None,
        instance_name: str = "plant",
    ) -> None:
        # lazy: heavy (fmpy)
        from fmpy import extract, read_model_description
        from fmpy.fmi2 import FMU2Slave

        self.path = Path(fmu)
        if not self.path.is_file():
            raise FMUError(f"Plant FMU {str(self.path)!r} does not exist.")
        try:
            md = read_model_description(str(self.path), validate=False)
        except Exception as exc:  # fmpy raises bare exceptions for broken archives
            raise FMUError(f"{str(self.path)!r} is not a readable FMU: {exc}") from None
        variables = {v.name: v for v in md.modelVariables}
        missing = [n for n in (*INPUTS, *OUTPUTS) if n not in variables]
        if md.coSimulation is None or missing:
            raise FMUError(
                f"{str(self.path)!r} is not a tendonkit plant FMU"
                + (f": it lacks {', '.join(missing)}." if missing else ": no co-simulation.")
            )
        step = md.defaultExperiment.stepSize if md.defaultExperiment else None
        self.step_size = float(step) if step else 0.03
        params = {v.name: v for v in md.modelVariables if v.causality == "parameter"}
        self.parameters = {n: _typed(v.type, v.start) for n, v in params.items()}
        problems: list[str] = []
        overrides: dict[str, Any] = {}
        for name, value in (parameters or {}).items():
            if name not in params:
                problems.append(
                    f"the plant FMU has no parameter {name!r}; parameters: {', '.join(params)}"
                )
                continue
            try:
                overrides[name] = _typed(params[name].type, value)
            except (TypeError, ValueError):
                problems.append(f"{name} has an invalid value {value!r} ({params[name].type})")
        raise_if(problems, OptionError, "Invalid plant FMU parameters:")
        self.parameters.update(overrides)
        self.messages: list[tuple[int, str]] = []
        self._unzipped = extract(str(self.path))
        self._fmu = FMU2Slave(
            guid=md.guid,
            unzipDirectory=self._unzipped,
            modelIdentifier=md.coSimulation.modelIdentifier,
            instanceName=instance_name,
        )
        self._callbacks = self._make_callbacks()
        self._live = False
        self.time = 0.0
        try:
            self._fmu.instantiate(callbacks=self._callbacks, loggingOn=True)
            self._live = True
            for name, value in overrides.items():
                self._set(params[name].type, params[name].valueReference, value)
            self._fmu.setupExperiment(startTime=0.0)
            self._fmu.enterInitializationMode()
            self._fmu.exitInitializationMode()
        except Exception as exc:
            self.close()
            raise FMUError(self._failure("initialisation", exc)) from None
        self._check_errors("initialisation")
        self._prepare_io({v.name: v.valueReference for v in md.modelVariables})

    # ------------------------------------------------------------------ FMI plumbing
    def _make_callbacks(self) -> Any:
        # lazy: heavy (fmpy)
        from fmpy import calloc, free
        from fmpy.fmi2 import (
            fmi2CallbackAllocateMemoryTYPE,
            fmi2CallbackFreeMemoryTYPE,
            fmi2CallbackFunctions,
        )

        key = next(_SESSION_KEYS)
        _SESSIONS[key] = self.messages
        callbacks = fmi2CallbackFunctions()
        callbacks.logger = _session_logger()
        callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        callbacks.componentEnvironment = ctypes.c_void_p(key)
        try:
            # lazy: heavy (fmpy)
            from fmpy.logging import addLoggerProxy

            addLoggerProxy(ctypes.byref(callbacks))
        except Exception:  # pragma: no cover - the proxy only formats printf-style messages
            pass
        self._session_key = key
        return callbacks

    def _set(self, kind: str, vr: int, value: Any) -> None:
        fmu = self._fmu
        if kind == "Real":
            fmu.setReal([vr], [float(value)])
        elif kind in ("Integer", "Enumeration"):
            fmu.setInteger([vr], [int(value)])
        elif kind == "Boolean":
            fmu.setBoolean([vr], [bool(value)])
        else:
            fmu.setString([vr], [str(value)])

    def _prepare_io(self, refs: Mapping[str, int]) -> None:
        # lazy: heavy (fmpy)
        from fmpy.fmi2 import fmi2Real, fmi2ValueReference

        self._vr_in = (fmi2ValueReference * len(INPUTS))(*[refs[n] for n in INPUTS])
        self._vr_out = (fmi2ValueReference * len(OUTPUTS))(*[refs[n] for n in OUTPUTS])
        self._buf_in = (fmi2Real * len(INPUTS))()
        self._buf_out = (fmi2Real * len(OUTPUTS))()
        self._u = np.ctypeslib.as_array(self._buf_in)
        self.outputs = np.ctypeslib.as_array(self._buf_out)
        dll = self._fmu.dll
        self._set_real, self._get_real = dll.fmi2SetReal, dll.fmi2GetReal
        self._do_step = dll.fmi2DoStep
        self._do_step.argtypes = [ctypes.c_void_p, ctypes.c_double, ctypes.c_double, ctypes.c_int]
        self._do_step.restype = ctypes.c_int
        self._n_out = len(OUTPUTS)
        self._component = self._fmu.component
        self._read()

    def _read(self) -> None:
        status = self._get_real(self._component, self._vr_out, self._n_out, self._buf_out)
        if status > 1:
            raise FMUError(self._failure("fmi2GetReal", status))

    def _failure(self, what: str, cause: Any) -> str:
        logged = [m for s, m in self.messages if s >= 1]
        detail = "; ".join(logged) if logged else str(cause)
        return f"The plant FMU {self.path.name} failed during {what}: {detail}"

    def _check_errors(self, what: str) -> None:
        errors = [m for s, m in self.messages if s >= 3]
        if errors:
            self.close()
            raise FMUError(
                f"The plant FMU {self.path.name} reported during {what}: " + "; ".join(errors)
            )

    # ------------------------------------------------------------------ public
    def step(self, u: Sequence[float] | FloatArray) -> FloatArray:
        """Apply commanded tensions ``u`` (4,) over one step and return the new outputs.

        Returns
        -------
        numpy.ndarray
            The outputs at the end of the step (a view, overwritten by the next step).
        """
        self._u[:] = u
        c = self._component
        if self._set_real(c, self._vr_in, 4, self._buf_in) > 1:
            raise FMUError(self._failure("fmi2SetReal", "error"))
        status = self._do_step(c, self.time, self.step_size, 1)
        if status > 1:
            raise FMUError(self._failure(f"fmi2DoStep at t = {self.time:g} s", status))
        self.time += self.step_size
        self._read()
        return self.outputs

    def close(self) -> None:
        """Terminate and free the instance and delete the unpacked FMU."""
        if getattr(self, "_live", False):
            self._live = False
            try:
                self._fmu.terminate()
            except Exception:
                pass
            try:
                self._fmu.freeInstance()
            except Exception:
                pass
        unzipped = getattr(self, "_unzipped", None)
        if unzipped:
            shutil.rmtree(unzipped, ignore_errors=True)
            self._unzipped = None
        _SESSIONS.pop(getattr(self, "_session_key", 0), None)

    def __enter__(self) -> PlantSession:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def fmu_parameters(fmu: str | Path) -> dict[str, Any]:
    """Parameter start values of an FMU, ``name -> value`` in the variable's Python type.

    Parameters
    ----------
    fmu : str or Path
        Any FMI 2.0 FMU.

    Returns
    -------
    dict
    """
    # lazy: heavy (fmpy)
    from fmpy import read_model_description

    try:
        md = read_model_description(str(fmu), validate=False)
    except Exception as exc:  # fmpy raises bare exceptions for broken archives
        raise FMUError(f"{str(fmu)!r} is not a readable FMU: {exc}") from None
    return {
        v.name: _typed(v.type, v.start) for v in md.modelVariables if v.causality == "parameter"
    }


def _typed(kind: str, value: Any) -> Any:
    """Convert ``value`` (possibly a string from the command line) to an FMI variable type."""
    if kind == "Real":
        return float(value)
    if kind in ("Integer", "Enumeration"):
        number = float(value)
        if not number.is_integer():
            raise ValueError(value)
        return int(number)
    if kind == "Boolean":
        if isinstance(value, str):
            low = value.strip().lower()
            if low in ("1", "true", "yes", "on"):
                return True
            if low in ("0", "false", "no", "off"):
                return False
            raise ValueError(value)
        if value in (0, 1):
            return bool(value)
        raise ValueError(value)
    return "" if value is None else str(value)


def collect(
    protocol: Protocol,
    *,
    plant: str | Path,
    effects: Mapping[str, Any] | None = None,
    seed: int | None = None,
    progress: bool | None = None,
) -> Recording:
    """Play ``protocol`` into a plant FMU and log every frame.

    Parameters
    ----------
    protocol : Protocol
        Commands and references (:func:`~tendonkit.robot.protocol.circles`,
        :func:`~tendonkit.robot.protocol.pseudo_random`, :func:`~tendonkit.robot.protocol.petal`); its
        sample time must equal the FMU's step.
    plant : str or Path
        The plant FMU (``tendonkit plant build``, or
        :func:`tendonkit.fmu.build.cached_plant_fmu` for a cached one).
    effects : mapping, optional
        Parameter overrides for this run, by FMU parameter name (``friction_on``,
        ``delay_s`` …).
    seed : int, optional
        Noise seed of the plant (its ``seed`` parameter); the FMU's own value by default.
    progress : bool, optional
        Show a progress bar on standard error; by default only when it is a terminal.

    Returns
    -------
    Recording
        Columns :data:`COLUMNS`, aligned as described in the module docs.

    Raises
    ------
    OptionError
        Unknown parameter names or values of the wrong type.
    FMUError
        The FMU rejected the parameters, the step size or a step.
    """
    # lazy: heavy (tqdm)
    from tqdm import tqdm

    overrides = dict(effects or {})
    if seed is not None:
        overrides["seed"] = seed
    n = protocol.n_samples
    with PlantSession(plant, overrides) as session:
        if not math.isclose(session.step_size, protocol.h, rel_tol=1e-9):
            raise FMUError(
                f"The protocol samples every {protocol.h:g} s but the plant FMU steps at "
                f"{session.step_size:g} s; build the protocol with h={session.step_size:g}."
            )
        frames = np.empty((n + 1, len(OUTPUTS)))
        frames[0] = session.outputs
        u = np.asarray(protocol.u, dtype=float)
        chunk = 512
        with tqdm(
            total=n,
            desc=f"collect {protocol.name}",
            unit="frame",
            file=_stderr(),
            disable=(None if progress is None else not progress),
            leave=False,
        ) as bar:
            for k in range(n):
                frames[k + 1] = session.step(u[k])
                if (k + 1) % chunk == 0:
                    bar.update(chunk)
            bar.update(n % chunk)
        force_lag = bool(session.parameters.get("forcelag_on", False))
        used = dict(session.parameters)
    now, after = frames[:n], frames[1:]
    forces = now[:, _FORCES] if force_lag else after[:, _FORCES]
    columns: dict[str, FloatArray] = {"t": np.asarray(protocol.t, dtype=float).copy()}
    for k in range(4):
        columns[f"u{k + 1}"] = u[:, k].copy()
    for k in range(4):
        columns[f"T{k + 1}"] = forces[:, k].copy()
    for j, name in enumerate(OUTPUTS):
        if not name.startswith("T"):
            columns[name] = now[:, j].copy()
    return Recording(
        columns={c: columns[c] for c in COLUMNS},
        protocol=protocol,
        parameters=used,
        plant=Path(plant),
    )


def _stderr() -> Any:
    return sys.stderr

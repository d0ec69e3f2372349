"""An FMI 2.0 co-simulation FMU opened with fmpy, ready to step: shared by the FMU tests."""

from __future__ import annotations

from pathlib import Path
from typing import Any


def open_slave(path: str | Path, instance: str = "model") -> tuple[Any, Any]:
    """``(model description, FMU2Slave)``: instantiated, set up at t = 0 and initialised."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    md = read_model_description(str(path))
    fmu = FMU2Slave(
        guid=md.guid,
        unzipDirectory=extract(str(path)),
        modelIdentifier=md.coSimulation.modelIdentifier,
        instanceName=instance,
    )
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    return md, fmu

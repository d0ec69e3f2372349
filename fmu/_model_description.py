"""Complete the ``modelDescription.xml`` that pythonfmu writes (see :mod:`tendonkit.fmu.build`).

pythonfmu writes a valid archive but an incomplete model description;
:func:`finalize_model_description` adds units, output dependencies, initial unknowns and the
fixed-step default experiment so that :func:`fmpy.validation.validate_fmu` reports no problem.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
import zipfile
from collections.abc import Mapping, Sequence
from pathlib import Path

from tendonkit import __version__
from tendonkit.errors import FMUError

#: SI base-unit exponents of the units our FMUs use (FMI 2.0 ``BaseUnit`` attributes).
UNIT_BASES: dict[str, dict[str, int]] = {
    "N": {"kg": 1, "m": 1, "s": -2},
    "rad": {"rad": 1},
    "m": {"m": 1},
    "s": {"s": 1},
    "Hz": {"s": -1},
    "kg": {"kg": 1},
    "m/s": {"m": 1, "s": -1},
    "m/s2": {"m": 1, "s": -2},
    "N/m": {"kg": 1, "s": -2},
    "kg.m2": {"kg": 1, "m": 2},
    "N.m": {"kg": 1, "m": 2, "s": -2},
    "N.m/rad": {"kg": 1, "m": 2, "s": -2, "rad": -1},
    "rad/s": {"rad": 1, "s": -1},
    "cm": {"m": 1},
    "mm": {"m": 1},
    "deg": {"rad": 1},
}
_UNIT_FACTORS = {"cm": 0.01, "mm": 0.001, "deg": 0.017453292519943295}


def finalize_model_description(
    fmu: str | Path,
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
) -> None:
    """Rewrite ``modelDescription.xml`` inside ``fmu`` (see module docs).

    Parameters
    ----------
    fmu : str or Path
        An FMU written by pythonfmu; rewritten in place.
    step_size, stop_time : float
        The fixed communication step and the default stop time, s.
    units : mapping
        Variable name -> unit name (variables not listed have no unit).
    outputs : mapping
        Every output name -> the names of the inputs it depends on directly at the same
        communication point (empty: no direct feedthrough).
    initial_unknowns : mapping
        Calculated output name -> the knowns its initial value depends on (``None``: all).
    naming : str
        ``variableNamingConvention``: ``"structured"`` or ``"flat"``.
    state : bool
        The slave implements ``fmi2Get/SetFMUstate`` and their serialisation.
    model_name, description : str, optional
        ``modelName`` and ``description`` of this FMU (pythonfmu writes the slave class's).
    """
    fmu = Path(fmu)
    with zipfile.ZipFile(fmu) as zf:
        entries = {info.filename: zf.read(info.filename) for info in zf.infolist()}
    root = ET.fromstring(entries["modelDescription.xml"])
    root.set("variableNamingConvention", naming)

    root.set("version", __version__)
    if model_name:
        root.set("modelName", model_name)
    if description:
        root.set("description", description)
    cosim = root.find("CoSimulation")
    assert cosim is not None
    for flag, value in (
        ("needsExecutionTool", True),
        ("canHandleVariableCommunicationStepSize", False),
        ("canInterpolateInputs", False),
        ("maxOutputDerivativeOrder", 0),
        ("canRunAsynchronuously", False),
        ("canBeInstantiatedOnlyOncePerProcess", False),
        ("canNotUseMemoryManagementFunctions", True),
        ("canGetAndSetFMUstate", state),
        ("canSerializeFMUstate", state),
        ("providesDirectionalDerivative", False),
    ):
        cosim.set(flag, str(value).lower())
    variables = root.find("ModelVariables")
    assert variables is not None
    index: dict[str, int] = {}
    used_units: list[str] = []
    for i, sv in enumerate(variables.findall("ScalarVariable"), start=1):
        name = sv.get("name", "")
        index[name] = i
        unit = units.get(name)
        real = sv.find("Real")
        if unit and real is not None:
            real.set("unit", unit)
            if unit not in used_units:
                used_units.append(unit)
    missing = [n for n in (*outputs, *initial_unknowns) if n not in index]
    if missing:
        raise FMUError(f"finalize_model_description: unknown variables {missing}.")
    position = list(root).index(cosim) + 1
    for tag in ("UnitDefinitions", "DefaultExperiment"):
        for old in root.findall(tag):
            root.remove(old)
    if used_units:
        root.insert(position, _unit_definitions(used_units))
    experiment = ET.Element(
        "DefaultExperiment",
        {"startTime": "0.0", "stopTime": repr(float(stop_time)), "stepSize": repr(step_size)},
    )
    root.insert(list(root).index(variables), experiment)
    structure = root.find("ModelStructure")
    if structure is not None:
        root.remove(structure)
    structure = ET.SubElement(root, "ModelStructure")
    if outputs:
        node = ET.SubElement(structure, "Outputs")
        for name in sorted(outputs, key=index.__getitem__):
            deps = sorted(index[d] for d in outputs[name])
            ET.SubElement(
                node,
                "Unknown",
                {"index": str(index[name]), "dependencies": " ".join(map(str, deps))},
            )
    if initial_unknowns:
        node = ET.SubElement(structure, "InitialUnknowns")
        for name in sorted(initial_unknowns, key=index.__getitem__):
            attrib = {"index": str(index[name])}
            known = initial_unknowns[name]
            if known is not None:
                attrib["dependencies"] = " ".join(map(str, sorted(index[d] for d in known)))
            ET.SubElement(node, "Unknown", attrib)
    ET.indent(root, space="  ")
    entries["modelDescription.xml"] = ET.tostring(root, encoding="UTF-8", xml_declaration=True)
    tmp = fmu.with_name(fmu.name + ".tmp")
    with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name, data in entries.items():
            zf.writestr(name, data)
    os.replace(tmp, fmu)


def _unit_definitions(names: Sequence[str]) -> ET.Element:
    node = ET.Element("UnitDefinitions")
    for name in names:
        unit = ET.SubElement(node, "Unit", {"name": name})
        base = UNIT_BASES.get(name)
        if base is not None:
            attrib = {k: str(v) for k, v in base.items()}
            if name in _UNIT_FACTORS:
                attrib["factor"] = repr(_UNIT_FACTORS[name])
            ET.SubElement(unit, "BaseUnit", attrib)
    return node

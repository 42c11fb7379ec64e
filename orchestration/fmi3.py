"""FMI 3.0 co-simulation FMUs from the FMI 2.0 ones: the same sources, the same Python slaves.

An FMI 3.0 FMU of ours is its FMI 2.0 FMU (:mod:`orchestration.build`) with two things
changed (:func:`convert`):

* ``modelDescription.xml`` in FMI 3.0 (:func:`model_description`), translated from the FMI 2.0
  one the slave class wrote (``FlexFusionSlave.to_xml``), so both describe the same variables:
  the same names, value references, descriptions, causality, variability, initial and start
  values (the parameters' defaults), units and ``<UnitDefinitions>``, log categories, default
  experiment, output dependencies (FMI 3.0 names them by value reference) and our vendor
  annotation (``<Annotations><Annotation type="flexfusion">``, docs/fmu_annotation.md). Real is
  ``Float64``, Integer ``Int32``. Vector signals stay scalars ``name[i]``, as in FMI 2.0 (what the
  master, the scenarios, the SSP export and the results address); FMI 3.0 arrays are not used.
  FMI 3.0 requires an independent variable: ``time`` (``s``), value reference one past the
  slave's last variable, which the native layer answers with the last successful time.
* the binary: ``binaries/x86_64-linux/<modelIdentifier>.so`` is our FMI 3.0 layer
  (``native/fmi3_python.c``, the FMI 2.0 layer with FMI 3.0 entry points), in place of every
  FMI 2.0 binary (pythonfmu's Windows library is FMI 2.0 only: the FMI 3.0 FMU is Linux only).

Everything in ``resources/`` (the script, the vendored package, the compiled kernels, the
bytecode) is the FMI 2.0 FMU's, byte for byte. No clocks, no Event Mode, no early return.
"""
from __future__ import annotations

from pathlib import Path
from xml.etree import ElementTree as ET

from orchestration.build import BuildError, rewritten

PLATFORM = "x86_64-linux"                        # FMI 3.0's platform tuple
TIME_NAME = "time"
ANNOTATION_TYPE = "flexfusion"                   # fmus.common.fmi.ANNOTATION_TOOL

_TYPES = {"Real": "Float64", "Integer": "Int32", "Boolean": "Boolean", "String": "String"}
# FMI 2.0 <CoSimulation> attribute -> its FMI 3.0 name (the others have no FMI 3.0 counterpart
# or are false by default)
_COSIM = {"modelIdentifier": "modelIdentifier", "needsExecutionTool": "needsExecutionTool",
          "canBeInstantiatedOnlyOncePerProcess": "canBeInstantiatedOnlyOncePerProcess",
          "canHandleVariableCommunicationStepSize": "canHandleVariableCommunicationStepSize",
          "canGetAndSetFMUstate": "canGetAndSetFMUState", "canSerializeFMUstate": "canSerializeFMUState"}
_ROOT = ("modelName", "description", "author", "version", "copyright", "license", "generationTool",
         "generationDateAndTime", "variableNamingConvention")
# FMI 2.0 attributes of a ScalarVariable (or its type element) kept as they are
_VARIABLE = ("name", "valueReference", "description", "causality", "variability", "initial")
_TYPE_ATTRIBUTES = ("declaredType", "quantity", "unit", "displayUnit", "relativeQuantity", "min", "max",
                    "nominal", "unbounded", "start")


def model_description(fmi2: bytes) -> bytes:
    """The FMI 3.0 modelDescription of the FMI 2.0 one ``fmi2`` (the module docstring).

    Raises
    ------
    BuildError
        ``fmi2`` is not an FMI 2.0 co-simulation description, or has a variable of a type
        without an FMI 3.0 translation here (Enumeration).
    """
    src = ET.fromstring(fmi2)
    cosim2 = src.find("CoSimulation")
    if src.get("fmiVersion") != "2.0" or cosim2 is None:
        raise BuildError("not an FMI 2.0 co-simulation modelDescription")
    root = ET.Element("fmiModelDescription", {"fmiVersion": "3.0"})
    for key in _ROOT[:1]:
        root.set(key, src.get(key))
    root.set("instantiationToken", src.get("guid"))
    for key in _ROOT[1:]:
        if src.get(key) is not None:
            root.set(key, src.get(key))
    cosim = ET.SubElement(root, "CoSimulation")
    for key, name in _COSIM.items():
        if cosim2.get(key) is not None:
            cosim.set(name, cosim2.get(key))
    cosim.set("hasEventMode", "false")
    units = src.find("UnitDefinitions")
    units = ET.Element("UnitDefinitions") if units is None else units
    if not any(u.get("name") == "s" for u in units):
        unit = ET.SubElement(units, "Unit", name="s")
        ET.SubElement(unit, "BaseUnit", s="1")
        units[:] = sorted(units, key=lambda u: u.get("name"))
    root.append(units)
    for name in ("LogCategories", "DefaultExperiment"):
        if src.find(name) is not None:
            root.append(src.find(name))
    for category in root.iterfind("LogCategories/Category"):     # "... with fmi2Warning status."
        if category.get("description"):
            category.set("description", category.get("description").replace("fmi2", "fmi3"))

    variables2 = list(src.find("ModelVariables"))
    variables = ET.SubElement(root, "ModelVariables")
    vrs = [int(sv.get("valueReference")) for sv in variables2]
    time_vr = len(variables2)
    if sorted(vrs) != list(range(time_vr)):
        raise BuildError("the FMI 2.0 value references are not 0 .. n-1: no free one for 'time'")
    ET.SubElement(variables, "Float64", name=TIME_NAME, valueReference=str(time_vr),
                  description="Simulation time", causality="independent", variability="continuous",
                  unit="s")
    for sv in variables2:
        typed = next(iter(sv))
        if typed.tag not in _TYPES:
            raise BuildError(f"variable '{sv.get('name')}': {typed.tag} has no FMI 3.0 translation here")
        var = ET.SubElement(variables, _TYPES[typed.tag])
        for key in _VARIABLE:
            if sv.get(key) is not None:
                var.set(key, sv.get(key))
        for key in _TYPE_ATTRIBUTES:
            value = typed.get(key)
            if value is None:
                continue
            if typed.tag == "String" and key == "start":
                ET.SubElement(var, "Start", value=value)
            else:
                var.set(key, value)

    structure = ET.SubElement(root, "ModelStructure")
    structure2 = src.find("ModelStructure")
    for section, tag in (("Outputs", "Output"), ("InitialUnknowns", "InitialUnknown")):
        for unknown in structure2.findall(f"{section}/Unknown"):
            attrs = {"valueReference": str(vrs[int(unknown.get("index")) - 1])}
            deps = unknown.get("dependencies")
            if deps is not None:
                attrs["dependencies"] = " ".join(str(vrs[int(i) - 1]) for i in deps.split())
            if unknown.get("dependenciesKind") is not None:
                attrs["dependenciesKind"] = unknown.get("dependenciesKind")
            ET.SubElement(structure, tag, attrs)

    vendor = src.find("VendorAnnotations")
    if vendor is not None:
        annotations = ET.SubElement(root, "Annotations")
        for tool in vendor.findall("Tool"):
            annotation = ET.SubElement(annotations, "Annotation", type=tool.get("name"))
            annotation.extend(list(tool))
    ET.indent(root)
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="utf-8") + b"\n"


def convert(fmi2_fmu: Path, fmi3_fmu: Path, library: Path) -> Path:
    """Write the FMI 3.0 FMU ``fmi3_fmu`` of the FMI 2.0 FMU ``fmi2_fmu`` (the module
    docstring): its modelDescription translated, ``library`` (the FMI 3.0 layer) as its only
    binary, every other member as it is. Returns ``fmi3_fmu``."""
    from orchestration.native import model_identifier
    identifier = model_identifier(fmi2_fmu)
    fmi3_fmu.parent.mkdir(parents=True, exist_ok=True)
    fmi3_fmu.write_bytes(fmi2_fmu.read_bytes())
    with rewritten(fmi3_fmu) as (src, dst):
        for info in src.infolist():
            if info.filename == "modelDescription.xml":
                dst.writestr(info, model_description(src.read(info)))
            elif not info.filename.startswith("binaries/"):
                dst.writestr(info, src.read(info))
        dst.write(library, f"binaries/{PLATFORM}/{identifier}.so")
    return fmi3_fmu


__all__ = ["PLATFORM", "convert", "model_description"]

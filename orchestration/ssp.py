"""Export a scenario as an SSP 1.0 package (``.ssp``) that another co-simulation engine can run.

The package holds ``SystemStructure.ssd`` and every FMU under ``resources/``. Parameters are
bound inline (``ssv:ParameterSet``), each component's communication step is given as the Open
Simulation Platform's ``osp:StepSizeHint`` and the base step as ``osp:FixedStepAlgorithm``
(libcosim reads both; other engines ignore unknown annotations, as SSP allows).

Another engine's master need not be ours: libcosim's fixed-step master is Jacobi (every
component reads the outputs of the previous communication step), ours Gauss–Seidel, so a
consumer with direct feedthrough lags one step there, and coupled components differ by the
first-order coupling error (``tests/test_ssp.py`` measures both).
"""
from __future__ import annotations

import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from xml.etree.ElementTree import Element, SubElement, tostring

NS = {
    "ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
    "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
    "ssv": "http://ssp-standard.org/SSP1/SystemStructureParameterValues",
    "osp": "https://opensimulationplatform.com/SSP/OSPAnnotations",
}
OSP_ANNOTATION = "com.opensimulationplatform"


@dataclass
class SspComponent:
    """One FMU instance: its name, FMU file, communication step (s) and scalar start values."""
    name: str
    fmu: Path
    step: float
    parameters: dict[str, float | int | bool | str] = field(default_factory=dict)
    inputs: list[str] = field(default_factory=list)    # scalar variable names
    outputs: list[str] = field(default_factory=list)


def _q(prefix: str, tag: str) -> str:
    return f"{{{NS[prefix]}}}{tag}"


def _value_element(parent: Element, value: float | int | bool | str) -> None:
    if isinstance(value, bool):
        SubElement(parent, _q("ssv", "Boolean"), value=str(value).lower())
    elif isinstance(value, int):
        SubElement(parent, _q("ssv", "Integer"), value=str(value))
    elif isinstance(value, str):
        SubElement(parent, _q("ssv", "String"), value=value)
    else:
        SubElement(parent, _q("ssv", "Real"), value=repr(float(value)))


def system_structure(name: str, components: list[SspComponent],
                     connections: list[tuple[str, str, str, str]],
                     base_step: float, stop_time: float) -> bytes:
    """The ``SystemStructure.ssd`` document.

    ``connections`` are scalar ``(from_component, from_variable, to_component, to_variable)``.
    """
    from xml.etree.ElementTree import register_namespace
    for prefix, uri in NS.items():
        register_namespace(prefix, uri)
    root = Element(_q("ssd", "SystemStructureDescription"), name=name, version="1.0")
    system = SubElement(root, _q("ssd", "System"), name=name)
    elements = SubElement(system, _q("ssd", "Elements"))
    for comp in components:
        el = SubElement(elements, _q("ssd", "Component"), name=comp.name,
                        source=f"resources/{comp.fmu.name}")
        connectors = SubElement(el, _q("ssd", "Connectors"))
        for kind, names in (("input", comp.inputs), ("output", comp.outputs)):
            for var in names:
                c = SubElement(connectors, _q("ssd", "Connector"), name=var, kind=kind)
                SubElement(c, _q("ssc", "Real"))
        if comp.parameters:
            bindings = SubElement(el, _q("ssd", "ParameterBindings"))
            binding = SubElement(bindings, _q("ssd", "ParameterBinding"))
            values = SubElement(binding, _q("ssd", "ParameterValues"))
            pset = SubElement(values, _q("ssv", "ParameterSet"), version="1.0", name=f"{comp.name}_parameters")
            params = SubElement(pset, _q("ssv", "Parameters"))
            for pname, pvalue in comp.parameters.items():
                _value_element(SubElement(params, _q("ssv", "Parameter"), name=pname), pvalue)
        annotations = SubElement(el, _q("ssd", "Annotations"))
        ann = SubElement(annotations, _q("ssc", "Annotation"), type=OSP_ANNOTATION)
        SubElement(ann, _q("osp", "StepSizeHint"), value=repr(comp.step))
    conns = SubElement(system, _q("ssd", "Connections"))
    for src, svar, dst, dvar in connections:
        SubElement(conns, _q("ssd", "Connection"), startElement=src, startConnector=svar,
                   endElement=dst, endConnector=dvar)
    experiment = SubElement(root, _q("ssd", "DefaultExperiment"), startTime="0.0", stopTime=repr(stop_time))
    annotations = SubElement(experiment, _q("ssd", "Annotations"))
    ann = SubElement(annotations, _q("ssc", "Annotation"), type=OSP_ANNOTATION)
    algorithm = SubElement(ann, _q("osp", "Algorithm"))
    SubElement(algorithm, _q("osp", "FixedStepAlgorithm"), baseStepSize=repr(base_step))
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + tostring(root, encoding="utf-8")


def write_ssp(path: Path, name: str, components: list[SspComponent],
              connections: list[tuple[str, str, str, str]], base_step: float, stop_time: float) -> Path:
    """Write the ``.ssp`` archive (the SSD and each distinct FMU once)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("SystemStructure.ssd", system_structure(name, components, connections, base_step, stop_time))
        for fmu in sorted({c.fmu.resolve() for c in components}):
            z.write(fmu, f"resources/{fmu.name}")
    return path

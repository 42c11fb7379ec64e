"""SSP 1.0 packages (``.ssp``): export a scenario for another co-simulation engine, and read a
standard SSP (ours or another tool's) as a scenario that our master runs.

Export
------
The package holds ``SystemStructure.ssd`` and under ``resources/`` every FMU (each distinct file
once, a second different FMU with the same file name as ``Name_2.fmu``) and every file a
``*_file`` parameter names (bound by its relative URI ``resources/NAME``; a file that does not
exist is refused with a :class:`ScenarioError`). Parameters are bound inline (``ssv:ParameterSet``).
The SSD is valid against the Modelica Association's SSP 1.0 schemas (``tests/test_ssp.py``) and
carries what each engine reads, in the order each reads it:

* OMSimulator (``org.openmodelica``): ``oms:SimulationInformation`` with a ``oms:FixedStepMaster``
  on the system (without it OMSimulator cannot tell the system's kind) and the logging interval
  in the ``DefaultExperiment``, as OMSimulator writes them itself (the expected SSDs of its
  testsuite, e.g. ``addExternalResources3.py``). In its sources (``src/OMSimulatorLib/``):
  ``Model.cpp`` reads the system's kind and the experiment from the *first* ``ssc:Annotation``
  of an ``Annotations`` element only, so ours comes first; ``ComponentFMUCS.cpp``
  (``NewComponent`` from XML) rejects any element of a component besides connectors, geometry
  and parameter bindings ("Wrong xml schema detected"), so it cannot take a component's step
  size hint; ``Values.cpp`` (``importStartValuesHelper``) binds ``ssv:Real``, ``ssv:Integer``
  and ``ssv:Boolean`` only, so it ignores ``ssv:String`` values.
* libcosim (``com.opensimulationplatform``): the base step as ``osp:FixedStepAlgorithm`` and each
  component's own communication step as ``osp:StepSizeHint``. The hint is written only where a
  component's step differs from the base step, so a single-rate scenario loads in both engines
  from the same package; ``host="omsimulator"`` leaves the hints out (and warns: OMSimulator
  then steps those components at the base step).
* FlexFusion (``org.flexfusion``): what a scenario has beyond SSP (seed, description, recorded
  variables, record interval, metrics, oracles), so that ``flexfusion run X.ssp`` gives the
  scenario's results; other engines ignore it, as SSP allows.

Import
------
:func:`load_ssp` reads an ``.ssp`` (or an unpacked ``.ssd``): FMU components of one system,
their connections (complete vectors regrouped into whole-variable connections), parameter
bindings inline or from ``.ssv`` files, on the components or on the system (names
``component.parameter``; a system binding wins, as in OMSimulator), the ``DefaultExperiment``'s
stop time, and the base step from ``osp:FixedStepAlgorithm``, else OMSimulator's
``oms:FixedStepMaster``, else :data:`DEFAULT_BASE_STEP`; each component's step from its
``osp:StepSizeHint``, else the base step. Everything else our master cannot honour (nested systems,
parameter mappings, start time other than 0, connections to the system's own connectors) is a
:class:`ScenarioError` naming it.

Another engine's master need not be ours: libcosim's fixed-step master is Jacobi (every
component reads the outputs of the previous communication step), ours Gauss–Seidel, so a
consumer with direct feedthrough lags one step there, and coupled components differ by the
first-order coupling error (``tests/test_ssp.py`` measures both).
"""
from __future__ import annotations

import re
import shutil
import tempfile
import warnings
import zipfile
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Any, Iterable, Iterator
from xml.etree.ElementTree import Element, ParseError, SubElement, parse, register_namespace, tostring

import numpy as np

from .archive import ArchiveError, check as check_archive
from .scenario import (Overrides, ParamValue, Scenario, ScenarioError, load_scenario, read_variables,
                       stable_seed)

NS = {
    "ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
    "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
    "ssv": "http://ssp-standard.org/SSP1/SystemStructureParameterValues",
    "osp": "https://opensimulationplatform.com/SSP/OSPAnnotations",
    "oms": "https://raw.githubusercontent.com/OpenModelica/OMSimulator/master/schema/oms.xsd",
    "ff": "urn:flexfusion:ssp-annotations:1",
}
OSP_ANNOTATION = "com.opensimulationplatform"
OMS_ANNOTATION = "org.openmodelica"
FF_ANNOTATION = "org.flexfusion"
HOSTS = ("libcosim", "omsimulator")
DEFAULT_BASE_STEP = 1e-3
"""Base step (s) of an SSP that gives none: the base step of every shipped scenario."""
SSD_NAME = "SystemStructure.ssd"
# OMSimulator's own exports write these tolerances with the fixed-step master (used by its
# variable-step FMUs only; ours ignore them)
OMS_TOLERANCE = "0.0001"


@dataclass
class SspComponent:
    """One FMU instance: its name, FMU file, communication step (s) and scalar start values."""
    name: str
    fmu: Path
    step: float
    parameters: dict[str, ParamValue] = field(default_factory=dict)
    inputs: list[str] = field(default_factory=list)    # scalar variable names
    outputs: list[str] = field(default_factory=list)


def _q(prefix: str, tag: str) -> str:
    return f"{{{NS[prefix]}}}{tag}"


def _annotation(parent: Element, kind: str) -> Element:
    """A new ``ssc:Annotation`` of ``kind`` in ``parent``'s ``ssd:Annotations`` (created once)."""
    annotations = parent.find(_q("ssd", "Annotations"))
    if annotations is None:
        annotations = SubElement(parent, _q("ssd", "Annotations"))
    return SubElement(annotations, _q("ssc", "Annotation"), type=kind)


# ---------------------------------------------------------------------------------------------
# export
# ---------------------------------------------------------------------------------------------
def _value_element(parent: Element, value: ParamValue) -> None:
    if isinstance(value, bool):
        SubElement(parent, _q("ssv", "Boolean"), value=str(value).lower())
    elif isinstance(value, int):
        SubElement(parent, _q("ssv", "Integer"), value=str(value))
    elif isinstance(value, str):
        SubElement(parent, _q("ssv", "String"), value=value)
    else:
        SubElement(parent, _q("ssv", "Real"), value=repr(float(value)))


def system_structure(name: str, components: list[SspComponent],
                     connections: list[tuple[str, str, str, str]], base_step: float, stop_time: float,
                     sources: dict[str, str] | None = None, scenario: dict[str, Any] | None = None,
                     host: str = "libcosim") -> bytes:
    """The ``SystemStructure.ssd`` document.

    ``connections`` are scalar ``(from_component, from_variable, to_component, to_variable)``;
    ``sources`` maps a component name to its URI in the package (default
    ``resources/<FMU file name>``); ``scenario`` holds the FlexFusion annotation's entries
    (``seed``, ``description``, ``record``, ``record_interval``, ``metrics``, ``oracles``).
    """
    for prefix, uri in NS.items():
        register_namespace(prefix, uri)
    root = Element(_q("ssd", "SystemStructureDescription"), name=name, version="1.0")
    system = SubElement(root, _q("ssd", "System"), name=name)
    elements = SubElement(system, _q("ssd", "Elements"))
    for comp in components:
        source = (sources or {}).get(comp.name, f"resources/{comp.fmu.name}")
        el = SubElement(elements, _q("ssd", "Component"), name=comp.name,
                        type="application/x-fmu-sharedlibrary", source=source)
        if comp.inputs or comp.outputs:
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
        if host == "libcosim" and _own_step(comp.step, base_step):
            SubElement(_annotation(el, OSP_ANNOTATION), _q("osp", "StepSizeHint"), value=repr(comp.step))
    conns = SubElement(system, _q("ssd", "Connections"))
    for src, svar, dst, dvar in connections:
        SubElement(conns, _q("ssd", "Connection"), startElement=src, startConnector=svar,
                   endElement=dst, endConnector=dvar)
    info = SubElement(SubElement(_annotation(system, OMS_ANNOTATION), _q("oms", "Annotations")),
                      _q("oms", "SimulationInformation"))
    SubElement(info, _q("oms", "FixedStepMaster"), description="oms-ma", stepSize=_decimal(base_step),
               absoluteTolerance=OMS_TOLERANCE, relativeTolerance=OMS_TOLERANCE)

    experiment = SubElement(root, _q("ssd", "DefaultExperiment"), startTime="0.0", stopTime=repr(stop_time))
    extra = scenario or {}
    SubElement(SubElement(_annotation(experiment, OMS_ANNOTATION), _q("oms", "Annotations")),
               _q("oms", "SimulationInformation"), resultFile=f"{name}_res.mat",
               loggingInterval=_decimal(extra.get("record_interval", base_step)))
    algorithm = SubElement(_annotation(experiment, OSP_ANNOTATION), _q("osp", "Algorithm"))
    SubElement(algorithm, _q("osp", "FixedStepAlgorithm"), baseStepSize=repr(base_step))
    if scenario is not None:
        _write_flexfusion(_annotation(experiment, FF_ANNOTATION), scenario)
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + tostring(root, encoding="utf-8")


def _decimal(x: float) -> str:
    """``x`` exactly as an ``xs:decimal`` (no exponent: 1e-05 -> 0.00001), the type of
    OMSimulator's step and interval attributes (its ``schema/oms.xsd``)."""
    return np.format_float_positional(x, trim="-")


def _own_step(step: float, base_step: float) -> bool:
    """Whether a component's communication step is not the base step."""
    return abs(step - base_step) > 1e-12 * base_step


_METRIC_KEYS = ("kind", "name", "estimate", "truth", "truth_time", "after", "low", "high", "order")


def _write_flexfusion(annotation: Element, scenario: dict[str, Any]) -> None:
    el = SubElement(annotation, _q("ff", "Scenario"), seed=str(scenario["seed"]),
                    description=scenario.get("description", ""),
                    recordInterval=repr(scenario["record_interval"]))
    for ref in scenario.get("record", []):
        SubElement(el, _q("ff", "Record"), variable=ref)
    for text in scenario.get("oracles", []):
        SubElement(el, _q("ff", "Oracle"), connection=text)
    for text in scenario.get("delays", []):
        SubElement(el, _q("ff", "Delay"), connection=text)
    for metric in scenario.get("metrics", []):
        SubElement(el, _q("ff", "Metric"), {k: repr(v) if isinstance(v, float) else str(v)
                                            for k, v in metric.items() if k in _METRIC_KEYS and v is not None})


def _unique_names(paths: Iterable[Path]) -> dict[Path, str]:
    """``resources/NAME`` for each distinct file; a later different file with a taken name gets
    ``resources/STEM_2.EXT`` (``_3`` ...)."""
    out: dict[Path, str] = {}
    taken: set[str] = set()
    for path in paths:
        key = path.resolve()
        if key in out:
            continue
        name, k = path.name, 2
        while name in taken:
            name = f"{path.stem}_{k}{path.suffix}"
            k += 1
        taken.add(name)
        out[key] = f"resources/{name}"
    return out


def export_scenario(sc: Scenario, out: Path, host: str = "libcosim") -> Path:
    """Write a loaded scenario as an SSP package (see the module's docstring).

    Raises
    ------
    ScenarioError
        An unknown ``host``, or a ``*_file`` parameter that names no file.
    """
    if host not in HOSTS:
        raise ScenarioError(f"unknown SSP host {host!r} (choose one of {', '.join(HOSTS)})")
    inputs: dict[str, list[str]] = {n: [] for n in sc.components}
    outputs: dict[str, list[str]] = {n: [] for n in sc.components}
    conns: list[tuple[str, str, str, str]] = []
    for c in sc.connections:
        for s, d in c.pairs:
            if s not in outputs[c.src]:
                outputs[c.src].append(s)
            inputs[c.dst].append(d)
            conns.append((c.src, s, c.dst, d))
    for col in sc.record_columns():        # recorded outputs are connectors too
        cname, var = col.split(".", 1)
        if sc.components[cname].variables[var].causality == "output" and var not in outputs[cname]:
            outputs[cname].append(var)

    files: list[tuple[str, str, Path]] = []   # (component, parameter, file)
    for c in sc.components.values():
        for pname, value in c.parameters.items():
            if pname.endswith("_file") and isinstance(value, str) and value:
                if not Path(value).is_file():
                    raise ScenarioError(f"component '{c.name}': parameter '{pname}' names {value!r}, "
                                        "which is not a file: it cannot be packed into the SSP")
                files.append((c.name, pname, Path(value)))
    archive = _unique_names([c.fmu for c in sc.components.values()] + [f for _, _, f in files])
    comps = [SspComponent(c.name, c.fmu, c.step, dict(c.parameters), inputs[c.name], outputs[c.name])
             for c in sc.components.values()]
    by_name = {c.name: c for c in comps}
    for cname, pname, path in files:
        by_name[cname].parameters[pname] = archive[path.resolve()]
    if host == "omsimulator":
        _warn_omsimulator(sc, comps)
    extra = {"seed": sc.seed, "description": sc.description, "record": sc.record,
             "record_interval": sc.record_interval, "oracles": sc.oracles, "delays": sc.delays,
             "metrics": [vars(m) for m in sc.metrics]}
    ssd = system_structure(sc.name, comps, conns, sc.base_step, sc.stop_time,
                           {c.name: archive[c.fmu.resolve()] for c in comps}, extra, host)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr(SSD_NAME, ssd)
        for path, name in archive.items():
            z.write(path, name)
    return out


def _warn_omsimulator(sc: Scenario, comps: list[SspComponent]) -> None:
    multirate = [c.name for c in comps if _own_step(c.step, sc.base_step)]
    if multirate:
        warnings.warn(f"OMSimulator takes no step size per component: {', '.join(multirate)} will be "
                      f"stepped at the base step {sc.base_step:g} s there instead of their own",
                      stacklevel=3)
    strings = [f"{c.name}.{p}" for c in comps for p, v in c.parameters.items() if isinstance(v, str)]
    if strings:
        warnings.warn(f"OMSimulator ignores string parameter values (ssv:String): {', '.join(strings)} "
                      "keep their FMU defaults there", stacklevel=3)


# ---------------------------------------------------------------------------------------------
# import
# ---------------------------------------------------------------------------------------------
@contextmanager
def opened(path: str | Path) -> Iterator[Path]:
    """The ``SystemStructure.ssd`` of an ``.ssp`` (unpacked into a temporary folder, removed
    afterwards), or a ``.ssd`` file itself. The package is checked against the archive limits
    (size, entries, compression ratio, entry names: :mod:`orchestration.archive`) from its
    central directory before anything is extracted; one beyond them is a :class:`ScenarioError`."""
    path = Path(path)
    if path.suffix.lower() == ".ssd":
        if not path.is_file():
            raise ScenarioError(f"SSD file not found: {path}")
        yield path
        return
    if not path.is_file():
        raise ScenarioError(f"SSP file not found: {path}")
    if not zipfile.is_zipfile(path):
        raise ScenarioError(f"{path}: not an SSP package (not a zip archive)")
    folder = Path(tempfile.mkdtemp(prefix="flexfusion_ssp_"))
    try:
        with zipfile.ZipFile(path) as z:
            try:
                check_archive(z.infolist(), str(path))     # before anything is extracted
            except ArchiveError as exc:
                raise ScenarioError(str(exc)) from None
            if SSD_NAME not in z.namelist():
                raise ScenarioError(f"{path}: no {SSD_NAME} in the package")
            z.extractall(folder)
        yield folder / SSD_NAME
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _local(el: Element) -> str:
    return el.tag.rsplit("}", 1)[-1]


def _child(el: Element | None, prefix: str, tag: str) -> Element | None:
    return None if el is None else el.find(_q(prefix, tag))


def _children(el: Element | None, prefix: str, tag: str) -> list[Element]:
    return [] if el is None else el.findall(_q(prefix, tag))


def _annotations(el: Element | None, kind: str) -> list[Element]:
    """The content of every ``ssc:Annotation`` of ``kind`` on ``el``."""
    out: list[Element] = []
    for ann in _children(_child(el, "ssd", "Annotations"), "ssc", "Annotation"):
        if ann.get("type") == kind:
            out.extend(list(ann))
    return out


def _float(where: str, text: str | None) -> float:
    try:
        return float(text)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ScenarioError(f"{where}: {text!r} is not a number") from None


def _read_xml(where: str, path: Path) -> Element:
    try:
        return parse(path).getroot()
    except ParseError as exc:
        raise ScenarioError(f"{where}: malformed XML: {exc}") from None
    except (LookupError, ValueError) as exc:     # an XML declaration naming no known encoding
        raise ScenarioError(f"{where}: malformed XML: {exc}") from None
    except OSError as exc:
        raise ScenarioError(f"{where}: cannot read: {exc}") from None


def _inside(where: str, base: Path, uri: str | None, what: str) -> Path:
    """A relative URI of the package (``resources/X``) as a path inside ``base``."""
    if not uri or re.match(r"^[A-Za-z][\w+.-]*:", uri) or uri.startswith("/") or ".." in PurePosixPath(uri).parts:
        raise ScenarioError(f"{where}: {what} {uri!r} is not a relative URI inside the package")
    path = base / uri
    if not path.is_file():
        raise ScenarioError(f"{where}: {what} {uri!r} is not in the package")
    return path


def _parameter_values(where: str, binding: Element, base: Path) -> list[tuple[str, ParamValue]]:
    """The (name, value) pairs of one ``ssd:ParameterBinding`` (inline or an ``.ssv`` file)."""
    if _child(binding, "ssd", "ParameterMapping") is not None:
        raise ScenarioError(f"{where}: parameter mappings (ssm) are not supported: give the values "
                            "under the FMU's own parameter names")
    source = binding.get("source")
    if source:
        if binding.get("type", "application/x-ssp-parameter-set") != "application/x-ssp-parameter-set":
            raise ScenarioError(f"{where}: parameter source type {binding.get('type')!r} is not supported")
        pset = _read_xml(f"{where}: {source}", _inside(where, base, source, "parameter file"))
        where = f"{where}: {source}"
    else:
        pset = _child(_child(binding, "ssd", "ParameterValues"), "ssv", "ParameterSet")
        if pset is None:
            return []
    if pset.tag != _q("ssv", "ParameterSet"):
        raise ScenarioError(f"{where}: expected an ssv:ParameterSet, got <{_local(pset)}>")
    prefix = binding.get("prefix", "")
    out: list[tuple[str, ParamValue]] = []
    for p in _children(_child(pset, "ssv", "Parameters"), "ssv", "Parameter"):
        name = prefix + (p.get("name") or "")
        kinds = [c for c in p if c.tag.startswith(f"{{{NS['ssv']}}}")]
        if len(kinds) != 1:
            raise ScenarioError(f"{where}: parameter {name!r} has no single value element")
        kind, raw = _local(kinds[0]), kinds[0].get("value")
        if raw is None:
            raise ScenarioError(f"{where}: parameter {name!r} has no value")
        if kind == "Real":
            value: ParamValue = _float(f"{where}: parameter {name!r}", raw)
        elif kind == "Integer":
            try:
                value = int(raw)
            except ValueError:
                raise ScenarioError(f"{where}: parameter {name!r}: {raw!r} is not an integer") from None
        elif kind == "Boolean":
            if raw not in ("true", "false", "1", "0"):
                raise ScenarioError(f"{where}: parameter {name!r}: {raw!r} is not a boolean")
            value = raw in ("true", "1")
        elif kind == "String":
            value = raw
        else:
            raise ScenarioError(f"{where}: parameter {name!r}: ssv:{kind} values are not supported")
        out.append((name, value))
    return out


def _group(scalars: list[tuple[str, str]], sizes: dict[str, int]) -> list[str]:
    """Scalar connections ``("a.x[1]", "b.y[1]"), ...`` in order, as connections of whole
    variables ``a.x -> b.y`` where a run of them covers two complete vectors element by element
    (so the order, and with it the master's plan, is the scenario's)."""
    out: list[str] = []
    run: list[tuple[str, str]] = []      # consecutive (a.x[i], b.y[i]), i = 1, 2, ...

    def flush() -> None:
        if run:
            s, d = (name.rsplit("[", 1)[0] for name in run[0])
            whole = sizes.get(s) == len(run) == sizes.get(d)
            out.extend([f"{s} -> {d}"] if whole else [f"{a} -> {b}" for a, b in run])
            run.clear()

    for s, d in scalars:
        i = len(run) + 1
        if run and (s, d) == (f"{run[0][0].rsplit('[', 1)[0]}[{i}]", f"{run[0][1].rsplit('[', 1)[0]}[{i}]"):
            run.append((s, d))
            continue
        flush()
        if s.endswith("[1]") and d.endswith("[1]"):
            run.append((s, d))
        else:
            out.append(f"{s} -> {d}")
    flush()
    return out


def _vector_sizes(variables: Iterable[str], prefix: str) -> dict[str, int]:
    sizes: dict[str, int] = {}
    for name in variables:
        m = re.match(r"^(.*)\[(\d+)\]$", name)
        if m:
            sizes[f"{prefix}{m.group(1)}"] = max(sizes.get(f"{prefix}{m.group(1)}", 0), int(m.group(2)))
    return sizes


def ssp_document(ssd: Path, label: str) -> dict[str, Any]:
    """The scenario document (as :func:`orchestration.scenario.load_scenario` takes it) of the
    SSD ``ssd``, whose relative URIs resolve against its folder; ``label`` names it in errors."""
    base = ssd.parent
    root = _read_xml(label, ssd)
    system = _system(label, root)
    components: dict[str, dict[str, Any]] = {}
    declared: dict[str, dict[str, ParamValue]] = {}       # each component's bound parameters
    sizes: dict[str, int] = {}
    for el in _children(_child(system, "ssd", "Elements"), "ssd", "Component"):
        name = el.get("name") or ""
        if name in components:
            raise ScenarioError(f"{label}: two components are named '{name}' (a component's name must be "
                                "unique in its system)")
        components[name], declared[name], variables = _component(f"{label}: component '{name}'", el, base)
        sizes.update(_vector_sizes(variables, f"{name}."))
    if not components:
        raise ScenarioError(f"{label}: the system has no FMU components")
    _bind_system_parameters(label, system, base, declared)
    connections = _group(_scalar_connections(label, system, components), sizes)
    experiment = _child(root, "ssd", "DefaultExperiment")
    doc: dict[str, Any] = {"scenario": _head(label, root, ssd, system, experiment),
                           "components": components, "connections": connections}
    ours = [e for e in _annotations(experiment, FF_ANNOTATION) if e.tag == _q("ff", "Scenario")]
    if ours:
        try:
            _read_flexfusion(ours[0], doc, declared)
        except (TypeError, ValueError) as exc:
            raise ScenarioError(f"{label}: malformed {FF_ANNOTATION} annotation: {exc}") from None
    for name, params in declared.items():
        components[name]["parameters"] = _packed_files(f"{label}: component '{name}'", base, params)
    return doc


def _system(label: str, root: Element) -> Element:
    """The one ``ssd:System`` of an SSD's root, a system of FMUs (no nested systems)."""
    if root.tag != _q("ssd", "SystemStructureDescription"):
        raise ScenarioError(f"{label}: not a system structure description (root <{_local(root)}>)")
    system = _child(root, "ssd", "System")
    if system is None:
        raise ScenarioError(f"{label}: no ssd:System")
    if _children(_child(system, "ssd", "Elements"), "ssd", "System"):
        raise ScenarioError(f"{label}: nested systems are not supported (one system of FMUs)")
    return system


def _component(where: str, el: Element, base: Path) -> tuple[dict[str, Any], dict[str, ParamValue], dict[str, Any]]:
    """An ``ssd:Component``: its scenario entry (``fmu``, and ``step`` from an
    ``osp:StepSizeHint``), its bound parameters and its FMU's variables (connectors checked)."""
    kind = el.get("type", "application/x-fmu-sharedlibrary")
    if kind != "application/x-fmu-sharedlibrary":
        raise ScenarioError(f"{where}: component type {kind!r} is not supported (FMUs only)")
    if el.get("implementation", "any") not in ("any", "CoSimulation"):
        raise ScenarioError(f"{where}: implementation {el.get('implementation')!r} is not supported")
    fmu = _inside(where, base, el.get("source"), "FMU")
    try:
        variables = read_variables(fmu)[2]
    except ScenarioError as exc:
        raise ScenarioError(f"{where}: {exc}") from None
    except Exception as exc:  # noqa: BLE001 - a broken FMU file is a user error
        raise ScenarioError(f"{where}: cannot read the modelDescription of {el.get('source')}: {exc}") from None
    for c in _children(_child(el, "ssd", "Connectors"), "ssd", "Connector"):
        if c.get("name") not in variables:
            raise ScenarioError(f"{where}: connector '{c.get('name')}' is not a variable of "
                                f"{el.get('source')}")
    params: dict[str, ParamValue] = {}
    for binding in _children(_child(el, "ssd", "ParameterBindings"), "ssd", "ParameterBinding"):
        params.update(_parameter_values(where, binding, base))
    step = None
    for hint in _annotations(el, OSP_ANNOTATION):
        if hint.tag == _q("osp", "StepSizeHint"):
            step = _float(f"{where}: osp:StepSizeHint", hint.get("value"))
    return {"fmu": str(fmu), **({"step": step} if step is not None else {})}, params, variables


def _bind_system_parameters(label: str, system: Element, base: Path,
                            declared: dict[str, dict[str, ParamValue]]) -> None:
    """The system's own parameter bindings (``comp.param``) over the components' ones."""
    for binding in _children(_child(system, "ssd", "ParameterBindings"), "ssd", "ParameterBinding"):
        for pname, value in _parameter_values(f"{label}: system '{system.get('name')}'", binding, base):
            cname, _, var = pname.partition(".")
            if cname not in declared or not var:
                raise ScenarioError(f"{label}: system parameter {pname!r} names no component's "
                                    f"parameter (components: {', '.join(declared)})")
            declared[cname][var] = value      # the system's binding wins (as in OMSimulator)


def _scalar_connections(label: str, system: Element, components: dict[str, Any]) -> list[tuple[str, str]]:
    """The system's connections as scalar pairs ``("a.x[1]", "b.y[1]")``, in order."""
    scalars: list[tuple[str, str]] = []
    for c in _children(_child(system, "ssd", "Connections"), "ssd", "Connection"):
        a, av, b, bv = (c.get(k) for k in ("startElement", "startConnector", "endElement", "endConnector"))
        where = f"{label}: connection {a}.{av} -> {b}.{bv}"
        if not a or not b:
            raise ScenarioError(f"{where}: connections to the system's own connectors are not supported")
        for e in (a, b):
            if e not in components:
                raise ScenarioError(f"{where}: no element '{e}' (components: {', '.join(components)})")
        scalars.append((f"{a}.{av}", f"{b}.{bv}"))
    return scalars


def _head(label: str, root: Element, ssd: Path, system: Element, experiment: Element | None) -> dict[str, Any]:
    """The scenario's ``[scenario]`` table: name, stop time (``ssd:DefaultExperiment``, which
    must start at 0) and base step."""
    head: dict[str, Any] = {"name": root.get("name") or ssd.stem}
    if experiment is not None:
        start = _float(f"{label}: DefaultExperiment startTime", experiment.get("startTime", "0"))
        if start != 0.0:
            raise ScenarioError(f"{label}: DefaultExperiment startTime = {start:g}: our master starts at 0")
        if experiment.get("stopTime") is not None:
            head["stop_time"] = _float(f"{label}: DefaultExperiment stopTime", experiment.get("stopTime"))
    head["base_step"] = _base_step(label, system, experiment)
    return head


def _packed_files(where: str, base: Path, params: dict[str, ParamValue]) -> dict[str, ParamValue]:
    """``params`` with each relative ``*_file`` value resolved inside the package (in place)."""
    for pname, value in params.items():
        if pname.endswith("_file") and isinstance(value, str) and value and not Path(value).is_absolute():
            params[pname] = str(_inside(f"{where}: parameter '{pname}'", base, value, "file"))
    return params


def _base_step(label: str, system: Element, experiment: Element | None) -> float:
    for el in _annotations(experiment, OSP_ANNOTATION):
        fixed = _child(el, "osp", "FixedStepAlgorithm")
        if fixed is not None:
            return _float(f"{label}: osp:FixedStepAlgorithm baseStepSize", fixed.get("baseStepSize"))
    for el in _annotations(system, OMS_ANNOTATION):
        info = el if el.tag == _q("oms", "SimulationInformation") else _child(el, "oms", "SimulationInformation")
        master = _child(info, "oms", "FixedStepMaster")
        if master is not None:
            return _float(f"{label}: oms:FixedStepMaster stepSize", master.get("stepSize"))
    return DEFAULT_BASE_STEP


def _read_flexfusion(el: Element, doc: dict[str, Any], declared: dict[str, dict[str, ParamValue]]) -> None:
    """Our annotation: seed, description, record, metrics, oracles. A bound seed equal to the
    one the scenario seed gives the component is dropped, so ``--set scenario.seed=N`` works."""
    seed = int(el.get("seed", "0"))
    doc["scenario"].update(seed=seed, description=el.get("description", ""))
    for name, params in declared.items():
        if params.get("seed") == stable_seed(seed, name):
            del params["seed"]
    doc["record"] = {"variables": [r.get("variable") for r in _children(el, "ff", "Record")],
                     "interval": float(el.get("recordInterval", doc["scenario"]["base_step"]))}
    doc["oracles"] = [o.get("connection") for o in _children(el, "ff", "Oracle")]
    doc["delays"] = [d.get("connection") for d in _children(el, "ff", "Delay")]
    types = {"after": float, "low": float, "high": float, "order": int}
    doc["metrics"] = [{k: types.get(k, str)(v) for k, v in m.attrib.items()}
                      for m in _children(el, "ff", "Metric")]


def load_ssp(path: str | Path, ssd: Path, overrides: Overrides = ()) -> Scenario:
    """The scenario of an SSP: ``ssd`` is its ``SystemStructure.ssd`` (from :func:`opened`),
    ``path`` the package named in messages. Overrides as for a scenario file.

    Raises
    ------
    ScenarioError
        One message naming the package, the component and the variable.
    """
    label = str(path)
    doc = ssp_document(ssd, label)
    try:
        with warnings.catch_warnings(record=True) as caught:   # named after the package, as errors
            warnings.simplefilter("always")
            sc = load_scenario(doc, overrides)
    except ScenarioError as exc:
        raise ScenarioError(f"{label}: {str(exc).removeprefix('<scenario>: ')}") from None
    for w in caught:
        warnings.warn(str(w.message).replace("<scenario>", label, 1), w.category, stacklevel=2)
    return sc


__all__ = ["NS", "SspComponent", "system_structure", "export_scenario", "opened", "ssp_document",
           "load_ssp", "DEFAULT_BASE_STEP", "HOSTS"]

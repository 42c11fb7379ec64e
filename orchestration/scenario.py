"""Scenario files (TOML): what FMUs to run, their parameters and steps, how they are connected,
what to record and which metrics to compute.

A scenario is loaded, resolved against each FMU's ``modelDescription.xml`` and validated in one
go by :func:`load_scenario`; every problem a user can cause raises :class:`ScenarioError` with
one message naming the file, the component and the variable.

Format::

    [scenario]
    name = "flagship"          # default: the file's stem; a plain folder name (the default
                               # output folder is results/<name>): no '/', '\\', '..'
    description = "..."
    stop_time = 10.0           # s; at most MAX_STEPS (1e8) base steps, and no component
                               # step may be longer
    base_step = 0.001          # s; every communication step is an integer multiple of it
    seed = 1                   # seeds every component that declares an Integer parameter `seed`
    include = ["tuned.toml"]   # optional: [components.X.parameters] and [parameter_sets.S] of
                               # these files are merged in (relative to this file; an included
                               # value wins over this file's, an override given on the command
                               # line wins over both)
    # parameters named *_file (e.g. csv_file) are paths relative to the file that sets them

    [parameter_sets.identified_robot]   # a named parameter set (here or in an included file)
    k_lo = [3.9e5, 1.2e5]      # applied to every component that lists the set and whose FMU
    J_m = [5.1e-3, 4.0e-3]     # declares the parameter (others ignore it); a key no such
                               # component declares is an error

    [components.plant]
    fmu = "FlexibleRobot2DOF"  # model identifier in dist/fmus (or $FLEXFUSION_FMU_DIR),
                               # or a path to a .fmu relative to this file
    step = 0.001               # communication step (default: base_step)
    [components.plant.parameters]
    k_hi = [4.0e5, 2.0e5]      # a list sets a vector parameter k_hi[1], k_hi[2]

    [components.ekf]
    fmu = "EkfComplete"
    parameter_sets = ["identified_robot"]   # optional: sets applied in order (a later set wins);
                               # the component's own parameters win over its sets

    connections = ["plant.q_m -> encoder.q_m"]   # (top level) whole vectors or scalars
    oracles = []   # (top level) connections that feed plant truth to an estimator or a
                   # controller on purpose, e.g. ["plant.p_tool -> observer.p_tool"]
    delays = []    # (top level) connections of a cycle that are meant to read the producer's
                   # previous value (a one-step delay): the master breaks the cycle there without
                   # a warning, e.g. ["controller.tau_m -> plant.tau_m"]; each must be one of the
                   # connections and must be where a cycle is broken

    [record]
    variables = ["plant.p_tool"]   # default: every connected output (whole vectors)
    interval = 0.001               # default: base_step

    [[metrics]]
    kind = "rmse"                  # rmse | bandpass | max | nees | nis
    name = "rigid_position"
    estimate = "rigid.p_tool_hat"
    truth = "plant.p_tool"
    after = 0.5                    # s: ignore the start (default 0; before the last record)
    # metrics.json says what `truth` is: "against" = "truth" (plant, environment), "reference"
    # (a reference system such as the Tracker) or the providing component's role
    truth_time = "tracker.t_meas"  # optional: the truth's sample times; compare only at fresh
                                   # samples, the estimate interpolated to their time stamps
    # bandpass only: low = 3.0, high = 30.0, order = 4 (Hz, Hz, Butterworth order)
    # nees: also covariance = "ekf.P_x" (packed lower triangle; the estimate's d states are
    #   its first d), dof = d; nis: estimate = "ekf.innovation_norm" (or a `nis` output), no
    #   truth, dof = the measurement dimension (orchestration.metrics.nees / nis)

Honest signals (:mod:`orchestration.roles`): a truth output (of the plant, the contact
environment or a force pulse) may feed only sensors, the environment, the plant and the
reference system (Tracker); the MotionController may read the plant's q_m (an ideal motor
encoder: no shipped scenario does, each drive reads an Encoder and forms its speed from it). Any
other such connection gives an :class:`HonestSignalWarning` when the
scenario is loaded, unless it is listed in ``oracles`` (each entry must be one of the
``connections``, written the same way up to spaces, else :class:`ScenarioError`).

Overrides (``--set``) are strings ``comp.param=value`` (value parsed as a TOML value, a vector as
``[1, 2]``), ``comp.param[2]=value`` and ``scenario.<key>=value`` for ``seed``, ``stop_time``,
``base_step``, ``name`` and ``description``. A parameter set is changed with
``parameter_sets.S.param=value`` or replaced as a whole with ``parameter_sets.S={...}``
(``parameter_sets.S={}`` empties it: its components keep their FMU defaults), and a
component's list of sets with ``comp.parameter_sets=["S"]``.
"""
from __future__ import annotations

import json
import math
import os
import re
import tomllib
import warnings
import zlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Union

import numpy as np

from . import roles
from .fmu_annotation import describe

REPO = Path(__file__).resolve().parent.parent
DEFAULT_FMU_DIR = REPO / "dist" / "fmus"
#: the most base steps a run may take: 1e8 is about a day of wall time at the flagship's
#: ~1,400 base steps/s (11 s simulated in 7.7 s at base_step = 1 ms, docs/figures.md)
MAX_STEPS = 10**8

ParamValue = float | int | bool | str


class ScenarioError(ValueError):
    """A scenario file (or an override of it) is wrong; the message names file, component, variable."""


@dataclass(frozen=True)
class VariableInfo:
    """One scalar FMI variable of a component (from its modelDescription)."""
    name: str
    value_reference: int
    type: str            # Real | Integer | Boolean | String | Enumeration
    causality: str       # input | output | parameter | calculatedParameter | local | independent
    variability: str
    unit: str | None
    depends_on: tuple[str, ...] | None = None   # outputs: names of the inputs with direct feedthrough


@dataclass
class Component:
    """One FMU instance of a scenario."""
    name: str
    fmu: Path
    step: float
    ratio: int                                   # step / base_step
    parameters: dict[str, ParamValue]            # scalar variable name -> value (seed included)
    model_identifier: str
    guid: str
    variables: dict[str, VariableInfo]
    fmi_version: str = "2.0"                     # its modelDescription's fmiVersion (fmi_version)

    def group(self, name: str) -> list[str]:
        """Scalar names of a whole variable: ``[name]`` for a scalar, ``name[1..n]`` for a vector."""
        if name in self.variables:
            return [name]
        scalars = []
        i = 1
        while f"{name}[{i}]" in self.variables:
            scalars.append(f"{name}[{i}]")
            i += 1
        return scalars

    @property
    def inputs(self) -> list[str]:
        return [n for n, v in self.variables.items() if v.causality == "input"]

    @property
    def outputs(self) -> list[str]:
        return [n for n, v in self.variables.items() if v.causality == "output"]


@dataclass(frozen=True)
class Connection:
    """A connection of whole variables, with its scalar pairs."""
    src: str            # producer component
    src_var: str        # variable (group) name
    dst: str
    dst_var: str
    pairs: tuple[tuple[str, str], ...]   # (producer scalar, consumer scalar)
    text: str                            # as written in the scenario

    def __str__(self) -> str:
        return f"{self.src}.{self.src_var} -> {self.dst}.{self.dst_var}"


@dataclass(frozen=True)
class MetricSpec:
    """One ``[[metrics]]`` entry."""
    kind: str
    name: str
    estimate: str
    truth: str
    after: float = 0.0
    low: float = 3.0
    high: float = 30.0
    order: int = 4
    against: str = "truth"   # what `truth` is: truth | reference | another role (roles.against)
    truth_time: str | None = None   # the truth's sample time stamps (a held, skewed measurement)
    covariance: str | None = None   # nees: the filter's packed covariance
    dof: int | None = None          # nees, nis: degrees of freedom of the statistic


@dataclass
class Scenario:
    """A loaded, resolved and validated scenario."""
    path: Path | None
    name: str
    description: str
    stop_time: float
    base_step: float
    seed: int
    components: dict[str, Component]
    connections: list[Connection]
    record: list[str]                 # whole variables "comp.var"
    record_interval: float
    metrics: list[MetricSpec]
    overrides: tuple[str, ...] = ()
    source: dict[str, Any] = field(default_factory=dict)   # the merged TOML document
    oracles: list[str] = field(default_factory=list)        # connections marked as oracles
    delays: list[str] = field(default_factory=list)         # connections declared as delays

    @property
    def n_steps(self) -> int:
        return int(round(self.stop_time / self.base_step))

    @property
    def record_every(self) -> int:
        return int(round(self.record_interval / self.base_step))

    def record_columns(self) -> list[str]:
        """Scalar column names ``comp.var[i]`` of the recorded variables, in order."""
        cols = []
        for rv in self.record:
            comp, var = rv.split(".", 1)
            cols += [f"{comp}.{s}" for s in self.components[comp].group(var)]
        return cols

    def column_units(self) -> dict[str, str]:
        """The unit of ``time`` (``"s"``) and of every :meth:`record_columns` column, as its
        FMU's modelDescription gives it (the variable's ``unit``, else its ``declaredType``'s);
        ``""`` for a variable without one."""
        units = {"time": "s"}
        for col in self.record_columns():
            comp, scalar = col.split(".", 1)
            units[col] = self.components[comp].variables[scalar].unit or ""
        return units

    def describe(self) -> dict[str, Any]:
        """A JSON-able summary (for ``run.json``)."""
        return {
            "name": self.name, "file": str(self.path) if self.path else None,
            "description": self.description, "stop_time": self.stop_time,
            "base_step": self.base_step, "seed": self.seed,
            "components": {c.name: {"fmu": str(c.fmu), "model_identifier": c.model_identifier,
                                    "step": c.step, "parameters": c.parameters}
                           for c in self.components.values()},
            "connections": [str(c) for c in self.connections], "oracles": self.oracles,
            "delays": self.delays,
            "record": self.record, "record_interval": self.record_interval,
            "metrics": [vars(m) for m in self.metrics], "overrides": list(self.overrides),
        }


# ---------------------------------------------------------------------------------------------
# model descriptions
# ---------------------------------------------------------------------------------------------
_MD_CACHE: dict[str, tuple[str, str, dict[str, VariableInfo]]] = {}
MODEL_DESCRIPTIONS_KEPT = 64      # parsed model descriptions kept in the disk cache (a few kB each)


def read_variables(fmu: Path) -> tuple[str, str, dict[str, VariableInfo]]:
    """Model identifier, GUID and the variables (with feedthrough dependencies) of an FMU.

    Parsed once per FMU content: kept in the FMU store's model-description cache
    (:func:`orchestration.fmu_store.described`, ``model_descriptions/``), which saves a run's
    start-up about 3 ms per FMU.

    Raises
    ------
    ScenarioError
        Not a co-simulation FMU, or an archive beyond the limits (:mod:`orchestration.archive`).
    OSError, zipfile.BadZipFile
        Not a readable zip archive.
    """
    from . import fmu_store
    from .archive import ArchiveError
    try:
        key = fmu_store.content_key(fmu)
    except ArchiveError as exc:
        raise ScenarioError(str(exc)) from None
    if key not in _MD_CACHE:
        ident, guid, rows = fmu_store.described(fmu, "model_descriptions", _parse_variables, MODEL_DESCRIPTIONS_KEPT)
        _MD_CACHE[key] = (ident, guid, {row[0]: VariableInfo(*row[:6], None if row[6] is None else tuple(row[6]))
                                        for row in rows})
    return _MD_CACHE[key]


_VERSIONS: dict[str, str] = {}


def fmi_version(fmu: Path) -> str:
    """The ``fmiVersion`` of an FMU's modelDescription (``"2.0"``, ``"3.0"``), once per FMU
    content and process."""
    import zipfile
    from xml.etree import ElementTree

    from . import fmu_store
    key = fmu_store.content_key(fmu)
    if key not in _VERSIONS:
        with zipfile.ZipFile(fmu) as z:
            _VERSIONS[key] = ElementTree.fromstring(z.read("modelDescription.xml")).get("fmiVersion", "")
    return _VERSIONS[key]


# FMI 3.0's variable types by the FMI 2.0 type names the scenarios use
_FMI2_TYPES = {"Float64": "Real", "Float32": "Real", "Int8": "Integer", "UInt8": "Integer", "Int16": "Integer",
               "UInt16": "Integer", "Int32": "Integer", "UInt32": "Integer", "Int64": "Integer",
               "UInt64": "Integer"}


def _parse_variables(fmu: Path) -> tuple[str, str, list[list[Any]]]:
    """:func:`read_variables` from the modelDescription, each variable a list of the fields of
    :class:`VariableInfo` (JSON for the disk cache)."""
    from fmpy import read_model_description
    md = read_model_description(str(fmu), validate=False)
    if md.coSimulation is None:
        raise ScenarioError(f"{fmu}: not a co-simulation FMU")
    deps: dict[str, tuple[str, ...]] = {}
    for unknown in md.outputs:
        if unknown.dependencies is None:       # not given: depends on every input (FMI 2 rule)
            deps[unknown.variable.name] = None  # type: ignore[assignment]
        else:
            deps[unknown.variable.name] = tuple(d.name for d in unknown.dependencies)
    all_inputs = tuple(v.name for v in md.modelVariables if v.causality == "input")
    variables = []
    for v in md.modelVariables:
        if v.causality == "independent":       # FMI 3.0's `time`: not a signal of a scenario
            continue
        d = None
        if v.causality == "output":
            d = deps.get(v.name, all_inputs)
            if d is None:
                d = all_inputs
        variables.append([v.name, int(v.valueReference), _FMI2_TYPES.get(v.type, v.type), v.causality, v.variability,
                          getattr(v, "unit", None) or (v.declaredType.unit if getattr(v, "declaredType", None)
                                                       is not None else None), None if d is None else list(d)])
    return md.coSimulation.modelIdentifier, md.guid, variables


def fmu_dir() -> Path:
    """Where model identifiers are looked up: ``$FLEXFUSION_FMU_DIR`` or ``dist/fmus``."""
    env = os.environ.get("FLEXFUSION_FMU_DIR")
    return Path(env) if env else DEFAULT_FMU_DIR


def stable_seed(seed: int, component: str) -> int:
    """The seed of a component: a stable hash (crc32, 31 bits) of the scenario seed (any integer)
    and its name. Distinct scenario seeds give distinct component seeds for 0 .. 2,000,000 and
    the shipped scenarios' component names (checked; beyond, a hash cannot promise it). A
    component ``seed`` set directly is an FMI Integer: 32 bits, a larger value is refused."""
    return zlib.crc32(f"{int(seed)}:{component}".encode()) & 0x7FFFFFFF


# ---------------------------------------------------------------------------------------------
# overrides
# ---------------------------------------------------------------------------------------------
_OVERRIDE = re.compile(r"^\s*([A-Za-z_][\w]*)\.([^=\[\]]+?)(?:\[(\d+)\])?\s*=(.*)$", re.S)
_SCENARIO_KEYS = {"name", "description", "stop_time", "base_step", "seed", "include"}


def parse_value(text: str) -> Any:
    """A TOML value (``2``, ``1.5``, ``true``, ``[1, 2]``, ``"x"``); a bare word is a string."""
    try:
        return tomllib.loads(f"v = {text.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        if re.fullmatch(r"[\w.\-+]+", text.strip()):
            return text.strip()
        raise ScenarioError(f"override value {text.strip()!r} is not a TOML value") from None


def parse_override(text: str) -> tuple[str, str, int | None, Any]:
    """``comp.param[2]=value`` -> ``("comp", "param", 2, value)``."""
    m = _OVERRIDE.match(text)
    if not m:
        raise ScenarioError(f"override {text!r}: expected comp.param=value, comp.param[i]=value "
                            "or scenario.key=value")
    comp, name, index, value = m.group(1), m.group(2).strip(), m.group(3), m.group(4)
    return comp, name, int(index) if index else None, parse_value(value)


#: Overrides as ``comp.param=value`` strings (the command line's ``--set``) or as a mapping
#: ``{("ekf", "stiffness_scale"): 0.5, ("plant", "q0", 2): 0.1, ("scenario", "seed"): 3}``.
Overrides = Union[Iterable[str], Mapping[tuple, Any]]


def toml_value(v: Any) -> str:
    """``v`` (a number, bool, string, list or dict; numpy scalars too) as TOML text that reads
    back to the same value (floats by ``repr``, the shortest text that round-trips)."""
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{json.dumps(str(k))} = {toml_value(x)}" for k, x in v.items()) + "}"
    if isinstance(v, str):
        return json.dumps(v)
    return repr(float(v))


def override_strings(overrides: Overrides) -> tuple[str, ...]:
    """The ``comp.param=value`` strings of ``overrides``: strings as given, a mapping's
    ``(component, parameter[, index]) -> value`` items written as such strings (so that a run
    records and :func:`parse_override` reads both forms the same way).

    Raises
    ------
    ScenarioError
        A mapping key that is not ``(component, parameter)`` or ``(component, parameter, index)``.
    """
    if isinstance(overrides, str):
        raise ScenarioError(f"overrides must be a list of strings or a mapping, not the string {overrides!r}")
    if not isinstance(overrides, Mapping):
        return tuple(overrides)
    out = []
    for key, value in overrides.items():
        if not (isinstance(key, tuple) and len(key) in (2, 3) and all(isinstance(k, str) for k in key[:2])
                and (len(key) == 2 or isinstance(key[2], int))):
            raise ScenarioError(f"override key {key!r}: expected (component, parameter) or "
                                "(component, parameter, index)")
        index = f"[{key[2]}]" if len(key) == 3 else ""
        out.append(f"{key[0]}.{key[1]}{index}={toml_value(value)}")
    return tuple(out)


# ---------------------------------------------------------------------------------------------
# loading
# ---------------------------------------------------------------------------------------------
def _read_toml(path: Path) -> dict[str, Any]:
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise ScenarioError(f"scenario file not found: {path}") from None
    except OSError as exc:
        raise ScenarioError(f"{path}: cannot read: {exc.strerror or exc}") from None
    try:
        return tomllib.loads(_utf8(path, data))
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{path}: malformed TOML: {exc}") from None


def _utf8(path: Path, data: bytes) -> str:
    """The text of a TOML file (UTF-8, TOML 1.0), or a ScenarioError saying what the file is
    and where it stops being UTF-8 (line, column; never its content)."""
    if data.startswith(b"PK\x03\x04"):
        raise ScenarioError(f"{path}: {_zip_kind(data)}, not a TOML scenario; give a scenario's .toml file")
    if data.startswith((b"\xff\xfe", b"\xfe\xff")):
        raise ScenarioError(f"{path}: the file is UTF-16; a TOML scenario must be UTF-8 (save it as UTF-8)")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        column = exc.start - (data.rfind(b"\n", 0, exc.start) + 1) + 1
        kind = "a binary file" if b"\0" in data[:4096] else "not UTF-8 text (Latin-1?)"
        raise ScenarioError(f"{path}: {kind}: a TOML scenario must be UTF-8; the first byte that "
                            f"is not is at line {line}, column {column}") from None


def _zip_kind(data: bytes) -> str:
    """What a zip file given as a scenario is: an SSP package, an FMU or another archive."""
    import io
    import zipfile
    try:
        names = set(zipfile.ZipFile(io.BytesIO(data)).namelist())
    except zipfile.BadZipFile:
        names = set()
    if "SystemStructure.ssd" in names:
        return "this is an SSP package (flexfusion runs one whose name ends in .ssp)"
    if "modelDescription.xml" in names:
        return "this is an FMU (name it in a scenario: [components.NAME] fmu = \"path/to/it.fmu\")"
    return "this is a zip archive"


def _table(where: str, value: Any) -> dict[str, Any]:
    """``value`` if it is a TOML table, else a ScenarioError."""
    if not isinstance(value, dict):
        raise ScenarioError(f"{where} must be a table, got {_type_name(value)}")
    return value


def _type_name(value: Any) -> str:
    return {str: "a string", int: "an integer", float: "a number", bool: "a boolean", list: "a list",
            dict: "a table"}.get(type(value), type(value).__name__)


def _number(where: str, value: Any, *, positive: bool = True) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ScenarioError(f"{where} must be a finite number, got {value!r}")
    if positive and value <= 0:
        raise ScenarioError(f"{where} must be > 0, got {value!r}")
    return float(value)


def _multiple(where: str, value: float, base: float) -> int:
    ratio = value / base
    k = int(round(ratio))
    if k < 1 or abs(ratio - k) > 1e-9 * max(1.0, ratio):
        raise ScenarioError(f"{where} = {value!r} is not an integer multiple of the base step {base!r}")
    return k


def _flatten_parameters(where: str, comp: Component, params: dict[str, Any]) -> dict[str, ParamValue]:
    """Scenario parameters (vectors as lists) -> scalar variable name -> value, checked."""
    out: dict[str, ParamValue] = {}
    for name, value in params.items():
        if isinstance(value, list):
            group = comp.group(name)
            if not group or group == [name]:
                if name in comp.variables:
                    raise ScenarioError(f"{where}: parameter '{name}' is a scalar, got the list {value!r}")
                raise ScenarioError(f"{where}: component '{comp.name}' has no parameter '{name}'"
                                    + did_you_mean(name, _parameter_names(comp, name)))
            if len(group) != len(value):
                raise ScenarioError(f"{where}: parameter '{name}' has {len(group)} elements, "
                                    f"got {len(value)}: {value!r}")
            pairs = list(zip(group, value))
        else:
            if name not in comp.variables and comp.group(name):
                raise ScenarioError(f"{where}: parameter '{name}' is a vector of "
                                    f"{len(comp.group(name))} elements, give a list")
            pairs = [(name, value)]
        for scalar, v in pairs:
            info = comp.variables.get(scalar)
            if info is None:
                raise ScenarioError(f"{where}: component '{comp.name}' has no parameter '{scalar}'"
                                    + did_you_mean(scalar, _parameter_names(comp, scalar)))
            if info.causality != "parameter":
                raise ScenarioError(f"{where}: '{comp.name}.{scalar}' is an {info.causality}, "
                                    "not a parameter")
            out[scalar] = _coerce(f"{where}: parameter '{scalar}'", info, v)
    return out


def _coerce(where: str, info: VariableInfo, v: Any) -> ParamValue:
    t = info.type
    if t == "Real":
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ScenarioError(f"{where} is Real, got {v!r}")
        return float(v)
    if t in ("Integer", "Enumeration"):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or (isinstance(v, float) and not v.is_integer()):
            raise ScenarioError(f"{where} is Integer, got {v!r}")
        if not -2**31 <= v < 2**31:      # fmi2Integer is 32-bit: a larger value would wrap
            raise ScenarioError(f"{where} = {v!r} is out of the FMI Integer range "
                                f"[{-2**31}, {2**31 - 1}]")
        return int(v)
    if t == "Boolean":
        if not isinstance(v, bool):
            raise ScenarioError(f"{where} is Boolean, got {v!r}")
        return v
    if t == "String":
        if not isinstance(v, str):
            raise ScenarioError(f"{where} is String, got {v!r}")
        return v
    raise ScenarioError(f"{where} has the unsupported type {t}")


def _resolve_fmu(where: str, spec: Any, base_dir: Path) -> Path:
    if not isinstance(spec, str) or not spec:
        raise ScenarioError(f"{where}: 'fmu' must be a model identifier or a path to a .fmu")
    if spec.endswith(".fmu") or "/" in spec or os.sep in spec:
        path = Path(spec)
        if not path.is_absolute():
            path = base_dir / path
        if not path.is_file():
            raise ScenarioError(f"{where}: FMU file not found: {path}")
        return path
    path = fmu_dir() / f"{spec}.fmu"
    if not path.is_file():
        raise ScenarioError(f"{where}: FMU file not found: {path} (model identifier '{spec}'; "
                            "run `flexfusion build` or set FLEXFUSION_FMU_DIR)")
    return path


def did_you_mean(name: str, choices: Iterable[str]) -> str:
    """`` (did you mean 'x'?)`` naming the up to three ``choices`` closest to ``name``
    (:func:`difflib.get_close_matches`, its default cutoff 0.6), or ``""`` if none is close."""
    import difflib
    close = difflib.get_close_matches(name, sorted(set(choices)), n=3)
    return f" (did you mean {' or '.join(repr(c) for c in close)}?)" if close else ""


def _parameter_names(comp: Component, name: str) -> list[str]:
    """A component's parameters as a user names them: whole vectors (``p_tool0``), or their
    elements (``p_tool0[1]``) when ``name`` is an element."""
    scalars = [s for s, info in comp.variables.items() if info.causality == "parameter"]
    return scalars if name.endswith("]") else [s.split("[", 1)[0] for s in scalars]


def _split_ref(where: str, ref: Any) -> tuple[str, str]:
    if not isinstance(ref, str) or "." not in ref:
        raise ScenarioError(f"{where}: {ref!r} is not of the form component.variable")
    comp, var = ref.strip().split(".", 1)
    return comp.strip(), var.strip()


def _lookup(where: str, components: dict[str, Component], ref: str) -> tuple[Component, str, list[str]]:
    comp_name, var = _split_ref(where, ref)
    comp = components.get(comp_name)
    if comp is None:
        raise ScenarioError(f"{where}: unknown component '{comp_name}' (components: "
                            f"{', '.join(components) or 'none'})" + did_you_mean(comp_name, components))
    group = comp.group(var)
    if not group:
        raise ScenarioError(f"{where}: component '{comp_name}' ({comp.model_identifier}) has no "
                            f"variable '{var}'" + did_you_mean(var, [v if var.endswith("]") else
                                                                     v.split("[", 1)[0] for v in comp.variables]))
    return comp, var, group


def resolve_file_parameters(params: dict[str, Any], base_dir: Path) -> None:
    """Make relative paths in file parameters (names ending in ``_file``) relative to the
    scenario file that sets them, so a scenario runs from any working directory."""
    for key, value in params.items():
        if key.endswith("_file") and isinstance(value, str) and value and not Path(value).is_absolute():
            params[key] = str(base_dir / value)


def _check_keys(where: str, table: Any, allowed: Iterable[str]) -> None:
    if not isinstance(table, dict):
        raise ScenarioError(f"{where} must be a table")
    unknown = sorted(set(table) - set(allowed))
    if unknown:
        raise ScenarioError(f"{where}: unknown key(s) {', '.join(unknown)} "
                            f"(allowed: {', '.join(sorted(allowed))})"
                            + "".join(did_you_mean(k, allowed) for k in unknown[:1]))


def scenario_document(source: str | Path | dict[str, Any], overrides: Overrides = ()) -> dict[str, Any]:
    """The scenario as one self-contained TOML document: includes merged in, overrides applied,
    relative FMU paths and ``*_file`` parameters made absolute (no FMU is read).

    Raises
    ------
    ScenarioError
        An unreadable file, an unknown component in an include or an override.
    """
    doc, path, _, base_dir = _document(source, override_strings(overrides))
    doc["scenario"].setdefault("name", path.stem if path else "scenario")
    for ctab in doc["components"].values():
        fmu = ctab.get("fmu") if isinstance(ctab, dict) else None
        if isinstance(fmu, str) and (fmu.endswith(".fmu") or "/" in fmu) and not Path(fmu).is_absolute():
            ctab["fmu"] = str(base_dir / fmu)
    return doc


def _document(source: str | Path | dict[str, Any], overrides: tuple[str, ...]
              ) -> tuple[dict[str, Any], Path | None, str, Path]:
    """``(document, path, label, base_dir)``: the TOML with includes and overrides applied."""
    if isinstance(source, dict):
        path, doc, label, base_dir = None, copy_document(source), "<scenario>", Path.cwd()
    else:
        path = Path(source)
        doc = _read_toml(path)
        label, base_dir = str(path), path.resolve().parent
    _check_keys(label, doc, {"scenario", "components", "connections", "oracles", "delays", "record",
                             "metrics", "parameter_sets"})
    head = doc.get("scenario", {})
    _check_keys(f"{label}: [scenario]", head, _SCENARIO_KEYS)
    comps_doc = _table(f"{label}: [components]", doc.get("components", {}))
    if not comps_doc:
        raise ScenarioError(f"{label}: no [components.*] given")
    for cname, ctab in comps_doc.items():
        _check_component_name(label, cname)
        _table(f"{label}: [components.{cname}]", ctab)
        if isinstance(ctab.get("parameters"), dict):
            resolve_file_parameters(ctab["parameters"], base_dir)

    sets = _parameter_sets(label, doc.get("parameter_sets", {}), base_dir)

    # includes: their [components.X.parameters] and [parameter_sets.S] are merged over this file's
    includes = head.get("include", [])
    if isinstance(includes, str):
        includes = [includes]
    if not isinstance(includes, list) or not all(isinstance(i, str) and i for i in includes):
        raise ScenarioError(f"{label}: [scenario] include must be a file name or a list of file "
                            f"names, got {includes!r}")
    doc["parameter_sets"] = sets
    for inc in includes:
        merge_include(doc, base_dir / inc, label)

    for text in overrides:
        _apply_override(text, head, doc["parameter_sets"], comps_doc, label, base_dir)
    head.pop("include", None)
    doc["scenario"] = head
    return doc, path, label, base_dir


def _apply_override(text: str, head: dict[str, Any], sets: dict[str, dict[str, Any]],
                    comps_doc: dict[str, Any], label: str, base_dir: Path) -> None:
    """Apply the override ``text`` (``comp.param[i]=value``, ``scenario.key=value`` or
    ``parameter_sets.S.key=value``) to the document's parts."""
    cname, pname, index, value = parse_override(text)
    where = f"override {text.strip()!r}"
    if cname == "scenario":
        if pname not in _SCENARIO_KEYS - {"include"} or index is not None:
            raise ScenarioError(f"{where}: unknown scenario key '{pname}' (allowed: "
                                "seed, stop_time, base_step, name, description)"
                                + did_you_mean(pname, _SCENARIO_KEYS - {"include"}))
        head[pname] = value
        return
    if cname == "parameter_sets":
        sname, _, key = pname.partition(".")
        if sname not in sets:
            raise ScenarioError(f"{where}: unknown parameter set '{sname}' (defined: "
                                f"{', '.join(sets) or 'none'})" + did_you_mean(sname, sets))
        if not key:
            sets[sname] = _parameter_sets(where, {sname: value}, base_dir)[sname]
        else:
            sets[sname][key if index is None else f"{key}[{index}]"] = value
        return
    if cname not in comps_doc:
        raise ScenarioError(f"{where}: unknown component '{cname}' (components: "
                            f"{', '.join(comps_doc)})" + did_you_mean(cname, comps_doc))
    if pname == "parameter_sets" and index is None:
        comps_doc[cname]["parameter_sets"] = value
        return
    params = _table(f"{label}: [components.{cname}.parameters]",
                    comps_doc[cname].setdefault("parameters", {}))
    if index is None:
        params[pname] = value
    else:
        params[f"{pname}[{index}]"] = value


def merge_include(doc: dict[str, Any], inc_path: Path, label: str = "<scenario>", *,
                  skip_unknown: bool = False) -> None:
    """Merge the include file ``inc_path`` over the scenario document ``doc`` (in place): its
    ``[components.X.parameters]`` update X's parameters, its ``[parameter_sets.S]`` update set S
    (``*_file`` values relative to the include file).

    Raises
    ------
    ScenarioError
        An unreadable file, a key other than those two tables, or a component ``doc`` does not
        have (unless ``skip_unknown``: a tuned file may name estimators a scenario lacks).
    """
    inc_path = Path(inc_path)
    inc_doc = _read_toml(inc_path)
    _check_keys(str(inc_path), inc_doc, {"components", "parameter_sets"})
    sets = doc.setdefault("parameter_sets", {})
    for sname, table in _parameter_sets(str(inc_path), inc_doc.get("parameter_sets", {}),
                                        inc_path.resolve().parent).items():
        sets.setdefault(sname, {}).update(table)
    comps_doc = doc["components"]
    for cname, ctab in _table(f"{inc_path}: [components]", inc_doc.get("components", {})).items():
        if cname not in comps_doc:
            if skip_unknown:
                continue
            raise ScenarioError(f"{inc_path}: unknown component '{cname}' (not in {label})")
        _check_keys(f"{inc_path}: [components.{cname}]", ctab, {"parameters"})
        params = dict(_table(f"{inc_path}: [components.{cname}.parameters]", ctab.get("parameters", {})))
        resolve_file_parameters(params, inc_path.resolve().parent)
        comps_doc[cname].setdefault("parameters", {}).update(params)


_COMPONENT_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def _check_component_name(label: str, name: str) -> None:
    """A component name is an identifier: it becomes a CSV column prefix (``name.var``), an SSP
    element name and a part of ``--set name.param=value``."""
    if not _COMPONENT_NAME.fullmatch(name):
        raise ScenarioError(f"{label}: component name {name!r} must be an identifier (letters, digits "
                            "and '_', not starting with a digit)")


def _parameter_sets(where: str, table: Any, base_dir: Path) -> dict[str, dict[str, Any]]:
    """The ``[parameter_sets.S]`` tables of a file, checked to be tables (copies, ``*_file``
    values made relative to ``base_dir``)."""
    if not isinstance(table, dict):
        raise ScenarioError(f"{where}: 'parameter_sets' must be a table of [parameter_sets.NAME] tables")
    out = {}
    for sname, params in table.items():
        if not isinstance(params, dict):
            raise ScenarioError(f"{where}: [parameter_sets.{sname}] must be a table of parameter values")
        out[sname] = dict(params)
        resolve_file_parameters(out[sname], base_dir)
    return out


def _set_parameters(where: str, comp: Component, names: Any, sets: dict[str, dict[str, Any]],
                    users: dict[str, list[Component]]) -> dict[str, ParamValue]:
    """The values the component's parameter sets give it (later sets win), restricted to the
    parameters its FMU declares; records the component in ``users`` per set."""
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise ScenarioError(f"{where}: 'parameter_sets' must be a list of set names, got {names!r}")
    out: dict[str, ParamValue] = {}
    for sname in names:
        if sname not in sets:
            raise ScenarioError(f"{where}: unknown parameter set '{sname}' (defined: "
                                f"{', '.join(sets) or 'none'})" + did_you_mean(sname, sets))
        users.setdefault(sname, []).append(comp)
        declared = {k: v for k, v in sets[sname].items() if _declares(comp, k)}
        out.update(_flatten_parameters(f"{where}: parameter set '{sname}'", comp, declared))
    return out


def _declares(comp: Component, name: str) -> bool:
    """Whether the component's FMU has the parameter ``name`` (a scalar or a whole vector)."""
    group = comp.group(name)
    return bool(group) and comp.variables[group[0]].causality == "parameter"


def _check_set_keys(label: str, sets: dict[str, dict[str, Any]], users: dict[str, list[Component]]) -> None:
    """A key of a used set that none of its components declares is a typo: reject it."""
    for sname, comps in users.items():
        unused = [k for k in sets[sname] if not any(_declares(c, k) for c in comps)]
        if unused:
            raise ScenarioError(f"{label}: parameter set '{sname}': {', '.join(repr(k) for k in unused)} "
                                f"is a parameter of none of the components that use the set "
                                f"({', '.join(c.name for c in comps)})")


def _head(label: str, head: dict[str, Any], path: Path | None) -> tuple[str, str, float, float, int]:
    """``(name, description, stop_time, base_step, seed)`` of the ``[scenario]`` table."""
    name = head.get("name", path.stem if path else "scenario")
    if not isinstance(name, str):
        raise ScenarioError(f"{label}: [scenario] name must be a string")
    if name in ("", ".", "..") or any(c in name for c in "/\\") or not name.isprintable():
        raise ScenarioError(f"{label}: [scenario] name {name!r} must be a plain folder name "
                            "(it names the default output folder): no '/', '\\', '..'")
    description = str(head.get("description", ""))
    if "stop_time" not in head:
        raise ScenarioError(f"{label}: [scenario] stop_time is missing")
    if "base_step" not in head:
        raise ScenarioError(f"{label}: [scenario] base_step is missing")
    stop_time = _number(f"{label}: [scenario] stop_time", head["stop_time"])
    base_step = _number(f"{label}: [scenario] base_step", head["base_step"])
    _multiple(f"{label}: [scenario] stop_time", stop_time, base_step)
    seed = head.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise ScenarioError(f"{label}: [scenario] seed must be an integer, got {seed!r}")
    return name, description, stop_time, base_step, seed


def _components(label: str, comps_doc: dict[str, Any], sets: dict[str, dict[str, Any]], base_dir: Path,
                base_step: float, seed: int) -> dict[str, Component]:
    """The components, their FMUs read and their parameters resolved: parameter sets first,
    then the component's own, and a stable per-component ``seed`` unless one is given."""
    set_users: dict[str, list[Component]] = {}
    components: dict[str, Component] = {}
    for cname, ctab in comps_doc.items():
        where = f"{label}: component '{cname}'"
        if "connections" in ctab:
            raise ScenarioError(f"{where}: 'connections' ended up inside [components.{cname}]: "
                                "put the top-level connections = [...] before the first [table]")
        _check_keys(where, ctab, {"fmu", "step", "parameters", "parameter_sets"})
        if "fmu" not in ctab:
            raise ScenarioError(f"{where}: 'fmu' is missing")
        fmu = _resolve_fmu(where, ctab["fmu"], base_dir)
        step = _number(f"{where}: step", ctab.get("step", base_step))
        ratio = _multiple(f"{where}: step", step, base_step)
        try:
            ident, guid, variables = read_variables(fmu)
            describe(fmu)                 # its vendor annotation: a malformed one is an error here
        except ScenarioError:
            raise
        except Exception as exc:  # noqa: BLE001 - a broken FMU file is a user error
            raise ScenarioError(f"{where}: cannot read the modelDescription of {fmu}: {exc}") from None
        comp = Component(cname, fmu, step, ratio, {}, ident, guid, variables, fmi_version(fmu))
        params = ctab.get("parameters", {})
        if not isinstance(params, dict):
            raise ScenarioError(f"{where}: [parameters] must be a table")
        comp.parameters = _set_parameters(where, comp, ctab.get("parameter_sets", []), sets, set_users)
        comp.parameters.update(_flatten_parameters(where, comp, params))
        seed_info = variables.get("seed")
        if seed_info is not None and seed_info.causality == "parameter" and "seed" not in comp.parameters:
            comp.parameters["seed"] = _coerce(f"{where}: parameter 'seed'", seed_info,
                                              stable_seed(seed, cname))
        components[cname] = comp
    _check_set_keys(label, sets, set_users)
    return components


def _connections(label: str, conn_doc: Any, components: dict[str, Component]) -> list[Connection]:
    """The ``a.x -> b.y`` connections: output to input, Real, same size and unit, each input
    driven once."""
    if not isinstance(conn_doc, list):
        raise ScenarioError(f"{label}: 'connections' must be a list of \"a.x -> b.y\" strings "
                            "(put it before the first [table])")
    connections: list[Connection] = []
    driven: dict[tuple[str, str], str] = {}
    for text in conn_doc:
        where = f"{label}: connection {text!r}"
        if not isinstance(text, str) or text.count("->") != 1:
            raise ScenarioError(f"{where}: expected \"component.variable -> component.variable\"")
        left, right = (s.strip() for s in text.split("->"))
        sc, svar, sgroup = _lookup(where, components, left)
        dc, dvar, dgroup = _lookup(where, components, right)
        for comp, var, group, role, need in ((sc, svar, sgroup, "source", "output"),
                                             (dc, dvar, dgroup, "target", "input")):
            caus = comp.variables[group[0]].causality
            if caus != need:
                kind = ("input-to-input connection: " if role == "source" and caus == "input" else
                        "output-to-output connection: " if role == "target" and caus == "output" else "")
                raise ScenarioError(f"{where}: {kind}the {role} '{comp.name}.{var}' is "
                                    f"{_article(caus)} {caus}, must be an {need}")
            vtype = comp.variables[group[0]].type
            if vtype != "Real":
                raise ScenarioError(f"{where}: '{comp.name}.{var}' is {vtype}; only Real "
                                    "variables can be connected")
        if len(sgroup) != len(dgroup):
            raise ScenarioError(f"{where}: size mismatch: '{sc.name}.{svar}' has {len(sgroup)} "
                                f"element(s), '{dc.name}.{dvar}' has {len(dgroup)}")
        su, du = sc.variables[sgroup[0]].unit, dc.variables[dgroup[0]].unit
        if su and du and su != du:
            raise ScenarioError(f"{where}: unit mismatch: '{sc.name}.{svar}' is in {su}, "
                                f"'{dc.name}.{dvar}' in {du}")
        if sc is dc:
            pass  # a self-loop is allowed (the master breaks it like any other cycle)
        for d in dgroup:
            key = (dc.name, d)
            if key in driven:
                raise ScenarioError(f"{where}: input '{dc.name}.{d}' is already connected "
                                    f"by {driven[key]!r}")
            driven[key] = text
        connections.append(Connection(sc.name, svar, dc.name, dvar,
                                      tuple(zip(sgroup, dgroup)), text))
    return connections


def _record(label: str, rec: Any, components: dict[str, Component], connections: list[Connection],
            base_step: float) -> tuple[list[str], float]:
    """``(recorded variables, interval)`` of ``[record]`` (default: every connected output)."""
    _check_keys(f"{label}: [record]", rec, {"variables", "interval"})
    if "variables" in rec:
        if not isinstance(rec["variables"], list):
            raise ScenarioError(f"{label}: [record] variables must be a list of \"comp.var\"")
        record = []
        for ref in rec["variables"]:
            comp, var, group = _lookup(f"{label}: [record] variable {ref!r}", components, ref)
            if comp.variables[group[0]].type != "Real":
                raise ScenarioError(f"{label}: [record] variable {ref!r} is not Real")
            record.append(f"{comp.name}.{var}")
    else:                          # every connected output once (a dict: linear in the connections)
        record = list(dict.fromkeys(f"{c.src}.{c.src_var}" for c in connections))
    interval = _number(f"{label}: [record] interval", rec.get("interval", base_step))
    _multiple(f"{label}: [record] interval", interval, base_step)
    return record, interval


def _metrics(label: str, metrics_doc: Any, components: dict[str, Component], record: list[str],
             interval: float) -> list[MetricSpec]:
    """The ``[[metrics]]``, checked; what they read is added to ``record``."""
    if not isinstance(metrics_doc, list):
        raise ScenarioError(f"{label}: metrics must be given as [[metrics]] tables")
    metrics: list[MetricSpec] = []
    for i, m in enumerate(metrics_doc):
        metrics.append(_metric(f"{label}: [[metrics]] #{i + 1}", label, m, components, record, interval))
    names = [m.name for m in metrics]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise ScenarioError(f"{label}: duplicate metric name(s) {', '.join(sorted(dup))}")
    return metrics


def _metric(where: str, label: str, m: Any, components: dict[str, Component], record: list[str],
            interval: float) -> MetricSpec:
    """One ``[[metrics]]`` table (``where`` names it until its name is known)."""
    _check_keys(where, m, {"kind", "name", "estimate", "truth", "truth_time", "after", "low", "high",
                           "order", "covariance", "dof"})
    if "kind" not in m:
        raise ScenarioError(f"{where}: 'kind' is missing")
    if m["kind"] not in ("rmse", "bandpass", "max", "nees", "nis"):
        raise ScenarioError(f"{where}: unknown kind {m.get('kind')!r} (rmse, bandpass, max, nees, nis)")
    needed = {"nis": ("estimate", "dof"), "nees": ("estimate", "truth", "covariance")}.get(
        m["kind"], ("estimate", "truth"))
    for key in needed:
        if key not in m:
            raise ScenarioError(f"{where}: '{key}' is missing (kind {m['kind']!r})")
    mname = m.get("name", f"{m['kind']}_{m['estimate']}")
    where = f"{label}: metric '{mname}'"
    sizes = []
    for key in ("estimate", "truth", "covariance"):
        if key not in m:
            continue
        comp, var, group = _lookup(f"{where}: {key}", components, m[key])
        sizes.append(len(group))
        ref = f"{comp.name}.{var}"
        if ref not in record:
            record.append(ref)
    dof = m.get("dof", sizes[0])
    if m["kind"] == "nees" and dof != sizes[0]:
        raise ScenarioError(f"{where}: the NEES of {sizes[0]} states has {sizes[0]} degrees of "
                            f"freedom, got dof = {dof!r}")
    if m["kind"] == "nis" and sizes[0] != 1:
        raise ScenarioError(f"{where}: estimate {m['estimate']!r} must be a scalar (the filter's "
                            "nis or innovation_norm output)")
    if m["kind"] in ("nees", "nis") and (isinstance(dof, bool) or not isinstance(dof, int) or dof < 1):
        raise ScenarioError(f"{where}: dof must be a positive integer, got {dof!r}")
    if m["kind"] == "nees":
        from .metrics import packed_dimension
        n = packed_dimension(sizes[2])
        if n is None or n < sizes[0]:
            raise ScenarioError(f"{where}: covariance {m['covariance']!r} has {sizes[2]} elements: "
                                f"not a packed covariance (n (n + 1) / 2 elements) of at least the "
                                f"{sizes[0]} states of the estimate")
    if len(sizes) > 1 and sizes[0] != sizes[1]:
        raise ScenarioError(f"{where}: size mismatch: estimate {m['estimate']!r} has {sizes[0]} "
                            f"element(s), truth {m['truth']!r} has {sizes[1]}")
    truth_time = m.get("truth_time")
    if truth_time is not None:
        comp, var, group = _lookup(f"{where}: truth_time", components, truth_time)
        if len(group) != 1 or comp.variables[group[0]].unit not in (None, "s"):
            raise ScenarioError(f"{where}: truth_time {truth_time!r} must be a scalar time (s), "
                                "the sample time of the truth (e.g. tracker.t_meas)")
        if f"{comp.name}.{var}" not in record:
            record.append(f"{comp.name}.{var}")
    after = _number(f"{where}: after", m.get("after", 0.0), positive=False)
    low = _number(f"{where}: low", m.get("low", 3.0))
    high = _number(f"{where}: high", m.get("high", 30.0))
    order = m.get("order", 4)
    if m["kind"] == "bandpass":
        nyq = 0.5 / interval
        if not low < high < nyq:
            raise ScenarioError(f"{where}: need low < high < Nyquist frequency {nyq:g} Hz "
                                f"of the record interval, got low={low:g}, high={high:g}")
    if isinstance(order, bool) or not isinstance(order, int) or order < 1:
        raise ScenarioError(f"{where}: order must be a positive integer")
    against = (roles.against(components[_split_ref(where, m["truth"])[0]]) if "truth" in m
               else "innovations")      # nis: the filter's innovations against its own S
    return MetricSpec(m["kind"], mname, m["estimate"], m.get("truth", ""), after, low, high,
                      order, against, truth_time, m.get("covariance"),
                      dof if m["kind"] in ("nees", "nis") else None)


def load_scenario(source: str | Path | dict[str, Any], overrides: Overrides = ()) -> Scenario:
    """Load, resolve and validate a scenario.

    Parameters
    ----------
    source
        Path of a TOML file, or an already parsed document (paths then relative to the cwd).
    overrides
        ``comp.param=value`` / ``comp.param[i]=value`` / ``scenario.key=value`` strings, or a
        mapping ``{(comp, param): value, (comp, param, i): value}`` (:func:`override_strings`).

    Raises
    ------
    ScenarioError
        One message naming the file, the component and the variable.
    """
    overrides = override_strings(overrides)
    doc, path, label, base_dir = _document(source, overrides)
    name, description, stop_time, base_step, seed = _head(label, doc["scenario"], path)
    components = _components(label, doc["components"], doc["parameter_sets"], base_dir, base_step, seed)
    connections = _connections(label, doc.get("connections", []), components)
    oracles = _check_honest_signals(label, doc.get("oracles", []), connections, components)
    delays = _marked_connections(label, "delays", doc.get("delays", []), connections)
    record, interval = _record(label, doc.get("record", {}), components, connections, base_step)
    metrics = _metrics(label, doc.get("metrics", []), components, record, interval)
    _check_run_length(label, stop_time, base_step, components)
    return Scenario(path=path, name=name, description=description, stop_time=stop_time,
                    base_step=base_step, seed=int(seed), components=components,
                    connections=connections, record=record, record_interval=interval,
                    metrics=metrics, overrides=overrides, source=doc, oracles=oracles, delays=delays)


def _check_run_length(label: str, stop_time: float, base_step: float, components: dict[str, Component]) -> None:
    """At most :data:`MAX_STEPS` base steps, and every component one step at least (the master
    never steps past the stop time)."""
    n_steps = round(stop_time / base_step)
    if n_steps > MAX_STEPS:
        raise ScenarioError(f"{label}: stop_time / base_step = {n_steps:.3g} base steps, more than "
                            f"the limit {MAX_STEPS:.0e} (a day or more of wall time): shorten the run "
                            "or lengthen base_step")
    for c in components.values():
        if c.ratio > n_steps:
            raise ScenarioError(f"{label}: component '{c.name}': step {c.step:g} s is longer than "
                                f"the stop time {stop_time:g} s (it would never step)")


def check_metric_windows(sc: Scenario) -> None:
    """Every metric has a recorded sample at or after its ``after`` (else it would be NaN).

    Not part of :func:`load_scenario`: a study that shortens a scenario and computes its own
    metrics may leave the scenario's unused; a run that computes them calls this first.
    """
    last = sc.record_interval * (sc.n_steps // sc.record_every)
    for m in sc.metrics:
        if m.after > last + 1e-12:
            raise ScenarioError(f"{sc.path or sc.name}: metric '{m.name}': after = {m.after:g} s leaves "
                                f"no recorded sample (the last is at t = {last:g} s, stop_time "
                                f"{sc.stop_time:g} s)")


def connection_key(text: str) -> str:
    """A connection as ``"a.x -> b.y"``, whatever the spaces it was written with."""
    return " -> ".join(part.strip() for part in text.split("->"))


def _check_honest_signals(label: str, oracles: Any, connections: list[Connection],
                          components: dict[str, Component]) -> list[str]:
    """Warn once per connection that feeds plant truth to an estimator or controller and is
    not listed in ``oracles``; an oracle that is not a connection is an error. Returns the
    oracles as ``"a.x -> b.y"``."""
    marked = _marked_connections(label, "oracles", oracles, connections)
    for c in roles.dishonest_connections(connections, components):
        if str(c) not in marked:
            dst = components[c.dst]
            warnings.warn(f"{label}: connection '{c}' feeds plant truth into the "
                          f"{roles.role(dst)} '{c.dst}' ({dst.model_identifier}); connect a "
                          "sensor or an estimate, or mark it in oracles = [...]",
                          roles.HonestSignalWarning, stacklevel=3)
    return marked


def _marked_connections(label: str, key: str, texts: Any, connections: list[Connection]) -> list[str]:
    """The connections a top-level list (``oracles``, ``delays``) marks, as ``"a.x -> b.y"``;
    each entry must be one of the connections."""
    if not isinstance(texts, list) or not all(isinstance(o, str) for o in texts):
        raise ScenarioError(f"{label}: '{key}' must be a list of \"a.x -> b.y\" strings "
                            "(put it before the first [table])")
    written = {str(c) for c in connections}
    for text in texts:
        if text.count("->") != 1 or connection_key(text) not in written:
            raise ScenarioError(f"{label}: {key[:-1]} {text!r} is not one of the connections")
    return [connection_key(t) for t in texts]


def _article(word: str) -> str:
    return "an" if word[0] in "aeiou" else "a"


def copy_document(doc: Any) -> Any:
    """A deep copy of a TOML document (its tables and arrays; the values are immutable)."""
    if isinstance(doc, dict):
        return {k: copy_document(v) for k, v in doc.items()}
    if isinstance(doc, list):
        return [copy_document(v) for v in doc]
    return doc


__all__ = ["ScenarioError", "Scenario", "Component", "Connection", "MetricSpec", "VariableInfo",
           "load_scenario", "copy_document", "merge_include", "Overrides", "override_strings", "toml_value", "parse_override", "parse_value", "stable_seed", "fmu_dir", "read_variables", "fmi_version",
           "connection_key", "check_metric_windows", "MAX_STEPS"]

"""The thin FMI adapter every FlexFusion FMU derives from.

pythonfmu (0.7) knows scalar variables without units, and declares every output as depending on
every input. This base class adds what our FMUs all need, once:

* vector variables as 1-based indexed scalars (``q_a[1]``, ``q_a[2]``) backed by numpy arrays;
  the vector outputs are consecutive views of one buffer (``_outputs``, in declaration order),
  so that ``fmi2GetReal`` of a step's outputs copies the span of it they lie in, and an
  adapter (or its kernel) may write several outputs at once (:meth:`FlexFusionSlave.output_span`);
  ``fmi2GetReal`` and ``fmi2SetReal`` of a list of value references run a function of plain
  assignments generated for that list at its first use;
* a unit and a description on every variable, and the ``<UnitDefinitions>`` they refer to;
* the real direct-feedthrough dependencies of each output in ``<ModelStructure>``, which the
  master algorithm uses to order the components;
* parameters declared from a parameter dataclass (:mod:`fmus.common.parameters`) and validated
  when initialisation ends, so a bad value is rejected with an FMI error naming the parameter
  instead of crashing the host;
* outputs with direct feedthrough recomputed lazily when an input was set;
* outputs valid in Initialization Mode (``initial="calculated"``): reading one there builds
  the model from the parameters and inputs set so far, and again after a later change;
* the FMI contract: a bad step size, a non-finite output or a change of a fixed parameter after
  initialisation is an FMI error; a parameter declared ``param(..., tunable=True)`` may change
  between steps (FMI 2.0 variability "tunable"): it is validated, ``self.params`` follows and
  :meth:`FlexFusionSlave.tuned` tells the model; errors reach the host's logger even without
  debug logging;
* get/set (and serialise) FMU state of the complete internal state, bit-exact; serialised as
  data only (:mod:`fmus.common.state_codec`: no pickle), stamped with the FMU's identity, and
  checked against the instance that reads it (a foreign, corrupted or crafted state is an FMI
  error naming why);
* every exception turned into an FMI error status with one clear log message (pythonfmu 0.7's
  native layer turns an exception into ``fmi2Fatal``, a ``do_step`` returning False into
  ``fmi2Discard``).

Subclasses implement :meth:`FlexFusionSlave.setup` (build the model from validated parameters),
:meth:`FlexFusionSlave.step` (advance one communication step) and, if an output depends
directly on an input, :meth:`FlexFusionSlave.update_outputs`.
"""
from __future__ import annotations

import copy
import ctypes
import hashlib
import keyword
import math
import sys
from functools import partial
import traceback
from typing import Any, Iterable, Sequence
from xml.etree.ElementTree import Element, SubElement

import numpy as np
from pythonfmu.enums import Fmi2Causality, Fmi2Initial, Fmi2Status, Fmi2Variability
from pythonfmu.fmi2slave import Fmi2Slave
from pythonfmu.variables import Boolean, Integer, Real, String

from . import parameters as _parameters
from . import state_codec as _state_codec

_MODULE_DICTS: list = []   # see FlexFusionSlave.__init_subclass__

# SI base-unit exponents (kg, m, s, rad) of every unit our FMUs use.
_UNITS: dict[str, dict[str, int]] = {
    "1": {},
    "s": {"s": 1},
    "Hz": {"s": -1},
    "m": {"m": 1},
    "m/s": {"m": 1, "s": -1},
    "m/s2": {"m": 1, "s": -2},
    "m/s3": {"m": 1, "s": -3},
    "rad": {"rad": 1},
    "rad/s": {"rad": 1, "s": -1},
    "rad/s2": {"rad": 1, "s": -2},
    "rad/s3": {"rad": 1, "s": -3},
    "kg": {"kg": 1},
    "kg.m2": {"kg": 1, "m": 2},
    "N": {"kg": 1, "m": 1, "s": -2},
    "N.m": {"kg": 1, "m": 2, "s": -2},
    "N.m/rad": {"kg": 1, "m": 2, "s": -2, "rad": -1},
    "N.m.s/rad": {"kg": 1, "m": 2, "s": -1, "rad": -1},
    "N/m": {"kg": 1, "s": -2},
    "N.s/m": {"kg": 1, "s": -1},
    "m/N": {"kg": -1, "s": 2},
    "N2": {"kg": 2, "m": 2, "s": -4},
    "rad2": {"rad": 2},
    "m2": {"m": 2},
    "(m/s2)2": {"m": 2, "s": -4},
    "(rad/s)2": {"rad": 2, "s": -2},
    "(rad/s3)2": {"rad": 2, "s": -6},
    "m/s2/s": {"m": 1, "s": -3},
    "rad/s/s": {"rad": 1, "s": -2},
    "m/s2.s0.5": {"m": 1, "s": -1},  # noise density (m/s2)/sqrt(Hz); exponent rounded (FMI needs ints)
    "rad/s.s0.5": {"rad": 1},        # noise density (rad/s)/sqrt(Hz); exponent rounded
    "m/s2/s0.5": {"m": 1, "s": -2},  # random-walk intensity (m/s2)/sqrt(s); exponent rounded
    "rad/s/s0.5": {"rad": 1, "s": -1},  # random-walk intensity (rad/s)/sqrt(s); exponent rounded
    "rad/s0.5": {"rad": 1},          # random-walk intensity rad/sqrt(s); exponent rounded
    "N/s0.5": {"kg": 1, "m": 1, "s": -2},  # random-walk intensity N/sqrt(s); exponent rounded
}


def known_units() -> tuple[str, ...]:
    """The unit names an FMU may use."""
    return tuple(_UNITS)


#: The roles a component may declare (docs/fmu_annotation.md).
ROLES = ("plant", "environment", "sensor", "reference", "controller", "estimator", "log")
#: The vendor annotation's tool name and schema version (docs/fmu_annotation.md).
ANNOTATION_TOOL = "flexfusion"
ANNOTATION_VERSION = "1"


# attributes that are declarations, not state (see FlexFusionSlave._get_fmu_state)
_NOT_STATE = frozenset({"vars", "log_queue", "instance_name", "resources", "visible", "guid",
                        "_units", "_inputs", "_depends", "_arrays", "_output_vrs", "_host_log",
                        "_real_setters", "_input_slots", "_real_slots", "_read_plans", "_write_plans",
                        "_outputs", "_output_spans"})
_BOUND = "flexfusion.bound"   # deepcopy memo key: the live objects _Bound names stand for
_OUTPUT_CAPACITY = 512        # floats of a slave's output buffer (vector outputs beyond it: own arrays)
_NOMINAL: dict[float, float] = {}    # nominal_step's results: a run meets few distinct steps
_IDENTITIES: dict[type, dict[str, str]] = {}   # FlexFusionSlave._state_identity, by class


def nominal_step(h: float) -> float:
    """The communication step rounded to 12 significant digits.

    Hosts differ in the last bits of the step they pass: fmpy's ``simulate_fmu`` passes
    ``(n + 1) h - n h`` (0.03 - 0.02 = 0.009999999999999998), our master ``h``. A filter's
    discretisation (F, Q of the sample period) would carry those bits into its estimate, so
    every FMU steps with the nominal step instead (a relative change below 5e-13).
    """
    nominal = _NOMINAL.get(h)
    if nominal is None:
        nominal = float(f"{h:.12g}")
        if h and len(_NOMINAL) < 4096:     # not 0.0 == -0.0 (two results); bounded (NaN never hits)
            _NOMINAL[h] = nominal
    return nominal


def _attribute(name: str) -> str:
    """The expression of the slave's attribute ``name`` in :func:`_generated` code."""
    return f"slave.{name}" if name.isidentifier() and not keyword.iskeyword(name) else f"slave.__dict__[{name!r}]"


def _generated(name: str, arguments: str, body: list[str], env: dict[str, Any]) -> Any:
    """The function ``name(arguments)`` of the source lines ``body``, whose free names are the
    objects of ``env``: a host's list of value references read or written with one call of
    straight assignments (generated once per list, as :func:`collections.namedtuple` builds
    its methods; ``body`` holds only numbers, names of ``env`` and :func:`_attribute`)."""
    source = f"def {name}({arguments}):\n" + ("\n".join(body) or "    pass") + "\n"
    exec(compile(source, f"<fmi {name}>", "exec"), env)     # noqa: S102 - our own identifiers and numbers
    return env[name]


class _Bound:
    """In a saved FMU state, the slave (name "") or one of its vector variables' arrays, which
    the FMI getters and setters are bound to: restored as that live object, not as a copy."""

    def __init__(self, name: str) -> None:
        self.name = name

    def __deepcopy__(self, memo: dict) -> Any:
        return memo[_BOUND][self.name]


def _build_id() -> str:
    """The build of this package: the bundle id in an FMU's package name (``fmus_<12 hex>``,
    orchestration/build.py), else (the working tree) the first 12 hex of
    :func:`fmus.common.jit.bundle_id`, the same for the same sources. Not read from the
    package's ``BUNDLE_ID`` file: in the process that built the FMUs the package was imported
    from a staging folder that is gone."""
    package = __name__.partition(".")[0]
    suffix = package[len("fmus_"):]
    if package.startswith("fmus_") and len(suffix) == 12 and all(c in "0123456789abcdef" for c in suffix):
        return suffix
    from .jit import bundle_id
    return bundle_id()[:12]


def _like(new: Any, live: Any, path: str, depth: int) -> None:
    """Raise :class:`~fmus.common.state_codec.StateError` where a decoded state's value ``new``
    at ``path`` does not fit the value ``live`` an instance holds there: an array of another
    dtype or number of dimensions (not shape: buffers grow), or another class of object
    (recursively through objects, tuples and dicts of equal keys; a value absent on either
    side, or None, is not compared)."""
    if new is None or live is None or isinstance(new, _Bound) or depth > 50:
        return
    if isinstance(live, np.ndarray) or isinstance(new, np.ndarray):
        if not (type(new) is type(live) and new.dtype == live.dtype and new.ndim == live.ndim):
            def shown(a: Any) -> str:
                return f"{a.dtype} of {a.ndim} dimensions" if isinstance(a, np.ndarray) else f"a {type(a).__name__}"
            raise _state_codec.StateError(f"'{path}' is {shown(new)}, this instance holds {shown(live)}")
        return
    if type(new) is not type(live):
        if isinstance(new, (int, float)) and isinstance(live, (int, float)):
            return                                   # a number whose type changed as it was computed
        raise _state_codec.StateError(f"'{path}' is a {type(new).__name__}, this instance holds a "
                                      f"{type(live).__name__}")
    if isinstance(new, tuple) and len(new) == len(live):
        for i, (a, b) in enumerate(zip(new, live)):
            _like(a, b, f"{path}[{i}]", depth + 1)
    elif isinstance(new, dict):
        for k in new.keys() & live.keys():
            _like(new[k], live[k], f"{path}[{k!r}]", depth + 1)
    elif hasattr(new, "__dict__") and not isinstance(new, np.random.Generator):
        mine = vars(live)
        for k, v in vars(new).items():
            if k in mine:
                _like(v, mine[k], f"{path}.{k}", depth + 1)


_LOGGER = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p,
                           ctypes.c_char_p)


def _host_logger(handle: Any, instance_name: str) -> Any:
    """``log(status, category, message)`` straight to the host's ``fmi2CallbackLogger``, or None.

    ``handle`` is the ``logger`` the FMI layer gives the slave: a callable (a native layer may
    pass one), or pythonfmu 0.7's address of its ``Fmi2Logger``, whose layout (x86-64
    libstdc++: vtable, ``bool debugLogging_``, ``std::string instanceName_``,
    ``std::vector categories_``, ``const fmi2CallbackFunctions* f_``) is checked by finding
    this instance's name in it before its callback pointer is used.
    """
    if callable(handle):
        return handle
    if not isinstance(handle, int) or handle <= 0 or sys.platform != "linux" \
            or sys.maxsize < 2 ** 63 - 1:
        return None
    words = (ctypes.c_uint64 * 10).from_address(handle)
    name = instance_name.encode()
    if words[3] != len(name) or not words[2] or ctypes.string_at(words[2], len(name)) != name \
            or not words[9]:
        return None
    functions = (ctypes.c_void_p * 5).from_address(words[9])   # logger, alloc, free, stepFinished, env
    if not functions[0]:
        return None
    callback, environment = _LOGGER(functions[0]), functions[4]

    def log(status: int, category: str, message: str) -> None:
        # the message is a printf format for the host (FMI 2.0, fmi2CallbackLogger)
        callback(environment, name, status, category.encode(), message.replace("%", "%%").encode())
    return log


class FlexFusionSlave(Fmi2Slave):
    """Base class of every FlexFusion FMU (see the module docstring).

    Class attributes a subclass may set:

    ``parameters_class``
        The frozen parameter dataclass whose fields become FMI parameters.
    ``nan_inputs``
        ``"error"`` (default): a non-finite input ends the step with an FMI error naming it;
        ``"pass"``: the component handles non-finite inputs itself (and flags them).
    ``nan_outputs``
        ``"error"`` (default): reading a non-finite output is an FMI error naming it;
        ``"pass"``: allowed (a test toy standing for a third-party FMU that outputs NaN).
    ``role``
        What the component is for the orchestration (:data:`ROLES`; ``"estimator"`` by
        default): the honest-signals rule, the judge and the studies read it.
    ``batched``
        The name of the component's batched kernel in :mod:`orchestration.batched`, or None.

    The role, the batched kernel and the default search ranges of the tuner (``param(...,
    search=(low, high))`` of ``parameters_class``) go into the modelDescription as the vendor
    annotation ``<Tool name="flexfusion">`` (:meth:`self_description`, docs/fmu_annotation.md),
    which is what the orchestration reads, from our FMUs and a third party's alike.

    The constructor takes pythonfmu's ``kwargs`` (``instance_name``, ``resources``, ``logger``,
    ...), passes them on to :class:`pythonfmu.Fmi2Slave` and declares the parameters of
    ``parameters_class``.
    """

    parameters_class: type | None = None
    nan_inputs: str = "error"
    nan_outputs: str = "error"
    role: str = "estimator"
    batched: str | None = None
    author = "FlexFusion"
    license = "MIT"

    def __init_subclass__(cls, **kwargs: Any) -> None:
        """Keep one more reference to the defining script's module dictionary.

        pythonfmu 0.7's ``findClass`` (PySlaveInstance.cpp) re-executes the FMU script in its
        module's dictionary on every ``fmi2Instantiate`` and then ``Py_DECREF``s that dictionary,
        which it only borrowed: each instance drains one reference, and a thin script (no
        functions holding ``__globals__``) loses its dictionary at the first instance, so the
        second one fails or crashes. Defining the class runs this once per execution, before
        that decrement, and balances it. Our Linux library (native/) needs none of this, but
        the FMUs' Windows binary is still pythonfmu's (tests/test_fmi_hosting.py shows the
        defect with its Linux twin).
        """
        super().__init_subclass__(**kwargs)
        module = sys.modules.get(cls.__module__)
        if module is not None:
            _MODULE_DICTS.append(module.__dict__)

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self._units: dict[str, str] = {}
        self._inputs: list[str] = []          # attribute names of the inputs, in order
        self._depends: dict[str, tuple[str, ...]] = {}   # output variable name -> input attrs
        self._inputs_dirty = False
        self._stale = True        # the model is not built from the current parameters and inputs
        self._phase = "instantiated"   # -> "initialization" -> "stepping" -> "terminated"
        self._arrays: dict[str, np.ndarray] = {}   # every vector variable's array, by attribute
        self._output_vrs: set[int] = set()
        self._host_log = _host_logger(kwargs.get("logger"), self.instance_name)
        self._real_setters: dict | None = None   # value reference -> setter, built on first use
        # value reference of each Real scalar (of the inputs only: _input_slots) -> (the array
        # that holds it, index) or (None, attribute name)
        self._real_slots: dict[int, tuple[np.ndarray | None, int | str]] = {}
        self._input_slots: dict[int, tuple[np.ndarray | None, int | str]] = {}
        # a host reads and sets the same value references at every step: the reading (and
        # writing) of each list is generated once (_reader, _writer), keyed by the references
        self._read_plans: dict[tuple[int, ...], Any] = {}
        self._write_plans: dict[tuple[int, ...], Any] = {}     # the same for the inputs set
        # the vector outputs are consecutive views of one buffer, in declaration order: a host
        # reads them with one copy, an adapter may write several at once (output_span)
        self._outputs = np.zeros(_OUTPUT_CAPACITY)
        self._output_spans: dict[str, tuple[int, int]] = {}   # output name -> buffer positions
        self._inputs_unchecked = True   # an input may be non-finite: check each at the next step
        self._ready = False
        self._time = 0.0
        self._host_step = self._step = math.nan     # the step as the host gave it; as used
        self.params: Any = None
        if self.parameters_class is not None:
            self._declare_parameters(self.parameters_class())

    # ---- declarations -------------------------------------------------------------------
    def _register(self, var: Any, unit: str | None) -> None:
        if unit is not None:
            if unit not in _UNITS:
                raise ValueError(f"unit '{unit}' of '{var.name}' is not in fmus.common.fmi._UNITS")
            self._units[var.name] = unit
        self.register_variable(var, nested=False)

    def _declare_real_array(self, attr: str, size: int | None, causality: Fmi2Causality,
                            unit: str, description: str, start: float | Sequence[float],
                            variability: Fmi2Variability | None, initial: Fmi2Initial | None,
                            on_set: Any = None, after_set: Any = None) -> None:
        if size is None:
            setattr(self, attr, float(start))  # type: ignore[arg-type]

            def setter(v: float, attr: str = attr) -> None:
                if on_set:
                    on_set()          # first: a fixed parameter refuses the change
                setattr(self, attr, float(v))
                if after_set:
                    after_set()
            self._real_slots[len(self.vars)] = (None, attr)
            if causality == Fmi2Causality.output:
                self._output_vrs.add(len(self.vars))
            elif causality == Fmi2Causality.input:
                self._input_slots[len(self.vars)] = (None, attr)
            self._register(Real(attr, causality=causality, description=description,
                                variability=variability, initial=initial,
                                getter=lambda attr=attr: getattr(self, attr), setter=setter), unit)
            return
        first = max((b for _, b in self._output_spans.values()), default=0)
        if causality == Fmi2Causality.output and first + size <= len(self._outputs):
            values = self._outputs[first:first + size]
            values[:] = start
            self._output_spans[attr] = (first, first + size)
            base = self._outputs
        else:
            values = np.broadcast_to(np.asarray(start, dtype=float), (size,)).copy()
            base, first = values, 0
        setattr(self, attr, values)
        self._arrays[attr] = values
        # getters and setters bind the array itself (fast): assign vectors in place, never rebind
        for i in range(size):
            getter = partial(values.item, i)
            self._real_slots[len(self.vars)] = (base, first + i)
            if causality == Fmi2Causality.output:
                self._output_vrs.add(len(self.vars))
            elif causality == Fmi2Causality.input:
                self._input_slots[len(self.vars)] = (values, i)

            def setter(v: float, i: int = i) -> None:
                if on_set:
                    on_set()
                values[i] = v
                if after_set:
                    after_set()
            self._register(Real(f"{attr}[{i + 1}]", causality=causality,
                                description=f"{description} ({i + 1})", variability=variability,
                                initial=initial, getter=getter, setter=setter), unit)

    def input(self, name: str, size: int | None = None, *, unit: str, description: str,
              start: float | Sequence[float] = 0.0) -> None:
        """Declare a Real input ``name``; ``self.<name>`` holds a float (``size`` None) or an
        array of ``size`` elements, declared as ``name[1]`` ... ``name[size]``. ``unit`` must be
        in ``_UNITS``; ``description`` goes to the modelDescription; ``start`` is the start
        value (a scalar or one per element)."""
        self._inputs.append(name)
        self._declare_real_array(name, size, Fmi2Causality.input, unit, description, start,
                                 Fmi2Variability.continuous, None, on_set=self._mark_dirty)

    def output(self, name: str, size: int | None = None, *, unit: str, description: str,
               start: float | Sequence[float] = 0.0, depends_on: Iterable[str] = ()) -> None:
        """Declare a Real output ``name`` (a float, or ``size`` elements ``name[1]`` ...), with its
        ``unit`` (in ``_UNITS``), ``description`` and ``start`` value (valid until :meth:`setup`
        sets it); ``depends_on`` names the inputs with direct feedthrough (the
        ``<ModelStructure>`` dependencies)."""
        deps = tuple(depends_on)
        for d in deps:
            if d not in self._inputs:
                raise ValueError(f"output '{name}' depends on '{d}', which is not a declared input")
        names = [name] if size is None else [f"{name}[{i + 1}]" for i in range(size)]
        for n in names:
            self._depends[n] = deps
        self._declare_real_array(name, size, Fmi2Causality.output, unit, description, start,
                                 Fmi2Variability.continuous, Fmi2Initial.calculated)

    def output_span(self, first: str, last: str) -> slice:
        """The positions in ``self._outputs`` (the vector outputs' buffer) of the vector outputs
        declared from ``first`` to ``last``, for one assignment ``self._outputs[span] = ...``
        (the scalar outputs declared between them are not in the buffer)."""
        try:
            return slice(self._output_spans[first][0], self._output_spans[last][1])
        except KeyError as exc:
            raise ValueError(f"'{exc.args[0]}' is not a vector output in the output buffer") from None

    def _declare_parameters(self, defaults: Any) -> None:
        for f in _parameters.fields(defaults):
            value = getattr(defaults, f.name)
            meta = f.metadata
            desc = meta.get("description", "") or f.name
            if meta.get("source"):
                desc = f"{desc} [source: {meta['source']}]"
            variability = Fmi2Variability.tunable if meta.get("tunable") else Fmi2Variability.fixed
            kw = dict(causality=Fmi2Causality.parameter, variability=variability, description=desc)
            if isinstance(value, bool):
                setattr(self, f.name, value)
                self._register(Boolean(f.name, getter=lambda n=f.name: getattr(self, n),
                                       setter=partial(self._set_parameter, f.name, bool), **kw), None)
            elif isinstance(value, int):
                setattr(self, f.name, value)
                self._register(Integer(f.name, getter=lambda n=f.name: getattr(self, n),
                                       setter=partial(self._set_parameter, f.name, int), **kw), None)
            elif isinstance(value, str):
                setattr(self, f.name, value)
                self._register(String(f.name, getter=lambda n=f.name: getattr(self, n),
                                      setter=partial(self._set_parameter, f.name, str), **kw), None)
            else:
                size = len(value) if isinstance(value, tuple) else None
                self._declare_real_array(f.name, size, Fmi2Causality.parameter, meta.get("unit", "1"),
                                         desc, value, variability, Fmi2Initial.exact,
                                         on_set=partial(self._parameter_set, f.name),
                                         after_set=partial(self._retune, f.name))

    def _set_parameter(self, name: str, kind: type, value: Any) -> None:
        self._parameter_set(name)
        setattr(self, name, kind(value))
        self._retune(name)

    def _collect_parameters(self) -> Any:
        values = {}
        for f in _parameters.fields(self.parameters_class):
            v = getattr(self, f.name)
            values[f.name] = tuple(float(x) for x in v) if isinstance(v, np.ndarray) else v
        return _parameters.validate(self.parameters_class(**values))

    def _mark_dirty(self) -> None:
        self._inputs_dirty = True
        self._stale = True

    def _parameter_set(self, name: str) -> None:
        if self._phase in ("instantiated", "initialization"):
            self._stale = True
        elif not (self._phase == "stepping" and self._is_tunable(name)):
            msg = (f"{self.instance_name}: parameter '{name}' is fixed: it cannot change after "
                   "initialisation (FMI 2.0, variability \"fixed\")")
            self.log(msg, Fmi2Status.error)
            raise ValueError(msg)

    def _is_tunable(self, name: str) -> bool:
        return any(f.name == name and f.metadata.get("tunable")
                   for f in _parameters.fields(self.parameters_class))

    def _retune(self, name: str) -> None:
        """After a tunable parameter changed between steps: validate, then :meth:`tuned`; a bad
        value is refused (an FMI error naming it) and the old one kept."""
        if self._phase != "stepping":
            return                          # before initialisation ends: setup() reads it
        old = getattr(self.params, name)
        try:
            self.params = self._collect_parameters()
            self.tuned(name)
        except Exception as exc:  # noqa: BLE001 - every failure becomes an FMI error status
            if name in self._arrays:
                self._arrays[name][:] = old     # in place: the getters are bound to the array
            else:
                setattr(self, name, old)
            self.params = self._collect_parameters()
            self._fail(f"tunable parameter '{name}'", exc)
            raise

    # ---- what a subclass implements ------------------------------------------------------
    def setup(self, params: Any) -> None:
        """Build the model from ``params``, the validated instance of ``parameters_class``
        (None without one), and set the initial outputs."""

    def step(self, t: float, dt: float) -> None:
        """Advance from ``t`` to ``t + dt`` with the current inputs; update the outputs."""
        raise NotImplementedError

    def update_outputs(self) -> None:
        """Recompute outputs that depend directly on inputs (called after an input changed)."""

    def tuned(self, name: str) -> None:
        """A tunable parameter ``name`` changed between steps; ``self.params`` holds the new
        value. Nothing to do for a model that reads ``self.params`` at every step."""

    # ---- FMI life cycle ------------------------------------------------------------------
    def _fail(self, where: str, exc: BaseException) -> None:
        if isinstance(exc, (_parameters.ParameterError, ValueError, FloatingPointError)):
            msg = f"{self.instance_name}: {where}: {exc}"
        else:
            msg = f"{self.instance_name}: {where}: {type(exc).__name__}: {exc}\n{traceback.format_exc()}"
        self.log(msg, Fmi2Status.error)

    def log(self, msg: str, status: Fmi2Status = Fmi2Status.ok, category: str | None = None,
            debug: Any = None) -> None:
        """pythonfmu's log of ``msg`` with ``status``, ``category`` and ``debug``, except that
        errors always reach the host.

        pythonfmu 0.7 passes a message to the host's logger only while the host has debug
        logging on (and its category enabled). An error must be reported whatever the host's
        setting, as the Reference-FMUs do (their ``logError`` ignores ``loggingOn``): errors go
        straight to the host's ``fmi2CallbackLogger`` when we can reach it.
        """
        if self._host_log is not None and status in (Fmi2Status.error, Fmi2Status.fatal):
            self._host_log(status.value, category or f"logStatus{status.name.capitalize()}", msg)
        else:
            super().log(msg, status, category)

    def setup_experiment(self, start_time: float, stop_time: float | None, tolerance: float | None) -> None:
        """FMI ``fmi2SetupExperiment``: the time starts at ``start_time`` [s]; ``stop_time`` and
        ``tolerance`` are not used (fixed-step components)."""
        self._time = float(start_time)

    def enter_initialization_mode(self) -> None:
        """FMI ``fmi2EnterInitializationMode``: outputs read from now on build the model."""
        self._phase = "initialization"

    def _build(self) -> None:
        """Build the model from the current parameters and inputs (FMI 2.0, section 4.2.4: in
        Initialization Mode an output is valid as soon as what it depends on is set)."""
        try:
            self.params = self._collect_parameters() if self.parameters_class else None
            self.setup(self.params)
        except Exception as exc:  # noqa: BLE001 - every failure becomes an FMI error status
            self._ready = False
            self._fail("initialisation", exc)
            raise
        self._ready = True
        self._stale = False
        self._inputs_dirty = True

    def exit_initialization_mode(self) -> int | None:
        """FMI ``fmi2ExitInitializationMode``: validate the parameters and build the model with
        them and the inputs set (unless an output read already did), then step."""
        if self._stale or not self._ready:
            self._build()
        self._phase = "stepping"
        return None

    def _check_inputs(self, t: float) -> None:
        for name in self._inputs:
            v = getattr(self, name)
            if not np.all(np.isfinite(v)):
                raise FloatingPointError(f"input '{name}' is not finite ({v}) at t = {t:.6g} s")
        self._inputs_unchecked = False

    def do_step(self, current_time: float, step_size: float) -> bool:
        """FMI ``fmi2DoStep`` from ``current_time`` [s] over ``step_size`` [s] (> 0): check the
        inputs, call :meth:`step` with the step rounded by :func:`nominal_step`. A bad step size
        or state raises (an FMI error); a failed step logs the cause and returns False."""
        if not (step_size > 0.0 and math.isfinite(step_size) and math.isfinite(current_time)) \
                or self._phase != "stepping":
            msg = (f"{self.instance_name}: fmi2DoStep(t = {current_time!r}, h = {step_size!r}) "
                   + ("refused: the step size must be finite and > 0, the time finite"
                      if self._phase == "stepping" else f"called in the {self._phase} state"))
            self.log(msg, Fmi2Status.error)
            raise ValueError(msg)           # an FMI error status, not a Discard
        if step_size != self._host_step:
            self._host_step, self._step = step_size, nominal_step(step_size)
        try:
            if self._inputs_unchecked and self.nan_inputs == "error":
                self._check_inputs(current_time)
            self.step(current_time, self._step)
            self._inputs_dirty = False
            self._time = current_time + step_size
            return True
        except Exception as exc:  # noqa: BLE001
            self._fail(f"step at t = {current_time:.6g} s", exc)
            return False

    def get_real(self, vrs: list[int]) -> list[float]:
        """FMI ``fmi2GetReal`` of the value references ``vrs``: first the model (in
        Initialization Mode) or the direct-feedthrough outputs (:meth:`update_outputs`) brought
        up to date with the inputs set; a non-finite output is an FMI error naming it."""
        if self._stale and self._phase == "initialization":
            self._build()
        if self._inputs_dirty and self._ready:
            self._inputs_dirty = False
            try:
                self.update_outputs()
            except Exception as exc:  # noqa: BLE001
                self._fail(f"output update at t = {self._time:.6g} s", exc)
                raise
        key = tuple(vrs)
        read = self._read_plans.get(key)
        if read is None:
            try:
                read = self._reader(key)
            except KeyError:
                return super().get_real(vrs)     # pythonfmu's message for a non-Real reference
        values = read(self)
        total = sum(values)
        if total - total != 0.0 and self.nan_outputs == "error":   # NaN, inf, or an overflowed sum
            self._check_outputs(vrs, values)
        return values

    def _reader(self, vrs: tuple[int, ...]) -> Any:
        """The reading of the value references ``vrs`` (each a key of ``_real_slots``, else
        KeyError): ``read(slave)`` returns their values as a list of floats, with one ``tolist``
        of the span each array holds them in (the vector outputs: of the output buffer) and
        the scalars' attributes. Kept in ``_read_plans``."""
        arrays: dict[int, list] = {}           # id -> [name, array, lowest, highest index]
        items = []
        for vr in vrs:
            array, index = self._real_slots[vr]
            if array is None:
                items.append(_attribute(index))
                continue
            a = arrays.setdefault(id(array), [f"a{len(arrays)}", array, index, index])
            a[2], a[3] = min(a[2], index), max(a[3], index)
            items.append((a, index))
        lines = [f"    l{name} = {name}[{lo}:{hi + 1}].tolist()" for name, _, lo, hi in arrays.values()]
        listed = [item if isinstance(item, str) else f"l{item[0][0]}[{item[1] - item[0][2]}]" for item in items]
        read = _generated("read", "slave", lines + [f"    return [{', '.join(listed)}]"],
                          {name: array for name, array, _, _ in arrays.values()})
        if len(self._read_plans) < 64:              # a host's few lists (bounded whatever the host does)
            self._read_plans[vrs] = read
        return read

    def _check_outputs(self, vrs: list[int], values: list[float]) -> None:
        bad = [(self.vars[vr].name, v) for vr, v in zip(vrs, values)
               if vr in self._output_vrs and not math.isfinite(v)]
        if bad:
            also = f" (also {', '.join(n for n, _ in bad[1:])})" if bad[1:] else ""
            msg = (f"{self.instance_name}: output '{bad[0][0]}' is not finite ({bad[0][1]}) at "
                   f"t = {self._time:.6g} s{also}")
            self.log(msg, Fmi2Status.error)
            raise FloatingPointError(msg)

    def terminate(self) -> None:
        """FMI ``fmi2Terminate``: no step after this."""
        self._phase = "terminated"

    # ---- FMU state: the complete internal state, restored bit-exactly ----------------------
    def _get_fmu_state(self) -> dict[str, Any]:
        """A deep copy of everything the slave holds but its declarations (model, filter
        covariances, particles, RNG states, integrators, inputs, outputs, parameters, mode).

        The vector variables' arrays are bound to the FMI getters and setters, so the copy
        refers to them by name and :meth:`_set_fmu_state` writes them in place."""
        memo: dict[Any, Any] = {id(a): _Bound(name) for name, a in self._arrays.items()}
        memo[id(self)] = _Bound("")
        attrs = {k: v for k, v in vars(self).items() if k not in _NOT_STATE}
        return {"arrays": {k: a.copy() for k, a in self._arrays.items()},
                "attrs": copy.deepcopy(attrs, memo)}

    def _set_fmu_state(self, state: dict[str, Any]) -> None:
        for name, values in state["arrays"].items():
            self._arrays[name][:] = values
        bound = dict(self._arrays, **{"": self})
        attrs = copy.deepcopy(state["attrs"], {_BOUND: bound})   # a fresh copy: restorable again
        for k in [k for k in vars(self) if k not in _NOT_STATE and k not in attrs]:
            delattr(self, k)                 # made after the state was saved
        for k, v in attrs.items():
            setattr(self, k, v)

    def _state_identity(self) -> dict[str, str]:
        """What a serialised state must carry to be read by this FMU: its model identifier and
        a hash of its build (:func:`_build_id`) and of its variables (reference, name, type,
        causality, variability). Not of the FMU script's file: a host process may hold two
        builds' scripts under one module name."""
        cls = type(self)
        identity = _IDENTITIES.get(cls)
        if identity is None:
            digest = hashlib.sha256(_build_id().encode())
            for vr, v in sorted(self.vars.items()):
                digest.update(f"\0{vr}:{v.name}:{type(v).__name__}:{v.causality}:{v.variability}".encode())
            identity = _IDENTITIES[cls] = {"model": cls.__name__, "build": digest.hexdigest()[:32]}
        return identity

    def _fmu_state_to_bytes(self, state: dict[str, Any]) -> bytes:
        """``fmi2SerializeFMUstate``: the bytes of ``state`` (:meth:`_get_fmu_state`'s) in the
        data-only format of :mod:`fmus.common.state_codec`, stamped with the FMU's identity."""
        return _state_codec.encode(state, self._state_identity(), bound=_Bound,
                                   script=type(self).__module__, forbidden=(Fmi2Slave,))

    def _fmu_state_from_bytes(self, data: bytes) -> dict[str, Any]:
        """``fmi2DeSerializeFMUstate``: the state in the bytes ``data``, if they are a state of
        this FMU's build that fits this instance; else an FMI error naming why (no code in
        ``data`` ever runs: :mod:`fmus.common.state_codec`)."""
        bound = dict(self._arrays, **{"": self})

        def live(name: str) -> _Bound:
            if name not in bound:
                raise KeyError(name)
            return _Bound(name)
        try:
            state = _state_codec.decode(bytes(data), self._state_identity(), bound=live,
                                        script=type(self).__module__, forbidden=(Fmi2Slave,))
            self._check_state(state)
        except _state_codec.StateError as exc:
            msg = f"{self.instance_name}: fmi2DeSerializeFMUstate: state refused: {exc}"
            self.log(msg, Fmi2Status.error)
            raise ValueError(msg) from None
        return state

    def _check_state(self, state: Any) -> None:
        """Refuse a decoded ``state`` that does not fit this instance: its vector variables'
        arrays (names, shapes), and, where this instance holds them already, the arrays (dtype,
        dimensions) and our objects (class) at the same place in its attributes (:func:`_like`)."""
        if not (isinstance(state, dict) and set(state) == {"arrays", "attrs"}
                and isinstance(state["arrays"], dict) and isinstance(state["attrs"], dict)):
            raise _state_codec.StateError("not an FMU state (arrays and attributes)")
        arrays = state["arrays"]
        if set(arrays) != set(self._arrays):
            raise _state_codec.StateError(f"vector variables {sorted(arrays)}, not {sorted(self._arrays)}")
        for name, a in arrays.items():
            if not (isinstance(a, np.ndarray) and a.shape == self._arrays[name].shape):
                raise _state_codec.StateError(f"variable '{name}': not an array of shape {self._arrays[name].shape}")
        attrs = state["attrs"]
        for k in attrs:
            if not isinstance(k, str) or k in _NOT_STATE:
                raise _state_codec.StateError(f"attribute {k!r} is not part of an FMU state")
        mine = vars(self)
        for k, v in attrs.items():
            if k in mine:
                _like(v, mine[k], k, 0)

    def set_real(self, vrs: list[int], values: list[float]) -> None:
        """FMI ``fmi2SetReal`` of ``values`` to the value references ``vrs``.

        Inputs straight into their arrays (the hot path: no setter per scalar), marked dirty
        once; one sum flags a non-finite value for the check at the next step. Anything else
        (parameters) goes through its variable's setter."""
        if not vrs:
            return
        key = tuple(vrs)
        write = self._write_plans.get(key)
        if write is None:
            write = self._writer(key)
            if write is None:
                self._set_each(vrs, values)
                return
        write(self, values)
        self._inputs_dirty = self._stale = True
        total = sum(values)
        if total - total != 0.0:        # NaN, inf, or an overflowed sum
            self._inputs_unchecked = True

    def _writer(self, vrs: tuple[int, ...]) -> Any:
        """The writing of values to the value references ``vrs`` if all are inputs (else None):
        ``write(slave, values)`` assigns each straight to its array element or (as a float)
        attribute. Kept in ``_write_plans``."""
        slots = self._input_slots
        if not all(vr in slots for vr in vrs):
            return None
        names: dict[int, str] = {}
        env, lines = {}, []
        for i, vr in enumerate(vrs):
            array, index = slots[vr]
            if array is None:
                lines.append(f"    {_attribute(index)} = float(values[{i}])")
            else:
                name = names.setdefault(id(array), f"a{len(names)}")
                env[name] = array
                lines.append(f"    {name}[{index}] = values[{i}]")
        write = _generated("write", "slave, values", lines, env)
        if len(self._write_plans) < 64:
            self._write_plans[vrs] = write
        return write

    def _set_each(self, vrs: list[int], values: list[float]) -> None:
        self._inputs_unchecked = True
        setters = self._real_setters
        if setters is None:
            setters = self._real_setters = {vr: var.setter for vr, var in self.vars.items()
                                            if isinstance(var, Real) and var.setter is not None}
        try:
            for vr, v in zip(vrs, values):
                setters[vr](v)
        except KeyError:
            super().set_real(vrs, values)

    # ---- modelDescription ----------------------------------------------------------------
    @classmethod
    def self_description(cls) -> dict[str, Any]:
        """What the FMU declares about itself: ``{"role": str, "batched": str | None,
        "search": {scalar name: (low, high)}}``, the search ranges of ``parameters_class``'s
        fields in declaration order (a vector's element by element, ``name[1]``, ...)."""
        if cls.role not in ROLES:
            raise ValueError(f"{cls.__name__}.role = {cls.role!r} is not one of {', '.join(ROLES)}")
        search: dict[str, tuple[float, float]] = {}
        if cls.parameters_class is not None:
            defaults = cls.parameters_class()
            for f in _parameters.fields(cls.parameters_class):
                bounds = f.metadata.get("search")
                if bounds is None:
                    continue
                value = getattr(defaults, f.name)
                names = ([f"{f.name}[{i + 1}]" for i in range(len(value))] if isinstance(value, tuple)
                         else [f.name])
                for n in names:
                    search[n] = bounds
        return {"role": cls.role, "batched": cls.batched, "search": search}

    def _vendor_annotation(self) -> Element:
        """``<VendorAnnotations><Tool name="flexfusion"><Component .../></Tool>`` of
        :meth:`self_description` (schema: docs/fmu_annotation.md)."""
        described = self.self_description()
        annotations = Element("VendorAnnotations")
        tool = SubElement(annotations, "Tool", name=ANNOTATION_TOOL)
        attrs = {"version": ANNOTATION_VERSION, "role": described["role"]}
        if described["batched"] is not None:
            attrs["batched"] = described["batched"]
        comp = SubElement(tool, "Component", attrs)
        for name, (low, high) in described["search"].items():
            SubElement(comp, "Tune", name=name, low=repr(low), high=repr(high))
        return annotations

    def to_xml(self, model_options: dict[str, str] = dict()) -> Element:  # noqa: B006 - pythonfmu's signature
        """pythonfmu's modelDescription (``model_options`` passed on) with what it lacks: FMU
        state support, units and ``<UnitDefinitions>``, fixed String parameters and each
        output's real direct-feedthrough dependencies and initial unknowns."""
        root = super().to_xml(model_options)
        cosim = root.find("CoSimulation")
        cosim.set("canGetAndSetFMUstate", "true")     # see _get_fmu_state
        cosim.set("canSerializeFMUstate", "true")
        used = set()
        index_of = {}
        for i, sv in enumerate(root.find("ModelVariables")):
            name = sv.get("name")
            index_of[name] = i + 1
            unit = self._units.get(name)
            real = sv.find("Real")
            if unit is not None and real is not None:
                real.set("unit", unit)
                used.add(unit)
            if sv.get("causality") == "parameter" and sv.find("String") is not None:
                sv.set("variability", "fixed")
        # UnitDefinitions go right after CoSimulation (FMI 2.0 schema order)
        units = Element("UnitDefinitions")
        for u in sorted(used):
            ue = SubElement(units, "Unit", name=u)
            SubElement(ue, "BaseUnit", {k: str(v) for k, v in _UNITS[u].items()})
        position = list(root).index(root.find("CoSimulation")) + 1
        root.insert(position, units)
        # VendorAnnotations go right before ModelVariables (FMI 2.0 schema order)
        if root.find("VendorAnnotations") is not None:
            raise ValueError("pythonfmu wrote VendorAnnotations: merge ours into them")
        root.insert(list(root).index(root.find("ModelVariables")), self._vendor_annotation())
        # real direct-feedthrough dependencies of every output
        input_indices: dict[str, list[int]] = {}
        for attr in self._inputs:
            input_indices[attr] = [idx for n, idx in index_of.items()
                                   if n == attr or n.startswith(attr + "[")]
        outputs = root.find("ModelStructure/Outputs")
        if outputs is not None:
            for unknown in outputs:
                name = root.find("ModelVariables")[int(unknown.get("index")) - 1].get("name")
                deps = sorted(i for attr in self._depends.get(name, ()) for i in input_indices[attr])
                unknown.set("dependencies", " ".join(str(i) for i in deps))
                if deps:
                    unknown.set("dependenciesKind", " ".join("dependent" for _ in deps))
            # outputs are initial="calculated", so each is an initial unknown; no `dependencies`
            # attribute = it may depend on every parameter and input in Initialization Mode
            # (true: setup() may read any of them, e.g. a sensor's first sample)
            initial = SubElement(root.find("ModelStructure"), "InitialUnknowns")
            for unknown in outputs:
                SubElement(initial, "Unknown", index=unknown.get("index"))
        return root


__all__ = ["ANNOTATION_TOOL", "ANNOTATION_VERSION", "FlexFusionSlave", "ROLES", "known_units", "nominal_step"]

"""The thin FMI adapter every FlexFusion FMU derives from.

pythonfmu (0.7) knows scalar variables without units, and declares every output as depending on
every input. This base class adds what our FMUs all need, once:

* vector variables as 1-based indexed scalars (``q_a[1]``, ``q_a[2]``) backed by numpy arrays;
* a unit and a description on every variable, and the ``<UnitDefinitions>`` they refer to;
* the real direct-feedthrough dependencies of each output in ``<ModelStructure>``, which the
  master algorithm uses to order the components;
* parameters declared from a parameter dataclass (:mod:`fmus.common.parameters`) and validated
  when initialisation ends, so a bad value is rejected with an FMI error naming the parameter
  instead of crashing the host;
* outputs with direct feedthrough recomputed lazily when an input was set;
* every exception turned into an FMI error status with one clear log message.

Subclasses implement :meth:`FlexFusionSlave.setup` (build the model from validated parameters),
:meth:`FlexFusionSlave.step` (advance one communication step) and, if an output depends
directly on an input, :meth:`FlexFusionSlave.update_outputs`.
"""
from __future__ import annotations

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


class FlexFusionSlave(Fmi2Slave):
    """Base class of every FlexFusion FMU (see the module docstring).

    Class attributes a subclass may set:

    ``parameters_class``
        The frozen parameter dataclass whose fields become FMI parameters.
    ``nan_inputs``
        ``"error"`` (default): a non-finite input ends the step with an FMI error naming it;
        ``"pass"``: the component handles non-finite inputs itself (and flags them).
    """

    parameters_class: type | None = None
    nan_inputs: str = "error"
    author = "FlexFusion"
    license = "MIT"

    def __init_subclass__(cls, **kwargs: Any) -> None:
        """Keep one more reference to the defining script's module dictionary.

        pythonfmu 0.7's ``findClass`` (PySlaveInstance.cpp) re-executes the FMU script in its
        module's dictionary on every ``fmi2Instantiate`` and then ``Py_DECREF``s that dictionary,
        which it only borrowed: each instance drains one reference, and a thin script (no
        functions holding ``__globals__``) loses its dictionary at the first instance, so the
        second one fails or crashes. Defining the class runs this once per execution, before
        that decrement, and balances it.
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
        self._real_getters: dict | None = None   # value reference -> getter, built on first use
        self._real_setters: dict | None = None
        self._ready = False
        self._time = 0.0
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
                            on_set: Any = None) -> None:
        if size is None:
            setattr(self, attr, float(start))  # type: ignore[arg-type]

            def setter(v: float, attr: str = attr) -> None:
                setattr(self, attr, float(v))
                if on_set:
                    on_set()
            self._register(Real(attr, causality=causality, description=description,
                                variability=variability, initial=initial,
                                getter=lambda attr=attr: getattr(self, attr), setter=setter), unit)
            return
        values = np.broadcast_to(np.asarray(start, dtype=float), (size,)).copy()
        setattr(self, attr, values)
        # getters and setters bind the array itself (fast): assign vectors in place, never rebind
        for i in range(size):
            getter = partial(values.item, i)

            def setter(v: float, i: int = i) -> None:
                values[i] = v
                if on_set:
                    on_set()
            self._register(Real(f"{attr}[{i + 1}]", causality=causality,
                                description=f"{description} ({i + 1})", variability=variability,
                                initial=initial, getter=getter, setter=setter), unit)

    def input(self, name: str, size: int | None = None, *, unit: str, description: str,
              start: float | Sequence[float] = 0.0) -> None:
        """Declare a Real input; ``self.<name>`` holds a float (size None) or an array."""
        self._inputs.append(name)
        self._declare_real_array(name, size, Fmi2Causality.input, unit, description, start,
                                 Fmi2Variability.continuous, None, on_set=self._mark_dirty)

    def output(self, name: str, size: int | None = None, *, unit: str, description: str,
               start: float | Sequence[float] = 0.0, depends_on: Iterable[str] = ()) -> None:
        """Declare a Real output; ``depends_on`` names the inputs with direct feedthrough."""
        deps = tuple(depends_on)
        for d in deps:
            if d not in self._inputs:
                raise ValueError(f"output '{name}' depends on '{d}', which is not a declared input")
        names = [name] if size is None else [f"{name}[{i + 1}]" for i in range(size)]
        for n in names:
            self._depends[n] = deps
        self._declare_real_array(name, size, Fmi2Causality.output, unit, description, start,
                                 Fmi2Variability.continuous, Fmi2Initial.exact)

    def _declare_parameters(self, defaults: Any) -> None:
        for f in _parameters.fields(defaults):
            value = getattr(defaults, f.name)
            meta = f.metadata
            desc = meta.get("description", "") or f.name
            if meta.get("source"):
                desc = f"{desc} [source: {meta['source']}]"
            kw = dict(causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed,
                      description=desc)
            if isinstance(value, bool):
                setattr(self, f.name, value)
                self._register(Boolean(f.name, getter=lambda n=f.name: getattr(self, n),
                                       setter=lambda v, n=f.name: setattr(self, n, bool(v)), **kw), None)
            elif isinstance(value, int):
                setattr(self, f.name, value)
                self._register(Integer(f.name, getter=lambda n=f.name: getattr(self, n),
                                       setter=lambda v, n=f.name: setattr(self, n, int(v)), **kw), None)
            elif isinstance(value, str):
                setattr(self, f.name, value)
                self._register(String(f.name, getter=lambda n=f.name: getattr(self, n),
                                      setter=lambda v, n=f.name: setattr(self, n, str(v)), **kw), None)
            else:
                size = len(value) if isinstance(value, tuple) else None
                self._declare_real_array(f.name, size, Fmi2Causality.parameter, meta.get("unit", "1"),
                                         desc, value, Fmi2Variability.fixed, Fmi2Initial.exact)

    def _collect_parameters(self) -> Any:
        values = {}
        for f in _parameters.fields(self.parameters_class):
            v = getattr(self, f.name)
            values[f.name] = tuple(float(x) for x in v) if isinstance(v, np.ndarray) else v
        return _parameters.validate(self.parameters_class(**values))

    def _mark_dirty(self) -> None:
        self._inputs_dirty = True

    # ---- what a subclass implements ------------------------------------------------------
    def setup(self, params: Any) -> None:
        """Build the model from validated parameters and set the initial outputs."""

    def step(self, t: float, dt: float) -> None:
        """Advance from ``t`` to ``t + dt`` with the current inputs; update the outputs."""
        raise NotImplementedError

    def update_outputs(self) -> None:
        """Recompute outputs that depend directly on inputs (called after an input changed)."""

    # ---- FMI life cycle ------------------------------------------------------------------
    def _fail(self, where: str, exc: BaseException) -> None:
        if isinstance(exc, (_parameters.ParameterError, ValueError, FloatingPointError)):
            msg = f"{self.instance_name}: {where}: {exc}"
        else:
            msg = f"{self.instance_name}: {where}: {type(exc).__name__}: {exc}\n{traceback.format_exc()}"
        self.log(msg, Fmi2Status.error)

    def setup_experiment(self, start_time: float, stop_time: float | None, tolerance: float | None) -> None:
        self._time = float(start_time)

    def exit_initialization_mode(self) -> int | None:
        try:
            self.params = self._collect_parameters() if self.parameters_class else None
            self.setup(self.params)
            self._ready = True
            self._inputs_dirty = True
        except Exception as exc:  # noqa: BLE001 - every failure becomes an FMI error status
            self._fail("initialisation", exc)
            raise
        return None

    def _check_inputs(self, t: float) -> None:
        for name in self._inputs:
            v = getattr(self, name)
            # fast path: a sum of finite numbers is finite (but for overflow, checked below)
            if not math.isfinite(float(v) if isinstance(v, float) else float(v.sum())) \
                    and not np.all(np.isfinite(v)):
                raise FloatingPointError(f"input '{name}' is not finite ({v}) at t = {t:.6g} s")

    def do_step(self, current_time: float, step_size: float) -> bool:
        try:
            if self.nan_inputs == "error":
                self._check_inputs(current_time)
            self.step(current_time, step_size)
            self._inputs_dirty = False
            self._time = current_time + step_size
            return True
        except Exception as exc:  # noqa: BLE001
            self._fail(f"step at t = {current_time:.6g} s", exc)
            return False

    def get_real(self, vrs: list[int]) -> list[float]:
        if self._inputs_dirty and self._ready:
            self._inputs_dirty = False
            try:
                self.update_outputs()
            except Exception as exc:  # noqa: BLE001
                self._fail(f"output update at t = {self._time:.6g} s", exc)
                raise
        getters = self._real_getters
        if getters is None:
            getters = self._real_getters = {vr: var.getter for vr, var in self.vars.items()
                                            if isinstance(var, Real)}
        try:
            return [getters[vr]() for vr in vrs]    # floats or numpy float64 (a float)
        except KeyError:
            return super().get_real(vrs)     # pythonfmu's message for a non-Real reference

    def set_real(self, vrs: list[int], values: list[float]) -> None:
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
    def to_xml(self, model_options: dict[str, str] = dict()) -> Element:  # noqa: B006 - pythonfmu's signature
        root = super().to_xml(model_options)
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
        return root


__all__ = ["FlexFusionSlave", "known_units"]

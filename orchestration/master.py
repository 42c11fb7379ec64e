"""The co-simulation master algorithm on fmpy's ``FMU2Slave``.

* The schedule (:class:`orchestration.schedule.Schedule`, computed once from the scenario):
  fixed base step ``h``, multi-rate (a component of step ``k h`` is stepped every ``k`` base
  steps and its outputs held in between; no step past the stop time), Gauss–Seidel order with
  cycles broken at one edge (Jacobi; an undeclared one gives a :class:`CouplingWarning` naming
  it once; an algebraic loop is rejected), initialisation in that order with one more pass
  when an edge is broken. The master follows it with the FMUs; so does the batched study
  engine (:mod:`orchestration.batched`) with its kernels.
* Each FMU's folder (its extraction, shared by every process of the user) comes from the FMU
  store, :mod:`orchestration.fmu_store`; the master tells it when a run begins and ends.
* Per component and step: one batched ``fmi2SetReal`` of all connected inputs and one batched
  ``fmi2GetReal`` of all needed outputs, straight from/to one shared value buffer (ctypes arrays
  and numpy views, value references precomputed), through the library's raw functions.
* The stepping loop runs in C (``orchestration/cosim_loop.c``, :mod:`orchestration.cloop`), in
  chunks of at most 100 base steps; between chunks Python sinks the recorded rows, saves a
  fork's state, checks for a signal and reports progress. :func:`_python_steps` is the same
  loop in Python, the reference, run where there is no C compiler or with
  ``FLEXFUSION_PYTHON_LOOP=1``: the results are the same, bit for bit.
* A NaN on a connection, or an FMU status error/discard/fatal, stops the run with a
  :class:`RunError` naming the component, the variable and the time (with the FMU's own log).
  The NaN check runs once per base step; a consumer that fails on a NaN input before it is
  reported by the producer's NaN. Instances are always terminated and freed.
* Inside :func:`stop_on_signals`, SIGINT and SIGTERM stop the stepping loop at its next check
  (every 100 base steps at most, between FMU calls, never inside one) with
  :class:`Interrupted`.
"""
from __future__ import annotations

import ctypes
import signal
import sys
import tempfile
import threading
import time
import warnings
from contextlib import contextmanager
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterator

import numpy as np

from .scenario import Component, Overrides, Scenario, ScenarioError, check_metric_windows
from .schedule import Schedule

if TYPE_CHECKING:
    from .results import Result


class RunError(RuntimeError):
    """A run failed (FMU error, NaN on a connection); the message names component and time."""

    def __init__(self, message: str, time: float | None = None, component: str | None = None) -> None:
        super().__init__(message)
        self.time = time
        self.component = component


class CouplingWarning(UserWarning):
    """A connection of a cycle uses the producer's previous value (Jacobi)."""


class Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM stopped a run (inside :func:`stop_on_signals`) at simulated time ``time``."""

    def __init__(self, signum: int, time: float) -> None:
        self.signum, self.time = signum, time
        super().__init__(f"interrupted by {signal.Signals(signum).name} at t = {time:.6g} s")


_STOP = [0]   # the signal that asked the running simulation to stop (0: none)


@contextmanager
def stop_on_signals() -> Iterator[None]:
    """While active (in the main thread), SIGINT and SIGTERM do not raise where they land (that
    could be inside an FMU's Python code, which would turn them into an FMU error) but ask the
    stepping loop to stop with :class:`Interrupted` at its next check; a second signal raises
    KeyboardInterrupt at once (for a run stuck before its first step). The previous handlers
    are restored on exit."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def request_stop(signum: int, frame: Any) -> None:
        if _STOP[0]:
            raise KeyboardInterrupt
        _STOP[0] = signum

    previous = {s: signal.signal(s, request_stop) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        _STOP[0] = 0


# ---------------------------------------------------------------------------------------------
# instances
# ---------------------------------------------------------------------------------------------
_STATUS = ["ok", "warning", "discard", "error", "fatal", "pending"]


class _Instance:
    """One FMU2Slave (or, for an FMI 3.0 FMU, FMU3Slave) instance with its log, buffers and raw
    FMI function pointers."""

    def __init__(self, comp: Component, unzip_dir: str) -> None:
        from fmpy import calloc, free
        from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                               fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)
        self.comp = comp
        self.name = comp.name
        self.log: list[str] = []
        self.fmi3 = comp.fmi_version.startswith("3")

        def logger(env: Any, instance: bytes, status: int, category: bytes, message: bytes) -> None:
            text = message.decode(errors="replace") if message else ""
            label = _STATUS[status] if 0 <= status < len(_STATUS) else str(status)
            self.log.append(f"[{label}] {text}")

        self.instantiated = False
        self.initialized = False
        if self.fmi3:
            self._init_fmi3(comp, unzip_dir, logger)
            return
        cb = fmi2CallbackFunctions()
        cb.logger = fmi2CallbackLoggerTYPE(logger)
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        self._callbacks = cb
        self._logger = logger
        self.fmu = FMU2Slave(guid=comp.guid, unzipDirectory=unzip_dir,
                             modelIdentifier=comp.model_identifier, instanceName=comp.name)
        self.fmu.instantiate(callbacks=cb, loggingOn=True)
        self.instantiated = True
        # The stepping loop's FMI functions: fresh pointers into the library (``CDLL[name]``),
        # without fmpy's per-call logging and status exceptions and without ctypes argument
        # conversion (no argtypes: every argument is passed as a ctypes object), returning the
        # status as an int. Measured: 0.28 us per call instead of 0.55 us through argtypes.
        dll = self.fmu.dll
        self.c_set, self.c_get, self.c_step = (dll[f] for f in ("fmi2SetReal", "fmi2GetReal", "fmi2DoStep"))
        self.handle = ctypes.c_void_p(self.fmu.component)
        self.set_reals, self.get_reals = self.fmu.fmi2SetReal, self.fmu.fmi2GetReal
        self._calls(self.fmu.getReal, self.fmu.setReal, self.fmu.setInteger, self.fmu.getFMUstate,
                    self.fmu.setFMUstate, self.fmu.freeFMUstate, self.fmu.serializeFMUstate,
                    self.fmu.deSerializeFMUstate)

    def _calls(self, get_real: Callable[..., Any], set_real: Callable[..., Any], set_integer: Callable[..., Any],
               *state: Callable[..., Any]) -> None:
        """fmpy's calls of the instance's FMI version, by one name: ``get_real(vrs)``,
        ``setters[type](vrs, values)`` (the scenario's type names), and the FMU state's
        ``get_state()``, ``set_state(s)``, ``free_state(s)``, ``serialize_state(s)``,
        ``deserialize_state(bytes)`` (orchestration/fork.py)."""
        self.get_real = get_real
        self.setters = {"Real": set_real, "Integer": set_integer, "Enumeration": set_integer,
                        "Boolean": self.fmu.setBoolean, "String": self.fmu.setString}
        (self.get_state, self.set_state, self.free_state, self.serialize_state,
         self.deserialize_state) = state

    def _init_fmi3(self, comp: Component, unzip_dir: str, logger: Callable[..., None]) -> None:
        """An FMI 3.0 instance (fmpy's ``FMU3Slave``): ``c_set``, ``c_get`` and ``c_step`` are
        the raw ``fmi3SetFloat64``, ``fmi3GetFloat64`` and ``fmi3DoStep`` behind the FMI 2.0
        signatures the Python stepping loop calls (scalars: as many values as references; the
        step's event, termination, early-return and time results are not read). The C loop
        calls FMI 2.0 functions only: a run with an FMI 3.0 FMU steps in Python (_stepper)."""
        from fmpy.fmi3 import FMU3Slave

        def log_message(env: Any, status: int, category: bytes, message: bytes) -> None:
            logger(env, b"", status, category, message)
        self._logger = log_message
        self.fmu = FMU3Slave(guid=comp.guid, unzipDirectory=unzip_dir,
                             modelIdentifier=comp.model_identifier, instanceName=comp.name)
        self.fmu.instantiate(loggingOn=True, logMessage=log_message)
        self.instantiated = True
        dll = self.fmu.dll
        raw_set, raw_get, raw_step = (dll[f] for f in ("fmi3SetFloat64", "fmi3GetFloat64", "fmi3DoStep"))
        flags = [ctypes.byref(ctypes.c_bool()) for _ in range(3)]
        last = ctypes.byref(ctypes.c_double())
        self.c_set = lambda h, vr, n, values: raw_set(h, vr, n, values, n)
        self.c_get = lambda h, vr, n, values: raw_get(h, vr, n, values, n)
        self.c_step = lambda h, t, dt, no_set_prior: raw_step(h, t, dt, no_set_prior, *flags, last)
        self.handle = ctypes.c_void_p(self.fmu.component)
        fmu = self.fmu
        self.set_reals = lambda h, vr, n, values: fmu.fmi3SetFloat64(h, vr, n, values, n)
        self.get_reals = lambda h, vr, n, values: fmu.fmi3GetFloat64(h, vr, n, values, n)
        self._calls(fmu.getFloat64, fmu.setFloat64, fmu.setInt32, fmu.getFMUState, fmu.setFMUState,
                    fmu.freeFMUState, fmu.serializeFMUState, fmu.deserializeFMUState)

    def enter_initialization(self, stop_time: float) -> None:
        """Set up the experiment from t = 0 to ``stop_time`` and enter Initialization Mode."""
        if self.fmi3:
            self.fmu.enterInitializationMode(startTime=0.0, stopTime=stop_time)
        else:
            self.fmu.setupExperiment(startTime=0.0, stopTime=stop_time)
            self.fmu.enterInitializationMode()
        self.initialized = True

    def log_text(self, last: int = 5) -> str:
        """The FMU's last log messages on one line."""
        lines = [" ".join(line.split()) for line in self.log if line.strip()]
        if not lines:
            return "(the FMU logged nothing)"
        return " | ".join(lines[-last:])

    def close(self) -> None:
        try:
            if self.instantiated:
                try:
                    if self.initialized:
                        self.fmu.terminate()
                except Exception:  # noqa: BLE001 - terminate after an error may fail too
                    pass
                self.fmu.freeInstance()
                self.instantiated = False
        except Exception:  # noqa: BLE001
            pass


def _set_parameters(inst: _Instance) -> None:
    by_type: dict[str, tuple[list[int], list[Any]]] = {}
    for name, value in inst.comp.parameters.items():
        info = inst.comp.variables[name]
        vrs, vals = by_type.setdefault(info.type, ([], []))
        vrs.append(info.value_reference)
        vals.append(value)
    for t, (vrs, vals) in by_type.items():
        if t in inst.setters:
            inst.setters[t](vrs, [str(v) for v in vals] if t == "String" else vals)


# ---------------------------------------------------------------------------------------------
# the run
# ---------------------------------------------------------------------------------------------
Sink = Callable[[float, np.ndarray], None]


@dataclass(slots=True)
class _Slot:
    """Precomputed per-component data of the stepping loop: the arguments of its FMI calls as
    ctypes objects (the raw functions of :class:`_Instance` take no argtypes)."""
    inst: _Instance
    step: ctypes.c_double
    n_in: ctypes.c_size_t     # false when there is no input (a ctypes number is false at 0)
    in_vr: Any
    in_buf: Any
    in_view: np.ndarray
    in_idx: np.ndarray
    n_out: ctypes.c_size_t
    out_vr: Any
    out_ptr: Any
    out_start: int
    n_check: int             # the first n_check outputs are connected: checked for NaN
    out_names: list[str]


class _Buffer:
    """The schedule's buffer of every output read (:attr:`Schedule.offsets
    <orchestration.schedule.Schedule.offsets>`) as one ctypes array ``values_c`` and its numpy
    view ``values``; ``record_idx`` the recorded columns' slots."""

    def __init__(self, schedule: Schedule, record_columns: list[str]) -> None:
        self.schedule = schedule
        self.values_c = (ctypes.c_double * (schedule.size + 1))()   # + 1: a component reading nothing points at the end
        self.values = np.ctypeslib.as_array(self.values_c)
        self.values[:] = 0.0
        self.record_idx = np.array([schedule.offsets[tuple(col.split(".", 1))] for col in record_columns],
                                   dtype=np.intp)

    def slot(self, i: int, inst: _Instance) -> _Slot:
        """The stepping loop's data of component ``i`` of the schedule's order, instance
        ``inst``: its input and output value references and buffers (its outputs written
        straight into ``values``)."""
        sch, n = self.schedule, inst.name
        comp = inst.comp
        ins, reads = sch.inputs[n], sch.reads[n]
        in_vr = (ctypes.c_uint * max(len(ins), 1))(*[comp.variables[d].value_reference for d, _, _ in ins])
        in_buf = (ctypes.c_double * max(len(ins), 1))()
        out_vr = (ctypes.c_uint * max(len(reads), 1))(*[comp.variables[v].value_reference for v in reads])
        out_ptr = (ctypes.c_double * max(len(reads), 1)).from_buffer(self.values_c, 8 * sch.starts[n])
        return _Slot(inst, ctypes.c_double(sch.step[i]), ctypes.c_size_t(len(ins)), in_vr, in_buf,
                     np.ctypeslib.as_array(in_buf), np.array(sch.gathers[i], dtype=np.intp),
                     ctypes.c_size_t(len(reads)), out_vr, out_ptr, sch.starts[n], sch.connected[n], reads)


def _instantiate(comp: Component) -> _Instance:
    """An instance of the component's FMU (its folder from :func:`orchestration.fmu_store.folder`),
    or a :class:`RunError` saying why there is none. A cached folder whose library does not
    load is set aside and extracted again, once (:func:`orchestration.fmu_store.set_aside`);
    if it still fails, the error names the folder and ``flexfusion cache clear``."""
    from fmpy.fmi1 import FMICallException

    from . import fmu_store

    n = comp.name
    for repaired in (False, True):
        try:
            where = fmu_store.folder(comp.fmu)
        except Exception as exc:  # noqa: BLE001 - not an FMU, beyond the archive limits
            raise RunError(f"component '{n}' ({comp.fmu.name}): cannot extract the FMU: {exc}", 0.0, n) from None
        try:
            inst = _Instance(comp, where)
            break
        except FMICallException as exc:
            raise RunError(f"component '{n}' ({comp.fmu.name}): instantiate failed: {exc}", 0.0, n) from None
        except Exception as exc:  # noqa: BLE001 - a library that does not load
            if not repaired and fmu_store.set_aside(where):
                continue
            again = (f" from the cache entry {where}, extracted again (`flexfusion cache clear` removes the "
                     "cache's unused entries)") if repaired else ""
            raise RunError(f"component '{n}' ({comp.fmu.name}): cannot load the FMU{again}: "
                           f"{type(exc).__name__}: {exc}", 0.0, n) from None
    if not inst.handle.value:
        raise RunError(f"component '{n}' ({comp.fmu.name}): fmi2Instantiate failed; FMU log: "
                       + inst.log_text(), 0.0, n)
    return inst


def _exchange_initial_values(s: _Slot, values: np.ndarray, leave_initialisation: bool) -> None:
    """Set the slot's inputs from ``values``, leave initialisation mode if asked, and read its
    outputs into ``values`` (checked for NaN)."""
    if s.n_in:
        values.take(s.in_idx, out=s.in_view)
        s.inst.set_reals(s.inst.handle, s.in_vr, s.n_in, s.in_buf)
    if leave_initialisation:
        s.inst.fmu.exitInitializationMode()
    if s.n_out:
        s.inst.get_reals(s.inst.handle, s.out_vr, s.n_out, s.out_ptr)
        _check_nan([s], values, 0.0)


def simulate(scenario: Scenario, sink: Sink, progress: Callable[[int], None] | None = None,
             hook: Any = None, schedule: Schedule | None = None) -> list[str]:
    """Run the scenario; ``sink(t, values)`` gets every recorded row (values in
    ``scenario.record_columns()`` order, t = 0 first). Returns the coupling warnings given.

    ``hook`` (:mod:`orchestration.fork`) may save the whole state at its base step
    (``hook.step``) or, after initialisation, set a saved one and return the base step to go
    on from: ``hook.start(instances, values, offsets)`` and ``hook.save(k, ...)``.
    ``schedule``: the scenario's :class:`~orchestration.schedule.Schedule` if the caller has
    it already (else computed here).

    Raises
    ------
    ScenarioError
        Algebraic loop.
    RunError
        An FMU failed (instantiate, initialise, doStep) or produced NaN on a connection.
    """
    from fmpy.fmi1 import FMICallException

    from . import fmu_store

    schedule = Schedule.of(scenario) if schedule is None else schedule
    notes = list(schedule.notes)
    for msg in notes:
        warnings.warn(msg, CouplingWarning, stacklevel=2)

    buffer = _Buffer(schedule, scenario.record_columns())
    values = buffer.values

    instances: list[_Instance] = []
    h = scenario.base_step
    t_now = 0.0
    current: _Instance | None = None
    fmu_store.run_began()
    try:
        # ---- instantiate, parameters -----------------------------------------------------
        for n in schedule.order:
            current = None
            inst = _instantiate(scenario.components[n])
            instances.append(inst)
            current = inst
            inst.enter_initialization(scenario.stop_time)
            _set_parameters(inst)

        by_name = {i.name: i for i in instances}
        slots = [buffer.slot(i, inst) for i, inst in enumerate(instances)]

        # ---- initialisation (the schedule's passes) --------------------------------------
        def exchange(i: int, leave: bool) -> None:
            nonlocal current
            current = slots[i].inst
            _exchange_initial_values(slots[i], values, leave)
        schedule.initialise(exchange)
        current = None
        k0 = hook.start(by_name, values, schedule.offsets) if hook is not None else 0
        record_idx = buffer.record_idx
        sink(round(k0 * h, 12), values[record_idx])

        # ---- stepping --------------------------------------------------------------------
        # In chunks of at most ``tick`` base steps, ending at the hook's save step: the C loop
        # (orchestration/cosim_loop.c) or its reference, _python_steps, runs a chunk into a row
        # buffer; between chunks the rows go to the sink (before an error is raised, so nothing
        # computed is lost), then the hook's save, the signal check and the progress.
        n_steps = scenario.n_steps
        every = scenario.record_every
        tick = max(1, min(n_steps // 200, 100))
        save_at = getattr(hook, "step", None)
        steps = _stepper(slots, buffer, every, h)
        k = k0
        while k < n_steps:
            end = min(n_steps, (k // tick + 1) * tick, save_at if save_at is not None and save_at > k else n_steps)
            rows = np.empty((end - k, 1 + len(record_idx)))
            n_rows, stopped = steps(k, end, rows)
            for row in rows[:n_rows]:
                sink(round(float(row[0]), 12), row[1:])
            if stopped is not None:
                k, i, function, status = stopped
                t_now = k * h
                # a NaN (i None) raises here; so does one handed to a failing FMU, the cause
                _check_nan(slots, values, (k + 1) * h)
                _fail(slots[i].inst, function, status, t_now)
            k = end
            t_now = (k - 1) * h
            if k == save_at:
                hook.save(k, by_name, values, schedule.offsets)
            if k % tick == 0:
                if _STOP[0]:
                    raise Interrupted(_STOP[0], round(k * h, 12))
                if progress is not None:
                    progress(k)
        if progress is not None:
            progress(n_steps)
        t_now = scenario.stop_time
    except FMICallException as exc:
        if current is not None:
            raise RunError(f"component '{current.name}' failed at t = {t_now:.6g} s: {str(exc).rstrip('.')}; FMU log: "
                           + current.log_text(), t_now, current.name) from None
        raise RunError(f"FMI call failed at t = {t_now:.6g} s: {exc}", t_now) from None
    finally:
        for inst in reversed(instances):
            inst.close()
        fmu_store.run_ended()
    return notes


def _fail(inst: _Instance, function: str, status: int, t: float) -> None:
    label = _STATUS[status] if 0 <= status < len(_STATUS) else str(status)
    raise RunError(f"component '{inst.name}' failed at t = {t:.6g} s: {function} returned "
                   f"{label}; FMU log: {inst.log_text()}", t, inst.name)


def _nan_outputs(slots: list[_Slot], values: np.ndarray) -> tuple[_Slot, list[str]] | None:
    """The first of ``slots`` with a NaN on a connected output and those outputs' names, or None
    (a NaN on an output that is only recorded is not an error)."""
    for s in slots:
        chk = values[s.out_start:s.out_start + s.n_check]
        bad = [s.out_names[i] for i in np.flatnonzero(np.isnan(chk))]
        if bad:
            return s, bad
    return None


def _check_nan(slots: list[_Slot], values: np.ndarray, t: float) -> None:
    """A :class:`RunError` naming the first of ``slots`` with a NaN on a connected output, if any."""
    found = _nan_outputs(slots, values)
    if found:
        s, bad = found
        raise RunError(f"NaN on a connection: component '{s.inst.name}' output "
                       f"'{bad[0]}' is NaN at t = {t:.6g} s"
                       + (f" (also {', '.join(bad[1:])})" if len(bad) > 1 else ""), t, s.inst.name)


# ---------------------------------------------------------------------------------------------
# the stepping loop: in C (orchestration/cosim_loop.c), and here in Python, its reference
# ---------------------------------------------------------------------------------------------
_Stopped = tuple[int, "int | None", str, int]   # base step, slot index (None: a NaN), function, status


def _stepper(slots: list[_Slot], buffer: _Buffer, every: int,
             h: float) -> Callable[[int, int, np.ndarray], tuple[int, _Stopped | None]]:
    """``steps(k0, k1, rows)``: run base steps ``k0 .. k1-1`` of the buffer's schedule, write the
    recorded rows (t, then the recorded values) into ``rows`` and return how many, and where it
    stopped early (an FMU status above warning, a NaN on a connection) or None. The C loop
    (:mod:`orchestration.cloop`), or where there is none or an FMU is FMI 3.0,
    :func:`_python_steps`."""
    from . import cloop
    lib = cloop.library()
    if lib is None or any(s.inst.fmi3 for s in slots):     # the C loop calls FMI 2.0 functions
        return partial(_python_steps, slots, buffer.schedule, buffer.values, buffer.record_idx, every, h)
    return cloop.CLoop(lib, slots, buffer.schedule, buffer.values_c, buffer.record_idx, every, h)


def _python_steps(slots: list[_Slot], schedule: Schedule, values: np.ndarray, record_idx: np.ndarray,
                  every: int, h: float, k0: int, k1: int, rows: np.ndarray) -> tuple[int, _Stopped | None]:
    """The stepping loop in Python, line by line as ``cosim_steps`` in cosim_loop.c (keep them
    alike): per base step, each component the schedule has due (``schedule.due_at(k)``, slot
    indices in Gauss–Seidel order) gets one fmi2SetReal, fmi2DoStep and fmi2GetReal through the
    raw function pointers, straight from/to ``values``; then one NaN check (the dot product of
    ``values`` with itself is NaN if and only if a value is) and, every ``every`` base steps, a
    row."""
    t_c = ctypes.c_double()          # the communication point of every doStep of a base step
    true = ctypes.c_int(1)           # noSetFMUStatePriorToCurrentPoint
    take, dot = values.take, values.dot
    due_at = schedule.due_at
    n_rows = 0
    for k in range(k0, k1):
        t_c.value = k * h
        for i in due_at(k):
            s = slots[i]
            inst = s.inst
            if s.n_in:
                take(s.in_idx, out=s.in_view)
                st = inst.c_set(inst.handle, s.in_vr, s.n_in, s.in_buf)
                if st > 1:
                    return n_rows, (k, i, "fmi2SetReal", st)
            st = inst.c_step(inst.handle, t_c, s.step, true)
            if st > 1:
                return n_rows, (k, i, "fmi2DoStep", st)
            if s.n_out:
                st = inst.c_get(inst.handle, s.out_vr, s.n_out, s.out_ptr)
                if st > 1:
                    return n_rows, (k, i, "fmi2GetReal", st)
        d = dot(values)
        if d != d and _nan_outputs(slots, values):
            return n_rows, (k, None, "NaN", 0)
        if (k + 1) % every == 0:
            rows[n_rows, 0] = (k + 1) * h
            take(record_idx, out=rows[n_rows, 1:])
            n_rows += 1
    return n_rows, None


# ---------------------------------------------------------------------------------------------
# the one run path: a loaded scenario into a Result, in memory and, given a folder, on disk
# ---------------------------------------------------------------------------------------------
def run(scenario: str | Path | Scenario | dict[str, Any], overrides: Overrides = (),
        out_dir: str | Path | None = None, progress: bool = False, force: bool = False,
        hook: Any = None) -> "Result":
    """Run a scenario and write its results.

    Parameters
    ----------
    scenario
        A scenario file, a parsed TOML document, or a loaded :class:`Scenario`.
    overrides
        ``comp.param=value``, ``comp.param[i]=value``, ``scenario.seed=3`` ... strings, or a
        mapping ``{("ekf", "stiffness_scale"): 0.5}`` (:func:`~orchestration.scenario.override_strings`).
    out_dir
        Folder for ``results.csv``, ``metrics.json``, ``run.json`` (created, and owned by this
        run: :func:`orchestration.results.own_folder`); default: a new temporary folder.
    progress
        Show a tqdm progress bar on stderr.
    force
        Replace an earlier run's results in ``out_dir`` (else they are refused).
    hook
        Save the state at a time, or start from a saved one (:mod:`orchestration.fork`).

    Returns
    -------
    Result
        Time, recorded variables (``result["plant.p_tool"]`` -> (n, 2)) and metrics.

    Raises
    ------
    ScenarioError
        The scenario is wrong (nothing is written).
    OutputError
        The folder is another run's, holds earlier results, or cannot be written (a full disk:
        the rows written before stay, whole).
    RunError
        The run failed.
    Interrupted, KeyboardInterrupt
        The run was stopped.

    After a failure or an interruption ``results.csv`` holds every row up to it and
    ``run.json`` the status (``failed`` / ``interrupted``), the cause and the time reached; the
    exception's ``out_dir`` is the folder.
    """
    from .results import OutputError, own_folder
    from .scenario import override_strings

    overrides = override_strings(overrides)
    sc = load(scenario, overrides)
    schedule = Schedule.of(sc)  # rejects an algebraic loop before anything is written
    check_metric_windows(sc)
    if _STOP[0]:      # a signal while the scenario was loading: stop before writing anything
        raise Interrupted(_STOP[0], 0.0)
    out = Path(out_dir) if out_dir is not None else Path(tempfile.mkdtemp(prefix=f"flexfusion_{sc.name}_"))
    with own_folder(out, force):
        try:
            return run_loaded(sc, RunFolder(out, sc, overrides), progress, hook, schedule)
        except (RunError, OutputError, KeyboardInterrupt) as exc:
            exc.out_dir = out  # type: ignore[union-attr]
            raise


def load(scenario: str | Path | Scenario | dict[str, Any], overrides: Overrides = ()) -> Scenario:
    """The scenario to run: a file or a document loaded with the overrides, or a loaded
    :class:`Scenario` (loaded again from its file with its overrides and these, if any).

    Raises
    ------
    ScenarioError
        The scenario is wrong; overrides of a scenario that was not loaded from a file.
    """
    from .scenario import load_scenario, override_strings

    overrides = override_strings(overrides)
    if not isinstance(scenario, Scenario):
        return load_scenario(scenario, overrides)
    if not overrides:
        return scenario
    if not scenario.path:
        raise ScenarioError("overrides need a scenario loaded from a file or a document")
    return load_scenario(scenario.path, scenario.overrides + overrides)


def run_loaded(sc: Scenario, folder: RunFolder | None = None, progress: bool = False,
               hook: Any = None, schedule: Schedule | None = None) -> "Result":
    """Run a loaded scenario into a :class:`~orchestration.results.Result`: the one run path,
    of :func:`run` (into its run folder) and of the studies' :func:`orchestration.study.simulate`
    (in memory, ``folder`` None).

    The recorded rows are kept in memory and, with a ``folder``, written to its ``results.csv``
    as they come; the scenario's metrics are evaluated on them (:func:`evaluate_metrics`).
    Coupling warnings are issued for a run into a folder; in memory (a study runs a scenario
    many times) they are only on ``Result.warnings``.

    Parameters
    ----------
    sc
        The loaded scenario.
    folder
        The run folder that gets ``results.csv``, ``metrics.json`` and ``run.json``
        (:class:`RunFolder`); None: nothing is written.
    progress
        Show a tqdm progress bar on stderr.
    hook
        Save the state at a time, or start from a saved one (:mod:`orchestration.fork`).
    schedule
        The scenario's :class:`~orchestration.schedule.Schedule`, if the caller has it (else
        :func:`simulate` computes it).

    Returns
    -------
    Result
        The recorded signals and the metrics; ``out_dir`` the folder (None in memory),
        ``wall_time`` the seconds the stepping took (and the writing of the rows).

    Raises
    ------
    ScenarioError, RunError, OutputError, Interrupted, KeyboardInterrupt
        As :func:`run`; with a folder, its ``run.json`` says how the run ended first.
    """
    from contextlib import nullcontext

    t0 = time.perf_counter()
    recording = (folder.stepping(t0) if folder is not None
                 else nullcontext(_Recorder(capacity=_row_capacity(sc))))
    with recording as recorder, _progress_bar(sc, progress) as report:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", CouplingWarning)
            recorder.notes = simulate(sc, recorder, report, hook, schedule)
        for w in caught:  # re-issued once, outside the recording context
            if folder is not None or not issubclass(w.category, CouplingWarning):
                warnings.warn(w.message, w.category, stacklevel=3)
    wall = time.perf_counter() - t0
    result = recorder.result(sc.record_columns(), wall)
    result.units = sc.column_units()
    try:
        described = evaluate_metrics(sc, result)
        if folder is not None:
            folder.ok(described, wall)
    except BaseException as exc:
        if folder is not None:
            folder.failed_after_run(exc, wall)
        raise
    result.set_metrics(described)
    result.out_dir = folder.out if folder is not None else None
    return result


def _row_capacity(sc: Scenario) -> int:
    """The most rows a run of ``sc`` records: one every ``record_every`` base steps, and the
    start's."""
    return sc.n_steps // max(sc.record_every, 1) + 2


class _Recorder:
    """The sink of a run: every recorded row kept in memory and, with a ``writer``
    (:class:`~orchestration.results.CsvWriter`), written to disk as it comes; ``notes`` the
    run's coupling warnings once it has stepped to its end.

    The rows go into one array allocated for ``capacity`` rows at the first row (its pages are
    taken from the system only as rows fill them, so a run's memory grows by the recorded
    columns' own size, 8 bytes a value, and the result is a view of it, not a copy); past the
    capacity, or where so large an array cannot be reserved, it grows by doubling."""

    def __init__(self, writer: Sink | None = None, capacity: int = 1024) -> None:
        self.writer = writer
        self.capacity = max(int(capacity), 1)
        self.n = 0
        self._times = np.empty(0)
        self._data: np.ndarray | None = None
        self.notes: list[str] = []

    def __call__(self, t: float, values: np.ndarray) -> None:
        if self._data is None or self.n == len(self._times):
            self._grow(len(values))
        self._times[self.n] = t
        self._data[self.n] = values       # type: ignore[index]
        self.n += 1
        if self.writer is not None:
            self.writer(t, values)

    def _grow(self, width: int) -> None:
        size = self.capacity if self._data is None else 2 * len(self._times)
        try:
            times, data = np.empty(size), np.empty((size, width))
        except MemoryError:
            if self._data is not None or size <= 1024:
                raise
            size = 1024
            times, data = np.empty(size), np.empty((size, width))
        if self._data is not None:
            times[:self.n], data[:self.n] = self._times[:self.n], self._data[:self.n]
        self._times, self._data = times, data

    def result(self, columns: list[str], wall: float) -> "Result":
        from .results import Result
        data = self._data[:self.n] if self._data is not None else np.empty((0, len(columns)))
        return Result(None, self._times[:self.n], columns, data.reshape(self.n, len(columns)),
                      warnings=self.notes, wall_time=wall)


@contextmanager
def _progress_bar(sc: Scenario, shown: bool) -> Iterator[Callable[[int], None] | None]:
    """A tqdm bar on stderr over the run's base steps, moved by the callable given (None when
    not ``shown``)."""
    if not shown:
        yield None
        return
    from tqdm import tqdm
    bar = tqdm(total=sc.n_steps, unit="step", desc=sc.name, file=sys.stderr, leave=False)
    last = [0]

    def report(k: int) -> None:
        bar.update(k - last[0])
        last[0] = k
    try:
        yield report
    finally:
        bar.close()


class RunFolder:
    """The files of one run in its folder ``out`` (owned by
    :func:`orchestration.results.own_folder`): ``run.json`` says ``running`` first, then the
    true end; ``results.csv`` gets the rows as they come; ``metrics.json`` the metrics.
    ``run.json`` names the packages' versions from the run's end on (looking them up costs
    0.03-0.1 s, which the start of a run does not need)."""

    def __init__(self, out: Path, sc: Scenario, overrides: tuple[str, ...] = ()) -> None:
        self.out = Path(out)
        self.columns = sc.record_columns()
        self.stop_time = sc.stop_time
        self.info: dict[str, Any] = {"scenario": sc.describe(), "overrides": list(overrides or sc.overrides),
                                     "versions": None, "status": "running", "error": None,
                                     "rows": 0, "time_reached": None, "units": sc.column_units()}
        self.writer: Any = None
        self.recorder = _Recorder(capacity=_row_capacity(sc))
        self.t0 = 0.0                       # perf_counter() when the stepping began

    @contextmanager
    def stepping(self, t0: float) -> Iterator[_Recorder]:
        """``run.json`` says ``running``; the sink given records the rows and writes them to
        ``results.csv`` (:class:`~orchestration.results.CsvWriter`). If the stepping (begun at
        ``perf_counter()`` ``t0``) ends in an exception, ``run.json`` gets the true end with the
        rows computed before: ``failed`` (an OS error becomes
        :class:`~orchestration.results.OutputError`) or ``interrupted`` (KeyboardInterrupt)."""
        from .results import CSV_NAME, RUN_NAME, CsvWriter, OutputError, write_json
        self.t0 = t0
        try:
            write_json(self.out / RUN_NAME, self.info)
            self.writer = self.recorder.writer = CsvWriter(self.out / CSV_NAME, self.columns)
            yield self.recorder
            self.writer.close()
            self.info.update(rows=self.writer.rows, time_reached=self.writer.time_reached)
        except RunError as exc:
            self._finish("failed", str(exc))
            raise
        except OSError as exc:
            reached = self.writer.time_reached if self.writer is not None else None
            at = f" after t = {reached:.6g} s" if reached is not None else ""
            message = f"cannot write the results{at}: {exc.strerror or exc}"
            try:
                self._finish("failed", message)
            except OSError:
                message += f" ({RUN_NAME} could not be updated either)"
            raise OutputError(message + ("; the rows written before are kept, whole" if at else "")) from None
        except KeyboardInterrupt as exc:
            self._finish("interrupted", str(exc) or "KeyboardInterrupt")
            raise
        except BaseException as exc:
            self._finish("failed", f"{type(exc).__name__}: {exc}")
            raise

    def _ended(self, **info: Any) -> None:
        """The run's end into ``info``, with the versions."""
        from .results import versions
        self.info.update(info, versions=versions())

    def _finish(self, status: str, error: str) -> None:
        """Flush what was computed, then write the true status (whatever else fails)."""
        from .results import RUN_NAME, write_json
        if self.writer is not None:
            try:
                self.writer.close()
            except OSError:
                pass          # the rows of the failed block are cut off; the rest stays
            self.info.update(rows=self.writer.rows, time_reached=self.writer.time_reached)
        self._ended(status=status, error=error, wall_time_s=time.perf_counter() - self.t0,
                    warnings=self.recorder.notes)
        write_json(self.out / RUN_NAME, self.info)

    def ok(self, described: dict[str, dict[str, Any]], wall: float) -> None:
        """Write ``metrics.json``, then ``run.json`` with status ``ok``."""
        from .results import METRICS_NAME, RUN_NAME, write_json
        write_json(self.out / METRICS_NAME, described)
        self._ended(status="ok", wall_time_s=wall, real_time_factor=self.stop_time / wall if wall > 0 else None,
                    warnings=self.recorder.notes)
        write_json(self.out / RUN_NAME, self.info)

    def failed_after_run(self, exc: BaseException, wall: float) -> None:
        """``run.json`` says ``failed`` after the run (the metrics): an OS error is raised as
        :class:`~orchestration.results.OutputError`. If ``run.json`` cannot be written, it still
        says ``running``: :meth:`Result.load` reports that, never as ok."""
        from .results import RUN_NAME, OutputError, write_json
        self._ended(status="failed", error=f"after the run: {exc}", wall_time_s=wall,
                    warnings=self.recorder.notes)
        try:
            write_json(self.out / RUN_NAME, self.info)
        except OSError:
            pass
        if isinstance(exc, OSError):
            raise OutputError(f"cannot write the metrics after the run: {exc.strerror or exc}") from None


def evaluate_metrics(sc: Scenario, result: "Result") -> dict[str, dict[str, Any]]:
    """The scenario's metrics on a run's recorded signals, as ``metrics.json`` holds them:
    ``{name: {"value", "unit", "against", ...}}`` (:func:`orchestration.metrics.entries`).
    The one evaluation of a run's metrics (:func:`run_loaded`).

    Raises
    ------
    ScenarioError
        A metric that cannot be computed on these signals (e.g. no sample after ``after``).
    """
    from . import metrics as _metrics        # after the run: a failed run never needs it
    described: dict[str, dict[str, Any]] = {}
    for spec in sc.metrics:
        try:
            computed = _metrics.compute(spec, result.time, result[spec.estimate],
                                        result[spec.truth] if spec.truth else None,
                                        result[spec.truth_time] if spec.truth_time else None,
                                        result[spec.covariance] if spec.covariance else None)
        except ValueError as exc:
            raise ScenarioError(f"{sc.name}: metric '{spec.name}': {exc}") from None
        # NEES and NIS are squared errors normalised by their covariance: dimensionless ("1"),
        # whatever the unit of the estimate
        unit = "1" if spec.kind in ("nees", "nis") else metric_unit(sc, spec.estimate)
        described.update({k: {**e, "unit": unit} for k, e in _metrics.entries(spec, computed).items()})
    return described


def metric_unit(sc: Scenario, ref: str) -> str:
    """The unit of a recorded variable ``comp.var`` ("" when its FMU gives none)."""
    comp, var = (part.strip() for part in ref.split(".", 1))
    c = sc.components[comp]
    return c.variables[c.group(var)[0]].unit or ""


__all__ = ["RunError", "CouplingWarning", "Interrupted", "stop_on_signals", "metric_unit", "simulate", "run", "load",
           "run_loaded", "RunFolder", "evaluate_metrics"]

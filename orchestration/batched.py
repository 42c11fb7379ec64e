"""The batched study engine: many runs of one scenario (over seeds, and over parameter sets where
the structure allows) simulated together, vectorised over runs, without FMI.

The co-simulation's own schedule (:class:`orchestration.schedule.Schedule`, the one the master
follows): the Gauss–Seidel order and the broken cycle edges, which components step at each base
step (multi-rate, no step past the stop time), each one's inputs (set from the freshest outputs
before its step), the initialisation passes. Same math: every component is either

* **shared**: its parameters are the same in every run and so are its inputs (no per-run
  producer upstream): it is simulated once, by its own FMU class instantiated in this process
  (the FMU's Python code without the FMI layer); the noise-free closed loop of a study over
  noise seeds (controller and plant) is such a part; or
* **per run**: a batched kernel with a leading run axis (:data:`KERNELS`: the Encoder and Imu
  of :mod:`fmus.robot_plant.sensor_batched`, the EkfAccelerometer of
  :mod:`fmus.estimators.ekf_accelerometer_batched`), one kernel per group of runs whose
  parameters differ only in what the kernel takes per run (the sensors' seed, the EKF's
  ``q_jerk``); a per-run component without a kernel (e.g. the plant
  when noise enters the closed loop) runs as one in-process FMU class instance per run
  (correct, but a Python loop over the runs: :attr:`BatchResult.looped` names them).

:func:`simulate_runs` raises :class:`BatchError` when the runs differ in structure (another
component list, connection or step), so the caller falls back to the FMUs.

**Replay**: the shared part of a run can be kept as a :class:`Tape` (``BatchedRuns(...,
tape=True)``: every output its components handed on, in the order the schedule read them)
and replayed into later runs of the same scenario (``replay=tape``): a component whose
parameters and producers are those of the taped run then costs an array read per step. A
tuning study simulates the truth (plant, controller, sensors) of a seed once, and each
candidate estimator on its tape, in the same schedule.
"""
from __future__ import annotations

import importlib
import time as _time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from fmus.common.fmi import nominal_step

from .fmu_annotation import describe
from .master import RunError
from .scenario import Component, Scenario, load_scenario, scenario_document
from .schedule import Schedule


class BatchError(RuntimeError):
    """The runs cannot be simulated together (the message says why); use the FMUs."""


# ---------------------------------------------------------------------------------------------
# the FMU classes in this process
# ---------------------------------------------------------------------------------------------
_CLASSES: dict[str, type] = {}


def fmu_class(model_identifier: str) -> type:
    """The FMU class of a model identifier, from the working tree's ``fmus/*/*_fmu.py`` (the
    sources the FMUs are built from, :func:`orchestration.build.fmu_scripts`)."""
    if model_identifier not in _CLASSES:
        from .build import _CLASS, FMU_SOURCES, fmu_scripts
        for script in fmu_scripts():
            if model_identifier in _CLASS.findall(script.read_text()):
                rel = script.relative_to(FMU_SOURCES.parent).with_suffix("")
                module = importlib.import_module(".".join(rel.parts))
                _CLASSES[model_identifier] = getattr(module, model_identifier)
                break
        else:
            raise BatchError(f"no FMU script defines the class '{model_identifier}'")
    return _CLASSES[model_identifier]


class _Instance:
    """One component's FMU class instantiated here, parameters set, in Initialization Mode."""

    def __init__(self, comp: Component, stop_time: float) -> None:
        self.comp = comp
        self.slave = fmu_class(comp.model_identifier)(instance_name=comp.name)
        self.vr = {v.name: vr for vr, v in self.slave.vars.items()}
        self.slave.setup_experiment(0.0, stop_time, None)
        self.slave.enter_initialization_mode()
        setters = {"Real": self.slave.set_real, "Integer": self.slave.set_integer,
                   "Enumeration": self.slave.set_integer, "Boolean": self.slave.set_boolean,
                   "String": self.slave.set_string}
        for name, value in comp.parameters.items():
            setters[comp.variables[name].type]([self.vr[name]], [value])

    def start(self, name: str) -> float:
        """The value a variable has before anything is set (its start value)."""
        return float(self.slave.vars[self.vr[name]].getter())

    def parameters(self) -> Any:
        """The validated parameter set the FMU builds its model from."""
        return self.slave._collect_parameters()

    def fail(self, what: str, t: float) -> RunError:
        return RunError(f"component '{self.comp.name}' failed at t = {t:.6g} s: {what}", t, self.comp.name)


# ---------------------------------------------------------------------------------------------
# kernels: one component for b runs; inputs (n_in, b or 1) in, outputs (n_out, b) out
# ---------------------------------------------------------------------------------------------
class _Kernel:
    per_run_parameters: tuple[str, ...] = ()   # parameters that may differ between its runs

    def __init__(self, comps: Sequence[Component], inputs: list[str], outputs: list[str],
                 stop_time: float) -> None:
        self.runs = len(comps)
        self.input_names, self.output_names = inputs, outputs

    def set_inputs(self, values: np.ndarray) -> None:
        raise NotImplementedError

    def exit_init(self, t0: float) -> None:
        raise NotImplementedError

    def refresh(self, now: float) -> None:
        """An input was set without a step (the FMU's output update)."""

    def do_step(self, t: float, dt: float) -> None:
        raise NotImplementedError

    def outputs(self) -> np.ndarray:
        raise NotImplementedError


class _Slaves(_Kernel):
    """The component's FMU class, one instance per run (one for a shared component)."""

    def __init__(self, comps, inputs, outputs, stop_time) -> None:
        super().__init__(comps, inputs, outputs, stop_time)
        self.inst = [_Instance(c, stop_time) for c in comps]
        self.in_vr = [self.inst[0].vr[n] for n in inputs]
        self.out_vr = [self.inst[0].vr[n] for n in outputs]

    def set_inputs(self, values: np.ndarray) -> None:
        if not self.in_vr:
            return
        for j, i in enumerate(self.inst):
            i.slave.set_real(self.in_vr, values[:, j if values.shape[1] > 1 else 0].tolist())

    def exit_init(self, t0: float) -> None:
        for i in self.inst:
            try:
                i.slave.exit_initialization_mode()
            except Exception as exc:  # noqa: BLE001 - the FMU's own message
                raise i.fail(f"initialisation: {exc}", t0) from None

    def do_step(self, t: float, dt: float) -> None:
        for i in self.inst:
            if not i.slave.do_step(t, dt):
                raise i.fail("doStep failed: " + " | ".join(str(m) for m in i.slave.log_queue[-3:]), t)

    def outputs(self) -> np.ndarray:
        return np.array([i.slave.get_real(self.out_vr) for i in self.inst], dtype=float).T


class _Batched(_Kernel):
    """Base of the vectorised kernels: inputs by name (start values from the FMU class)."""

    def __init__(self, comps, inputs, outputs, stop_time) -> None:
        super().__init__(comps, inputs, outputs, stop_time)
        probe = _Instance(comps[0], stop_time)
        self.params = probe.parameters()
        self.seeds = [int(c.parameters.get("seed", 0)) for c in comps]
        names = [n for n, v in comps[0].variables.items() if v.causality == "input"]
        self.row = {n: i for i, n in enumerate(names)}
        self.values = np.array([[probe.start(n)] for n in names])      # (inputs, b or 1)
        self._connected = [self.row[n] for n in inputs]
        self._out = [(n.partition("[")[0], int(n.partition("[")[2][:-1]) - 1 if "[" in n else None)
                     for n in outputs]

    def run_parameters(self, comps, stop_time) -> list:
        """Each run's validated parameter set (one FMU class instance per distinct set)."""
        made: dict[tuple, Any] = {}
        out = []
        for c in comps:
            key = tuple(sorted(c.parameters.items()))
            if key not in made:
                made[key] = _Instance(c, stop_time).parameters()
            out.append(made[key])
        return out

    def set_inputs(self, values: np.ndarray) -> None:
        if values.shape[1] != self.values.shape[1]:
            keep = self.values
            self.values = np.empty((keep.shape[0], values.shape[1]))
            self.values[:] = keep
        self.values[self._connected] = values

    def vector(self, name: str, size: int) -> np.ndarray:
        """An input vector ``name[1..size]`` as ``(b or 1, size)``."""
        i = self.row[f"{name}[1]"]
        return self.values[i:i + size].T

    def scalar(self, name: str) -> np.ndarray:
        return self.values[self.row[name]]

    def time_input(self, name: str) -> float:
        """A time stamp input: one value for all runs."""
        v = self.values[self.row[name]]
        if v.shape[0] > 1 and np.any(v != v[0]):
            raise BatchError(f"input '{name}' differs between runs; the batched kernels share time stamps")
        return float(v[0])

    def pack(self, groups: dict[str, np.ndarray]) -> np.ndarray:
        """The requested output scalars from ``(b or 1, size)`` arrays per variable."""
        out = np.empty((len(self._out), self.runs))
        for k, (var, i) in enumerate(self._out):
            out[k] = groups[var][:, 0 if i is None else i]
        return out


class _Encoder(_Batched):
    per_run_parameters = ("seed",)

    def __init__(self, comps, inputs, outputs, stop_time) -> None:
        super().__init__(comps, inputs, outputs, stop_time)
        from fmus.robot_plant.sensor_batched import BatchedEncoder
        self.model = BatchedEncoder(self.params, self.seeds)

    def exit_init(self, t0: float) -> None:
        self.q = self.model.initial(self.vector("q_m", 2), t0, self.time_input("t_truth"))

    def do_step(self, t: float, dt: float) -> None:
        self.q = self.model.step(self.vector("q_m", 2), t, dt, self.time_input("t_truth"))

    def outputs(self) -> np.ndarray:
        return self.pack({"q_m_meas": self.q, "t_meas": np.array([[self.model.t_meas]])})


class _Imu(_Batched):
    per_run_parameters = ("seed",)

    def __init__(self, comps, inputs, outputs, stop_time) -> None:
        super().__init__(comps, inputs, outputs, stop_time)
        from fmus.robot_plant.sensor_batched import BatchedImu
        # the gyro has its own noise streams: without a reader it need not run
        self.model = BatchedImu(self.params, self.seeds, gyro=any(n.startswith("gyro_s") for n in outputs))

    def _inputs(self) -> tuple:
        return (self.vector("a_sensor", 2), self.scalar("phi_tool"), self.scalar("omega_tool"))

    def exit_init(self, t0: float) -> None:
        self.acc, self.gyro = self.model.initial(*self._inputs(), t0, self.time_input("t_truth"))

    def do_step(self, t: float, dt: float) -> None:
        self.acc, self.gyro = self.model.step(*self._inputs(), t, dt, self.time_input("t_truth"))

    def outputs(self) -> np.ndarray:
        return self.pack({"acc_s": self.acc, "gyro_s": self.gyro, "t_meas": np.array([[self.model.t_meas]])})


class _EkfAccelerometer(_Batched):
    per_run_parameters = ("q_jerk",)

    def __init__(self, comps, inputs, outputs, stop_time) -> None:
        super().__init__(comps, inputs, outputs, stop_time)
        from fmus.estimators.ekf_accelerometer_batched import BatchedEkfAccelerometer
        self.name = comps[0].name
        self.model = BatchedEkfAccelerometer(self.run_parameters(comps, stop_time), nominal_step(comps[0].step))
        self.wanted = sorted({n.partition("[")[0] for n in outputs})

    def _set(self) -> None:
        m = self.model
        m.q_m_meas, m.acc_s = self.vector("q_m_meas", 2), self.vector("acc_s", 3)
        m.dddq_a_ref, m.t_meas = self.vector("dddq_a_ref", 2), self.time_input("t_meas")

    def _guard(self, call, t: float) -> None:
        from fmus.estimators.ekf_accelerometer_model import FilterDivergence
        try:
            call()
        except FilterDivergence as exc:
            raise RunError(f"component '{self.name}' failed at t = {t:.6g} s: {exc}", t, self.name) from None

    def exit_init(self, t0: float) -> None:
        self._set()
        self._guard(lambda: self.model.initial(t0, self.runs), t0)

    def refresh(self, now: float) -> None:
        self._set()
        self._guard(lambda: self.model.refresh(now), now)

    def do_step(self, t: float, dt: float) -> None:
        self._set()
        self._guard(lambda: self.model.step(t, dt), t)

    def outputs(self) -> np.ndarray:
        return self.pack(self.model.outputs(self.wanted))


#: The vectorised kernels, by the name an FMU declares for its own (``batched`` of its class, in
#: its modelDescription's vendor annotation: :mod:`orchestration.fmu_annotation`).
KERNELS: dict[str, type[_Batched]] = {"Encoder": _Encoder, "Imu": _Imu, "EkfAccelerometer": _EkfAccelerometer}


def _kernel(comp: Component) -> type[_Batched] | None:
    """The batched kernel the component's FMU declares, or None."""
    name = describe(comp.fmu).batched
    if name is not None and name not in KERNELS:
        raise BatchError(f"component '{comp.name}' ({comp.model_identifier}) declares the batched kernel "
                         f"'{name}', which is not one of {', '.join(KERNELS)}")
    return None if name is None else KERNELS[name]


class _Groups(_Kernel):
    """A per-run component as one kernel per group of runs with the same parameters (but for
    the kernel's ``per_run_parameters``)."""

    def __init__(self, cls: type[_Batched], comps, inputs, outputs, stop_time) -> None:
        super().__init__(comps, inputs, outputs, stop_time)
        keys: dict[tuple, list[int]] = {}
        for r, c in enumerate(comps):
            key = tuple(sorted((k, v) for k, v in c.parameters.items() if k not in cls.per_run_parameters))
            keys.setdefault(key, []).append(r)
        self.groups = [(np.array(idx), cls([comps[r] for r in idx], inputs, outputs, stop_time))
                       for idx in keys.values()]
        self.single = len(self.groups) == 1

    def set_inputs(self, values: np.ndarray) -> None:
        for idx, k in self.groups:
            k.set_inputs(values if self.single or values.shape[1] == 1 else values[:, idx])

    def exit_init(self, t0: float) -> None:
        for _, k in self.groups:
            k.exit_init(t0)

    def refresh(self, now: float) -> None:
        for _, k in self.groups:
            k.refresh(now)

    def do_step(self, t: float, dt: float) -> None:
        dt = nominal_step(dt)                 # as FlexFusionSlave.do_step
        for _, k in self.groups:
            k.do_step(t, dt)

    def outputs(self) -> np.ndarray:
        if self.single:
            return self.groups[0][1].outputs()
        out = np.empty((len(self.output_names), self.runs))
        for idx, k in self.groups:
            out[:, idx] = k.outputs()
        return out


class _Taping(_Kernel):
    """A shared component's kernel that keeps every output it hands on (for a :class:`Tape`)."""

    def __init__(self, inner: _Kernel) -> None:
        self.inner, self.runs = inner, inner.runs
        self.reads: list[np.ndarray] = []

    def set_inputs(self, values: np.ndarray) -> None:
        self.inner.set_inputs(values)

    def exit_init(self, t0: float) -> None:
        self.inner.exit_init(t0)

    def refresh(self, now: float) -> None:
        self.inner.refresh(now)

    def do_step(self, t: float, dt: float) -> None:
        self.inner.do_step(t, dt)

    def outputs(self) -> np.ndarray:
        out = self.inner.outputs()
        self.reads.append(np.array(out, dtype=float))
        return out


class _Replay(_Kernel):
    """A shared component played back from a :class:`Tape`: its outputs in the order they were
    read (the schedule is the same, so the reads come in the same order); no inputs."""

    def __init__(self, name: str, reads: np.ndarray) -> None:
        self.name, self.reads, self.runs, self.k = name, reads, 1, 0

    def set_inputs(self, values: np.ndarray) -> None:
        pass

    def exit_init(self, t0: float) -> None:
        pass

    def do_step(self, t: float, dt: float) -> None:
        pass

    def outputs(self) -> np.ndarray:
        if self.k >= len(self.reads):
            raise BatchError(f"the tape of '{self.name}' ends after {len(self.reads)} reads: it was "
                             "recorded from a shorter run")
        self.k += 1
        return self.reads[self.k - 1]


@dataclass
class Tape:
    """The shared components of one simulated run, to be replayed (:class:`BatchedRuns`).

    ``reads[n]`` every output vector component ``n`` handed on, ``(reads, outputs, 1)`` in
    schedule order; ``parameters[n]`` and ``outputs[n]`` its parameters and the outputs read
    (a replay must have the same); ``shape`` the scenario's structure (steps, components,
    connections)."""

    reads: dict[str, np.ndarray]
    parameters: dict[str, dict[str, Any]]
    outputs: dict[str, list[str]]
    shape: tuple

    def replayable(self, sc: Scenario, shared: Sequence[str], needed: dict[str, list[str]],
                   inputs: dict[str, list[tuple[str, str, str]]]) -> list[str]:
        """The shared components of ``sc`` that can be played back: taped with the same
        parameters and outputs, and every producer (transitively) played back too."""
        if _shape(sc) != self.shape:
            raise BatchError("the tape was recorded from a scenario of another structure (components, "
                             "FMUs, steps or connections)")
        ok = {n for n in shared if n in self.reads and self.parameters[n] == sc.components[n].parameters
              and self.outputs[n] == needed[n]}
        changed = True
        while changed:
            before = len(ok)
            ok = {n for n in ok if all(src in ok for _, src, _ in inputs[n])}
            changed = len(ok) != before
        return [n for n in shared if n in ok]


# ---------------------------------------------------------------------------------------------
# the engine
# ---------------------------------------------------------------------------------------------
@dataclass
class BatchResult:
    """Recorded variables of all runs: ``values["plant.q_a"]`` is ``(b, rows, size)`` with
    ``b`` 1 for a shared component (the same in every run) and the number of runs otherwise;
    ``rows[var]`` the base-step indices recorded (row ``j`` is time ``j h``, 0 the initial
    values)."""

    time: np.ndarray
    values: dict[str, np.ndarray]
    rows: dict[str, np.ndarray]
    shared: list[str]               # components simulated once
    batched: list[str]              # components on a vectorised kernel
    looped: list[str]               # per-run components run instance by instance
    runs: int
    wall_time: float
    groups: dict[str, int] = field(default_factory=dict)   # kernel groups per batched component
    tape: Tape | None = None        # the shared components' outputs (BatchedRuns(tape=True))
    replayed: list[str] = field(default_factory=list)      # shared components played from a tape

    def __getitem__(self, var: str) -> np.ndarray:
        return self.values[var]


def _load_runs(scenario: str | dict, runs: Sequence[Sequence[str]]) -> list[Scenario]:
    """The scenario of each run; the file is read once per set of overrides besides the seed."""
    docs: dict[tuple[str, ...], dict] = {}
    out = []
    for overrides in runs:
        seed = tuple(o for o in overrides if o.replace(" ", "").startswith("scenario.seed="))
        rest = tuple(o for o in overrides if o not in seed)
        if rest not in docs:
            docs[rest] = scenario_document(scenario, rest)
        sc = load_scenario(docs[rest], seed)
        if not isinstance(scenario, dict):
            sc.path = Path(scenario)
        out.append(sc)
    return out


def _per_run(scenarios: Sequence[Scenario], inputs: dict[str, list[tuple[str, str, str]]]) -> set[str]:
    """Components that differ between runs: their parameters, or a producer's (transitively)."""
    sc0 = scenarios[0]
    varying = {n for n, c in sc0.components.items()
               if any(s.components[n].parameters != c.parameters for s in scenarios[1:])}
    changed = True
    while changed:
        changed = False
        for n, ins in inputs.items():
            if n not in varying and any(src in varying for _, src, _ in ins):
                varying.add(n)
                changed = True
    return varying


def _shape(s: Scenario) -> tuple:
    """What runs simulated together (or a tape and its replay) must share."""
    return (s.base_step, s.stop_time, tuple((n, c.model_identifier, c.ratio, str(c.fmu))
                                            for n, c in s.components.items()),
            tuple(c.text for c in s.connections))


def _check_structure(scenarios: Sequence[Scenario]) -> None:
    ref = _shape(scenarios[0])
    for r, s in enumerate(scenarios[1:], 1):
        if _shape(s) != ref:
            raise BatchError(f"run {r} has another structure (components, FMUs, steps or connections) "
                             "than run 0: its runs cannot be batched")


class BatchedRuns:
    """The runs of a scenario prepared to be simulated together (:meth:`run`); preparing
    loads every run's scenario and decides which components are shared, batched or looped, so
    a scenario the engine cannot run is refused before anything is simulated.

    Parameters
    ----------
    scenario
        A scenario file or parsed document (each run loads it with its overrides) or, for one
        run, a loaded Scenario.
    runs
        The overrides of each run (``scenario.seed=N``, ``comp.param=value`` ...).
    record
        ``"comp.var"`` -> the base-step indices to record (row ``j``: time ``j h``), or None
        for every row.
    no_loop
        Model identifiers that must not run instance by instance (a per-run component of one
        of them without a kernel is a :class:`BatchError`).
    tape
        Keep the shared components' outputs (:attr:`BatchResult.tape`, to replay them).
    replay
        A :class:`Tape` of a run of the same scenario: the shared components it can stand for
        (:meth:`Tape.replayable`) are played back instead of simulated.

    Raises
    ------
    BatchError
        Runs of different structure, or a component the engine cannot simulate.
    RunError
        (:meth:`run`) A component failed (a diverged filter), naming it and the time.
    """

    def __init__(self, scenario: str | Path | dict | Scenario, runs: Sequence[Sequence[str]],
                 record: dict[str, Any], no_loop: Sequence[str] = (), *, tape: bool = False,
                 replay: Tape | None = None) -> None:
        t_wall = _time.perf_counter()
        if isinstance(scenario, Scenario):
            scenarios = [scenario]
        else:
            scenarios = _load_runs(scenario if isinstance(scenario, dict) else str(scenario), runs)
        if not scenarios:
            raise BatchError("no runs")
        _check_structure(scenarios)
        sc = scenarios[0]
        R = len(scenarios)
        wanted: dict[str, list[str]] = {}
        for var in record:
            cname, v = var.split(".", 1)
            if cname not in sc.components:
                raise BatchError(f"unknown component '{cname}' in '{var}'")
            wanted[var] = sc.components[cname].group(v)
            if not wanted[var]:
                raise BatchError(f"component '{cname}' has no variable '{v}'")
        p = Schedule.of(sc, [f"{var.split('.', 1)[0]}.{s}" for var in record for s in wanted[var]])
        # which outputs each component hands on: connected first, then the recorded ones
        ins, needed = p.inputs, p.reads
        varying = _per_run(scenarios, ins)

        kernels: dict[str, _Kernel] = {}
        shared, batched, looped = [], [], []
        replayed = replay.replayable(sc, [n for n in p.order if n not in varying], needed, ins) if replay else []
        for n in p.order:
            in_names = [d for d, _, _ in ins[n]]
            comp = sc.components[n]
            if n in replayed:
                kernels[n] = _Replay(n, replay.reads[n])
                shared.append(n)
            elif n not in varying:
                kernels[n] = _Slaves([comp], in_names, needed[n], sc.stop_time)
                shared.append(n)
            elif _kernel(comp) is not None:
                kernels[n] = _Groups(_kernel(comp), [s.components[n] for s in scenarios],
                                     in_names, needed[n], sc.stop_time)
                batched.append(n)
            elif comp.model_identifier in no_loop:
                raise BatchError(f"component '{n}' ({comp.model_identifier}) differs between runs and has no "
                                 "batched kernel")
            else:
                kernels[n] = _Slaves([s.components[n] for s in scenarios], in_names, needed[n], sc.stop_time)
                looped.append(n)
        self.scenario, self.runs, self.schedule, self.inputs, self.varying = sc, R, p, ins, varying
        self.needed, self.wanted, self.kernels, self.record = needed, wanted, kernels, dict(record)
        self.shared, self.batched, self.looped = shared, batched, looped
        self.replayed = replayed
        if tape:
            for n in shared:
                if n not in replayed:
                    kernels[n] = _Taping(kernels[n])
        self._t0 = t_wall

    def run(self) -> BatchResult:
        """Simulate the runs (once: the kernels hold their state)."""
        t_wall, sc, R, p, ins, varying = self._t0, self.scenario, self.runs, self.schedule, self.inputs, self.varying
        needed, wanted, kernels, record = self.needed, self.wanted, self.kernels, self.record
        shared, batched, looped = self.shared, self.batched, self.looped
        out: dict[str, np.ndarray] = {n: np.zeros((len(needed[n]), 1)) for n in sc.components}
        index = {n: {s: i for i, s in enumerate(needed[n])} for n in sc.components}
        sources = {n: [] if n in self.replayed else [(src, index[src][s]) for _, src, s in ins[n]]
                   for n in sc.components}
        width = {n: (R if n in varying else 1) for n in sc.components}

        # each component's inputs: (inputs, 1) when all producers are shared, else (inputs, runs)
        buffers = {n: np.zeros((len(sources[n]), max([width[src] for src, _ in sources[n]], default=1)))
                   for n in sc.components}

        def gather(n: str) -> np.ndarray:
            buf = buffers[n]
            for r, (src, i) in enumerate(sources[n]):
                buf[r] = out[src][i]
            return buf

        n_steps = sc.n_steps
        masks: dict[str, np.ndarray] = {}
        for var, rows in record.items():
            m = np.zeros(n_steps + 1, dtype=bool)
            m[np.arange(n_steps + 1) if rows is None else np.asarray(rows, dtype=int)] = True
            masks[var] = m
        taken: dict[str, list[np.ndarray]] = {var: [] for var in record}
        rec_idx = {var: (var.split(".", 1)[0], [index[var.split(".", 1)[0]][s] for s in wanted[var]])
                   for var in record}

        def keep(j: int) -> None:
            for var, (cname, idx) in rec_idx.items():
                if masks[var][j]:
                    taken[var].append(out[cname][idx].T.copy())      # (b, size)

        # ---- initialisation: the schedule's passes
        def exchange(i: int, leave: bool) -> None:
            n = p.order[i]
            k = kernels[n]
            if sources[n]:
                k.set_inputs(gather(n))
                if not leave:
                    k.refresh(0.0)           # the FMU updates its outputs on a set input
            if leave:
                k.exit_init(0.0)
            if needed[n]:
                out[n] = k.outputs()
        p.initialise(exchange)
        keep(0)

        # ---- stepping: the schedule's rows of due components
        h = sc.base_step
        slots = [(n, kernels[n], p.step[i], bool(needed[n])) for i, n in enumerate(p.order)]
        stepping = [[slots[i] for i in row] for row in p.due]
        row = p.row
        for j in range(n_steps):
            t = j * h
            for n, k, dt, read in stepping[row(j)]:
                if sources[n]:
                    k.set_inputs(gather(n))
                k.do_step(t, dt)
                if read:
                    out[n] = k.outputs()
            keep(j + 1)

        values = {var: np.stack(rows, axis=1) if rows else np.zeros((width[rec_idx[var][0]], 0, len(wanted[var])))
                  for var, rows in taken.items()}
        return BatchResult(time=np.round(np.arange(n_steps + 1) * h, 12), values=values,
                           rows={var: np.flatnonzero(m) for var, m in masks.items()},
                           shared=shared, batched=batched, looped=looped, runs=R,
                           wall_time=_time.perf_counter() - t_wall,
                           groups={n: len(kernels[n].groups) for n in batched},
                           tape=self._tape(), replayed=list(self.replayed))

    def _tape(self) -> Tape | None:
        taped = {n: k for n, k in self.kernels.items() if isinstance(k, _Taping)}
        if not taped:
            return None
        sc = self.scenario
        return Tape(reads={n: np.array(k.reads).reshape(len(k.reads), len(self.needed[n]), 1)
                           for n, k in taped.items()},
                    parameters={n: dict(sc.components[n].parameters) for n in taped},
                    outputs={n: list(self.needed[n]) for n in taped}, shape=_shape(sc))


def simulate_runs(scenario: str | Path | dict | Scenario, runs: Sequence[Sequence[str]], record: dict[str, Any],
                  no_loop: Sequence[str] = (), *, tape: bool = False, replay: Tape | None = None) -> BatchResult:
    """Simulate the runs of a scenario together: ``BatchedRuns(...).run()``."""
    return BatchedRuns(scenario, runs, record, no_loop, tape=tape, replay=replay).run()


def not_ours(scenarios: Sequence[Scenario]) -> str | None:
    """Why the engine must not run ``scenarios``: components it would run with the wrong math,
    their FMU file not in our FMU folder (:func:`orchestration.scenario.fmu_dir`, where a model
    identifier is looked up), so someone else's FMU even if its model identifier is one of
    ours; None when every component is ours. A study then runs the FMUs and prints the reason."""
    from .scenario import fmu_dir
    ours = fmu_dir().resolve()
    foreign = list(dict.fromkeys(f"'{n}' ({c.model_identifier})" for sc in scenarios
                                 for n, c in sc.components.items() if c.fmu.resolve().parent != ours))
    if not foreign:
        return None
    return f"the batched engine knows only the math of our FMUs, and {', '.join(foreign)} is not one of them"


def run_recorded(scenario: str | Path | dict, runs: Sequence[Sequence[str]], variables: Sequence[str], *,
                 tape: bool = False, replay: Tape | None = None) -> tuple[list[dict[str, Any]], Tape | None]:
    """The runs together, each as the FMU path gives it (:func:`orchestration.study.simulate`
    with ``variables``): ``{"time", var: values at the recorded rows (every ``record_every``
    base steps from t = 0; a scalar 1-D, a vector (rows, size)), "wall_time": the engine's
    shared out over the runs}``; and the tape of the shared components (``tape=True``, else
    None). A job for a study's executor (module level: it pickles).

    Raises
    ------
    BatchError
        The engine cannot run these (use the FMUs).
    RunError
        A component failed, or a recorded value is not finite (where the master stops a run).
    """
    prepared = BatchedRuns(scenario, runs, {v: None for v in variables}, tape=tape, replay=replay)
    res = prepared.run()
    every = prepared.scenario.record_every
    time = res.time[::every]
    out = []
    for r in range(res.runs):
        run: dict[str, Any] = {"time": time, "wall_time": res.wall_time / res.runs}
        for var in variables:
            v = res.values[var]
            v = v[r if v.shape[0] > 1 else 0, ::every]
            scalar = prepared.wanted[var] == [var.split(".", 1)[1]]
            run[var] = v[:, 0].copy() if scalar else v.copy()
            if not np.all(np.isfinite(v)):
                t = float(time[np.flatnonzero(~np.all(np.isfinite(v.reshape(len(time), -1)), axis=1))[0]])
                raise RunError(f"run {r}: {var} is not finite at t = {t:.6g} s", t, var.split(".", 1)[0])
        out.append(run)
    return out, res.tape


__all__ = ["BatchError", "BatchResult", "BatchedRuns", "KERNELS", "Tape", "simulate_runs", "run_recorded", "not_ours",
           "fmu_class"]

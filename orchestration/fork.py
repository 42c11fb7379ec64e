"""Forking runs: save a whole co-simulation's state at a time and start runs from it.

A **state file** (JSON, ``format = "flexfusion-state-1"``) holds, at time ``T`` (a multiple of
the base step):

* every component's FMI state (``fmi2GetFMUstate`` + ``fmi2SerializeFMUstate``, base64): for
  our FMUs the complete internal state, bit-exact (models, filter covariances, particles, RNG
  states, held samples, inputs, outputs), as data only (:mod:`fmus.common.state_codec`: no
  pickle; an FMU refuses a state of another FMU or build, or a damaged or crafted one);
* the master's: the step index, and every value on its buffer (the connected and recorded
  outputs as last read, which multi-rate components hold and Jacobi edges read next); the
  master itself draws no random numbers;
* what the scenario's structure was (components with model identifier, GUID, step and
  parameters; connections; base step), to refuse a state for another system.

A run started from the state (:func:`resume`, ``flexfusion run SCENARIO --from-state F``)
instantiates and initialises every FMU as usual, then sets each one's saved state and the
master's, and steps on from ``T``: its ``results.csv`` rows from ``T`` on are bit-identical to
those of the uninterrupted run (tests/test_fork.py).

What a fork may change: FMI 2.0 lets a master change only **tunable** parameters after
initialisation (and ``fmi2SetFMUstate`` restores the parameters with everything else), so a
fork may override ``scenario.stop_time``, ``scenario.name``, the record and the metrics, and a
parameter whose variability is ``tunable`` (set after the state). Changing a fixed parameter,
a component, a connection or a step is refused with a :class:`ScenarioError`.

New noise in a fork (issue 17): a sensor's ``seed`` is fixed, but every sensor FMU (Encoder, Imu,
ForceTorqueSensor, Tracker) has the tunable ``reseed`` (:mod:`fmus.common.noise`): set in a fork,
it restarts the sensor's noise streams at the state's time from that seed, while everything else
(plant, filters, held samples, bias walks) continues the saved state. A fork that changes a
sensor's ``seed`` -- directly (``--set encoder.seed=7``) or through ``scenario.seed``, which
seeds every component (:func:`orchestration.scenario.stable_seed`) -- keeps the saved ``seed``
and sets ``reseed`` to the new value instead (:func:`reseed_fork`; an explicit ``reseed`` wins).
A component without ``reseed`` whose seed comes from a new ``scenario.seed`` keeps the saved one:
its random numbers (e.g. a particle filter's) continue the saved stream. So forks of one state
with different ``scenario.seed`` are the members of a Monte Carlo after a common warm-up
(:func:`monte_carlo`), each reproducible, and equal to each other up to the state's time; a
fork with the saved run's own seed changes nothing and continues that run exactly. The forks
may run in parallel, on a study's executor (``flexfusion run --forks N --workers K``, or
``--scheduler`` for Dask): the same numbers as one after the other.
"""
from __future__ import annotations

import base64
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterable

import numpy as np

from .scenario import Scenario, ScenarioError, load_scenario, stable_seed

if TYPE_CHECKING:
    from concurrent.futures import Executor

    from .results import Result

FORMAT = "flexfusion-state-1"


def structure(sc: Scenario) -> dict[str, Any]:
    """What a state belongs to: the components (FMU, GUID, step, parameters), connections and
    base step (JSON-able, compared as a whole)."""
    return {"base_step": sc.base_step,
            "components": {c.name: {"model_identifier": c.model_identifier, "guid": c.guid,
                                    "step": c.step, "parameters": c.parameters}
                           for c in sc.components.values()},
            "connections": sorted(str(c) for c in sc.connections)}


@dataclass
class SaveState:
    """Master hook: write the state file at the base step ``step`` (time ``step * h``)."""

    scenario: Scenario
    step: int
    path: Path

    def start(self, instances: dict[str, Any], values: np.ndarray, offsets: dict) -> int:
        return 0

    def save(self, k: int, instances: dict[str, Any], values: np.ndarray, offsets: dict) -> None:
        fmus = {}
        for name, inst in instances.items():
            state = inst.get_state()
            try:
                fmus[name] = base64.b64encode(inst.serialize_state(state)).decode()
            finally:
                inst.free_state(state)
        doc = {"format": FORMAT, "time": k * self.scenario.base_step, "step": k,
               "scenario": self.scenario.name, "structure": structure(self.scenario),
               "values": {f"{c}.{v}": float(values[i]) for (c, v), i in offsets.items()},
               "fmus": fmus}
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.path.write_text(json.dumps(doc, indent=1) + "\n")


@dataclass
class FromState:
    """Master hook: after initialisation, set the saved states and step on from their time."""

    scenario: Scenario
    doc: dict[str, Any]            #: :func:`read_state`'s (the FMU states decoded to bytes)
    where: str = "state file"

    def start(self, instances: dict[str, Any], values: np.ndarray, offsets: dict) -> int:
        from fmpy.fmi1 import FMICallException
        for name, inst in instances.items():
            try:
                state = inst.deserialize_state(self.doc["fmus"][name])
            except FMICallException:
                raise ScenarioError(f"{self.where}: component '{name}' refused its saved state; FMU log: "
                                    + inst.log_text(1)) from None
            try:
                inst.set_state(state)
            finally:
                inst.free_state(state)
        saved = self.doc["values"]
        for (c, v), i in offsets.items():
            if f"{c}.{v}" in saved:
                values[i] = saved[f"{c}.{v}"]
            else:            # recorded now, not then: the output as the FMU holds it
                info = self.scenario.components[c].variables[v]
                values[i] = instances[c].get_real([info.value_reference])[0]
        self._set_tunable(instances)
        return int(self.doc["step"])

    def _set_tunable(self, instances: dict[str, Any]) -> None:
        saved = self.doc["structure"]["components"]
        for name, comp in self.scenario.components.items():
            for var, value in comp.parameters.items():
                if saved[name]["parameters"].get(var) != value:      # checked tunable in load
                    info = comp.variables[var]
                    instances[name].setters[info.type]([info.value_reference], [value])

    def save(self, k: int, instances: dict[str, Any], values: np.ndarray, offsets: dict) -> None:
        pass


def read_state(path: str | Path) -> dict[str, Any]:
    """A state file's document, checked for its format and the type of every entry
    (:func:`check_document`); the FMU states decoded from base64 to bytes. A bad file raises
    :class:`ScenarioError` naming the entry and why. Nothing in the file is executed: the FMU
    states are data, which each FMU checks in its turn (``fmi2DeSerializeFMUstate``; for our
    FMUs :mod:`fmus.common.state_codec`)."""
    try:
        doc = json.loads(Path(path).read_bytes())
    except FileNotFoundError:
        raise ScenarioError(f"state file not found: {path}") from None
    except IsADirectoryError:
        raise ScenarioError(f"{path}: a folder, not a state file") from None
    except OSError as exc:
        raise ScenarioError(f"{path}: cannot read it: {exc.strerror or exc}") from None
    except (ValueError, RecursionError) as exc:
        raise ScenarioError(f"{path}: not a FlexFusion state file: {exc}") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ScenarioError(f"{path}: not a FlexFusion state file (format {FORMAT!r} expected)")
    check_document(doc, str(path))
    return doc


def _number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def check_document(doc: dict[str, Any], where: str) -> None:
    """Check the entries of a state document ``doc`` (from the file ``where``) for their types
    and ranges, and decode its FMU states from base64 in place; :class:`ScenarioError` naming
    the first bad entry."""
    def bad(key: str, why: str) -> ScenarioError:
        return ScenarioError(f"{where}: entry '{key}' {why}")

    for key in ("time", "step", "structure", "values", "fmus"):
        if key not in doc:
            raise bad(key, "is missing")
    time, step = doc["time"], doc["step"]
    if not (_number(time) and math.isfinite(time) and time > 0):
        raise bad("time", f"must be a number of seconds > 0, not {time!r}")
    if not (isinstance(step, int) and not isinstance(step, bool) and 0 < step < 2 ** 53):
        raise bad("step", f"must be a base step number > 0, not {step!r}")
    st = doc["structure"]
    if not (isinstance(st, dict) and _number(st.get("base_step")) and st["base_step"] > 0
            and isinstance(st.get("components"), dict) and isinstance(st.get("connections"), list)
            and all(isinstance(c, str) for c in st["connections"])):
        raise bad("structure", "must hold base_step (> 0), components and connections (names)")
    for name, c in st["components"].items():
        if not (isinstance(c, dict) and isinstance(c.get("model_identifier"), str) and isinstance(c.get("guid"), str)
                and _number(c.get("step")) and isinstance(c.get("parameters"), dict)):
            raise bad(f"structure.components.{name}", "must hold model_identifier, guid, step and parameters")
    if abs(step * st["base_step"] - time) > 1e-9 * max(1.0, time):
        raise bad("step", f"{step} base steps of {st['base_step']:g} s are not the state's time {time:g} s")
    values = doc["values"]
    if not (isinstance(values, dict) and all(_number(v) for v in values.values())):
        raise bad("values", "must map each connected output to a number")
    fmus = doc["fmus"]
    if not (isinstance(fmus, dict) and set(fmus) == set(st["components"])):
        raise bad("fmus", "must hold one state per component of the structure")
    for name, text in fmus.items():
        if isinstance(text, bytes):
            continue                                   # decoded already
        try:
            fmus[name] = base64.b64decode(text, validate=True)
        except (TypeError, ValueError) as exc:
            raise bad(f"fmus.{name}", f"is not base64: {exc}") from None


def reseed_fork(sc: Scenario, doc: dict[str, Any]) -> None:
    """A fork's new sensor seeds become reseeds (the module docstring), in ``sc`` itself."""
    then = doc["structure"]["components"]
    for name, comp in sc.components.items():
        saved = then.get(name, {}).get("parameters", {}).get("seed")
        new = comp.parameters.get("seed")
        if saved is None or new == saved:
            continue
        reseed = comp.variables.get("reseed")
        if reseed is not None and reseed.variability == "tunable":
            comp.parameters["seed"] = saved
            comp.parameters.setdefault("reseed", new)
        elif new == stable_seed(sc.seed, name):      # from scenario.seed: the stream continues
            comp.parameters["seed"] = saved


def check_fork(sc: Scenario, doc: dict[str, Any], where: str) -> None:
    """Refuse a state of another system, or a fork that changes what FMI 2.0 does not allow to
    change after initialisation (the module docstring)."""
    then, now = doc["structure"], structure(sc)
    if then["base_step"] != now["base_step"]:
        raise ScenarioError(f"{where}: base_step {now['base_step']} differs from the state's "
                            f"{then['base_step']}")
    if set(then["components"]) != set(now["components"]):
        raise ScenarioError(f"{where}: the components ({', '.join(now['components'])}) are not "
                            f"those of the state ({', '.join(then['components'])})")
    if then["connections"] != now["connections"]:
        extra = sorted(set(now["connections"]) ^ set(then["connections"]))
        raise ScenarioError(f"{where}: the connections differ from the state's ({', '.join(extra)})")
    for name, c in now["components"].items():
        t = then["components"][name]
        for key in ("model_identifier", "guid", "step"):
            if t[key] != c[key]:
                raise ScenarioError(f"{where}: component '{name}': {key} {c[key]!r} differs from "
                                    f"the state's {t[key]!r}")
        for var in sorted(set(c["parameters"]) | set(t["parameters"])):
            if c["parameters"].get(var) != t["parameters"].get(var):
                info = sc.components[name].variables[var]
                if info.variability != "tunable" or var not in c["parameters"]:
                    def shown(params: dict) -> str:
                        return repr(params[var]) if var in params else "(the FMU's default)"
                    raise ScenarioError(
                        f"{where}: parameter '{name}.{var}' = {shown(c['parameters'])} differs "
                        f"from the state's {shown(t['parameters'])}, and it is {info.variability}: "
                        "FMI 2.0 allows a change after initialisation only for a tunable parameter "
                        "(a fork continues the saved state)")
    T = float(doc["time"])
    if not T < sc.stop_time:
        raise ScenarioError(f"{where}: stop_time {sc.stop_time:g} s is not after the state's time "
                            f"{T:g} s")
    if not doc["step"] < sc.n_steps:
        raise ScenarioError(f"{where}: the state's step {doc['step']} is not before the scenario's "
                            f"last ({sc.n_steps})")


def check_capable(sc: Scenario) -> None:
    """Every FMU must get, set and serialise its state (modelDescription capability flags)."""
    from fmpy import read_model_description
    for c in sc.components.values():
        cs = read_model_description(str(c.fmu), validate=False).coSimulation
        if not (cs.canGetAndSetFMUstate and cs.canSerializeFMUstate):
            raise ScenarioError(f"component '{c.name}' ({c.fmu.name}) cannot save its state "
                                "(canGetAndSetFMUstate and canSerializeFMUstate must be true): a "
                                "run with it cannot be forked")


def save_step(sc: Scenario, t: float) -> int:
    """The base step at which to save the state of time ``t`` (checked)."""
    k = int(round(t / sc.base_step))
    if not 0 < k < sc.n_steps or abs(k * sc.base_step - t) > 1e-9 * max(1.0, abs(t)):
        raise ScenarioError(f"--save-state-at {t!r}: must be a multiple of the base step "
                            f"{sc.base_step:g} s, after 0 and before stop_time {sc.stop_time:g} s")
    return k


def saving(sc: Scenario, t: float, state_out: str | Path) -> SaveState:
    """The hook that saves the state of time ``t`` into ``state_out`` (checked)."""
    check_capable(sc)
    return SaveState(sc, save_step(sc, t), Path(state_out))


def from_state(sc: Scenario, state: str | Path) -> FromState:
    """The hook that starts from the state file ``state`` (checked against the scenario)."""
    doc = read_state(state)
    reseed_fork(sc, doc)
    where = f"{sc.path or sc.name} from state {state}"
    check_fork(sc, doc, where)
    check_capable(sc)
    return FromState(sc, doc, where)


def run_saving(scenario: str | Path, t: float, state_out: str | Path, overrides: Iterable[str] = (),
               out_dir: str | Path | None = None) -> "Result":
    """Run a scenario and save its whole state at time ``t`` into ``state_out``."""
    from .master import run
    sc = load_scenario(scenario, overrides)
    return run(sc, out_dir=out_dir, hook=saving(sc, t, state_out))


def resume(scenario: str | Path, state: str | Path, overrides: Iterable[str] = (),
           out_dir: str | Path | None = None) -> "Result":
    """Run a scenario on from a saved state (``results.csv`` starts at the state's time)."""
    from .master import run
    sc = load_scenario(scenario, overrides)
    return run(sc, out_dir=out_dir, hook=from_state(sc, state))


def monte_carlo(scenario: str | Path | dict[str, Any], t: float, seeds: Iterable[int],
                overrides: Iterable[str] = (), out_dir: str | Path | None = None,
                executor: "Executor | None" = None, progress: bool = False) -> list["Result"]:
    """A Monte Carlo after a common warm-up: run the scenario once, saving its state at ``t``,
    then one fork from that state per seed ``s`` (``scenario.seed=s``: every sensor reseeded at
    ``t``, the module docstring); the forks' results, in the order of ``seeds``.

    ``out_dir`` (default ``results/<name>-forks``) gets ``state.json``, the warm-up run in
    ``warmup/`` and fork ``s`` in ``seed-<s>/`` (each from ``t`` on). The warm-up runs to
    ``stop_time`` too: a shorter run may not fit the components' steps and the record interval,
    and it is the member of the scenario's own seed. The forks run one after the other here, or
    on ``executor`` (:func:`orchestration.study.open_executor`: local processes or Dask, whose
    workers must see ``out_dir``) through :func:`orchestration.study.map_jobs`: each fork is a
    whole run of its own from the state file, so the numbers are the same either way.
    """
    from .study import map_jobs
    seeds = [int(s) for s in seeds]
    if not seeds or len(set(seeds)) != len(seeds):
        raise ScenarioError(f"a Monte Carlo after a warm-up needs distinct seeds, got {seeds}")
    overrides = list(overrides)
    out = Path(out_dir) if out_dir is not None else \
        Path("results") / f"{load_scenario(scenario, overrides).name}-forks"
    state = out / "state.json"
    run_saving(scenario, t, state, overrides, out_dir=out / "warmup")
    if not isinstance(scenario, dict):        # a worker's folder may be another
        scenario = Path(scenario).resolve()
    jobs = [(scenario, state.resolve(), [*overrides, f"scenario.seed={s}"], (out / f"seed-{s}").resolve())
            for s in seeds]
    if executor is None:
        return [resume(*job) for job in jobs]
    return map_jobs(resume, jobs, executor, desc="forks", progress=progress, star=True)


__all__ = ["FORMAT", "SaveState", "FromState", "read_state", "check_document", "reseed_fork", "check_fork", "check_capable",
           "structure", "save_step", "saving", "from_state",
           "run_saving", "resume", "monte_carlo"]

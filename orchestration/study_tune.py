"""Automatic tuning of an estimator's parameters (Henriksson et al. 2009, section III-C).

The paper tunes the EKFs' covariance scalings ``lambda_1..lambda_5`` and the deterministic
observer's poles (eigenfrequency and damping) by minimising the tool-position error against the
measured truth on path P1 with a randomised global optimiser (COMPLEXRF). Here the optimiser is
``scipy.optimize.differential_evolution`` (also randomised and global), whose population is
evaluated in parallel on the study executor (``workers=executor.map``): each evaluation is one
scenario run (:func:`orchestration.study.simulate`) with the candidate as overrides
``component.param=value``, and its cost the RMSE (or the band-passed error) of the estimate.

The judge (``--against``, :mod:`orchestration.judge`): by default, as the paper, the scenario's
reference system (the ``Tracker``: its fresh samples at their stamps, its noise and clock skew
included); ``--against truth`` the plant's ``p_tool``; ``--truth COMP.VAR`` any variable (a
replayed log's ``log.p_tool``). ``--criterion nis`` needs no judge: the cost is the consistency
and whiteness of the filter's innovations (:func:`orchestration.metrics.innovation_criterion`:
``ln(ANIS/dof)^2 + sum_l rho_l^2``; Bar-Shalom, Li, Kirubarajan 2001, section 5.4.2; Mehra
1970), for the noise parameters (Q, R) of a filter with a ``nis`` or ``innovation_norm``
output, ``--nis-dof`` its measurement dimension. ``tune_COMPONENT.json`` says which
(``"against"``: ``"reference"``, ``"truth"`` or ``"innovations"``, and ``"judge"``).

Guards against over-fitting (the tuner sees its judge, so it can fit the noise realisation):

* **held-out seeds**: the cost is the mean over the training ``seeds`` (scenario seeds: every
  sensor's noise stream changes with it); the best candidate and the scenario's own values are
  then evaluated on ``holdout_seeds`` that the optimiser never saw (``holdout_cost``).
* **noise floors** (:func:`sensor_floors`): an EKF's motor-angle measurement std
  ``sqrt(lambda5) r_motor`` is kept at or above the Encoder's physical error, white noise plus
  quantisation, so ``lambda5 >= (sigma_enc / r_motor)^2`` (:func:`default_bounds`).

Speed: before tuning, the scenario is *pruned* to what the estimate and the truth depend on
(the components upstream of them through the connections); other estimators, their metrics and
recordings are dropped. The noise streams do not change (each component's seed depends on the
scenario seed and its own name only). Engines (``--engine``): ``batched`` (default) simulates
the truth of each seed once (the plant, controller and sensors do not depend on the
estimator's parameters: :mod:`orchestration.batched` keeps them as a tape) and replays every
candidate estimator on it in the co-simulation's schedule, a population at once, split over
the executor's workers; two candidates of the first population also run through the FMUs and
must agree to 1e-12 relative, or the tuning stops naming the difference. A scenario the engine
cannot run (e.g. a user's own estimator FMU) runs on the FMUs, with a line saying why;
``fmu``: one co-simulation per candidate and seed.

``--estimator`` is any component of the scenario: with the default estimate
(``COMPONENT.p_tool_hat``) it must meet the estimator contract (docs/estimator_contract.md),
checked as ``flexfusion study sweep`` does; an FMU type without default bounds (a user's
estimator) needs ``--param``.

:func:`write_include` writes the result as a TOML file a scenario can ``include``.

CLI::

    flexfusion study tune SCENARIO --estimator COMPONENT [--estimator ...] --out DIR
        [--param NAME=LOW:HIGH ...] [--maxiter N] [--popsize N] [--stop-time S]
        [--metric rmse|bandpass_mean|bandpass_max] [--against reference|truth | --truth COMP.VAR]
        [--criterion error|nis [--nis-dof N]] [--seeds 1,2 --holdout-seeds 3,4]
        [--apply-to OTHER_COMPONENT ...] [--engine batched|fmu] [--check-candidates N]
        [--workers K | --scheduler ADDR]

tunes each estimator in turn and writes ``DIR/tuned_COMPONENT.toml`` (the include file;
``--apply-to`` repeats the values for variants of a single estimator) and
``DIR/tune_COMPONENT.json`` (result, held-out costs, noise floors and history).
"""
from __future__ import annotations

import argparse
import json
import math
import time
import os
import sys
from concurrent.futures import Executor, Future
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .scenario import connection_key, copy_document, toml_value
from .study import (CHECK_RTOL, ENGINES, StudyError, add_engine_arguments, add_executor_arguments,
                    check_against_fmus, check_engine, map_jobs, open_executor, simulate, submit)

METRICS = ("rmse", "bandpass_mean", "bandpass_max")
#: What a candidate is judged by: its error against the judge (the reference system by default,
#: :mod:`orchestration.judge`), or the consistency and whiteness of its innovations (no judge:
#: :func:`orchestration.metrics.innovation_criterion`).
CRITERIA = ("error", "nis")
PENALTY = 1.0e3          # cost of a failed run (metres): far worse than any estimate
#: Engines of the evaluations: the truth of each seed simulated once and every candidate
#: replayed on it (orchestration.batched), or one co-simulation of the FMUs per candidate and seed.
#: Candidates of the first population also run through the FMUs on the batched engine, and the
#: relative difference allowed (as for the Monte Carlo study's checked seeds).
CHECK_CANDIDATES = 2


@dataclass
class TuneResult:
    """Outcome of :func:`tune`.

    ``params`` the best values (name -> value), ``cost`` its cost (m), ``initial_cost`` the
    cost of the scenario's own values (NaN if not evaluated), ``n_evals`` runs made,
    ``wall_time`` seconds, ``history`` one dict per evaluation (``params``, ``cost``) in order,
    ``failed`` the number of evaluations whose run failed (cost :data:`PENALTY`);
    ``cost`` and ``initial_cost`` are means over the training ``seeds``, ``holdout_cost`` and
    ``initial_holdout_cost`` over ``holdout_seeds`` (NaN without them); ``bounds`` the search
    ranges used, ``floors`` :func:`sensor_floors` of the scenario; ``engine`` how the candidates
    were evaluated (``used``: ``batched`` or ``fmu``; ``fallback`` why not batched; ``checked``
    the candidates also run through the FMUs and their largest relative difference);
    ``criterion`` ``error`` or ``nis`` (:data:`CRITERIA`), ``judge`` what the cost judged
    (:meth:`orchestration.judge.Judge.to_json`: ``against`` ``"reference"`` by default, the
    component and its variables; for the ``nis`` criterion ``against`` ``"innovations"``, the
    statistic and its degrees of freedom). Costs are metres for ``error``, the dimensionless
    :func:`~orchestration.metrics.innovation_criterion` for ``nis``. ``converged``: the
    optimiser stopped on its convergence test (the population's cost spread within ``tol`` of
    its mean: ``scipy.optimize.differential_evolution``), not on its budget of ``maxiter``
    generations; ``generations`` the generations it ran.
    """

    component: str
    params: dict[str, float]
    cost: float
    n_evals: int
    wall_time: float
    history: list[dict[str, Any]] = field(default_factory=list)
    initial_cost: float = float("nan")
    failed: int = 0
    metric: str = "rmse"
    message: str = ""
    seeds: list[int] = field(default_factory=list)
    holdout_seeds: list[int] = field(default_factory=list)
    holdout_cost: float = float("nan")
    initial_holdout_cost: float = float("nan")
    bounds: dict[str, tuple[float, float]] = field(default_factory=dict)
    floors: dict[str, float] = field(default_factory=dict)
    engine: dict[str, Any] = field(default_factory=dict)
    criterion: str = "error"
    judge: dict[str, Any] = field(default_factory=dict)
    converged: bool = False
    tol: float = float("nan")
    maxiter: int = 0
    generations: int = 0

    @property
    def against(self) -> str:
        """What the cost judged: ``"reference"``, ``"truth"``, another role, or
        ``"innovations"`` (the ``nis`` criterion)."""
        return str(self.judge.get("against", ""))

    def to_json(self) -> dict[str, Any]:
        return {"component": self.component, "against": self.against, "judge": self.judge,
                "criterion": self.criterion, "params": self.params, "cost": self.cost,
                "initial_cost": self.initial_cost, "seeds": self.seeds,
                "holdout_seeds": self.holdout_seeds, "holdout_cost": self.holdout_cost,
                "initial_holdout_cost": self.initial_holdout_cost, "metric": self.metric,
                "bounds": self.bounds, "floors": self.floors, "n_evals": self.n_evals,
                "failed": self.failed, "wall_time": self.wall_time, "message": self.message,
                "converged": self.converged, "tol": self.tol, "maxiter": self.maxiter,
                "generations": self.generations, "engine": self.engine, "history": self.history}


# ---------------------------------------------------------------------------------------------
# the scenario document
# ---------------------------------------------------------------------------------------------
def _component_of(ref: str) -> str:
    return ref.split(".", 1)[0]


def load_document(scenario: str | Path | dict[str, Any]) -> dict[str, Any]:
    """The scenario as a self-contained TOML document (:func:`orchestration.scenario.scenario_document`).

    Raises
    ------
    StudyError
        If the file cannot be read.
    """
    from .scenario import ScenarioError, scenario_document
    try:
        return scenario_document(scenario)
    except ScenarioError as exc:
        raise StudyError(f"cannot read scenario: {exc}") from None


def prune(doc: dict[str, Any], keep_refs: Sequence[str]) -> dict[str, Any]:
    """A copy of ``doc`` with only the components the variables ``keep_refs`` (``comp.var``)
    depend on through the connections; no metrics; those variables recorded."""
    doc = copy_document(doc)
    conns = [c for c in doc.get("connections", []) if isinstance(c, str) and "->" in c]
    edges = [(_component_of(a.strip()), _component_of(b.strip())) for a, b in (c.split("->") for c in conns)]
    need = {_component_of(r) for r in keep_refs}
    changed = True
    while changed:
        changed = False
        for src, dst in edges:
            if dst in need and src not in need:
                need.add(src)
                changed = True
    doc["components"] = {k: v for k, v in doc.get("components", {}).items() if k in need}
    doc["connections"] = [c for c, (s, d) in zip(conns, edges) if s in need and d in need]
    if "oracles" in doc:        # an oracle whose connection was pruned would be a ScenarioError
        kept = {connection_key(c) for c in doc["connections"]}
        doc["oracles"] = [o for o in doc["oracles"] if isinstance(o, str) and connection_key(o) in kept]
    doc["metrics"] = []
    doc["record"] = {k: v for k, v in doc.get("record", {}).items() if k == "interval"}
    doc["record"]["variables"] = list(dict.fromkeys(keep_refs))
    return doc


def fmu_type(doc: dict[str, Any], component: str) -> str:
    """The model identifier of a component (its ``fmu`` entry without a path or ``.fmu``)."""
    try:
        fmu = doc["components"][component]["fmu"]
    except KeyError:
        raise StudyError(f"component '{component}' is not in the scenario (components: "
                         f"{', '.join(doc.get('components', {}))})") from None
    return Path(str(fmu)).stem


def parameter_value(doc: dict[str, Any], component: str, name: str, default: Any) -> Any:
    """The value of a component's parameter in a scenario document: its own, else the last of
    its parameter sets that has it, else ``default`` (the FMU's)."""
    ctab = doc["components"][component]
    value = default
    for sname in ctab.get("parameter_sets", []):
        value = doc.get("parameter_sets", {}).get(sname, {}).get(name, value)
    return ctab.get("parameters", {}).get(name, value)


def _components_of_type(doc: dict[str, Any], kind: str) -> list[str]:
    return [c for c in doc.get("components", {}) if fmu_type(doc, c) == kind]


def sensor_floors(doc: dict[str, Any]) -> dict[str, float]:
    """The physical measurement error std of the scenario's sensors (per sample, per axis).

    The sensors add white noise after their anti-aliasing filter and then round to their
    resolution (:class:`fmus.robot_plant.sensor_model.SensorChannels`): the rounding error is
    uniform over one step ``Delta`` (variance ``Delta^2 / 12``) and independent of the noise, so::

        sigma = sqrt(noise^2 + Delta^2 / 12)

    ``encoder`` (rad, motor side; the defaults 2e-5 rad noise and Delta = 2 pi / 2^16 give
    3.4e-5 rad) and ``accelerometer`` (m/s2; 0.02 m/s2 and 32 g / 2^16 give 0.020 m/s2), for
    the first Encoder / Imu component of the scenario (absent sensors are left out). A filter
    that claims a smaller measurement std than this trusts its sensor more than it can be
    trusted: a fit to one noise realisation.
    """
    from fmus.robot_plant.sensor_model import EncoderParameters
    from fmus.robot_plant.sensor_model import ImuParameters

    floors = {}
    for key, kind, defaults, noise, res in (("encoder", "Encoder", EncoderParameters(), "noise", "resolution"),
                                            ("accelerometer", "Imu", ImuParameters(), "acc_noise",
                                             "acc_resolution")):
        comps = _components_of_type(doc, kind)
        if comps:
            sd = float(parameter_value(doc, comps[0], noise, getattr(defaults, noise)))
            step = float(parameter_value(doc, comps[0], res, getattr(defaults, res)))
            floors[key] = math.sqrt(sd * sd + step * step / 12.0)
    return floors


def default_bounds(doc: dict[str, Any], component: str) -> dict[str, tuple[float, float]]:
    """The default search ranges the component's FMU declares (``param(..., search=...)``, in
    its modelDescription's vendor annotation: :mod:`orchestration.fmu_annotation`; e.g. the
    observer's four pole pairs, section III-C-2, the EKFs' five covariance scalings of section
    III-C-1 over eight decades around the initial guess); for an EKF, ``lambda5`` (the
    motor-angle measurement variance scaling) starts at the Encoder's floor,
    ``(sensor_floors(doc)["encoder"] / r_motor)^2``, so the tuned std ``sqrt(lambda5) r_motor``
    is never below the encoder's physical error.

    Raises
    ------
    StudyError
        If there are none for that type (then give the bounds explicitly).
    """
    from .fmu_annotation import describe_entry
    kind = fmu_type(doc, component)
    bounds = dict(describe_entry(doc, component).search)
    if not bounds:
        raise StudyError(f"no default tuning parameters for '{component}' ({kind}): its FMU declares "
                         "none (docs/fmu_annotation.md); give them with --param NAME=LOW:HIGH")
    floors = sensor_floors(doc)
    if "lambda5" in bounds and "encoder" in floors:
        from fmus.estimators.ekf_flexible_model import EkfMotorParameters
        r_motor = float(parameter_value(doc, component, "r_motor", EkfMotorParameters().r_motor))
        low = (floors["encoder"] / r_motor) ** 2
        bounds["lambda5"] = (max(bounds["lambda5"][0], low), max(bounds["lambda5"][1], 10.0 * low))
    return bounds


def nis_output(doc: dict[str, Any], component: str, estimate: str | None, dof: int | None,
               overrides: Sequence[str] = ()) -> tuple[str, int]:
    """The innovation statistic of ``component`` the ``nis`` criterion judges and its degrees
    of freedom: ``estimate`` or the component's ``nis`` (else ``innovation_norm``) output; ``dof``
    or the ``dof`` of the scenario's ``nis`` metric of that output.

    Raises
    ------
    StudyError
        The component has no such output, or no degrees of freedom are known.
    """
    from .scenario import ScenarioError, load_scenario
    try:
        sc = load_scenario(doc, overrides)
    except ScenarioError as exc:
        raise StudyError(str(exc)) from None
    comp = sc.components[component]
    if estimate is None:
        out = next((v for v in ("nis", "innovation_norm") if comp.group(v)), None)
        if out is None:
            raise StudyError(f"--criterion nis: '{component}' ({comp.model_identifier}) has no 'nis' or "
                             "'innovation_norm' output (the estimator contract's innovation statistic)")
        estimate = f"{component}.{out}"
    if dof is None:
        dof = next((m.dof for m in sc.metrics if m.kind == "nis" and m.estimate == estimate), None)
    if dof is None or int(dof) < 1:
        raise StudyError(f"--criterion nis: the degrees of freedom of {estimate} (the dimension of the "
                         "measurement it fuses) are unknown: give --nis-dof N (e.g. 4 for the 2012 EKF "
                         "with accelerometer: 2 motor angles, 2 accelerometer axes)")
    return estimate, int(dof)


# ---------------------------------------------------------------------------------------------
# the objective (runs in the workers)
# ---------------------------------------------------------------------------------------------
def _value_text(v: float) -> str:
    return repr(float(v))


@dataclass(frozen=True)
class Score:
    """How a run is scored (picklable: it goes to the workers).

    ``estimate`` the estimator's output; ``criterion`` ``"error"`` (the error of the estimate
    against ``judge``, a variable, by ``metric``: :data:`METRICS`; with ``stamp`` only the
    judge's fresh samples at their stamps count, :func:`orchestration.judge.aligned`) or
    ``"nis"`` (the estimate is the filter's ``nis`` or ``innovation_norm`` output, judged by
    :func:`orchestration.metrics.innovation_criterion` with ``dof``: no judge); ``after``
    seconds at the start left out.
    """

    estimate: str
    judge: str | None = None
    stamp: str | None = None
    metric: str = "rmse"
    after: float = 0.5
    criterion: str = "error"
    dof: int | None = None

    @property
    def variables(self) -> list[str]:
        """The variables a run must record."""
        return list(dict.fromkeys(v for v in (self.estimate, self.judge, self.stamp) if v))

    def cost(self, time: np.ndarray, values: dict[str, np.ndarray]) -> float:
        """The cost of one run's recorded ``values`` (:data:`PENALTY` if it cannot be computed
        or is not finite)."""
        if self.criterion == "nis":
            from .metrics import innovation_criterion
            keep = np.asarray(time) >= self.after - 1e-12
            try:
                cost = innovation_criterion(np.asarray(values[self.estimate])[keep], int(self.dof),
                                            squared=not self.estimate.endswith("innovation_norm"))["cost"]
            except ValueError:
                return PENALTY
            return float(cost) if math.isfinite(cost) else PENALTY
        return cost_of(time, values[self.estimate], values[self.judge], self.after, self.metric,
                       None if self.stamp is None else values[self.stamp])


def evaluate(doc: dict[str, Any], overrides: Sequence[str], estimate: str, truth: str,
             after: float, metric: str, stamp: str | None = None) -> float:
    """Cost of one run: the error of ``estimate`` against ``truth`` (its fresh samples at the
    stamps ``stamp``, when given) after ``after`` seconds (metres); :data:`PENALTY` if the run
    fails or the error is not finite."""
    score = Score(estimate, truth, stamp, metric, after)
    run = _fmu_trajectory(doc, overrides, score)
    return PENALTY if run is None else score.cost(*run)


def _fmu_trajectory(doc: dict[str, Any], overrides: Sequence[str], score: Score
                    ) -> tuple[np.ndarray, dict[str, np.ndarray]] | None:
    """One co-simulation of the FMUs: the recorded ``(time, {variable: values})`` of
    ``score.variables``; None if the run fails."""
    try:
        run = simulate(doc, overrides, variables=score.variables)
    except Exception:  # noqa: BLE001 - a diverging candidate is a bad candidate, not an error
        return None
    return run.time, {v: run[v] for v in score.variables}


def cost_of(t: np.ndarray, est: np.ndarray, tru: np.ndarray, after: float, metric: str,
            stamps: np.ndarray | None = None) -> float:
    """The error of ``est`` against ``tru`` (rows at the times ``t``) after ``after`` seconds, by
    ``metric`` (:data:`METRICS`); with ``stamps`` (a reference system's sample stamps) only its
    fresh samples, at their stamps (:func:`orchestration.judge.aligned`); :data:`PENALTY` if it
    cannot be computed or is not finite."""
    from . import metrics as _metrics
    from .judge import aligned
    t, est, tru = aligned(t, est, tru, stamps)
    keep = t >= after - 1e-12
    try:
        if metric == "rmse":
            cost = _metrics.rmse(est[keep], tru[keep])
        else:
            fs = 1.0 / float(np.median(np.diff(t)))
            mx, mean = _metrics.bandpass_errors(est, tru, fs, keep=keep)
            cost = mean if metric == "bandpass_mean" else mx
    except ValueError:
        return PENALTY
    return float(cost) if math.isfinite(cost) else PENALTY


class _Objective:
    """``f(x)`` for differential evolution: decode ``x`` into overrides and run, the mean cost
    over the seeds (the scenario's own seed if none; picklable)."""

    def __init__(self, doc, component, names, log_mask, base_overrides, score: Score, seeds=()):
        self.doc, self.component, self.names = doc, component, list(names)
        self.log_mask = list(log_mask)
        self.base_overrides = tuple(base_overrides)
        self.score = score
        self.seeds = tuple(seeds)

    def values(self, x: Sequence[float]) -> dict[str, float]:
        return {n: float(10.0 ** v if lg else v) for n, v, lg in zip(self.names, x, self.log_mask)}

    def overrides(self, x: Sequence[float]) -> list[str]:
        return list(self.base_overrides) + [f"{self.component}.{n}={_value_text(v)}"
                                            for n, v in self.values(x).items()]

    def cost(self, overrides: Sequence[str], seeds: Sequence[int]) -> float:
        """Mean cost of one candidate's ``overrides`` over ``seeds`` (``()``: the scenario's)."""
        runs = [list(overrides) + [f"scenario.seed={int(s)}"] for s in seeds] or [list(overrides)]
        return float(np.mean([PENALTY if (run := _fmu_trajectory(self.doc, o, self.score)) is None
                              else self.score.cost(*run) for o in runs]))

    def __call__(self, x: Sequence[float]) -> float:
        return self.cost(self.overrides(x), self.seeds)


def _cost_job(objective: _Objective, overrides: Sequence[str], seeds: Sequence[int]) -> float:
    return objective.cost(overrides, seeds)


# ---------------------------------------------------------------------------------------------
# the batched engine: the truth of each seed simulated once, every candidate replayed on it
# ---------------------------------------------------------------------------------------------
def _seeded(overrides: Sequence[str], seed: int | None) -> list[str]:
    """``overrides`` with the scenario seed (None: the scenario's own)."""
    return list(overrides) + ([] if seed is None else [f"scenario.seed={int(seed)}"])


def _trajectories(prepared: Any, res: Any, score: Score) -> list[tuple[np.ndarray, dict[str, np.ndarray]]]:
    """Each run's ``(time, {variable: values})`` on the batched engine, at the rows the FMU path
    records (every ``record_every`` base steps from t = 0, :func:`orchestration.master.simulate`);
    a scalar as the FMU path gives it (1-D)."""
    every = prepared.scenario.record_every
    t = res.time[::every]
    out = []
    for r in range(res.runs):
        values = {}
        for v in score.variables:
            a = res[v][r if res[v].shape[0] > 1 else 0, ::every]
            values[v] = a[:, 0] if prepared.wanted[v] == [v.split(".", 1)[1]] else a
        out.append((t, values))
    return out


def _finite(run: tuple[np.ndarray, dict[str, np.ndarray]], score: Score) -> bool:
    return bool(np.all(np.isfinite(run[1][score.estimate])))


def _record(score: Score) -> dict[str, None]:
    return {v: None for v in score.variables}


def _tape_job(doc: dict[str, Any], overrides: Sequence[str], score: Score) -> tuple[Any, float | str]:
    """One run of the scenario's own values on the batched engine, kept as a tape (one run
    shares every component): the :class:`~orchestration.batched.Tape` and the run's cost; or
    ``(None, why)`` when the engine cannot run the scenario or its own values fail (no tape:
    the tuning runs on the FMUs; a value, not an exception, so that it reaches the tuner from
    a worker of :func:`~orchestration.study.map_jobs` as it is)."""
    from .batched import BatchedRuns, BatchError
    from .master import RunError
    try:
        prepared = BatchedRuns(doc, [list(overrides)], _record(score), tape=True)
        res = prepared.run()
    except BatchError as exc:
        return None, str(exc)
    except RunError as exc:
        return None, f"the scenario's own values fail ({exc}): there is no run to replay"
    return res.tape, score.cost(*_trajectories(prepared, res, score)[0])


def _replayed(doc: dict[str, Any], tape: Any, runs: Sequence[Sequence[str]], score: Score
              ) -> list[tuple[np.ndarray, dict[str, np.ndarray]] | None]:
    """Each run's ``(time, {variable: values})`` with the shared part played from ``tape``, the runs
    together; None for a run that fails (a failure in a group is found by running each alone)
    or whose estimate is not finite (the master stops such a run: a non-finite output)."""
    from .batched import BatchedRuns, BatchError
    try:
        prepared = BatchedRuns(doc, runs, _record(score), replay=tape)
        return [tr if _finite(tr, score) else None for tr in _trajectories(prepared, prepared.run(), score)]
    except BatchError:
        raise
    except Exception:  # noqa: BLE001 - a diverging or refused candidate is a bad candidate
        if len(runs) == 1:
            return [None]
        return [tr for run in runs for tr in _replayed(doc, tape, [run], score)]


def _candidates_job(doc: dict[str, Any], tape: Any, runs: Sequence[Sequence[str]], score: Score,
                    keep: Sequence[int] = ()) -> tuple[list[float], dict[int, Any]]:
    """The cost of each run on one seed's tape (:data:`PENALTY` if it fails), and the
    trajectories of the runs ``keep`` (to be checked against the FMUs)."""
    trajectories = _replayed(doc, tape, runs, score)
    costs = [PENALTY if tr is None else score.cost(*tr) for tr in trajectories]
    return costs, {i: trajectories[i] for i in keep}


def checked_quantities(run: tuple | None, score: Score) -> dict[str, Any] | None:
    """What :func:`orchestration.study.check_against_fmus` compares of a candidate's run
    ``(time, {variable: values})`` (None: it failed) on the batched engine and through the
    FMUs: the time, every recorded variable and the cost."""
    if run is None:
        return None
    return {"the time": run[0], **{f"'{v}'": a for v, a in run[1].items()}, "the cost": score.cost(*run)}


class _BatchedEngine:
    """Costs of candidates on the batched engine (:mod:`orchestration.batched`).

    The truth (everything but the estimator) does not depend on the estimator's parameters: each
    seed's run of the scenario's own values is simulated once and kept as a tape
    (:func:`_tape_job`; its cost is the scenario's own cost on that seed), and every candidate
    runs on the tape in the co-simulation's schedule (:func:`_candidates_job`), a population
    split into one job per worker and seed. The jobs go through
    :func:`orchestration.study.map_jobs` (kept in the study folder, a lost worker's job retried).
    In the first population, ``check`` candidates also run through the FMUs on the first seed,
    at the same time on the executor (:func:`orchestration.study.check_against_fmus`: the study
    stops if they differ).

    Raises
    ------
    BatchError
        (on construction) The engine cannot run the scenario: use the FMUs.
    """

    def __init__(self, objective: _Objective, executor: Executor | None, seeds: Sequence[int | None],
                 check: int) -> None:
        self.objective, self.executor, self.check = objective, executor, check
        workers = getattr(executor, "max_workers", None) or (1 if executor is None else os.cpu_count() or 1)
        self.chunks = max(1, int(workers))
        o = objective
        done = dict(zip(seeds, self._map(_tape_job, [(o.doc, _seeded(o.base_overrides, s), o.score)
                                                     for s in seeds])))
        from .batched import BatchError
        for tape, why in done.values():
            if tape is None:
                raise BatchError(why)                      # use the FMUs
        self.tapes = {s: d[0] for s, d in done.items()}
        self.own_costs = {s: d[1] for s, d in done.items()}
        self.checked: list[dict[str, Any]] = []

    def _submit(self, fn: Any, *args: Any) -> Future:
        return submit(self.executor, fn, *args)

    def _map(self, fn: Any, jobs: Sequence[tuple]) -> list[Any]:
        """``fn(*job)`` for every job: through :func:`orchestration.study.map_jobs` on the
        executor, or here without one."""
        if self.executor is None:
            return [fn(*job) for job in jobs]
        return map_jobs(fn, list(jobs), self.executor, progress=False, star=True)

    def own_cost(self, seeds: Sequence[int | None]) -> float:
        """The scenario's own values: mean cost over ``seeds`` (taped ones)."""
        return float(np.mean([self.own_costs[s] for s in seeds]))

    def costs(self, candidates: Sequence[Sequence[str]], seeds: Sequence[int | None]) -> list[float]:
        """Each candidate's (its overrides) mean cost over ``seeds``, in seed order as the FMU
        path's :meth:`_Objective.cost`; the first call checks its first candidates.

        Raises
        ------
        StudyError
            A checked candidate differs from the FMUs, or the engine fails.
        """
        o, n = self.objective, len(candidates)
        n_check = 0 if self.checked else min(self.check, n)
        checks = [self._submit(_fmu_trajectory, o.doc, _seeded(candidates[i], seeds[0]), o.score)
                  for i in range(n_check)]
        parts, jobs = [], []
        for s in seeds:
            runs = [_seeded(c, s) for c in candidates]
            for chunk in np.array_split(np.arange(n), min(self.chunks, n)):
                keep = [j for j, i in enumerate(chunk) if i < n_check and s == seeds[0]]
                parts.append((s, chunk))
                jobs.append((o.doc, self.tapes[s], [runs[i] for i in chunk], o.score, keep))
        try:
            done = self._map(_candidates_job, jobs)
        except Exception as exc:  # noqa: BLE001 - a BatchError in a job, named by map_jobs
            raise StudyError(f"batched engine: {exc}; rerun with --engine fmu") from None
        per_seed = {s: [PENALTY] * n for s in seeds}
        kept: dict[int, Any] = {}
        for (s, chunk), (costs, trajectories) in zip(parts, done):
            for j, i in enumerate(chunk):
                per_seed[s][int(i)] = costs[j]
            kept.update({int(chunk[j]): tr for j, tr in trajectories.items()})
        for i, f in enumerate(checks):
            own = list(candidates[i][len(o.base_overrides):])
            seed = "the scenario's seed" if seeds[0] is None else f"seed {seeds[0]}"
            what = f"candidate {i + 1} ({', '.join(c.split('.', 1)[1] for c in own)}) on {seed}"
            d = check_against_fmus(checked_quantities(kept[i], o.score),
                                   checked_quantities(f.result(), o.score), what)
            self.checked.append({"candidate": i + 1, "overrides": own, "seed": seeds[0],
                                 "max_relative_difference": d})
        return [float(np.mean([per_seed[s][i] for s in seeds])) for i in range(n)]


class _RecordingMap:
    """``workers`` for differential evolution: the executor's map (or the batched engine, a
    population at once), recording every evaluation."""

    def __init__(self, executor: Executor | None, objective: _Objective,
                 engine: _BatchedEngine | None = None) -> None:
        self.executor = executor
        self.objective = objective
        self.engine = engine
        self.history: list[dict[str, Any]] = []

    def __call__(self, fn: Any, xs: Any) -> list[float]:
        xs = [np.asarray(x, float) for x in xs]
        if self.engine is not None:
            costs = self.engine.costs([self.objective.overrides(x) for x in xs],
                                      list(self.objective.seeds) or [None])
        elif self.executor is None:
            costs = [fn(x) for x in xs]
        else:
            costs = map_jobs(fn, xs, self.executor, progress=False)   # kept in a study folder
        for x, c in zip(xs, costs):
            self.history.append({"params": self.objective.values(x), "cost": float(c)})
        return costs


def tune(scenario: str | Path | dict[str, Any], component: str,
         bounds: dict[str, tuple[float, float]] | None = None, *, truth: str | None = None,
         against: str = "reference", criterion: str = "error", nis_dof: int | None = None,
         estimate: str | None = None, after: float = 0.5, log_scale: bool = True,
         maxiter: int = 10, popsize: int = 4, seed: int = 0, executor: Executor | None = None,
         progress: bool = True, overrides: Sequence[str] = (), metric: str = "rmse",
         tol: float = 0.01, seeds: Sequence[int] = (), holdout_seeds: Sequence[int] = (),
         engine: str = "batched", check_candidates: int = CHECK_CANDIDATES) -> TuneResult:
    """Minimise the estimation error of ``component`` over ``bounds`` (section III-C), judged
    by the scenario's reference system by default; or its innovation criterion (no judge).

    Parameters
    ----------
    scenario
        Scenario file (or parsed document) with the estimator and the truth.
    component
        The estimator's component name. With the default ``estimate`` it must meet the estimator
        contract (docs/estimator_contract.md; checked as ``flexfusion study sweep`` does).
    bounds
        ``{parameter: (low, high)}``; a vector element as ``name[i]``. Default: those the FMU
        declares (:func:`default_bounds`).
    truth, against
        What the estimate is judged against (:func:`orchestration.judge.judge`): ``against``
        ``"reference"`` (default: the scenario's reference system, the Tracker, its fresh
        samples at their stamps) or ``"truth"`` (the plant's ``p_tool``); an explicit ``truth``
        variable ``comp.var`` instead (its component's role is then ``against``).
    criterion
        ``"error"`` (default): the error against the judge by ``metric``; ``"nis"``: no judge,
        the filter's innovations (:func:`orchestration.metrics.innovation_criterion` of its
        ``nis`` or ``innovation_norm`` output, ``nis_dof`` degrees of freedom, default: from
        the scenario's ``nis`` metric of that output).
    estimate
        Recorded variable compared (default ``f"{component}.p_tool_hat"``; with the ``nis``
        criterion the component's ``nis`` or ``innovation_norm``).
    after
        Seconds at the start left out of the cost.
    log_scale
        Search ``log10`` of every parameter whose low bound is positive.
    maxiter, popsize, seed, tol
        Of ``scipy.optimize.differential_evolution`` (population ``popsize * len(bounds)``; no
        final gradient polish: each evaluation is a simulation).
    executor
        Where the population is evaluated (``None``: in this process).
    overrides
        Extra ``comp.param=value`` / ``scenario.key=value`` for every run (e.g. a shorter
        ``scenario.stop_time``).
    metric
        ``rmse`` (the paper's 2-norm of the error), ``bandpass_mean`` or ``bandpass_max``
        (3-30 Hz).
    seeds, holdout_seeds
        Scenario seeds the cost is averaged over while tuning (``()``: the scenario's own), and
        seeds on which the best candidate and the scenario's own values are evaluated
        afterwards (never seen by the optimiser; ``()``: no held-out evaluation). They must not
        overlap.
    engine
        ``"batched"`` (default): per seed, the scenario's own values run once on the batched
        engine and every candidate is replayed on that run's truth (:class:`_BatchedEngine`),
        ``check_candidates`` of the first population also through the FMUs (identical to
        :data:`CHECK_RTOL` relative, or :class:`StudyError`); a scenario the engine cannot run
        (an estimator FMU not built from this project's sources) goes through the FMUs, and
        ``TuneResult.engine["fallback"]`` says why. ``"fmu"``: one co-simulation of the FMUs per
        candidate and seed.

    Raises
    ------
    StudyError
        For bounds that are empty or inverted, an unknown component, metric or engine, an
        estimator that does not meet the contract; a batched evaluation that differs from the
        FMUs.
    ScenarioError
        For a parameter the component does not have (checked before the first run).
    """
    from scipy.optimize import differential_evolution

    if metric not in METRICS:
        raise StudyError(f"unknown tuning metric {metric!r} (one of {', '.join(METRICS)})")
    if criterion not in CRITERIA:
        raise StudyError(f"unknown tuning criterion {criterion!r} (one of {', '.join(CRITERIA)})")
    check_engine(engine, check_candidates, "--check-candidates")
    if set(seeds) & set(holdout_seeds):
        raise StudyError(f"held-out seeds {sorted(set(seeds) & set(holdout_seeds))} are also "
                         "training seeds: a held-out cost must come from noise the tuner never saw")
    doc = load_document(scenario)
    fmu_type(doc, component)
    judged = None
    if criterion == "error":
        from .judge import JudgeError, judge
        try:
            judged = judge(doc, against, truth)
        except JudgeError as exc:
            raise StudyError(str(exc)) from None
    if estimate is None:        # any estimator meeting the contract, as in every generic study
        from .study_sweep import prepare
        if judged is not None:
            prepare(doc, [component], judged.position, overrides)
    if bounds is None:
        bounds = default_bounds(doc, component)
    if not bounds:
        raise StudyError("no parameters to tune")
    names = list(bounds)
    log_mask, de_bounds = [], []
    for n in names:
        lo, hi = (float(b) for b in bounds[n])
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise StudyError(f"bounds of '{n}' must be finite with low < high, got ({lo}, {hi})")
        lg = bool(log_scale and lo > 0)
        log_mask.append(lg)
        de_bounds.append((math.log10(lo), math.log10(hi)) if lg else (lo, hi))
    if criterion == "nis":
        estimate, nis_dof = nis_output(doc, component, estimate, nis_dof, overrides)
        score = Score(estimate, None, None, metric, after, "nis", nis_dof)
    else:
        estimate = estimate or f"{component}.p_tool_hat"
        score = Score(estimate, judged.position, judged.stamp, metric, after)
    small = prune(doc, score.variables)
    if component not in small["components"]:
        raise StudyError(f"the estimate '{estimate}' is not an output of '{component}'")
    objective = _Objective(small, component, names, log_mask, overrides, score, seeds)
    # a parameter name or value the FMU rejects fails here, once, with the scenario's message
    # (in the workers it would only make every candidate cost the penalty)
    from .scenario import load_scenario
    load_scenario(small, objective.overrides([0.5 * (lo + hi) for lo, hi in de_bounds]))
    t0 = time.perf_counter()
    training = list(seeds) or [None]                # None: the scenario's own seed
    batched, engine_info = None, {"used": "fmu"}
    if engine == "batched":
        from .batched import BatchError
        try:
            batched = _BatchedEngine(objective, executor, training + list(holdout_seeds), check_candidates)
            engine_info = {"used": "batched", "check_rtol": CHECK_RTOL}
        except BatchError as exc:
            reason = f"the batched engine cannot run this tuning ({exc}): every candidate runs through the FMUs"
            print(f"tune {component}: {reason}", file=sys.stderr)
            engine_info = {"used": "fmu", "fallback": reason}
    recorder = _RecordingMap(executor, objective, batched)

    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=maxiter, desc=f"tune {component}", unit="gen", file=sys.stderr, leave=False)

    def callback(xk: Any, convergence: float = 0.0) -> bool:
        if bar is not None:
            best = min(h["cost"] for h in recorder.history)
            bar.set_postfix(best=f"{best * 1e3:.4g} mm")
            bar.update(1)
        return False

    try:
        res = differential_evolution(objective, de_bounds, maxiter=maxiter, popsize=popsize, seed=seed,
                                     tol=tol, polish=False, updating="deferred", workers=recorder,
                                     callback=callback, init="latinhypercube")
    finally:
        if bar is not None:
            bar.close()
    best = objective.values(res.x)
    # the scenario's own values on the training seeds; both on the held-out seeds
    if batched is not None:
        costs = [batched.own_cost(training)]
        if holdout_seeds:
            costs += [batched.costs([objective.overrides(res.x)], list(holdout_seeds))[0],
                      batched.own_cost(holdout_seeds)]
        engine_info["checked"] = batched.checked
    else:
        checks = [(objective, list(overrides), seeds)]
        if holdout_seeds:
            checks += [(objective, objective.overrides(res.x), holdout_seeds),
                       (objective, list(overrides), holdout_seeds)]
        if executor is None:
            costs = [_cost_job(*c) for c in checks]
        else:
            costs = map_jobs(_cost_job, checks, executor, progress=False, star=True)
    costs += [float("nan")] * (3 - len(costs))
    wall = time.perf_counter() - t0
    return TuneResult(component=component, params=best, cost=float(res.fun), n_evals=len(recorder.history),
                      wall_time=wall, history=recorder.history, metric=metric,
                      failed=sum(1 for h in recorder.history if h["cost"] >= PENALTY),
                      message=str(res.message), initial_cost=costs[0], seeds=[int(s) for s in seeds],
                      holdout_seeds=[int(s) for s in holdout_seeds], holdout_cost=costs[1],
                      initial_holdout_cost=costs[2], bounds={n: tuple(bounds[n]) for n in names},
                      floors=sensor_floors(doc), engine=engine_info, criterion=criterion,
                      judge=judged.to_json() if judged else {"against": "innovations", "estimate": estimate,
                                                             "dof": nis_dof},
                      converged=bool(res.success), tol=float(tol), maxiter=int(maxiter), generations=int(res.nit))


# ---------------------------------------------------------------------------------------------
# output
# ---------------------------------------------------------------------------------------------
def _collapse(params: dict[str, float]) -> dict[str, Any]:
    """``name[1..n]`` given completely -> ``name = [..]``; other keys unchanged."""
    out: dict[str, Any] = {}
    groups: dict[str, dict[int, float]] = {}
    for k, v in params.items():
        if k.endswith("]") and "[" in k:
            base, idx = k[:-1].split("[", 1)
            if idx.isdigit():
                groups.setdefault(base, {})[int(idx)] = v
                continue
        out[k] = v
    for base, items in groups.items():
        if sorted(items) == list(range(1, len(items) + 1)):
            out[base] = [items[i] for i in range(1, len(items) + 1)]
        else:
            for i, v in items.items():
                out[f"{base}[{i}]"] = v
    return out


def write_include(path: str | Path, component: str | Sequence[str], params: dict[str, Any],
                  comment: str = "") -> Path:
    """Write ``params`` as ``[components.<component>.parameters]`` of a TOML file a scenario can
    list in ``include = [...]`` (complete vectors ``name[1..n]`` written as one list). Several
    components (a list) get the same values, each in its own table."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = [f"# {line}" for line in comment.splitlines()] if comment else []
    for comp in [component] if isinstance(component, str) else list(component):
        lines.append(f"[components.{comp}.parameters]")
        for k, v in _collapse(params).items():
            key = k if k.replace("_", "").isalnum() else json.dumps(k)
            lines.append(f"{key} = {toml_value(v)}")
        lines.append("")
    path.write_text("\n".join(lines))
    return path


# ---------------------------------------------------------------------------------------------
# CLI
# ---------------------------------------------------------------------------------------------
def parse_param(text: str) -> tuple[str, tuple[float, float]]:
    """``NAME=LOW:HIGH`` -> ``(NAME, (LOW, HIGH))``."""
    try:
        name, rng = text.split("=", 1)
        lo, hi = rng.split(":", 1)
        return name.strip(), (float(lo), float(hi))
    except ValueError:
        raise StudyError(f"--param {text!r}: expected NAME=LOW:HIGH, e.g. pole_freq[1]=0.5:40") from None


def parse_seeds(text: str | None) -> list[int]:
    """``"1,2"`` -> ``[1, 2]`` (``None`` or empty: ``[]``)."""
    if not text:
        return []
    try:
        return [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise StudyError(f"seeds {text!r}: expected integers separated by commas, e.g. 1,2") from None


def _mm(v: float) -> str:
    return f"{v * 1e3:.4g} mm"


def judged_by(res: TuneResult) -> str:
    """What a tuning's cost judged, in words: ``rmse against the reference tracker.p_tool_meas
    (at its stamps tracker.t_meas)``, or the innovation criterion of the statistic."""
    j = res.judge
    if res.criterion == "nis":
        return f"innovation criterion of {j['estimate']} ({j['dof']} dof)"
    return (f"{res.metric} against the {j['against']} {j['variable']}"
            + (f" (at its stamps {j['stamp']})" if j.get("stamp") else ""))


def convergence(res: TuneResult) -> str:
    """Whether the tuning converged, in words: ``converged (tol 0.01) in 12 of 40 generations``
    or ``NOT converged: the budget of 10 generations ran out (tol 0.01)``."""
    if res.converged:
        return f"converged (tol {res.tol:g}) in {res.generations} of {res.maxiter} generations"
    return f"NOT converged: the budget of {res.maxiter} generations ran out (tol {res.tol:g})"


def main(args: argparse.Namespace) -> int:
    bounds = dict(parse_param(t) for t in args.param) if args.param else None
    if args.apply_to and len(args.estimator) > 1:
        raise StudyError("--apply-to needs a single --estimator (the values are that estimator's)")
    seeds, holdout = parse_seeds(args.seeds), parse_seeds(args.holdout_seeds)
    overrides = list(args.set or [])
    if args.stop_time is not None:
        overrides.append(f"scenario.stop_time={args.stop_time}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with open_executor(args.workers, args.scheduler) as ex:
        for component in args.estimator:
            res = tune(args.scenario, component, bounds, truth=args.truth, against=args.against,
                       criterion=args.criterion, nis_dof=args.nis_dof, estimate=args.estimate,
                       after=args.after, log_scale=not args.linear, maxiter=args.maxiter,
                       popsize=args.popsize, seed=args.seed, tol=args.tol, executor=ex, progress=not args.no_progress,
                       overrides=overrides, metric=args.metric, seeds=seeds, holdout_seeds=holdout,
                       engine=args.engine, check_candidates=args.check_candidates)
            fmt = _mm if res.criterion == "error" else (lambda v: f"{v:.4g}")
            comment = (f"tuned by: flexfusion study tune {args.scenario} --estimator {component}"
                       + (f" --criterion nis --nis-dof {res.judge['dof']}" if res.criterion == "nis" else
                          f" --metric {res.metric}" + (f" --truth {args.truth}" if args.truth else
                                                       f" --against {args.against}"))
                       + f" --maxiter {args.maxiter} --popsize {args.popsize} --tol {args.tol:g}"
                       + (f" --seed {args.seed}" if args.seed else "")
                       + "".join(f" --param {t}" for t in args.param or ())
                       + "".join(f" --set {t}" for t in args.set or ())
                       + (f" --stop-time {args.stop_time}" if args.stop_time is not None else "")
                       + (f" --seeds {args.seeds}" if seeds else "")
                       + (f" --holdout-seeds {args.holdout_seeds}" if holdout else "")
                       + f"\ncost {fmt(res.cost)} on the training seeds (scenario's values "
                       f"{fmt(res.initial_cost)}), held out {fmt(res.holdout_cost)} (scenario's values "
                       f"{fmt(res.initial_holdout_cost)}), {judged_by(res)}; {res.n_evals} candidates, "
                       f"{res.wall_time:.0f} s; {convergence(res)}")
            inc = write_include(out / f"tuned_{component}.toml", [component] + list(args.apply_to or []),
                                res.params, comment)
            (out / f"tune_{component}.json").write_text(json.dumps(res.to_json(), indent=1))
            print(f"{component}: cost {fmt(res.cost)} ({judged_by(res)}; scenario's values "
                  f"{fmt(res.initial_cost)}), held out {fmt(res.holdout_cost)} (scenario's values "
                  f"{fmt(res.initial_holdout_cost)}) after {res.n_evals} candidates in {res.wall_time:.1f} s; {res.failed} failed; "
                  f"{convergence(res)}")
            if res.engine.get("checked"):
                worst = max(c["max_relative_difference"] for c in res.engine["checked"])
                print(f"  batched engine; {len(res.engine['checked'])} candidates checked through the FMUs: "
                      f"largest relative difference {worst:.3g} (allowed {CHECK_RTOL:g})")
            for k, v in res.params.items():
                lo, hi = res.bounds[k]
                print(f"  {k:<20} {v:.6g}   in [{lo:.4g}, {hi:.4g}]")
            print(f"include file: {inc}")
    return 0


def register(subparsers: Any) -> None:
    """Add ``flexfusion study tune``."""
    p = subparsers.add_parser("tune", help="tune an estimator's parameters on a scenario "
                              "(differential evolution, parallel on the study executor)",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("scenario", help="scenario TOML file with the estimator and the truth")
    p.add_argument("--estimator", required=True, action="append", metavar="COMPONENT",
                   help="component to tune (repeatable: each is tuned in turn)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--param", action="append", metavar="NAME=LOW:HIGH",
                   help="parameter and its range (repeatable; default: per FMU type)")
    p.add_argument("--maxiter", type=int, default=10, help="generations (default 10)")
    p.add_argument("--popsize", type=int, default=4, help="population per parameter (default 4)")
    p.add_argument("--seed", type=int, default=0, help="optimiser seed")
    p.add_argument("--tol", type=float, default=0.01,
                   help="convergence tolerance: stop when the population's cost spread is within tol of "
                        "its mean (default 0.01; the result says whether it converged or ran out of --maxiter)")
    p.add_argument("--metric", choices=METRICS, default="rmse", help="cost (default rmse)")
    p.add_argument("--against", choices=("reference", "truth"), default="reference",
                   help="judge of the error: the scenario's reference system (a Tracker, default: as "
                        "the papers tuned) or the plant's truth p_tool")
    p.add_argument("--truth", default=None, metavar="COMP.VAR",
                   help="judge against this variable instead (e.g. log.p_tool)")
    p.add_argument("--criterion", choices=CRITERIA, default="error",
                   help="error (against the judge, by --metric; default) or nis: no judge, the "
                        "innovations' consistency (ANIS against its chi-square mean) and whiteness")
    p.add_argument("--nis-dof", type=int, default=None, metavar="N",
                   help="degrees of freedom of the NIS for --criterion nis (default: the scenario's "
                        "nis metric of that output)")
    p.add_argument("--estimate", default=None, help="estimate variable (default COMPONENT.p_tool_hat)")
    p.add_argument("--after", type=float, default=0.5, help="seconds left out at the start")
    p.add_argument("--stop-time", type=float, default=None, help="shorter runs while tuning (s)")
    p.add_argument("--seeds", default=None, metavar="S1,S2",
                   help="scenario seeds the cost is averaged over (default: the scenario's seed)")
    p.add_argument("--holdout-seeds", default=None, metavar="S1,S2",
                   help="seeds on which the result is checked afterwards, never used for tuning")
    p.add_argument("--linear", action="store_true", help="search linearly, not in log10")
    p.add_argument("--set", action="append", metavar="COMP.PARAM=VALUE", help="override (repeatable)")
    p.add_argument("--apply-to", action="append", metavar="COMPONENT",
                   help="also write the tuned values for this component (repeatable; e.g. a variant "
                        "of the estimator)")
    add_engine_arguments(p, "candidates", CHECK_CANDIDATES,
                         batched="each seed's truth simulated once, every candidate replayed on it, a few "
                                 "candidates checked through the FMUs",
                         fmu="one co-simulation per candidate")
    add_executor_arguments(p)
    p.set_defaults(func=main)


__all__ = ["tune", "TuneResult", "convergence", "Score", "CRITERIA", "nis_output", "judged_by", "write_include", "evaluate", "cost_of", "checked_quantities", "ENGINES",
           "CHECK_CANDIDATES", "CHECK_RTOL", "prune", "load_document",
           "default_bounds", "sensor_floors", "parameter_value", "parse_seeds", "register", "PENALTY"]

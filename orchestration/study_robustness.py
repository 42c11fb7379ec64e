"""Robustness of the tool-position observers: the analogue of Table I and Figs. 4-6 of
Henriksson et al. (2009), section IV.

Rows (cases), each one scenario run:

* **Nominal** -- path P1 (``henriksson2009_p1.toml``), the observers tuned on it;
* **Tuning** -- path P2 (``henriksson2009_p2.toml``) with the tuning of P1;
* **Model errors** -- path P1 with the estimators' model stiffness 50 % low: the identified
  parameter set the estimators take (``identified_robot``) with ``k_lo`` and ``k_hi`` halved, as
  the paper reduced its identified stiffness parameters (section IV-C); the controller keeps the
  identified set. Rigid kinematics gets the same set (it uses no stiffness without gravity
  compensation, so its numbers do not change, as in the paper);
* **Model errors, joint 2** (beyond the paper) -- the same with only joint 2's stiffness halved:
  a common stiffness factor (the drift correction's) cannot explain it;
* **Identification errors** (beyond the paper) -- every identified dynamic parameter of the set
  (:data:`IDENTIFIED`) off by :data:`IDENT_ERROR` (5 %, the order of the 0.02-7 % relative std
  the identification reports in identified_robot.toml), signs drawn once from
  ``numpy.random.default_rng(IDENT_SIGN_SEED)``. Every case is on top of the identified set's
  own bias against the plant (e.g. k_lo -11 % / -29 %), which the nominal case already has.

Columns: every estimator in the scenarios (components of a known estimator FMU type), rigid
kinematics included. For each: max and mean of the tool-position error norm over all
frequencies and after the zero-phase 3-30 Hz band-pass (:func:`orchestration.metrics.bandpass_errors`),
after the first ``after`` seconds.

Judge (``--against``, :mod:`orchestration.judge`): as the paper (section IV, a Leica laser
tracker at 1 kHz), the error is that against the scenarios' ``Tracker`` by default: its fresh
samples at their stamps, the band-pass on those samples (1 kHz, not the record's 2 kHz rows),
its noise (0.02 mm) and its clock skew (1 ms) in the numbers; the same statistics against the
plant's truth are ``columns_truth`` in each case (and the second table of ``table.md``).
``--against truth`` judges against the truth. The findings are on the judged columns.

The ``findings`` (:func:`findings`) compare the paper's claims (section IV-B/C) with our numbers:
each ``{claim, paper, ours, reproduced, why}``.

Outputs in ``--out``: ``table.json`` (our numbers, the paper's, the findings and the wall time
with the number of workers), ``table.md`` (both side by
side, in millimetres) and ``fig4_nominal.png``, ``fig5_tuning.png``, ``fig6_model_errors.png``
(band-passed tool x-position of a part with a hammer strike, truth and estimates, like the
paper's figures) plus ``fig3_nominal_all.png`` (all frequencies, the paper's Fig. 3).

Any estimator, any scenario (issue 17): ``--estimator NAME`` (repeated) takes these components
as the columns instead, ours or anyone's, each checked against the estimator contract
(docs/estimator_contract.md, as ``study sweep`` does) in every case's scenario before any run;
another estimator's column is its component's name. ``--scenario FILE`` runs the nominal case
and the model errors on that scenario, ``--other-path FILE`` the tuning case (another path, the
same tuning). A model error reaches the estimators that take their model from
:data:`MODEL_SET` (ours); a case that reaches none of the studied estimators is left out, and
the study says so (``skipped`` in table.json). The paper's findings need its five columns.
Besides the tool position, each case gives ``arm_errors``: the RMSE and largest error of the
arm estimates an estimator gives (``q_a_hat``, ``dq_a_hat``, ``ddq_a_hat``, per the contract)
against the plant's.

Engines (``--engine``): ``fmu`` (default): one co-simulation of the FMUs per case. ``batched``
simulates the truth of each scenario once, on the
batched engine (:mod:`orchestration.batched`), with its first case, and plays the other cases of
that scenario (the model errors: only the estimators' parameters change) back on it; two cases
(``--check-cases``: a taped one, a replayed one) also run through the FMUs at the same time and
must agree to 1e-12 relative, or the study stops naming the case, the series and the
difference. A scenario with an FMU that is not ours runs on the FMUs, with one line saying why.
The FMUs are the default because they are faster here: the 2009 estimators' own math is most
of a case's cost and has no batched kernel, so a replayed case saves only the truth's share
and the FMI layer, less than the two check runs cost (measured: docs/figures.md).

CLI: ``flexfusion study robustness --out DIR [--tuned FILE ...] [--stop-time S] [--scenario FILE]
[--other-path FILE] [--estimator NAME ...] [--engine batched|fmu] [--check-cases N]
[--workers K | --scheduler ADDR]``.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from concurrent.futures import Executor
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .metrics import bandpass
from .scenario import copy_document
from .study import (ENGINES, StudyError, add_engine_arguments, add_executor_arguments, check_engine, compare_checks, map_jobs,
                    open_executor, simulate_recorded, submit)
from .study_montecarlo import PLANT_FMU

SCENARIOS = Path(__file__).resolve().parent / "scenarios"

#: (key, row label, scenario file, model error of the estimators: a key of :data:`MODEL_ERRORS`
#: or "" for none)
CASES: tuple[tuple[str, str, str, str], ...] = (
    ("nominal", "Nominal", "henriksson2009_p1.toml", ""),
    ("tuning", "Tuning", "henriksson2009_p2.toml", ""),
    ("model_errors", "Model errors", "henriksson2009_p1.toml", "stiffness_50"),
    ("model_errors_joint2", "Model errors, joint 2", "henriksson2009_p1.toml", "stiffness_50_joint2"),
    ("ident_errors", "Identification errors", "henriksson2009_p1.toml", "ident_5"),
)
#: The parameter set the estimators take their robot model from (identified on the plant).
MODEL_SET = "identified_robot"
#: The identified (not fixed nominal) dynamic parameters of :data:`MODEL_SET`
#: (identified_robot.toml marks them "identified").
IDENTIFIED = ("c1", "c2", "I1", "I2", "J_m", "k_hi", "k_lo", "d", "f_v", "f_c")
IDENT_ERROR = 0.05
IDENT_SIGN_SEED = 2009
#: The model errors of the cases (factors on :data:`MODEL_SET`: :func:`model_error_factors`).
MODEL_ERRORS = ("stiffness_50", "stiffness_50_joint2", "ident_5")
#: Cases checked through the FMUs on the batched engine.
CHECK_CASES = 2

#: Estimator FMU types and their column labels (the paper's names where it has them).
ESTIMATOR_TYPES = {
    "EkfComplete": "EKF Complete",
    "EkfMotor": "EKF Motor",
    "EkfIntegrated": "EKF Integrated",
    "AccelerationObserver": "Det. Observer",
    "RigidKinematics": "Rigid kinematics",
}

#: Table I of the paper (mm): case -> column -> (all max, all mean, 3-30 Hz max, 3-30 Hz mean).
PAPER_TABLE: dict[str, dict[str, tuple[float, float, float, float]]] = {
    "nominal": {"EKF Complete": (17.6, 9.7, 1.007, 0.070), "EKF Motor": (16.2, 7.2, 0.914, 0.111),
                "EKF Integrated": (174.3, 101.0, 1.114, 0.056), "Det. Observer": (97.0, 59.9, 1.121, 0.057),
                "Rigid kinematics": (5.6, 2.7, 2.142, 0.221)},
    "tuning": {"EKF Complete": (9.4, 7.2, 0.135, 0.027), "EKF Motor": (16.3, 6.0, 0.698, 0.122),
               "EKF Integrated": (82.0, 36.4, 0.110, 0.018), "Det. Observer": (43.3, 28.6, 0.108, 0.020),
               "Rigid kinematics": (2.1, 0.5, 1.351, 0.219)},
    "model_errors": {"EKF Complete": (24.0, 16.3, 1.070, 0.090), "EKF Motor": (24.0, 13.2, 2.803, 0.340),
                     "EKF Integrated": (163.3, 94.3, 1.113, 0.056), "Det. Observer": (69.8, 45.4, 1.120, 0.057),
                     "Rigid kinematics": (5.6, 2.7, 2.142, 0.221)},
}
STATS = ("all_max", "all_mean", "band_max", "band_mean")

#: Time windows (s) of the figures: a part with a hammer strike, like the paper's grey parts.
FIG_WINDOWS = {"nominal": (1.3, 2.5), "tuning": (1.0, 2.2), "model_errors": (1.3, 2.5),
               "model_errors_joint2": (1.3, 2.5), "ident_errors": (1.3, 2.5)}


# ---------------------------------------------------------------------------------------------
# cases
# ---------------------------------------------------------------------------------------------
def _load(path: Path, tuned: Sequence[str | Path]) -> dict[str, Any]:
    from .scenario import ScenarioError, merge_include
    from .study_tune import load_document
    doc = load_document(path)
    for f in tuned:
        try:
            merge_include(doc, Path(f), str(path), skip_unknown=True)
        except ScenarioError as exc:
            raise StudyError(f"cannot read tuned parameters {f}: {exc}") from None
    return doc


def estimators(doc: dict[str, Any], names: Sequence[str] = ()) -> dict[str, str]:
    """``{component: FMU type}`` of the estimators in a scenario document: the components
    ``names`` (``--estimator``), or every one of a type of :data:`ESTIMATOR_TYPES` in file order."""
    kinds = {name: Path(str(ctab.get("fmu", ""))).stem for name, ctab in doc.get("components", {}).items()}
    if names:
        return {name: kinds.get(name, "") for name in names}
    return {name: kind for name, kind in kinds.items() if kind in ESTIMATOR_TYPES}


def column_labels(doc: dict[str, Any], names: Sequence[str] = ()) -> dict[str, str]:
    """``{component: table column}`` of the estimators (:func:`estimators`): the paper's names,
    the observer's drift fix marked, ``[component]`` appended where two would share a name;
    another estimator's column is its component's name."""
    labels = {}
    for comp, kind in estimators(doc, names).items():
        label = ESTIMATOR_TYPES.get(kind, comp)
        params = doc["components"][comp].get("parameters", {})
        if kind == "AccelerationObserver" and float(params.get("drift_crossover", 0.0)) > 0:
            label += f" + FK fusion ({float(params['drift_crossover']):g} Hz)"
        if kind == "EkfIntegrated" and params.get("drift_correction", "off") != "off":
            label += f" + drift correction ({params['drift_correction']})"
        labels[comp] = label
    values = list(labels.values())
    return {c: (f"{l} [{c}]" if values.count(l) > 1 else l) for c, l in labels.items()}


def model_error_factors(kind: str, model: dict[str, Any]) -> dict[str, Any]:
    """``{parameter: factor}`` (a list per joint for vectors) of a model error (:data:`MODEL_ERRORS`)
    on the parameter set ``model``."""
    if kind == "stiffness_50":          # the paper's: stiffness parameters reduced by 50 %
        return {"k_lo": [0.5, 0.5], "k_hi": [0.5, 0.5]}
    if kind == "stiffness_50_joint2":
        return {"k_lo": [1.0, 0.5], "k_hi": [1.0, 0.5]}
    if kind == "ident_5":
        rng = np.random.default_rng(IDENT_SIGN_SEED)
        out = {}
        for name in IDENTIFIED:
            if name in model:
                n = len(model[name]) if isinstance(model[name], list) else 1
                f = (1.0 + IDENT_ERROR * rng.choice([-1.0, 1.0], size=n)).tolist()
                out[name] = f if isinstance(model[name], list) else f[0]
        return out
    raise StudyError(f"unknown model error {kind!r} (one of {', '.join(MODEL_ERRORS)})")


def takes_model(doc: dict[str, Any], names: Sequence[str] = ()) -> list[str]:
    """The estimators (:func:`estimators`) that take their robot model from :data:`MODEL_SET`:
    those a model error reaches (another estimator's model is its own)."""
    if MODEL_SET not in doc.get("parameter_sets", {}):
        return []
    return [c for c in estimators(doc, names) if MODEL_SET in doc["components"][c].get("parameter_sets", [])]


def with_model_error(doc: dict[str, Any], kind: str, names: Sequence[str] = ()) -> dict[str, Any]:
    """A copy of ``doc`` whose estimators (:func:`takes_model`) take :data:`MODEL_SET` with the
    model error ``kind`` (as a new set ``<MODEL_SET>_<kind>``); other components (the
    controller) keep theirs."""
    doc = copy_document(doc)
    if not kind:
        return doc
    model = doc.get("parameter_sets", {}).get(MODEL_SET)
    if model is None:
        raise StudyError(f"the scenario has no parameter set '{MODEL_SET}' to put the model error in")
    wrong = dict(model)
    for name, factor in model_error_factors(kind, model).items():
        wrong[name] = ([v * f for v, f in zip(model[name], factor)] if isinstance(factor, list)
                       else model[name] * factor)
    sname = f"{MODEL_SET}_{kind}"
    doc["parameter_sets"][sname] = wrong
    for comp in takes_model(doc, names):
        sets = doc["components"][comp].get("parameter_sets", [])
        doc["components"][comp]["parameter_sets"] = [sname if x == MODEL_SET else x for x in sets]
    return doc


def case_list(scenario: str | Path | None = None, other_path: str | Path | None = None
              ) -> tuple[tuple[str, str, str, str], ...]:
    """:data:`CASES` on other scenarios: the nominal case and the model errors on ``scenario``
    (default P1), the tuning case on ``other_path`` (another path with the same tuning; default
    P2 with P1, none with another scenario)."""
    if scenario is None and other_path is None:
        return CASES
    nominal = str(Path(scenario).resolve()) if scenario is not None else CASES[0][2]
    other = str(Path(other_path).resolve()) if other_path is not None else None
    return tuple((key, label, other if key == "tuning" else nominal, error)
                 for key, label, _, error in CASES if key != "tuning" or other)


def case_jobs(tuned: Sequence[str | Path] = (), stop_time: float | None = None,
              cases: Sequence[tuple[str, str, str, str]] = CASES,
              scenario_dir: Path = SCENARIOS, names: Sequence[str] = (), against: str = "reference"
              ) -> list[tuple[dict[str, Any], list[str], list[str]] | None]:
    """One ``(document, overrides, variables)`` job per case: the truth (the plant's tool
    position) first, then the judge's variables (:func:`orchestration.judge.judge` of
    ``against``: the tracker's measurement and stamps by default), each estimator's
    ``p_tool_hat`` and the arm estimates it gives with their truth
    (:func:`orchestration.study_sweep.arm_estimates`); ``None`` for a model error no studied
    estimator takes (:func:`takes_model`). The estimators ``names`` (``--estimator``) are
    checked against the estimator contract in every case's scenario before any run."""
    from .judge import JudgeError, judge
    from .scenario import ScenarioError, load_scenario
    from .study_sweep import ARM_TRUTH, arm_estimates, contract_estimators
    jobs: list[tuple[dict[str, Any], list[str], list[str]] | None] = []
    for key, _label, fname, error in cases:
        doc = _load(scenario_dir / fname, tuned)
        if error and not takes_model(doc, names):
            jobs.append(None)
            continue
        doc = with_model_error(doc, error, names)
        try:
            sc = load_scenario(doc)
        except ScenarioError as exc:
            raise StudyError(f"{fname}: {exc}") from None
        if names:
            contract_estimators(sc, names)
        plants = [n for n, c in sc.components.items() if c.model_identifier == PLANT_FMU]
        if len(plants) != 1:
            raise StudyError(f"{fname}: needs exactly one {PLANT_FMU} component for the truth, found {len(plants)}")
        try:
            judged = judge(doc, against)
        except JudgeError as exc:
            raise StudyError(f"{fname}: {exc}") from None
        est = estimators(doc, names)
        overrides = [f"scenario.stop_time={stop_time!r}"] if stop_time else []
        variables = [f"{plants[0]}.p_tool"] + judged.variables + [f"{c}.p_tool_hat" for c in est]
        variables += [v for c in est for a in arm_estimates(sc, c, plants[0])
                      for v in (f"{c}.{a}", f"{plants[0]}.{ARM_TRUTH[a][0]}")]
        variables = list(dict.fromkeys(variables))
        record = doc.setdefault("record", {}).setdefault("variables", [])
        record += [v for v in variables if v not in record]          # a scenario does not know the study
        jobs.append((doc, overrides, variables))
    return jobs


def _run_case(job: tuple[dict[str, Any], list[str], list[str]]) -> dict[str, Any]:
    """One case through the FMUs: ``{"time", "wall_time", variable: values}``."""
    return simulate_recorded(*job)


def _batched_case(job: tuple[dict[str, Any], list[str], list[str]], tape: bool, replay: Any = None
                  ) -> tuple[dict[str, Any], Any]:
    """One case on the batched engine, as :func:`_run_case` gives it, and its tape (``tape``)
    or played back from ``replay`` (a case of the same scenario: the truth, and any estimator
    whose parameters the case does not change)."""
    from .batched import run_recorded
    doc, overrides, variables = job
    runs, taped = run_recorded(doc, [overrides], variables, tape=tape, replay=replay)
    return runs[0], taped


def _cases_batched(run: Sequence[tuple[tuple[str, str, str, str], Any]], executor: Executor | None,
                   progress: bool, check_cases: int) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Every case's :func:`_run_case` result on the batched engine, and what the engine did.

    The cases of one scenario differ only in the estimators' parameters (their model errors):
    the first is simulated and kept as a tape, the others are played back on it
    (:func:`_batched_case`). ``check_cases`` of them (a taped one first, then a replayed one)
    also run through the FMUs, at the same time on the executor, and must agree to
    :data:`orchestration.study.CHECK_RTOL` (:func:`orchestration.study.check_against_fmus`). A
    scenario with an FMU that is not ours runs every case on the FMUs (``fallback``).
    """
    from .batched import not_ours
    from .scenario import load_scenario
    from .study import CHECK_RTOL
    jobs = [job for _, job in run]
    keys = [case[0] for case, _ in run]
    reason = not_ours([load_scenario(doc, overrides) for doc, overrides, _ in jobs])
    if reason:
        reason += ": every case runs through the FMUs"
        print(f"robustness: {reason}", file=sys.stderr)
        return _cases_fmu(jobs, executor, progress), {"used": "fmu", "fallback": reason}
    first: dict[str, int] = {}                   # scenario file -> its taped case
    for i, (case, _) in enumerate(run):
        first.setdefault(case[2], i)
    taped = list(first.values())
    replayed = [i for i in range(len(run)) if i not in taped]
    picks = (taped[:1] + replayed[:1] + [i for i in range(len(run)) if i not in taped[:1] + replayed[:1]])
    picks = sorted(picks[:check_cases])

    checks = {f"case '{keys[i]}'": submit(executor, _run_case, jobs[i]) for i in picks}

    def phase(idx: list[int], tapes: dict[str, Any] | None) -> list[tuple[dict[str, Any], Any]]:
        calls = [(jobs[i], tapes is None, None if tapes is None else tapes[run[i][0][2]]) for i in idx]
        if executor is None:
            return [_batched_case(*c) for c in calls]
        return map_jobs(_batched_case, calls, executor, desc="robustness", progress=progress, star=True)

    results: list[dict[str, Any]] = [{}] * len(run)
    tapes = {}
    for i, (res, tape) in zip(taped, phase(taped, None)):
        results[i], tapes[run[i][0][2]] = res, tape
    for i, (res, _) in zip(replayed, phase(replayed, tapes)):
        results[i] = res
    worst = compare_checks(checks, {f"case '{keys[i]}'": results[i] for i in picks})
    return results, {"used": "batched", "taped": [keys[i] for i in taped], "replayed": [keys[i] for i in replayed],
                     "checked_cases": [keys[i] for i in picks], "check_rtol": CHECK_RTOL,
                     "max_relative_difference": worst}


def _cases_fmu(jobs: Sequence[Any], executor: Executor | None, progress: bool) -> list[dict[str, Any]]:
    """Every case through the FMUs (in parallel on ``executor``; ``None``: here)."""
    if executor is None:
        return [_run_case(j) for j in jobs]
    return map_jobs(_run_case, list(jobs), executor, desc="robustness", progress=progress)


def error_stats(time_: np.ndarray, estimate: np.ndarray, truth: np.ndarray, after: float = 0.5,
                stamps: np.ndarray | None = None) -> dict[str, float]:
    """``all_max``, ``all_mean`` (error norm over all frequencies) and ``band_max``,
    ``band_mean`` (after the 3-30 Hz band-pass), metres, for ``time >= after``; against a
    sampled reference (``stamps``: its sample stamps) on its fresh samples at their stamps
    (:func:`orchestration.judge.aligned`), the band-pass at its rate."""
    from .judge import aligned
    from .metrics import bandpass_errors
    time_, estimate, truth = aligned(time_, estimate, truth, stamps)
    keep = time_ >= after - 1e-12
    e = np.linalg.norm(np.asarray(estimate) - np.asarray(truth), axis=1)[keep]
    fs = 1.0 / float(np.median(np.diff(time_)))
    bmax, bmean = bandpass_errors(estimate, truth, fs, keep=keep)
    return {"all_max": float(e.max()), "all_mean": float(e.mean()), "band_max": bmax, "band_mean": bmean}


# ---------------------------------------------------------------------------------------------
# the study
# ---------------------------------------------------------------------------------------------
def robustness(tuned: Sequence[str | Path] = (), *, executor: Executor | None = None,
               stop_time: float | None = None, after: float = 0.5, progress: bool = True,
               cases: Sequence[tuple[str, str, str, str]] = CASES,
               scenario_dir: Path = SCENARIOS, workers: int | None = None,
               names: Sequence[str] = (), engine: str = "fmu", check_cases: int = CHECK_CASES,
               against: str = "reference") -> dict[str, Any]:
    """Run the cases (in parallel on ``executor``; ``None``: here, one after the other) and
    return the table: ``{"cases": {key: {"label", "columns": {label: stats}, "arm_errors":
    {label: {estimate: {rmse, max_error, unit}}}, "wall_time"}}, "paper": PAPER_TABLE,
    "findings": findings(...), "wall_time", "workers" (as given, for the record), "series":
    {key: arrays for the figures}}``, and ``"skipped"`` ``{key: why}`` for a model error no
    studied estimator takes. ``names``: the estimators to study (``--estimator``, each meeting
    the estimator contract; default the paper's, :data:`ESTIMATOR_TYPES`). ``engine``:
    ``"batched"`` (default; :func:`_cases_batched`: each scenario's truth simulated once, the
    other cases played back on it, ``check_cases`` checked through the FMUs) or ``"fmu"`` (one
    co-simulation per case); ``"engine"`` in the table says what ran. ``against``: the judge
    of ``columns`` and the findings (:mod:`orchestration.judge`): ``"reference"`` (default, as
    the paper: the scenarios' laser tracker, its fresh samples at their stamps, the band-pass at
    its rate) or ``"truth"``; ``columns_truth`` holds the same statistics against the plant's
    truth, and the table ``"against"`` and ``"judge"``."""
    from .metrics import max_error, rmse
    from .study_sweep import ARM_TRUTH
    check_engine(engine, check_cases, "--check-cases")
    if stop_time is not None and stop_time <= after:
        raise StudyError(f"--stop-time {stop_time:g} s leaves nothing after the first {after:g} s "
                         "the errors leave out")
    jobs = case_jobs(tuned, stop_time, cases, scenario_dir, names, against)
    skipped = {key: f"no studied estimator takes the parameter set '{MODEL_SET}' the model error is put in"
               for (key, *_), job in zip(cases, jobs) if job is None}
    run = [(case, job) for case, job in zip(cases, jobs) if job is not None]
    t0 = time.perf_counter()
    if engine == "batched":
        results, engine_info = _cases_batched(run, executor, progress, check_cases)
    else:
        results, engine_info = _cases_fmu([j for _, j in run], executor, progress), {"used": "fmu"}
    wall = time.perf_counter() - t0
    judged = _judge_of(run[0][1][0], against) if run else None
    table: dict[str, Any] = {"against": judged.against if judged else against,
                             "judge": judged.to_json() if judged else None, "cases": {}, "paper": PAPER_TABLE,
                             "wall_time": wall, "workers": workers, "engine": engine_info, "series": {}}
    if skipped:
        table["skipped"] = skipped
    for ((key, label, fname, error), (doc, overrides, variables)), res in zip(run, results):
        truth = variables[0]
        plant = truth.partition(".")[0]
        labels = column_labels(doc, names)
        keep = res["time"] >= after - 1e-12
        cols, cols_truth, arm = {}, {}, {}
        position, stamps = _judge_of(doc, against).series(res)
        for comp, col in labels.items():
            cols[col] = error_stats(res["time"], res[f"{comp}.p_tool_hat"], position, after, stamps)
            cols_truth[col] = error_stats(res["time"], res[f"{comp}.p_tool_hat"], res[truth], after)
            arm[col] = {a: {"rmse": rmse(res[f"{comp}.{a}"][keep], res[f"{plant}.{t}"][keep]),
                            "max_error": max_error(res[f"{comp}.{a}"][keep], res[f"{plant}.{t}"][keep]),
                            "unit": unit}
                        for a, (t, unit) in ARM_TRUTH.items() if f"{comp}.{a}" in variables}
        factors = model_error_factors(error, doc["parameter_sets"][MODEL_SET]) if error else {}
        table["cases"][key] = {"label": label, "scenario": fname, "model_error": error,
                               "model_error_factors": factors, "overrides": overrides,
                               "columns": cols, "columns_truth": cols_truth, "arm_errors": arm,
                               "wall_time": res["wall_time"]}
        table["series"][key] = {"time": res["time"], "truth": res[truth],
                                **{labels[c]: res[f"{c}.p_tool_hat"] for c in labels}}
    table["findings"] = findings(table["cases"])
    return table


#: The paper's accelerometer-based observers (EKF Motor has no accelerometer) and its four
#: observers (Table I columns without rigid kinematics).
ACC_BASED = ("EKF Complete", "EKF Integrated", "Det. Observer")
PAPER_OBSERVERS = ("EKF Complete", "EKF Motor", "EKF Integrated", "Det. Observer")
#: An observer is "robust" to a model error if its 3-30 Hz mean error changes by at most this
#: (the paper: EKF Integrated and the observer "not affected at all", 0.0 % and +0.0 %; EKF
#: Complete +29 %, EKF Motor +206 %: 10 % separates the two groups with margin).
ROBUST_TOL = 0.10


def base_label(column: str) -> str:
    """The paper's observer a column is, or is a variant of (``EKF Integrated + drift ...`` ->
    ``EKF Integrated``)."""
    return column.split(" + ")[0].split(" [")[0]


def _paper_band_mean(case: str, col: str) -> float:
    return PAPER_TABLE[case][col][3]


def findings(cases: dict[str, Any]) -> list[dict[str, Any]]:
    """The paper's claims (section IV-B/C, Table I) against our cases: a list of ``{claim,
    paper, ours, reproduced, why}`` (3-30 Hz mean errors; ratios > 1 mean "better than"); none
    when a case lacks one of the paper's five columns (``--estimator``)."""
    out: list[dict[str, Any]] = []
    have = [k for k in ("nominal", "tuning") if k in cases]
    if not have or any(not {*PAPER_OBSERVERS, "Rigid kinematics"} <= set(case["columns"])
                       for case in cases.values()):
        return out                  # the claims are about the paper's five columns

    def mean(key: str, col: str) -> float:
        return cases[key]["columns"][col]["band_mean"]

    def acc_cols(key: str) -> list[str]:
        return [c for c in cases[key]["columns"] if base_label(c) in ACC_BASED]

    # 1. accelerometer-based observers against rigid kinematics
    ratios = {k: {c: mean(k, "Rigid kinematics") / mean(k, c) for c in acc_cols(k)} for k in have}
    ok = all(r > 1.0 for rk in ratios.values() for r in rk.values())
    out.append({
        "claim": "accelerometer-based observers beat rigid kinematics in 3-30 Hz (a factor 2-4 in "
                 "mean error, section IV-B)",
        "paper": {k: {c: round(_paper_band_mean(k, "Rigid kinematics") / _paper_band_mean(k, c), 2)
                      for c in ACC_BASED} for k in have},
        "ours": {k: {c: round(r, 2) for c, r in rk.items()} for k, rk in ratios.items()},
        "reproduced": ok,
        "why": ("the accelerometer measures the tool's vibration that the motor angles do not see"
                if ok else "at least one accelerometer-based observer is not better than rigid "
                "kinematics: its model (identified on a plant with a bending mode, torque ripple "
                "and kinematic errors) or the IMU's mounting/scale errors cost more than the "
                "accelerometer gives"),
    })
    # 2. accelerometer-based observers against EKF Motor
    vs_motor = {k: {c: mean(k, "EKF Motor") / mean(k, c) for c in acc_cols(k)} for k in have
                if "EKF Motor" in cases[k]["columns"]}
    ok = bool(vs_motor) and all(r > 1.0 for rk in vs_motor.values() for r in rk.values())
    out.append({
        "claim": "accelerometer-based observers beat EKF Motor in 3-30 Hz mean error (EKF Motor "
                 "+98 % on P1, +580 % on P2 against EKF Integrated, section IV-C)",
        "paper": {k: {c: round(_paper_band_mean(k, "EKF Motor") / _paper_band_mean(k, c), 2)
                      for c in ACC_BASED} for k in have},
        "ours": {k: {c: round(r, 2) for c, r in rk.items()} for k, rk in vs_motor.items()},
        "reproduced": ok,
        "why": ("EKF Motor sees the tool only through its model's gearbox deflection; the "
                "accelerometer measures it" if ok else "EKF Motor's own error is far below the "
                "paper's (nominal 3-30 Hz mean here vs 0.111 mm): our plant has the model's own "
                "two-mass structure per joint, so the identified model predicts the gearbox "
                "deflection from the motor torques well, while the accelerometer-based observers "
                "pay for the IMU's mounting and scale errors and bias drift and for the unmodelled "
                "35 Hz bending mode the accelerometer sees (the real robot's model error was larger)"),
    })
    # 3. EKF Motor the worst observer
    worst = {k: max((c for c in case["columns"] if base_label(c) in PAPER_OBSERVERS),
                    key=lambda c: case["columns"][c]["band_mean"]) for k, case in cases.items()}
    paper_keys = [k for k in worst if k in PAPER_TABLE]
    ok = all(worst[k] == "EKF Motor" for k in paper_keys)
    out.append({
        "claim": "EKF Motor is the worst observer in 3-30 Hz mean error (Table I, every case)",
        "paper": {k: max(PAPER_OBSERVERS, key=lambda c: _paper_band_mean(k, c)) for k in paper_keys},
        "ours": {k: f"{w} ({cases[k]['columns'][w]['band_mean'] * 1e3:.4f} mm)" for k, w in worst.items()},
        "reproduced": ok,
        "why": ("without the accelerometer only the model links motor and tool" if ok else
                "as for the finding above: on our plant EKF Motor's identified model is good enough "
                "that the accelerometer observers' IMU and bending-mode errors weigh more; with a "
                "stiffness error EKF Motor is the worst, as in the paper"),
    })
    # 4. robustness to the 50 % stiffness error (and, beyond the paper, the other model errors)
    if "model_errors" in cases and "nominal" in cases:
        change = {k: {c: mean(k, c) / mean("nominal", c) - 1.0 for c in cases[k]["columns"]
                      if c in cases["nominal"]["columns"]}
                  for k in cases if cases[k].get("model_error")}
        robust = sorted(c for c, d in change["model_errors"].items()
                        if c in PAPER_OBSERVERS and abs(d) <= ROBUST_TOL)
        ok = robust == sorted(("EKF Integrated", "Det. Observer"))
        out.append({
            "claim": "with the 50 % stiffness error EKF Integrated and the deterministic observer are "
                     "not affected in 3-30 Hz; EKF Complete +29 %, EKF Motor +206 % mean error "
                     f"(section IV-C; robust here: change <= {ROBUST_TOL:.0%})",
            "paper": {c: round(_paper_band_mean("model_errors", c) / _paper_band_mean("nominal", c) - 1, 3)
                      for c in PAPER_OBSERVERS},
            "ours": {k: {c: round(d, 3) for c, d in ch.items()} for k, ch in change.items()},
            "robust_ours": {k: [c for c, d in ch.items() if c != "Rigid kinematics" and abs(d) <= ROBUST_TOL]
                            for k, ch in change.items()},
            "reproduced": ok,
            "why": ("integrating the accelerometer (EKF Integrated, the observer) puts the tool's "
                    "motion in the measurement through kinematics only, not through the spring model"
                    if ok else f"robust here: {', '.join(robust) or 'none'}. EKF Complete reads the "
                    "accelerometer through the spring model (eq. 7) and EKF Motor has no "
                    "accelerometer: both scale the deflection with the wrong stiffness, as in the "
                    "paper but more. EKF Integrated and the observer were tuned on P1 for the "
                    "nominal error only, which weights the model (EKF Integrated's lambda5 near the "
                    "encoder floor): the paper's insensitivity is not what that tuning buys here "
                    "(untuned, every lambda = 1, EKF Integrated goes from 0.093 to 0.158 mm, +71 %: "
                    "more robust, still not unaffected; measured 2026-11-30)"),
        })
    return out


def _judge_of(doc: dict[str, Any], against: str) -> Any:
    from .judge import judge
    return judge(doc, against)


def markdown(table: dict[str, Any]) -> str:
    """Table I with our numbers and the paper's (mm): one row per case and band, two columns
    (max, mean) per estimator, ``ours (paper)``."""
    cases = table["cases"]
    j = table.get("judge") or {}
    judged = ("against the reference system, as the paper (" + f"{j['variable']} at its stamps {j['stamp']}: "
              "the tracker's noise and clock skew included)" if table.get("against") == "reference" else
              f"against the {table.get('against', 'truth')}" + (f" ({j['variable']})" if j else ""))
    lines = [f"Tool-position error in mm, {judged}: ours (paper's Table I in parentheses; the paper's "
             "column for a variant beyond it is its base observer's).", ""]
    lines += _table_rows(cases, "columns")
    if table.get("against") != "truth" and all("columns_truth" in case for case in cases.values()):
        lines += ["", "The same against the plant's truth (plant.p_tool), which the paper could not see:", ""]
        lines += _table_rows(cases, "columns_truth")
    return _notes(table, lines)


def _table_rows(cases: dict[str, Any], which: str) -> list[str]:
    """The Markdown table of the statistics ``cases[key][which]`` with the paper's."""
    cols = list(dict.fromkeys(c for case in cases.values() for c in case[which]))
    head = "| Case | Band | " + " | ".join(f"{c} max | {c} mean" for c in cols) + " |"
    sep = "|---|---|" + "---|---|" * len(cols)
    lines = [head, sep]
    for key, case in cases.items():
        for band, (imax, imean) in (("All", (0, 1)), ("3-30 Hz", (2, 3))):
            cells = []
            for c in cols:
                st = case[which].get(c)
                base = base_label(c)
                paper = PAPER_TABLE.get(key, {}).get(base)
                for i, stat in ((imax, STATS[0 if band == "All" else 2]), (imean, STATS[1 if band == "All" else 3])):
                    if st is None:
                        cells.append("-")
                        continue
                    v = st[stat] * 1e3
                    digits = 2 if band == "All" else 3
                    txt = f"{v:.{digits}f}"
                    if paper is not None:
                        txt += f" ({paper[i]:g})"
                    cells.append(txt)
            lines.append(f"| {case['label'] if band == 'All' else ''} | {band} | " + " | ".join(cells) + " |")
    return lines


def _notes(table: dict[str, Any], lines: list[str]) -> str:
    """The ratios, the changes with the model errors and the findings (on the judged
    ``columns``) after the tables."""
    cases = table["cases"]
    lines += ["", "Band-limited mean error relative to rigid kinematics (3-30 Hz):", ""]
    for key, case in cases.items():
        rigid = case["columns"].get("Rigid kinematics")
        if not rigid:
            continue
        ratios = ", ".join(f"{c}: {rigid['band_mean'] / st['band_mean']:.2f}x lower"
                           for c, st in case["columns"].items() if c != "Rigid kinematics")
        lines.append(f"* {case['label']}: {ratios}")
    if "nominal" in cases:
        nom = cases["nominal"]["columns"]
        for key, case in cases.items():
            if not case.get("model_error"):
                continue
            lines += ["", f"Change of the 3-30 Hz mean error, {case['label']} / Nominal:", ""]
            lines += [f"* {c}: {st['band_mean'] / nom[c]['band_mean']:.3f}"
                      for c, st in case["columns"].items() if c in nom]
    fnd = table.get("findings") or findings(cases)
    if fnd:
        lines += ["", "Findings (the paper's claims against ours):", ""]
        for f in fnd:
            lines.append(f"* {'REPRODUCED' if f['reproduced'] else 'NOT reproduced'}: {f['claim']}. "
                         f"Paper {json.dumps(f['paper'])}; ours {json.dumps(f['ours'])}. Why: {f['why']}.")
    return "\n".join(lines) + "\n"


def figures(table: dict[str, Any], out: Path) -> list[Path]:
    """Figs. 4-6 (band-passed x-position in a window with a hammer strike) and Fig. 3 (all
    frequencies, nominal case) as PNG."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = []
    names = {"nominal": ("fig4_nominal.png", "Fig. 4: P1, 3-30 Hz"),
             "tuning": ("fig5_tuning.png", "Fig. 5: P2 (tuned on P1), 3-30 Hz"),
             "model_errors": ("fig6_model_errors.png", "Fig. 6: P1, 50 % stiffness error, 3-30 Hz"),
             "model_errors_joint2": ("fig6b_model_errors_joint2.png",
                                     "P1, 50 % stiffness error on joint 2 only, 3-30 Hz"),
             "ident_errors": ("fig6c_ident_errors.png", "P1, 5 % error on the identified parameters, 3-30 Hz")}
    for key, s in table["series"].items():
        t = s["time"]
        fs = 1.0 / float(np.median(np.diff(t)))
        lo, hi = FIG_WINDOWS.get(key, (t[0], t[-1]))
        w = (t >= lo) & (t <= hi)
        if w.sum() < 10:
            w = np.ones_like(t, bool)
        fname, title = names.get(key, (f"fig_{key}.png", key))
        fig, (ax, ax2) = plt.subplots(2, 1, figsize=(9, 7), sharex=True,
                                      gridspec_kw={"height_ratios": [3, 2]})
        truth_bp = bandpass(s["truth"], fs)
        ax.plot(t[w], 1e3 * truth_bp[w, 0], "k", lw=2.0, label="true position")
        for label, est in s.items():
            if label in ("time", "truth"):
                continue
            est_bp = bandpass(est, fs)
            line, = ax.plot(t[w], 1e3 * est_bp[w, 0], lw=1.0, label=label)
            ax2.plot(t[w], 1e3 * (est_bp - truth_bp)[w, 0], lw=1.0, color=line.get_color())
        ax2.set_xlabel("time (s)")
        ax.set_ylabel("tool x, band-passed 3-30 Hz (mm)")
        ax2.set_ylabel("estimate - true (mm)")
        ax.set_title(title)
        ax.grid(alpha=0.3)
        ax2.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper right")
        fig.tight_layout()
        path = out / fname
        fig.savefig(path, dpi=110)
        plt.close(fig)
        files.append(path)
    if "nominal" in table["series"]:
        s = table["series"]["nominal"]
        t = s["time"]
        fig, ax = plt.subplots(figsize=(9, 4.5))
        ax.plot(t, 1e3 * s["truth"][:, 0], "k", lw=2.0, label="true position")
        for label, est in s.items():
            if label not in ("time", "truth"):
                ax.plot(t, 1e3 * est[:, 0], lw=1.0, label=label)
        ax.set_xlabel("time (s)")
        ax.set_ylabel("tool x (mm)")
        ax.set_title("Fig. 3: P1, all frequencies")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper right")
        fig.tight_layout()
        path = out / "fig3_nominal_all.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        files.append(path)
    return files


def write(table: dict[str, Any], out: Path) -> list[Path]:
    """``table.json``, ``table.md`` and the figures in ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    js = {k: v for k, v in table.items() if k != "series"}
    js["findings"] = table.get("findings") or findings(table["cases"])
    (out / "table.json").write_text(json.dumps(js, indent=1))
    (out / "table.md").write_text(markdown(table))
    return [out / "table.json", out / "table.md"] + figures(table, out)


def main(args: argparse.Namespace) -> int:
    out = Path(args.out)
    with open_executor(args.workers, args.scheduler) as ex:
        table = robustness(args.tuned or (), executor=ex, stop_time=args.stop_time,
                           progress=not args.no_progress, cases=case_list(args.scenario, args.other_path),
                           workers=args.workers or (os.cpu_count() if args.scheduler is None else None),
                           names=args.estimators, engine=args.engine, check_cases=args.check_cases,
                           against=args.against)
    for key, why in table.get("skipped", {}).items():
        print(f"robustness: case '{key}' left out: {why}", file=sys.stderr)
    eng = table["engine"]
    files = write(table, out)
    print(markdown(table))
    print(f"robustness study: {len(table['cases'])} cases in {table['wall_time']:.1f} s "
          + (f"({table['workers']} workers); " if table["workers"] else f"(scheduler {args.scheduler}); ")
          + f"wrote {', '.join(f.name for f in files)} to {out}")
    if eng["used"] == "batched":
        print(f"batched engine: cases {', '.join(eng['replayed']) or 'none'} played back on the truth of "
              f"{', '.join(eng['taped'])}; cases {', '.join(eng['checked_cases']) or 'none'} checked through the "
              f"FMUs: largest relative difference {eng['max_relative_difference']:.2g} (allowed {eng['check_rtol']:g})")
    return 0


def register(subparsers: Any) -> None:
    """Add ``flexfusion study robustness``."""
    p = subparsers.add_parser("robustness", help="Table I of Henriksson et al. 2009: observers on "
                              "P1, P2 and with model errors (50 %% stiffness, joint 2, identification)", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--tuned", action="append", metavar="FILE",
                   help="TOML include file(s) with tuned estimator parameters (from `study tune`)")
    p.add_argument("--stop-time", type=float, default=None, help="shorter runs (s)")
    p.add_argument("--scenario", metavar="FILE", help="the nominal case and the model errors on this "
                   "scenario (default: path P1, henriksson2009_p1.toml)")
    p.add_argument("--other-path", metavar="FILE", help="the tuning case: another path with the same "
                   "tuning (default: P2 with P1, none with --scenario)")
    p.add_argument("--estimator", action="append", default=[], metavar="NAME", dest="estimators",
                   help="study this component, ours or anyone's meeting the estimator contract "
                        "(repeatable; default: the paper's observers and rigid kinematics)")
    p.add_argument("--against", choices=("reference", "truth"), default="reference",
                   help="judge of the table and the findings: the scenarios' laser tracker (default, as the "
                        "paper) or the plant's truth (always reported beside it)")
    add_engine_arguments(p, "cases", CHECK_CASES, default="fmu",
                         batched="each scenario's truth simulated once, the other cases played back on it, "
                                 "a few cases checked through the FMUs",
                         fmu="one co-simulation per case, faster for this study")
    add_executor_arguments(p)
    p.set_defaults(func=main)


__all__ = ["robustness", "ENGINES", "CHECK_CASES", "error_stats", "markdown", "figures", "write", "case_list", "case_jobs", "estimators",
           "column_labels", "takes_model",
           "findings", "with_model_error", "model_error_factors", "base_label", "CASES", "PAPER_TABLE",
           "MODEL_ERRORS", "register"]

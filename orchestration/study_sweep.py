"""Generic study: any scenario, any estimator(s), seeds and parameter sweeps.

``flexfusion study sweep SCENARIO --estimator NAME [--estimator NAME2 ...] --out DIR
[--truth COMP.VAR] [--runs N] [--grid COMP.PARAM=V1,V2,...]... [--lhs COMP.PARAM=LO:HI]...
[--samples K] [--lhs-seed S]``

* The estimators are components of the scenario, ours or anyone's: each must meet the estimator
  contract (docs/estimator_contract.md) on its modelDescription
  (:func:`orchestration.contract.check_estimator` without running it), else the study stops
  before any run with one line naming what is missing.
* The judge of the position error (``--against``, :mod:`orchestration.judge`) is by default the
  scenario's reference measurement system, as the papers had it (the ``Tracker``: its fresh
  samples at their stamps, its noise and clock skew included); ``--against truth`` the plant's
  ``p_tool``; ``--truth COMP.VAR`` any variable (a recorded log's truth column e.g.
  ``log.p_tool``). Beside a judge that is not the truth, the position error against the truth
  (the plant's ``p_tool``) is reported too (``truth``: ``position_rmse_mean`` ...). The arm
  estimates and the NEES are judged by the truth component (the plant, or ``--truth``'s
  component): a tracker measures no arm angle.
* The sweep points: the product of the ``--grid`` values, times ``--samples`` points of a Latin
  hypercube over the ``--lhs`` ranges (:class:`scipy.stats.qmc.LatinHypercube`, seeded by
  ``--lhs-seed``: the same seed gives the same points). No ``--grid`` nor ``--lhs``: one point,
  the scenario as it is. Each point runs ``--runs`` seeds, ``scenario.seed = first_seed ..
  first_seed + N - 1`` (the same seeds at every point: paired comparisons).
* Per estimator and point, over the samples ``t >= --after``: the position RMSE of
  ``p_tool_hat`` against the truth (:func:`orchestration.metrics.rmse`), mean and standard
  deviation over the seeds, and the largest error of any seed (:func:`~orchestration.metrics.max_error`);
  the same (``arm``) for each arm estimate the contract allows and the estimator gives
  (``q_a_hat``, ``dq_a_hat``, ``ddq_a_hat``) against the truth component's ``q_a``, ``dq_a``,
  ``ddq_a`` when it has them (the plant does; a log where its truth columns are mapped).
  Consistency (Bar-Shalom et al. 2001, section 5.4.2), when the estimator gives what the contract
  allows: ANEES of its arm angles ``q_a_hat`` against the truth component's ``q_a`` with its
  covariance ``P_x`` (2 degrees of freedom: the angles' marginal), and ANIS from its ``nis`` or
  ``innovation_norm`` output, whose degrees of freedom (the number of measurements, which the
  contract does not carry) come from the scenario's ``nis`` metric of that output or from
  ``--nis-dof NAME=DOF``; without them the ANIS has no band. Each with the two-sided 95 %
  chi-square band of the average over the seeds (:func:`~orchestration.metrics.monte_carlo_consistency`)
  and the fraction of times inside it.

Runs go through :func:`orchestration.study.map_jobs` on the local pool or Dask (``--workers``,
``--scheduler``), each kept in ``--out`` as it finishes (``--resume``). Engines (``--engine``):
``batched`` (default) runs them in one group per worker on the batched engine
(:mod:`orchestration.batched`: what the runs of a group share, e.g. the truth of a sweep over an
estimator's parameters, simulated once; the sensors and the 2012 paper's EKF vectorised over
seeds and ``q_jerk``; other per-run components one instance per run, without FMI), and
``--check-runs`` of them (default 2, spread over the runs) through the FMUs at the same time:
they must agree to 1e-12 relative, or the study stops naming the run, the series and the
difference. A scenario with an FMU that is not ours (a user's estimator) runs on the FMUs, with
one line saying why. ``fmu``: one co-simulation of the FMUs per run. Output: ``DIR/study.json``
(settings, and per point its parameters and per estimator the figures above), ``DIR/study.csv``
(one row per point and estimator) and ``DIR/study.png`` (RMSE mean +- std per point).
"""
from __future__ import annotations

import argparse
import csv
import itertools
import os
import sys
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from fmus.common.estimator_contract import OPTIONAL_OUTPUTS

from . import study
from .metrics import chi2_band, max_error, monte_carlo_consistency, nees, nis, rmse
from .results import json_safe
from .safe_io import atomic_write_json
from .study import ENGINES, StudyError

NEES_DOF = 2                 # the arm angles q_a (the first 2 states of the contract's P_x)
#: Runs checked through the FMUs on the batched engine.
CHECK_RUNS = 2
#: The contract's optional arm estimates, each judged against the truth component's variable of
#: the same name without ``_hat`` (the plant's outputs, a log's truth columns): (truth, unit).
ARM_TRUTH = {s.name: (s.name.removesuffix("_hat"), s.unit) for s in OPTIONAL_OUTPUTS
             if s.name in ("q_a_hat", "dq_a_hat", "ddq_a_hat")}
CSV_FIELDS = ("position_rmse_mean", "position_rmse_std", "max_error", "position_rmse_truth_mean", "anees", "anees_band_lo",
              "anees_band_hi", "anees_fraction_in_band", "anis", "anis_band_lo", "anis_band_hi",
              "anis_fraction_in_band", *(f"{est}_rmse_mean" for est in ARM_TRUTH))


# ---------------------------------------------------------------------------------------------
# the sweep points
# ---------------------------------------------------------------------------------------------
def _assignment(option: str, text: str) -> tuple[str, str]:
    key, sep, value = text.partition("=")
    if not sep or "." not in key.strip() or not value.strip():
        raise StudyError(f"{option} {text!r}: expected COMP.PARAM={'V1,V2,...' if option == '--grid' else 'LO:HI'}")
    return key.strip(), value.strip()


def grid_axes(grid: Sequence[str]) -> dict[str, list[str]]:
    """``["ekf.r_acc=1e-4,4e-4"]`` -> ``{"ekf.r_acc": ["1e-4", "4e-4"]}`` (TOML values as text)."""
    axes: dict[str, list[str]] = {}
    for text in grid:
        key, values = _assignment("--grid", text)
        if key in axes:
            raise StudyError(f"--grid {key} given twice")
        axes[key] = [v.strip() for v in values.split(",")]
        if not all(axes[key]):
            raise StudyError(f"--grid {text!r}: an empty value")
    return axes


def lhs_points(lhs: Sequence[str], samples: int, seed: int) -> tuple[list[str], np.ndarray]:
    """The parameters and a ``(samples, d)`` Latin hypercube over their ``LO:HI`` ranges."""
    keys, lows, highs = [], [], []
    for text in lhs:
        key, bounds = _assignment("--lhs", text)
        lo, sep, hi = bounds.partition(":")
        try:
            lo_f, hi_f = float(lo), float(hi)
        except ValueError:
            raise StudyError(f"--lhs {text!r}: expected COMP.PARAM=LO:HI with numbers") from None
        if not sep or not lo_f < hi_f:
            raise StudyError(f"--lhs {text!r}: expected LO:HI with LO < HI")
        if key in keys:
            raise StudyError(f"--lhs {key} given twice")
        keys.append(key)
        lows.append(lo_f)
        highs.append(hi_f)
    if not keys:
        return [], np.zeros((1, 0))
    if samples < 1:
        raise StudyError(f"--lhs needs --samples K with K >= 1, not {samples}")
    from scipy.stats import qmc
    unit = qmc.LatinHypercube(d=len(keys), rng=np.random.default_rng(seed)).random(samples)
    return keys, qmc.scale(unit, lows, highs)


def sweep_points(grid: Sequence[str] = (), lhs: Sequence[str] = (), samples: int = 0,
                 lhs_seed: int = 0) -> list[dict[str, Any]]:
    """The sweep's points, each ``{"comp.param": value}``: every grid combination with every
    Latin hypercube sample (one empty point when nothing is swept)."""
    from .scenario import parse_value
    if samples and not lhs:
        raise StudyError("--samples goes with --lhs COMP.PARAM=LO:HI")
    axes = grid_axes(grid)
    keys, cube = lhs_points(lhs, samples, lhs_seed)
    if any(k.startswith("scenario.") for k in [*axes, *keys]):
        raise StudyError("sweep component parameters only: the seeds are --runs and --first-seed, "
                         "other scenario keys are --set")
    if set(keys) & set(axes):
        raise StudyError(f"both --grid and --lhs sweep {', '.join(sorted(set(keys) & set(axes)))}")
    points = []
    for combo in itertools.product(*axes.values()):
        for row in cube:
            point = {k: parse_value(v) for k, v in zip(axes, combo)}
            point.update({k: float(x) for k, x in zip(keys, row)})
            points.append(point)
    return points


# ---------------------------------------------------------------------------------------------
# the scenario and its estimators
# ---------------------------------------------------------------------------------------------
def _variable(sc: Any, ref: str) -> bool:
    comp, _, var = ref.partition(".")
    return comp in sc.components and bool(sc.components[comp].group(var))


def contract_estimators(sc: Any, names: Sequence[str]) -> dict[str, Any]:
    """The components ``names`` (``--estimator``, in order) of the loaded scenario ``sc``, each
    meeting the estimator contract on its modelDescription (:func:`orchestration.contract.check_estimator`
    without running it): what every study that takes ``--estimator`` checks before any run.

    Raises
    ------
    StudyError
        No name, an unknown component, one named twice, one that does not meet the contract.
    """
    from .contract import check_estimator

    if not names:
        raise StudyError("name the estimator component(s) to study: --estimator NAME (repeatable)")
    out: dict[str, Any] = {}
    for name in names:
        if name not in sc.components:
            raise StudyError(f"--estimator {name}: scenario '{sc.name}' has no component '{name}' "
                             f"(components: {', '.join(sc.components)})")
        if name in out:
            raise StudyError(f"--estimator {name} given twice")
        comp = sc.components[name]
        failures = check_estimator(comp.fmu, run=False)
        if failures:
            raise StudyError(f"--estimator {name}: {comp.fmu.name} does not meet the estimator "
                             f"contract (docs/estimator_contract.md): {'; '.join(failures)}")
        out[name] = comp
    return out


def _log_feeds(comp: Any, var: str) -> bool:
    """Whether a LogReplay component's column map (``output = column [unit]; ...``) feeds its
    output ``var``: it declares every contract signal, but reading one no column feeds is an error."""
    from .judge import log_feeds
    return log_feeds(str(comp.parameters.get("columns", "")), var)


def arm_estimates(sc: Any, name: str, truth_comp: str) -> list[str]:
    """The contract's arm estimates (:data:`ARM_TRUTH`) that component ``name`` outputs and the
    truth component ``truth_comp`` gives the truth of (a log: where its column map feeds it)."""
    comp = sc.components[truth_comp]
    return [est for est, (true, _) in ARM_TRUTH.items()
            if _variable(sc, f"{name}.{est}") and _variable(sc, f"{truth_comp}.{true}")
            and (comp.model_identifier != "LogReplay" or _log_feeds(comp, true))]


def prepare(scenario: str | Path, estimators: Sequence[str], truth: str,
            overrides: Sequence[str] = (), nis_dof: dict[str, int] | None = None
            ) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
    """The scenario document recording what the study needs, and per estimator what it gives:
    ``{"nees": bool, "nis": output or None, "nis_dof": int or None, "arm": [arm estimates]}``.

    Raises
    ------
    StudyError
        No estimator, an unknown component, one that does not meet the contract, a missing truth.
    """
    from .scenario import load_scenario, scenario_document

    doc = scenario_document(scenario, overrides)
    sc = load_scenario(doc)
    if truth is not None and not _variable(sc, truth):
        raise StudyError(f"--truth {truth}: scenario '{sc.name}' has no such variable (components: "
                         f"{', '.join(sc.components)}; a recorded log's truth is e.g. log.p_tool)")
    truth_comp = truth.partition(".")[0] if truth else None
    nis_dof = dict(nis_dof or {})
    unknown = sorted(set(nis_dof) - set(estimators))
    if unknown:
        raise StudyError(f"--nis-dof {', '.join(unknown)}: not an --estimator of the study")
    record = doc.setdefault("record", {}).setdefault("variables", [])
    needed = [truth] if truth else []
    gives: dict[str, dict[str, Any]] = {}
    for name, comp in contract_estimators(sc, estimators).items():
        has_nees = bool(truth_comp) and all(_variable(sc, v) for v in (f"{name}.q_a_hat", f"{name}.P_x",
                                                                          f"{truth_comp}.q_a"))
        nis_out = next((v for v in ("nis", "innovation_norm") if comp.group(v)), None)
        dof = nis_dof.get(name) or next((m.dof for m in sc.metrics if m.kind == "nis"
                                         and m.estimate == f"{name}.{nis_out}"), None)
        arm = arm_estimates(sc, name, truth_comp) if truth_comp else []
        gives[name] = {"nees": has_nees, "nis": nis_out, "nis_dof": dof if nis_out else None, "arm": arm}
        needed.append(f"{name}.p_tool_hat")
        needed += [v for est in arm for v in (f"{name}.{est}", f"{truth_comp}.{ARM_TRUTH[est][0]}")]
        if has_nees:
            needed += [f"{name}.q_a_hat", f"{name}.P_x", f"{truth_comp}.q_a"]
        if nis_out:
            needed.append(f"{name}.{nis_out}")
    record += [v for v in dict.fromkeys(needed) if v not in record]
    return doc, gives


def run_job(doc: dict[str, Any], overrides: tuple[str, ...], variables: tuple[str, ...]
            ) -> dict[str, np.ndarray]:
    """One run (a worker's job): the recorded ``variables`` and ``"time"``."""
    r = study.simulate(doc, overrides, variables)
    return {"time": r.time, **{v: r[v] for v in variables}}


def batched_job(doc: dict[str, Any], runs: Sequence[tuple[str, ...]], variables: tuple[str, ...]
                ) -> list[dict[str, np.ndarray]]:
    """Runs together on the batched engine (a worker's job): each as :func:`run_job` gives it.
    What they share is simulated once, the sensors and the EKF of the 2012 paper vectorised over
    the runs (:mod:`orchestration.batched`)."""
    from .batched import BatchError, run_recorded
    try:
        results, _ = run_recorded(doc, runs, variables)
    except BatchError as exc:
        raise StudyError(f"the batched engine cannot run these points ({exc}); rerun with --engine fmu") from None
    for r in results:
        del r["wall_time"]
    return results


def _run_batched(doc: dict[str, Any], jobs: Sequence[tuple], ex: Any, progress: bool, check_runs: int
                 ) -> tuple[list[dict[str, np.ndarray]], dict[str, Any]]:
    """Every job's :func:`run_job` result on the batched engine: the jobs in one contiguous
    group per worker (:func:`batched_job`, through :func:`orchestration.study.map_jobs`: kept in
    the study folder), and ``check_runs`` of them (spread over the jobs) through the FMUs at the
    same time, which must agree to :data:`orchestration.study.CHECK_RTOL`."""
    variables = jobs[0][2]
    n = len(jobs)
    picks = study.check_picks(n, check_runs)
    checks = {f"run {' '.join(jobs[i][1])}": ex.submit(run_job, *jobs[i]) for i in picks}
    workers = getattr(ex, "max_workers", None) or os.cpu_count() or 1      # a Dask client has none
    groups = [g for g in np.array_split(np.arange(n), min(workers, n)) if len(g)]
    parts = study.map_jobs(batched_job, [(doc, tuple(jobs[i][1] for i in g), variables) for g in groups], ex,
                           desc="sweep (batched)", progress=progress, star=True)
    results = [r for part in parts for r in part]
    worst = study.compare_checks(checks, {f"run {' '.join(jobs[i][1])}": results[i] for i in picks})
    return results, {"used": "batched", "groups": len(groups), "checked_runs": [list(jobs[i][1]) for i in picks],
                     "check_rtol": study.CHECK_RTOL, "max_relative_difference": worst}


# ---------------------------------------------------------------------------------------------
# the figures of one estimator at one point
# ---------------------------------------------------------------------------------------------
def _consistency(stat: np.ndarray, dof: int | None) -> dict[str, Any]:
    if dof is None:                      # no band without the degrees of freedom
        return {"mean": float(np.mean(stat)), "dof": None, "band_95": None, "fraction_in_band": None}
    c = monte_carlo_consistency(stat, dof)
    return {"mean": c["mean"], "dof": dof, "band_95": list(c["band"]),
            "fraction_in_band": c["fraction_in_band"], "single_run_band_95": list(chi2_band(dof))}


def errors_over_seeds(runs: Sequence[dict[str, np.ndarray]], estimate: str, truth: str,
                      keep: np.ndarray | float, stamp: str | None = None) -> dict[str, Any]:
    """The RMSE (eq. 27 of the 2012 paper, :func:`~orchestration.metrics.rmse`) of ``estimate``
    against ``truth`` over the rows ``keep`` of each run (or, with ``stamp``, a sampled
    reference's stamps: its fresh samples at their stamps from the time ``keep`` on,
    :func:`orchestration.judge.aligned`): mean and standard deviation over the runs, per run,
    and the largest error of any run."""
    from .judge import aligned
    pairs = []
    for r in runs:
        if stamp is None:
            pairs.append((r[estimate][keep], r[truth][keep]))
        else:
            t, est, ref = aligned(r["time"], r[estimate], r[truth], r[stamp])
            pairs.append((est[t >= keep - 1e-12], ref[t >= keep - 1e-12]))
    per_seed = [rmse(e, t) for e, t in pairs]
    return {"rmse_mean": float(np.mean(per_seed)),
            "rmse_std": float(np.std(per_seed, ddof=1)) if len(runs) > 1 else 0.0,
            "rmse_per_seed": per_seed,
            "max_error": max(max_error(e, t) for e, t in pairs)}


def estimator_figures(runs: Sequence[dict[str, np.ndarray]], name: str, truth: str,
                      gives: dict[str, Any], after: float, judged: Any = None) -> dict[str, Any]:
    """RMSE over the seeds ``runs`` (mean, std, per seed) and the largest error against the
    judge (``judged``, :class:`orchestration.judge.Judge`; None: ``truth``), the same against
    ``truth`` when the judge is another (``truth``), the arm estimates it gives against the
    truth component's (``arm``), ANEES and ANIS."""
    truth_comp = truth.partition(".")[0] if truth else None
    keep = runs[0]["time"] >= after - 1e-12
    if not keep.any():
        raise StudyError(f"--after {after:g}: no sample left (the runs end at {runs[0]['time'][-1]:g} s)")
    if judged is None or judged.position == truth:
        p, beside = errors_over_seeds(runs, f"{name}.p_tool_hat", truth, keep), None
    elif truth is None:              # a real robot's log: its reference system, no truth
        p, beside = errors_over_seeds(runs, f"{name}.p_tool_hat", judged.position,
                                      keep if judged.stamp is None else after, judged.stamp), None
    else:
        p = errors_over_seeds(runs, f"{name}.p_tool_hat", judged.position,
                              keep if judged.stamp is None else after, judged.stamp)
        t = errors_over_seeds(runs, f"{name}.p_tool_hat", truth, keep)
        beside = {"variable": truth, "position_rmse_mean": t["rmse_mean"], "position_rmse_std": t["rmse_std"],
                  "position_rmse_per_seed": t["rmse_per_seed"], "max_error": t["max_error"]}
    out: dict[str, Any] = {
        "position_rmse_mean": p["rmse_mean"], "position_rmse_std": p["rmse_std"],
        "position_rmse_per_seed": p["rmse_per_seed"], "max_error": p["max_error"], "truth": beside,
        "arm": {est: {"truth": f"{truth_comp}.{ARM_TRUTH[est][0]}", "unit": ARM_TRUTH[est][1],
                      **errors_over_seeds(runs, f"{name}.{est}", f"{truth_comp}.{ARM_TRUTH[est][0]}", keep)}
                for est in gives.get("arm", ())},
        "nees": None, "nis": None}
    if gives["nees"]:
        truth_q = f"{truth_comp}.q_a"
        try:
            stat = np.array([nees((r[f"{name}.q_a_hat"] - r[truth_q])[keep], r[f"{name}.P_x"][keep])
                             for r in runs])
        except np.linalg.LinAlgError:
            raise StudyError(f"{name}.P_x is singular at some time t >= {after:g} s: no NEES "
                             "(a later --after skips the filter's start)") from None
        out["nees"] = _consistency(stat, NEES_DOF)
    if gives["nis"]:
        stat = np.array([nis(r[f"{name}.{gives['nis']}"][keep], squared=gives["nis"] == "nis")
                         for r in runs])
        out["nis"] = _consistency(stat, gives["nis_dof"])
    return out


# ---------------------------------------------------------------------------------------------
# the study
# ---------------------------------------------------------------------------------------------
def run_study(scenario: str | Path, estimators: Sequence[str], out: str | Path, *,
              truth: str | None = None, against: str = "reference", runs: int = 1, first_seed: int = 1,
              grid: Sequence[str] = (), lhs: Sequence[str] = (), samples: int = 0, lhs_seed: int = 0,
              overrides: Sequence[str] = (), nis_dof: dict[str, int] | None = None, after: float = 0.0,
              workers: int | None = None, scheduler: str | None = None, progress: bool = True,
              plots: bool = True, engine: str = "batched", check_runs: int = CHECK_RUNS) -> dict[str, Any]:
    """Run the study and write ``study.json``, ``study.csv`` and ``study.png`` into ``out``;
    returns what ``study.json`` holds. ``engine``: ``"batched"`` (default, :func:`_run_batched`;
    a scenario with an FMU that is not ours runs on the FMUs, with one line saying why) or
    ``"fmu"`` (one co-simulation per run); ``"engine"`` in ``study.json`` says what ran.
    ``against``/``truth``: the judge of the position error (:func:`orchestration.judge.judge`:
    the scenario's reference system by default); ``truth`` (default: the plant's ``p_tool``)
    also judges the arm estimates and the NEES, and the position beside another judge;
    ``"against"`` and ``"judge"`` in ``study.json`` say which."""
    from .batched import not_ours
    from .scenario import load_scenario, toml_value

    if runs < 1:
        raise StudyError(f"--runs must be at least 1, not {runs}")
    study.check_engine(engine, check_runs, "--check-runs")
    from .judge import JudgeError, judge, truth_components
    from .scenario import scenario_document
    doc0 = scenario_document(scenario, overrides)
    try:
        judged = judge(doc0, against, truth)
    except JudgeError as exc:
        raise StudyError(str(exc)) from None
    if truth is None:                # the plant's; none in a real robot's log (its reference judges)
        plants = truth_components(doc0)
        if len(plants) > 1:
            raise StudyError(f"the truth is the plant's tool position, and the scenario has {len(plants)} plants: "
                             "name it with --truth COMP.VAR")
        truth = f"{plants[0]}.p_tool" if plants else None
    doc, gives = prepare(scenario, estimators, truth, overrides, nis_dof)
    record = doc["record"]["variables"]
    record += [v for v in judged.variables if v not in record]
    points = sweep_points(grid, lhs, samples, lhs_seed)
    sets = [tuple(f"{k}={toml_value(v)}" for k, v in p.items()) for p in points]
    for point_set in sets:               # a wrong parameter stops the study before any run
        load_scenario(doc, point_set)
    variables = tuple(doc["record"]["variables"])
    seeds = list(range(first_seed, first_seed + runs))
    jobs = [(doc, point_set + (f"scenario.seed={s}",), variables) for point_set in sets for s in seeds]
    engine_info: dict[str, Any] = {"used": "fmu"}
    foreign = not_ours([load_scenario(doc)]) if engine == "batched" else None
    if foreign:
        engine_info["fallback"] = foreign + ": every run goes through the FMUs"
        print(f"sweep: {engine_info['fallback']}", file=sys.stderr)
    with study.open_executor(workers, scheduler) as ex:
        if engine == "batched" and not foreign:
            results, engine_info = _run_batched(doc, jobs, ex, progress, check_runs)
        else:
            results = study.map_jobs(run_job, jobs, ex, desc="sweep", progress=progress, star=True)
    data: dict[str, Any] = {
        "scenario": str(scenario), "estimators": {n: {"gives": g} for n, g in gives.items()},
        "against": judged.against, "judge": judged.to_json(), "truth": truth, "runs": runs, "seeds": seeds, "after": after, "overrides": list(overrides),
        "grid": grid_axes(grid), "lhs": list(lhs), "samples": samples, "lhs_seed": lhs_seed,
        "units": {"position_rmse": "m", "max_error": "m"}, "engine": engine_info, "points": []}
    for i, point in enumerate(points):
        point_runs = results[i * runs:(i + 1) * runs]
        data["points"].append({"parameters": point, "estimators": {
            name: estimator_figures(point_runs, name, truth, gives[name], after, judged) for name in estimators}})
    out = Path(out)
    atomic_write_json(out / "study.json", json_safe(data))
    write_table(data, out / "study.csv")
    if plots:
        plot(data, out / "study.png")
    return data


def table_rows(data: dict[str, Any]) -> list[dict[str, Any]]:
    """One row per point and estimator: the point's parameters and the figures of CSV_FIELDS."""
    rows = []
    for i, point in enumerate(data["points"]):
        for name, f in point["estimators"].items():
            row: dict[str, Any] = {"point": i, **point["parameters"], "estimator": name}
            row.update({k: f[k] for k in ("position_rmse_mean", "position_rmse_std", "max_error")})
            row["position_rmse_truth_mean"] = (f.get("truth") or {}).get("position_rmse_mean", f["position_rmse_mean"])
            for kind in ("nees", "nis"):
                c = f[kind] or {}
                band = c.get("band_95") or (None, None)
                row.update({f"a{kind}": c.get("mean"), f"a{kind}_band_lo": band[0],
                            f"a{kind}_band_hi": band[1],
                            f"a{kind}_fraction_in_band": c.get("fraction_in_band")})
            row.update({f"{est}_rmse_mean": a["rmse_mean"] for est, a in f["arm"].items()})
            rows.append(row)
    return rows


def write_table(data: dict[str, Any], path: Path) -> None:
    params = list(data["points"][0]["parameters"]) if data["points"] else []
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, ["point", *params, "estimator", *CSV_FIELDS])
        writer.writeheader()
        for row in table_rows(data):
            writer.writerow({k: "" if v is None else v for k, v in row.items()})


def plot(data: dict[str, Any], path: Path) -> None:
    """Position RMSE (mm, mean +- std over the seeds) per point and estimator: against the swept
    parameter when there is one, else against the point's number."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    params = list(data["points"][0]["parameters"])
    one = len(params) == 1 and all(isinstance(p["parameters"][params[0]], (int, float))
                                   for p in data["points"])
    x = np.array([p["parameters"][params[0]] for p in data["points"]] if one
                 else range(len(data["points"])), dtype=float)
    order = np.argsort(x)
    fig, ax = plt.subplots(figsize=(8, 4.5))
    for name in data["estimators"]:
        mean = np.array([p["estimators"][name]["position_rmse_mean"] for p in data["points"]])
        std = np.array([p["estimators"][name]["position_rmse_std"] for p in data["points"]])
        ax.errorbar(x[order], 1e3 * mean[order], yerr=1e3 * std[order], marker="o", capsize=3, label=name)
    ax.set_xlabel(params[0] if one else "sweep point")
    ax.set_ylabel("tool position RMSE (mm)")
    ax.set_title(f"{Path(data['scenario']).stem}: {data['runs']} seed(s) per point, t >= {data['after']:g} s")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def format_summary(data: dict[str, Any]) -> str:
    j = data.get("judge") or {}
    judged = (f"judged against the {data.get('against')} {j.get('variable')}"
              + (f" at its stamps {j['stamp']}" if j.get("stamp") else "")
              + (f" (truth {data['truth']} beside)" if data["truth"] and j.get("variable") != data["truth"] else ""))
    lines = [f"{data['scenario']}: {len(data['points'])} point(s) x {data['runs']} seed(s), {judged}"]
    eng = data.get("engine") or {}
    if eng.get("used") == "batched":
        lines.append(f"  batched engine ({eng['groups']} group(s)); {len(eng['checked_runs'])} run(s) checked through "
                     f"the FMUs: largest relative difference {eng['max_relative_difference']:.2g} "
                     f"(allowed {eng['check_rtol']:g})")
    for i, point in enumerate(data["points"]):
        params = ", ".join(f"{k}={v:.6g}" if isinstance(v, float) else f"{k}={v}"
                           for k, v in point["parameters"].items())
        lines.append(f"  point {i}" + (f" ({params})" if params else ""))
        for name, f in point["estimators"].items():
            text = (f"    {name:<16} RMSE {1e3 * f['position_rmse_mean']:.4g} +- "
                    f"{1e3 * f['position_rmse_std']:.2g} mm, max {1e3 * f['max_error']:.4g} mm"
                    + (f" (truth: RMSE {1e3 * f['truth']['position_rmse_mean']:.4g} mm)" if f.get("truth") else ""))
            for kind in ("nees", "nis"):
                c = f[kind]
                if c:
                    band = f" band [{c['band_95'][0]:.3g}, {c['band_95'][1]:.3g}]" if c["band_95"] else ""
                    text += f", A{kind.upper()} {c['mean']:.3g}{band}"
            text += "".join(f", {est} RMSE {a['rmse_mean']:.3g} {a['unit']}" for est, a in f["arm"].items())
            lines.append(text)
    return "\n".join(lines)


def _nis_dof(text: str) -> tuple[str, int]:
    name, sep, dof = text.partition("=")
    if not sep or not dof.strip().isdigit() or int(dof) < 1:
        raise argparse.ArgumentTypeError(f"expected NAME=DOF (DOF a positive integer), not {text!r}")
    return name.strip(), int(dof)


def register(subparsers: Any) -> None:
    """Add ``sweep`` to the ``flexfusion study`` sub-commands."""
    p = subparsers.add_parser("sweep", help="any scenario, any estimator(s) (--estimator): seeds "
                              "and grid / Latin hypercube sweeps, RMSE, NEES, NIS",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("scenario", help="scenario file (TOML)")
    p.add_argument("--estimator", action="append", default=[], metavar="NAME", dest="estimators",
                   help="a component meeting the estimator contract (repeatable; at least one)")
    p.add_argument("--against", choices=("reference", "truth"), default="reference",
                   help="judge of the position error: the scenario's reference system (a Tracker, default, "
                        "as the papers) or the plant's truth p_tool (reported beside the reference)")
    p.add_argument("--truth", default=None, metavar="COMP.VAR",
                   help="judge against this variable instead, and take the arm truth from its component "
                        "(e.g. log.p_tool for a recorded log)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (study.json, study.csv, study.png)")
    p.add_argument("--runs", type=int, default=1, metavar="N", help="seeds per point (default 1)")
    p.add_argument("--first-seed", type=int, default=1, help="scenario.seed of the first run (default 1)")
    p.add_argument("--grid", action="append", default=[], metavar="COMP.PARAM=V1,V2,...",
                   help="sweep these values (repeatable: the product)")
    p.add_argument("--lhs", action="append", default=[], metavar="COMP.PARAM=LO:HI",
                   help="a Latin hypercube dimension (repeatable; with --samples)")
    p.add_argument("--samples", type=int, default=0, metavar="K", help="Latin hypercube samples")
    p.add_argument("--lhs-seed", type=int, default=0, metavar="S", help="the Latin hypercube's seed (default 0)")
    p.add_argument("--set", action="append", default=[], metavar="COMP.PARAM=VALUE", dest="overrides",
                   help="override a parameter in every run (repeatable)")
    p.add_argument("--nis-dof", action="append", default=[], type=_nis_dof, metavar="NAME=DOF",
                   help="degrees of freedom of an estimator's NIS (default: from the scenario's nis metric)")
    p.add_argument("--after", type=float, default=0.0,
                   help="ignore the samples before this time [s] (default 0)")
    p.add_argument("--no-plots", action="store_true", help="no study.png")
    study.add_engine_arguments(p, "runs", CHECK_RUNS,
                               batched="the runs together, vectorised where our kernels allow, a few runs "
                                       "checked through the FMUs",
                               fmu="one co-simulation of the FMUs per run")
    study.add_executor_arguments(p)
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    data = run_study(args.scenario, args.estimators, args.out, truth=args.truth, against=args.against,
                     runs=args.runs,
                     first_seed=args.first_seed, grid=args.grid, lhs=args.lhs, samples=args.samples,
                     lhs_seed=args.lhs_seed, overrides=args.overrides, nis_dof=dict(args.nis_dof),
                     after=args.after, workers=args.workers, scheduler=args.scheduler,
                     progress=not args.no_progress, plots=not args.no_plots, engine=args.engine,
                     check_runs=args.check_runs)
    print(format_summary(data))
    return 0


__all__ = ["ENGINES", "CHECK_RUNS", "batched_job", "sweep_points", "grid_axes", "lhs_points", "contract_estimators", "arm_estimates", "prepare",
           "run_job", "errors_over_seeds", "estimator_figures", "ARM_TRUTH",
           "run_study", "table_rows", "write_table", "plot", "format_summary", "register", "main"]

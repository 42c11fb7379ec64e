"""Monte Carlo study of the 2012 paper's section 4 (Axelsson, Karlsson, Norrlöf 2012): RMSE of the
EKF (and PF) against the posterior CRLB, with and without the accelerometer (Fig. 3, Table 1,
Fig. 4).

``flexfusion study montecarlo SCENARIO --runs N [--workers K | --scheduler ADDRESS] --out DIR``

* Runs ``N`` seeds (``scenario.seed = first_seed .. first_seed + N - 1``) of the scenario on a
  :mod:`concurrent.futures` executor (:func:`orchestration.study.open_executor`). The seed only
  changes the sensor noise: the true trajectory is the same in every run (checked: the largest
  deviation of the true states from run 0 is written to ``study.json``).
* The filters are the scenario's components whose FMU is ``EkfAccelerometer`` or
  ``ParticleFilter``; with and without accelerometer are two components of one scenario (the
  same noise realisation for both, so their difference is a paired comparison).
* Timing: the master steps a component with communication step ``T = n h`` at ``t_j = j T``
  after the faster producers have made their step to ``t_j + h``, so a filter's estimate fuses
  the measurements of ``t_j + h`` (see :mod:`orchestration.master`). The errors are taken at
  those instants, ``t_j + h``, against the plant's true ``q_a``, ``dq_a``, ``ddq_a`` recorded
  there.
* Per time, eq. 27: ``rmse(t) = sqrt(1/N sum_j ||x_true(t) - x_hat_j(t)||^2)``, separately for
  the angular position, velocity and acceleration (2-vectors). Time average: the arithmetic mean
  of ``rmse(t)`` over ``t >= after`` (the paper's Table 1 "ignoring the initial transient"); the
  CRLB's ``sqrt(trace P)`` is averaged the same way.
* The CRLB (:func:`orchestration.crlb.robot_crlb`) along the true trajectory of run 0, per
  filter, with that filter's ``Q``, ``R`` and accelerometer switch and the plant's dynamics
  (``crlb``, the paper's bound, eqs. 21-25), and the same with the EKF's own integrator
  dynamics (``ekf_model_bound``: the stationary covariance the EKF's model allows at the true
  state; the gap between the two is the cost of the EKF's simplified dynamics, and note that the
  paper's bound treats the motor velocity ``dq_m`` as a known, noise-free input).

Output ``DIR/study.json``: settings, per-time RMSE and CRLB, time averages, ratios, Table 1
beside the paper's, wall time; ``DIR/fig3.png`` (angular position RMSE and CRLB over time,
with and without accelerometer) and, when the scenario has a particle filter, ``DIR/fig4.png``
(PF against EKF). The numbers depend only on the scenario, the overrides and the seeds, not on
the executor or the number of workers (the reductions run in seed order).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from . import study

FILTER_FMUS = ("EkfAccelerometer", "ParticleFilter")
PLANT_FMU = "FlexibleRobot2DOF"
GROUPS = ("position", "velocity", "acceleration")
_ESTIMATES = {"position": "q_a_hat", "velocity": "dq_a_hat", "acceleration": "ddq_a_hat"}
_TRUTH = {"position": "q_a", "velocity": "dq_a", "acceleration": "ddq_a"}

#: Table 1 of the paper (EKF, 500 runs): RMSE of q_a [rad], dq_a [rad/s], ddq_a [rad/s^2].
PAPER_TABLE1 = {
    "accelerometer": {"position": 1.25e-5, "velocity": 7.57e-5, "acceleration": 1.23e-3},
    "no_accelerometer": {"position": 2.18e-5, "velocity": 4.08e-4, "acceleration": 3.91e-3},
}


@dataclasses.dataclass(frozen=True)
class FilterInfo:
    """A filter component of the scenario."""
    name: str
    fmu: str
    use_accelerometer: bool
    ratio: int
    step: float
    parameters: dict[str, Any]


# ---------------------------------------------------------------------------------------------
# the scenario's filters and plant
# ---------------------------------------------------------------------------------------------
def _dataclass_from_scalars(cls: type, scalars: dict[str, Any]) -> Any:
    """An instance of a parameter dataclass from a component's scalar FMU parameters
    (``name`` or ``name[i]``); names that are not fields are ignored, the rest keep defaults."""
    kw: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        if f.name in scalars:
            kw[f.name] = scalars[f.name]
            continue
        items = {int(k[len(f.name) + 1:-1]): v for k, v in scalars.items()
                 if k.startswith(f.name + "[") and k.endswith("]")}
        if items:
            default = list(f.default) if isinstance(f.default, tuple) else []
            n = max(len(default), max(items))
            vals = (default + [0.0] * n)[:n]
            for i, v in items.items():
                vals[i - 1] = v
            kw[f.name] = tuple(vals)
    return cls(**kw)


def _scenario_parts(scenario: str | Path, overrides: Sequence[str]):
    from .scenario import load_scenario
    sc = load_scenario(scenario, tuple(overrides))
    filters = [FilterInfo(n, c.model_identifier, bool(c.parameters.get("use_accelerometer", True)),
                          c.ratio, c.step, dict(c.parameters))
               for n, c in sc.components.items() if c.model_identifier in FILTER_FMUS]
    plants = [n for n, c in sc.components.items() if c.model_identifier == PLANT_FMU]
    if not filters:
        raise study.StudyError(f"scenario '{sc.name}' has no filter component (FMU "
                               f"{' or '.join(FILTER_FMUS)}): nothing to evaluate")
    if len(plants) != 1:
        raise study.StudyError(f"scenario '{sc.name}' needs exactly one {PLANT_FMU} component for the "
                               f"true states, found {len(plants)}")
    ratios = {f.ratio for f in filters}
    if len(ratios) != 1:
        raise study.StudyError("the filters of scenario '%s' run at different steps (%s); the study "
                               "compares them at common instants" % (sc.name, ", ".join(
                                   f"{f.name}: {f.step:g} s" for f in filters)))
    return sc, filters, plants[0]


def run_one(scenario: str, overrides: Sequence[str], filters: Sequence[FilterInfo], plant: str,
            ratio: int) -> dict[str, np.ndarray]:
    """One Monte Carlo run (a job; module level so that it pickles): the true states at the
    filters' update instants and each filter's estimation errors there.

    Returns
    -------
    dict
        ``"time"`` (K,), ``"truth"`` (K, 6) = (q_a, dq_a, ddq_a), ``"inputs"`` (K, 6) =
        (q_m, dq_m, ddq_m) (``ddq_m`` by central differences of the recorded ``dq_m``), and per
        filter ``"<name>"`` (K, 6): estimate minus truth.
    """
    extra = [f"{plant}.{x}" for x in ("q_a", "dq_a", "ddq_a", "q_m", "dq_m")]
    wanted = list(dict.fromkeys(extra + [f"{f.name}.{_ESTIMATES[g]}" for f in filters for g in GROUPS]))
    r = study.simulate(scenario, overrides, wanted)
    t = r.time
    idx = np.arange(1, len(t), ratio)              # t_j + h: the filters' fresh estimates
    truth = np.hstack([r[f"{plant}.{_TRUTH[g]}"] for g in GROUPS])
    dq_m = r[f"{plant}.dq_m"]
    ddq_m = np.gradient(dq_m, t, axis=0)
    out = {"time": t[idx], "truth": truth[idx],
           "inputs": np.hstack([r[f"{plant}.q_m"], dq_m, ddq_m])[idx], "wall_time": r.wall_time}
    for f in filters:
        est = np.hstack([r[f"{f.name}.{_ESTIMATES[g]}"] for g in GROUPS])
        out[f.name] = est[idx] - truth[idx]
    return out


# ---------------------------------------------------------------------------------------------
# the study
# ---------------------------------------------------------------------------------------------
def run_study(scenario: str | Path, runs: int, out: str | Path, overrides: Sequence[str] = (), *,
              workers: int | None = None, scheduler: str | None = None, first_seed: int = 1,
              after: float = 0.5, progress: bool = True, plots: bool = True,
              crlb: bool = True) -> dict[str, Any]:
    """Run the Monte Carlo study and write ``study.json`` (and the PNG figures) to ``out``.

    Parameters
    ----------
    scenario
        Scenario file with a plant and one or more EKF/PF components.
    runs
        Number of Monte Carlo runs (seeds ``first_seed ..``).
    out
        Output folder (created).
    overrides
        ``--set`` overrides applied to every run (a ``scenario.seed`` among them is replaced).
    workers, scheduler
        Executor (:func:`orchestration.study.open_executor`).
    after
        Start [s] of the time averages (the transient before it is ignored).
    plots, crlb
        Write the figures; compute the bound.

    Returns
    -------
    dict
        The content of ``study.json``.

    Raises
    ------
    StudyError
        Bad arguments, a scenario without filters, or failed runs (naming them).
    """
    from .crlb import CrlbError, robot_crlb
    from fmus.common.robot_params import RobotParameters
    from fmus.estimators.ekf_accelerometer_model import EkfAccelerometerParameters
    from .scenario import ScenarioError

    if runs < 1:
        raise study.StudyError(f"--runs must be at least 1, not {runs}")
    scenario = str(scenario)
    overrides = [o for o in overrides if not o.replace(" ", "").startswith("scenario.seed=")]
    try:
        sc, filters, plant = _scenario_parts(scenario, overrides)
    except ScenarioError as exc:
        raise study.StudyError(str(exc)) from None
    ratio = filters[0].ratio
    T = filters[0].step
    if not 0 <= after < sc.stop_time:
        raise study.StudyError(f"--after = {after:g} s must lie in [0, stop_time = {sc.stop_time:g} s)")
    seeds = list(range(first_seed, first_seed + runs))
    path = str(Path(scenario).resolve())
    jobs = [(path, tuple(overrides) + (f"scenario.seed={s}",), tuple(filters), plant, ratio)
            for s in seeds]
    t0 = time.perf_counter()
    with study.open_executor(workers, scheduler) as ex:
        results = study.map_jobs(run_one, jobs, ex, desc=f"montecarlo {sc.name}", progress=progress,
                                 star=True)
    wall_runs = time.perf_counter() - t0

    tk = results[0]["time"]
    truth0 = results[0]["truth"]
    truth_dev = max(float(np.max(np.abs(r["truth"] - truth0))) for r in results)
    keep = tk >= after
    summary: dict[str, Any] = {}
    per_time: dict[str, Any] = {"time": tk}
    for f in filters:
        err = np.stack([r[f.name] for r in results])             # (runs, K, 6), seed order
        entry: dict[str, Any] = {"fmu": f.fmu, "use_accelerometer": f.use_accelerometer}
        pt: dict[str, Any] = {}
        for gi, g in enumerate(GROUPS):
            e = err[:, :, 2 * gi:2 * gi + 2]
            rmse_t = np.sqrt(np.mean(np.sum(e * e, axis=2), axis=0))      # eq. 27
            pt[g] = rmse_t
            entry[f"rmse_{g}"] = float(np.mean(rmse_t[keep]))
        per_time[f.name] = pt
        summary[f.name] = entry

    # ---- the bound along the true trajectory of run 0
    bounds: dict[str, Any] = {}
    model_bounds: dict[str, Any] = {}
    t1 = time.perf_counter()
    if crlb:
        plant_p = _dataclass_from_scalars(RobotParameters, sc.components[plant].parameters)
        u0 = results[0]["inputs"]
        cache: dict[tuple, Any] = {}
        for f in filters:
            p = _dataclass_from_scalars(EkfAccelerometerParameters, f.parameters)
            for dyn, tag, store in (("physical", "crlb", bounds), ("ekf", "ekf_model_bound", model_bounds)):
                key = (f.use_accelerometer, p, dyn)
                if key not in cache:
                    try:
                        cache[key] = robot_crlb(truth0[:, 0:2], truth0[:, 2:4], truth0[:, 4:6], u0[:, 0:2],
                                                u0[:, 2:4], u0[:, 4:6], T, p, f.use_accelerometer, plant_p,
                                                dynamics=dyn)
                    except CrlbError as exc:
                        raise study.StudyError(f"CRLB ({dyn} dynamics) for filter '{f.name}': {exc}") from None
                b = cache[key]
                store[f.name] = {g: getattr(b, g) for g in GROUPS}
                for g in GROUPS:
                    summary[f.name][f"{tag}_{g}"] = float(np.mean(store[f.name][g][keep]))
                    summary[f.name][f"rmse_over_{tag}_{g}"] = (summary[f.name][f"rmse_{g}"]
                                                               / summary[f.name][f"{tag}_{g}"])
    wall_crlb = time.perf_counter() - t1

    # ---- Table 1 and the accelerometer's gain (first EKF with / without accelerometer)
    ekfs = [f for f in filters if f.fmu == "EkfAccelerometer"]
    with_acc = next((f.name for f in ekfs if f.use_accelerometer), None)
    without = next((f.name for f in ekfs if not f.use_accelerometer), None)
    table1: dict[str, Any] = {"paper": PAPER_TABLE1}
    if with_acc:
        table1["accelerometer"] = {g: summary[with_acc][f"rmse_{g}"] for g in GROUPS}
    if without:
        table1["no_accelerometer"] = {g: summary[without][f"rmse_{g}"] for g in GROUPS}
    if with_acc and without:
        table1["ratio_without_over_with"] = {g: summary[without][f"rmse_{g}"] / summary[with_acc][f"rmse_{g}"]
                                             for g in GROUPS}
        table1["paper_ratio_without_over_with"] = {
            g: PAPER_TABLE1["no_accelerometer"][g] / PAPER_TABLE1["accelerometer"][g] for g in GROUPS}
        table1["position_reduction"] = 1.0 - (summary[with_acc]["rmse_position"]
                                              / summary[without]["rmse_position"])
    pfs = [f for f in filters if f.fmu == "ParticleFilter"]
    pf_vs_ekf = {}
    for f in pfs:
        ref = with_acc if f.use_accelerometer else without
        if ref:
            pf_vs_ekf[f.name] = {"ekf": ref, "position_ratio": summary[f.name]["rmse_position"]
                                 / summary[ref]["rmse_position"]}

    data = {
        "study": "montecarlo",
        "scenario": sc.name,
        "scenario_file": scenario,
        "overrides": list(overrides),
        "runs": runs,
        "seeds": [seeds[0], seeds[-1]],
        "filter_step": T,
        "evaluation_instants": "t_j + base_step, t_j = j * filter_step (the filters' fresh estimates)",
        "after": after,
        "time_average": "arithmetic mean over t >= after of rmse(t) (eq. 27) and of sqrt(trace CRLB)",
        "filters": {f.name: {"fmu": f.fmu, "use_accelerometer": f.use_accelerometer,
                             "parameters": f.parameters} for f in filters},
        "truth_max_deviation_between_runs": truth_dev,
        "summary": summary,
        "table1": table1,
        "pf_vs_ekf": pf_vs_ekf,
        "per_time": {"time": tk, **{n: per_time[n] for n in summary}},
        "crlb": {"time": tk, **bounds} if bounds else None,
        "ekf_model_bound": {"time": tk, **model_bounds} if model_bounds else None,
        "wall_time_s": {"runs": wall_runs, "crlb": wall_crlb,
                        "mean_per_run": float(np.mean([r["wall_time"] for r in results]))},
        "executor": {"workers": workers, "scheduler": scheduler},
    }
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "study.json").write_text(json.dumps(_jsonable(data), indent=1) + "\n", encoding="utf-8")
    if plots:
        _plots(out, data, filters)
    return data


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return [_jsonable(v) for v in x.tolist()]
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if math.isfinite(v) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (np.bool_,)):
        return bool(x)
    return x


def _plots(out: Path, data: dict[str, Any], filters: Sequence[FilterInfo]) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.asarray(data["per_time"]["time"])
    ekfs = [f for f in filters if f.fmu == "EkfAccelerometer"]
    fig, ax = plt.subplots(figsize=(8, 4.5))
    for f, color in zip(ekfs, ("C0", "C1", "C2", "C3")):
        label = "with accelerometer" if f.use_accelerometer else "without accelerometer"
        ax.semilogy(t, data["per_time"][f.name]["position"], color=color, label=f"EKF RMSE, {label} ({f.name})")
        if data["crlb"]:
            ax.semilogy(t, data["crlb"][f.name]["position"], color=color, ls="--", label=f"CRLB, {label}")
            ax.semilogy(t, data["ekf_model_bound"][f.name]["position"], color=color, ls=":",
                        label=f"bound of the EKF's own model, {label}")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("angular position RMSE [rad]")
    ax.set_title(f"{data['scenario']}: {data['runs']} Monte Carlo runs (cf. Axelsson et al. 2012, Fig. 3)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "fig3.png", dpi=120)
    plt.close(fig)
    pfs = [f for f in filters if f.fmu == "ParticleFilter"]
    if pfs:
        fig, ax = plt.subplots(figsize=(8, 4.5))
        for f in [e for e in ekfs if e.use_accelerometer] + pfs:
            ax.semilogy(t, data["per_time"][f.name]["position"], label=f"{f.fmu} ({f.name})")
        ax.set_xlabel("time [s]")
        ax.set_ylabel("angular position RMSE [rad]")
        ax.set_title(f"{data['scenario']}: PF against EKF (cf. Axelsson et al. 2012, Fig. 4)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(out / "fig4.png", dpi=120)
        plt.close(fig)


# ---------------------------------------------------------------------------------------------
# CLI
# ---------------------------------------------------------------------------------------------
def register(subparsers: Any) -> None:
    """Add ``montecarlo`` to the ``flexfusion study`` sub-commands."""
    p = subparsers.add_parser("montecarlo", help="Monte Carlo over noise seeds: RMSE against the CRLB "
                              "(Axelsson et al. 2012, Fig. 3, Table 1, Fig. 4)",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("scenario", help="scenario file (e.g. orchestration/scenarios/axelsson2012.toml)")
    p.add_argument("--runs", type=int, required=True, metavar="N", help="number of Monte Carlo runs")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (study.json, fig3.png, fig4.png)")
    p.add_argument("--set", action="append", default=[], metavar="COMP.PARAM=VALUE", dest="overrides",
                   help="override a parameter in every run (repeatable)")
    p.add_argument("--first-seed", type=int, default=1, help="seed of the first run (default 1)")
    p.add_argument("--after", type=float, default=0.5,
                   help="ignore the transient before this time [s] in the time averages (default 0.5)")
    p.add_argument("--no-crlb", action="store_true", help="skip the Cramér-Rao bound")
    p.add_argument("--no-plots", action="store_true", help="write study.json only")
    study.add_executor_arguments(p)
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    """Run the study from parsed arguments; print the summary. Returns the exit code."""
    data = run_study(args.scenario, args.runs, args.out, args.overrides, workers=args.workers,
                     scheduler=args.scheduler, first_seed=args.first_seed, after=args.after,
                     progress=not args.no_progress, plots=not args.no_plots, crlb=not args.no_crlb)
    print(format_summary(data))
    return 0


def format_summary(data: dict[str, Any]) -> str:
    """A short text table of the time-averaged RMSE (and CRLB) per filter."""
    lines = [f"{data['scenario']}: {data['runs']} runs, t >= {data['after']:g} s, "
             f"wall {data['wall_time_s']['runs']:.1f} s"]
    for name, s in data["summary"].items():
        parts = [f"{g} RMSE {s[f'rmse_{g}']:.3g}"
                 + (f" (CRLB {s[f'crlb_{g}']:.3g}, EKF-model bound {s[f'ekf_model_bound_{g}']:.3g})"
                    if f"crlb_{g}" in s else "")
                 for g in GROUPS]
        lines.append(f"  {name} [{s['fmu']}, acc={'on' if s['use_accelerometer'] else 'off'}]: " + ", ".join(parts))
    t1 = data["table1"]
    if "ratio_without_over_with" in t1:
        r, pr = t1["ratio_without_over_with"], t1["paper_ratio_without_over_with"]
        lines.append("  without/with accelerometer: " + ", ".join(
            f"{g} {r[g]:.2f}x (paper {pr[g]:.2f}x)" for g in GROUPS))
    for name, v in data.get("pf_vs_ekf", {}).items():
        lines.append(f"  {name} / {v['ekf']} position RMSE: {v['position_ratio']:.3f}")
    return "\n".join(lines)


__all__ = ["run_study", "run_one", "register", "main", "format_summary", "PAPER_TABLE1", "FilterInfo"]

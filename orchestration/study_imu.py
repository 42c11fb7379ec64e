"""IMU study: complementary filter against an IMU EKF on forward-kinematics poses (IMU paper).

Reproduces Table 1 and Figs. 2, 5, 6 of the IMU paper (complementary filter vs extended Kalman
filter on an ABB IRB4600): the flexible two-axis robot (the realistic plant: link bending,
torque ripple, torque-constant and static kinematic errors) runs the ISO 9283-style path at
200 mm/s (``imu2019_iso.toml``) and the 30 mm square at 80 mm/s with stops
(``imu2019_square.toml``); the tool position is estimated by forward kinematics of the
encoders with the identified robot model (FK, with its static errors), by the paper's
complementary filter (CF: one second-order split for position and orientation at 28 Hz,
"slightly less than 30 Hz", section 4) -- the main column -- and by the IMU EKF; the IMU keeps
the residual mounting and scale errors of a calibration. Extensions, labelled as such: the CF
with tuned cut-offs, one for position and one for orientation (``cf``), and one tuned split
(``cf_same``).

* :func:`run_study` -- both scenarios in parallel on the study executor; ``table1.csv``,
  ``table1.md``, ``metrics.json`` (with ``findings``: each claim of the paper, our number,
  reproduced yes/no and why; and the wall time) and the figures in the output folder.
* :func:`tune_filters` -- the tuned CFs' cut-offs and damping and the EKF's noise levels with
  the project's tuner (:func:`orchestration.study_tune.tune`: differential evolution, one
  co-simulation per candidate, on the ISO path of the realistic plant with the identified
  model, noise seed 2, checked on the held-out seeds 3 and 4; the evaluation runs seed 1). The
  result goes to ``imu2019_tuned.toml``, which both scenarios include. The paper's CF is not
  tuned.

Engine: the FMUs only, one co-simulation per path. The batched engine
(:mod:`orchestration.batched`) does not fit this study: its two runs share nothing (two paths,
one seed), so batching them only removes the FMI layer (1.3 s instead of 2.3 s for 2 s of the
ISO path, identical numbers), while the check every batched study makes runs at least one of
the two through the FMUs as well: on two workers the study would take longer, not less. The
study also reports the scenarios' own metrics, which only the master computes.

Judge (``--against``, :mod:`orchestration.judge`): as the paper (section 3.3, a Leica laser
tracker), Table 1 and the findings are scored against the scenarios' ``Tracker`` by default: its
fresh samples at their stamps, with its noise (0.02 mm) and its clock 1 ms behind the
controller's (0.2 mm at 200 mm/s on the ISO path), which the judge does not correct. The same
table against the plant's truth is ``table1_truth`` (and the scenarios' own metrics).
``--against truth`` makes the truth the judge. The tuning (:func:`tune_filters`) is judged by
the tracker too (the tuner's default).

The IMU is the paper's STIM300 (high-end; its data-sheet noise and bias instability in the
scenarios), not the Imu FMU's MEMS-class default; ``--set imu.acc_bias_rw=1e-3 ...`` runs the
study with another IMU (the filters keep their tuning).

CLI: ``flexfusion study imu --out DIR [--tune] [--set COMP.PARAM=VALUE ...] [--stop-time S]
[--workers K | --scheduler A]``.
"""
from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .metrics import rmse
from .study import StudyError, add_executor_arguments, map_jobs, open_executor, simulate

REPO = Path(__file__).resolve().parent.parent
SCENARIOS = REPO / "orchestration" / "scenarios"
PATHS = {"iso": SCENARIOS / "imu2019_iso.toml", "square": SCENARIOS / "imu2019_square.toml"}
TUNED_INCLUDE = SCENARIOS / "imu2019_tuned.toml"
AFTER = 0.5              # s left out of the RMSE (the rest at the start)

#: Table 1 of the paper ("Root mean square error for the test trajectories and estimation
#: methods"): RMSE in metres; the paper's "Cube" row is our square, its CF is our ``cf_paper``.
PAPER_TABLE1 = {"iso": {"cf_paper": 0.95e-3, "ekf": 0.94e-3, "fk": 1.44e-3},
                "square": {"cf_paper": 0.81e-3, "ekf": 0.93e-3, "fk": 0.79e-3}}

#: What each estimate is in the scenarios, in the table's order: the paper's three first.
ESTIMATES = {"cf_paper": "cf_paper.p_tool_hat", "ekf": "ekf.p_tool_hat", "fk": "rigid.p_tool_hat",
             "cf": "cf.p_tool_hat", "cf_same": "cf_same.p_tool_hat"}
LABELS = {"fk": "forward kinematics", "cf_paper": "CF (the paper's: one split, 28 Hz)",
          "ekf": "IMU EKF", "cf": "CF, tuned, two splits (extension)",
          "cf_same": "CF, tuned, one split (extension)", "truth": "true tool position"}

#: Noise seeds of the tuning (the evaluation runs seed 1, the scenarios' own): the cost is
#: that of seed 2; seeds 3 and 4 are held out (never seen by the optimiser).
TUNE_SEEDS = (2,)
HOLDOUT_SEEDS = (3, 4)


# ---------------------------------------------------------------------------------------------
# metrics
# ---------------------------------------------------------------------------------------------
def error_norm(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Euclidean position error per sample (m)."""
    return np.linalg.norm(np.asarray(estimate, float) - np.asarray(truth, float), axis=1)


def table1(runs: dict[str, Any], after: float = AFTER, judge: Any = None) -> dict[str, dict[str, float]]:
    """RMSE (m) of every estimate per path, from runs with ``time`` and the recorded variables
    (a :class:`~orchestration.results.Result` or a dict of arrays), against ``judge``
    (:class:`orchestration.judge.Judge`: the tracker's fresh samples at their stamps,
    :func:`orchestration.judge.aligned`); None: against the plant's truth ``plant.p_tool`` at
    every row."""
    from .judge import aligned
    out: dict[str, dict[str, float]] = {}
    for path, r in runs.items():
        position, stamp = (np.asarray(r["plant.p_tool"]), None) if judge is None else judge.series(r)
        row = {}
        for key, var in ESTIMATES.items():
            t, est, ref = aligned(np.asarray(r["time"]), np.asarray(r[var]), position, stamp)
            keep = t >= after - 1e-12
            row[key] = rmse(est[keep], ref[keep])
        out[path] = row
    return out


def _finding(claim: str, ours: str, reproduced: bool, why: str) -> dict[str, Any]:
    return {"claim": claim, "ours": ours, "reproduced": "yes" if reproduced else "no", "why": why}


def findings(table: dict[str, dict[str, float]]) -> list[dict[str, Any]]:
    """The paper's claims (section 6-7, Table 1) checked on our Table 1, the paper's CF
    (``cf_paper``) as its CF; a last item on our tuned CF (extension).

    Thresholds: "beats" = at least 20 % lower RMSE (paper: 34 %); "similar" = within 10 %
    (paper: 1 % on ISO); "as good" = within 10 %.
    """
    out: list[dict[str, Any]] = []
    iso, sq = table.get("iso"), table.get("square")
    mm = lambda v: f"{v * 1e3:.3f} mm"   # noqa: E731

    def vs_fk(v: float, fk: float) -> str:
        g = 1 - v / fk
        return f"{abs(100 * g):.0f} % {'below' if g >= 0 else 'above'} FK"
    if iso:
        g_cf, g_ekf = 1 - iso["cf_paper"] / iso["fk"], 1 - iso["ekf"] / iso["fk"]
        ok = g_cf >= 0.2 and g_ekf >= 0.2
        out.append(_finding(
            "On the ISO path both filters beat forward kinematics (paper: 0.95 and 0.94 vs 1.44 mm, 34 %)",
            f"CF {mm(iso['cf_paper'])} ({vs_fk(iso['cf_paper'], iso['fk'])}), EKF {mm(iso['ekf'])} "
            f"({vs_fk(iso['ekf'], iso['fk'])}), FK {mm(iso['fk'])}; the same CF with tuned splits "
            f"(extension) {mm(iso['cf'])} ({vs_fk(iso['cf'], iso['fk'])})", ok,
            "" if ok else ("what we believe: a split at 28 Hz takes FK's position below 28 Hz, and "
                           "our arm's vibration (lowest modes 8-15 Hz, link bending 35 Hz) lies "
                           "below or at it, so the CF is FK with IMU detail above 28 Hz; a split "
                           "well below the vibration (our tuned CF's, below 1 Hz) removes it. The paper's "
                           "robot may have had its FK error above its split" if g_cf < 0.2 else
                           "the EKF's gain is below 20 %")))
        r = iso["cf_paper"] / iso["ekf"] - 1
        ok = abs(r) <= 0.1
        out.append(_finding(
            "The CF and the EKF give similar RMSE (paper ISO: CF +1 % vs EKF)",
            f"ISO: CF {100 * r:+.0f} % vs EKF ({mm(iso['cf_paper'])} vs {mm(iso['ekf'])})", ok,
            "" if ok else "the 28 Hz CF follows FK (previous finding); the EKF's split follows from "
            "its tuned noise levels (imu2019_tuned.toml), far below 28 Hz"))
    if sq:
        r = sq["fk"] / sq["cf_paper"] - 1
        ok = abs(r) <= 0.1
        fk_iso = f"; FK ISO -> square {mm(iso['fk'])} -> {mm(sq['fk'])}" if iso else ""
        out.append(_finding(
            "On the slow square (cube) with stops, forward kinematics is as good as the filters "
            "(paper: FK 0.79 vs CF 0.81 mm): FK errors come from acceleration",
            f"square: FK {mm(sq['fk'])}, CF {mm(sq['cf_paper'])} (FK {100 * r:+.0f} %), EKF "
            f"{mm(sq['ekf'])}{fk_iso} (paper 1.44 -> 0.79 mm)", ok,
            "reproduced, but trivially for the CF: at 28 Hz it follows FK on both paths; FK's "
            "error falls on the slower path as in the paper" if ok else
            "FK's error on our plant is not dominated by acceleration"))
        ok = sq["cf_paper"] < sq["ekf"]
        out.append(_finding(
            "The CF is slightly better than the EKF on the slower trajectory (paper: 0.81 vs 0.93 mm)",
            f"square: CF {mm(sq['cf_paper'])} vs EKF {mm(sq['ekf'])}", ok,
            "" if ok else "the 28 Hz CF is FK with IMU detail above 28 Hz; our tuned EKF weighs "
            "the IMU down to lower frequencies"))
    for path, row in table.items():
        g = 1 - row["cf"] / row["fk"]
        out.append(_finding(
            f"(extension) the CF with tuned splits (two cut-offs) beats FK on the {path} path",
            f"{path}: tuned CF {mm(row['cf'])} vs FK {mm(row['fk'])} ({vs_fk(row['cf'], row['fk'])}), one tuned "
            f"split {mm(row['cf_same'])}", g >= 0.2,
            "not a claim of the paper; tuned (imu2019_tuned.toml) on the ISO path of this plant "
            "with noise seed 2 (held out 3 and 4; the table's runs are seed 1)"))
    return out


def format_table(table: dict[str, dict[str, float]], against: str = "") -> str:
    """Table 1 as Markdown: ours beside the paper's (mm); ``against`` a line saying what ours
    are judged against."""
    lines = ([against, ""] if against else []) + ["| path | paper's CF (one split, 28 Hz) | IMU EKF | FK | paper CF | paper EKF | paper FK | "
             "ext.: tuned CF, two splits | ext.: tuned CF, one split |",
             "|---|---|---|---|---|---|---|---|---|"]
    for path, row in table.items():
        p = PAPER_TABLE1.get(path, {})
        name = "ISO 9283 (200 mm/s)" if path == "iso" else "30 mm square (80 mm/s, stops)"
        ours = [row[k] for k in ("cf_paper", "ekf", "fk")]
        paper = [p.get(k, math.nan) for k in ("cf_paper", "ekf", "fk")]
        ext = [row[k] for k in ("cf", "cf_same")]
        lines.append(f"| {name} | " + " | ".join(f"{v * 1e3:.3f} mm" for v in ours) + " | "
                     + " | ".join(f"{v * 1e3:.2f} mm" for v in paper) + " | "
                     + " | ".join(f"{v * 1e3:.3f} mm" for v in ext) + " |")
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------------------------
# figures
# ---------------------------------------------------------------------------------------------
def plot_figures(runs: dict[str, Any], out_dir: Path) -> list[Path]:
    """Fig. 2 (ISO path with the estimates), Fig. 4 (square path), Fig. 5 (ISO error over time),
    Fig. 6 (square error over time), as PNG."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    files: list[Path] = []
    styles = {"fk": dict(color="tab:red", lw=0.8), "cf_paper": dict(color="tab:blue", lw=0.8),
              "ekf": dict(color="tab:green", lw=0.8, ls="--"), "cf": dict(color="tab:purple", lw=0.6, ls=":")}
    for path, fig_no, zoom in (("iso", 2, None), ("square", 4, None)):
        if path not in runs:
            continue
        r = runs[path]
        truth = np.asarray(r["plant.p_tool"]) * 1e3
        fig, axes = plt.subplots(1, 2, figsize=(12, 5.5))
        for ax, detail in zip(axes, (False, True)):
            ax.plot(truth[:, 0], truth[:, 1], "k", lw=1.0, label=LABELS["truth"])
            for key, st in styles.items():
                p = np.asarray(r[ESTIMATES[key]]) * 1e3
                ax.plot(p[:, 0], p[:, 1], label=LABELS[key], **st)
            ax.plot(truth[0, 0], truth[0, 1], "ko", mfc="none", ms=9, label="start")
            ax.set_xlabel("x [mm]")
            ax.set_ylabel("z [mm]")
            ax.set_aspect("equal", adjustable="datalim")
            ax.grid(alpha=0.3)
            if detail:   # a corner with the largest FK error
                e = error_norm(np.asarray(r[ESTIMATES["fk"]]), np.asarray(r["plant.p_tool"]))
                k = int(np.argmax(e))
                c = truth[k]
                ax.set_xlim(c[0] - 3, c[0] + 3)
                ax.set_ylim(c[1] - 3, c[1] + 3)
                ax.set_title(f"detail at the largest FK error (t = {float(np.asarray(r['time'])[k]):.2f} s)")
            else:
                ax.set_title("tool path and estimates")
                ax.legend(fontsize=8)
        name = "ISO 9283-style path, 200 mm/s" if path == "iso" else "30 mm square, 80 mm/s with stops"
        fig.suptitle(f"Estimates on the {name} (cf. paper Fig. {fig_no})")
        fig.tight_layout()
        f = out_dir / f"fig{fig_no}_{path}_path.png"
        fig.savefig(f, dpi=120)
        plt.close(fig)
        files.append(f)
    for path, fig_no in (("iso", 5), ("square", 6)):
        if path not in runs:
            continue
        r = runs[path]
        t = np.asarray(r["time"])
        truth = np.asarray(r["plant.p_tool"])
        fig, axes = plt.subplots(2, 1, figsize=(11, 7), sharex=False)
        for key, st in styles.items():
            e = error_norm(np.asarray(r[ESTIMATES[key]]), truth) * 1e3
            axes[0].plot(t, e, label=LABELS[key], **st)
        a = np.linalg.norm(np.asarray(r["plant.a_tool"]), axis=1)
        axes[1].plot(t, a, "k", lw=0.8)
        axes[1].set_ylabel("|tool acceleration| [m/s²]")
        axes[0].set_ylabel("position error [mm]")
        axes[0].legend(fontsize=8)
        for ax in axes:
            ax.set_xlabel("t [s]")
            ax.grid(alpha=0.3)
            ax.set_xlim(AFTER, float(t[-1]))
        name = "ISO 9283-style path" if path == "iso" else "30 mm square"
        axes[0].set_title(f"Estimation error on the {name} (cf. paper Fig. {fig_no})")
        fig.tight_layout()
        f = out_dir / f"fig{fig_no}_{path}_error.png"
        fig.savefig(f, dpi=120)
        plt.close(fig)
        files.append(f)
    return files


# ---------------------------------------------------------------------------------------------
# the study
# ---------------------------------------------------------------------------------------------
def _overrides(stop_time: float | None) -> list[str]:
    return [] if stop_time is None else [f"scenario.stop_time={float(stop_time)!r}"]


def run_study(out_dir: Path, *, stop_time: float | None = None, workers: int | None = None,
              scheduler: str | None = None, progress: bool = True,
              paths: Sequence[str] = ("iso", "square"), overrides: Sequence[str] = (),
              against: str = "reference") -> dict[str, Any]:
    """Run the scenarios (in parallel), write Table 1, the findings and the figures.

    ``overrides`` (``comp.param=value``) apply to every run, e.g. another IMU. ``against``:
    the judge of Table 1 and the findings (:mod:`orchestration.judge`): ``"reference"``
    (default, as the paper: the scenarios' laser tracker, its fresh samples at their stamps) or
    ``"truth"`` (the plant's tool position); the table against the truth is always there too
    (``table1_truth``).

    Returns
    -------
    dict
        ``against`` and ``judge`` (what ``table1`` is judged against), ``table1`` (path ->
        estimate -> RMSE in m), ``table1_truth`` (the same against the plant's truth),
        ``paper_table1``, ``labels``, ``findings`` (list of {claim, ours, reproduced, why}, on
        ``table1``), ``wall_time`` (total on the workers, and per run) and ``figures``.
    """
    from .judge import JudgeError, judge
    from .study_tune import load_document
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    for p in paths:
        if p not in PATHS:
            raise StudyError(f"unknown path '{p}' (known: {', '.join(PATHS)})")
    docs, judges = {}, {}
    for p in paths:
        doc = load_document(PATHS[p])
        try:
            judges[p] = judge(doc, against)
        except JudgeError as exc:
            raise StudyError(f"{PATHS[p].name}: {exc}") from None
        record = doc.setdefault("record", {}).setdefault("variables", [])
        record += [v for v in judges[p].variables if v not in record]     # the scenario does not know the study
        docs[p] = doc
    jobs = [(docs[p], _overrides(stop_time) + list(overrides)) for p in paths]
    n_workers = workers or min(2, len(jobs))
    t0 = time.perf_counter()
    with open_executor(workers=n_workers, scheduler=scheduler) as ex:
        results = map_jobs(simulate, jobs, ex, desc="imu study", progress=progress, star=True)
    wall = time.perf_counter() - t0
    runs = dict(zip(paths, results))
    the_judge = judges[paths[0]]
    table = table1(runs, judge=the_judge)
    truth_table = table1(runs)
    res: dict[str, Any] = {
        "against": the_judge.against, "judge": the_judge.to_json(),
        "table1": table, "table1_truth": truth_table, "paper_table1": PAPER_TABLE1, "labels": LABELS,
        "findings": findings(table),
        "wall_time": {"total_s": wall, "workers": n_workers, **{p: r.wall_time for p, r in runs.items()}},
        "metrics": {p: r.metrics for p, r in runs.items()},
        "overrides": list(overrides),
    }
    (out_dir / "table1.md").write_text(format_table(table, judged_line(the_judge)) + "\n"
                                       + format_table(truth_table, "Against the plant's truth (plant.p_tool), "
                                                      "which the paper could not see:"))
    with open(out_dir / "table1.csv", "w") as fh:
        fh.write("path,estimate,rmse_mm,rmse_truth_mm,paper_rmse_mm\n")
        for p, row in table.items():
            for k, v in row.items():
                fh.write(f"{p},{k},{v * 1e3:.6f},{truth_table[p][k] * 1e3:.6f},"
                         f"{PAPER_TABLE1.get(p, {}).get(k, math.nan) * 1e3:.3f}\n")
    res["figures"] = [str(f) for f in plot_figures(runs, out_dir)]
    (out_dir / "metrics.json").write_text(json.dumps(res, indent=2))
    return res


def run_judge(res: dict[str, Any]) -> Any:
    """The :class:`orchestration.judge.Judge` of a study result's ``judge`` entry."""
    from .judge import Judge
    j = res["judge"]
    return Judge(j["against"], j["component"], j["variable"], j["stamp"], j["fmu"])


def judged_line(j: Any) -> str:
    """A line saying what a table is judged against (:class:`orchestration.judge.Judge`)."""
    if j.against == "reference":
        return (f"Against the reference system, as the paper ({j.component}.{j.position.split('.', 1)[1]}: "
                "its fresh samples at their stamps, its noise and clock skew included):")
    return f"Against the {j.against} ({j.position}):"


# ---------------------------------------------------------------------------------------------
# tuning (the project's tuner)
# ---------------------------------------------------------------------------------------------
#: The tuned estimators (the paper's CF, ``cf_paper``, is not tuned), components of the ISO path.
TUNED = ("cf", "cf_same", "ekf")


def tuned_bounds(kind: str) -> dict[str, tuple[float, float]]:
    """Search ranges of the tuning of ``kind`` (one of :data:`TUNED`; log10 search): the shared
    tuner's defaults, those its FMU declares (:func:`orchestration.study_tune.default_bounds`);
    the one-split CF without the orientation's own cut-off."""
    from .scenario import scenario_document
    from .study_tune import default_bounds
    bounds = default_bounds(scenario_document(PATHS["iso"]), kind)
    return {k: v for k, v in bounds.items() if not (kind == "cf_same" and k == "cutoff_orientation")}


def tune_filters(out_dir: Path, *, seeds: Sequence[int] = TUNE_SEEDS,
                 holdout_seeds: Sequence[int] = HOLDOUT_SEEDS, maxiter: int = 6, popsize: int = 4,
                 workers: int | None = None, scheduler: str | None = None, progress: bool = True,
                 stop_time: float | None = None, only: Sequence[str] | None = None) -> dict[str, Any]:
    """Tune the CF (position cut-off and damping, orientation cut-off), the CF with one tuned
    split (``cf_same``) and the EKF (jerk and angular-acceleration noise, FK position and
    orientation noise) with :func:`orchestration.study_tune.tune` on the ISO path (the realistic
    plant, FK with the identified model), the cost over the noise ``seeds``, checked on
    ``holdout_seeds``; write ``imu2019_tuned.toml`` and ``tuning.json`` into ``out_dir``.
    ``only`` tunes some of them and keeps the others' results from an earlier ``tuning.json``.
    The defaults are those of ``flexfusion study tune orchestration/scenarios/imu2019_iso.toml
    --estimator cf --estimator ekf --seeds 2 --holdout-seeds 3,4 --maxiter 6 --popsize 4`` (and
    ``cf_same`` with its two bounds), judged by the tuner's default, the scenario's tracker; the
    shipped include was tuned with ``--against truth`` (before the tracker was the default)."""
    from .study_tune import tune, write_include

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    result: dict[str, Any] = {"seeds": list(seeds), "holdout_seeds": list(holdout_seeds), "path": "iso"}
    previous = out_dir / "tuning.json"
    if only is not None and previous.exists():
        result.update({k: v for k, v in json.loads(previous.read_text()).items() if k in TUNED})
    with open_executor(workers=workers or 2, scheduler=scheduler) as ex:
        for kind in TUNED:
            if only is not None and kind not in only:
                continue
            r = tune(PATHS["iso"], kind, tuned_bounds(kind), after=AFTER, maxiter=maxiter, popsize=popsize,
                     executor=ex, progress=progress, overrides=_overrides(stop_time),
                     seeds=seeds, holdout_seeds=holdout_seeds)
            result[kind] = {"params": r.params, "rmse": r.cost, "holdout_rmse": r.holdout_cost,
                            "n_evals": r.n_evals, "failed": r.failed, "against": r.against, "judge": r.judge}
    result["wall_time"] = time.perf_counter() - t0
    parts = []
    for kind in TUNED:
        if kind in result:
            f = write_include(out_dir / f"tuned_{kind}.toml", kind, result[kind]["params"],
                              f"RMSE {result[kind]['rmse'] * 1e3:.4f} mm, held out "
                              f"{result[kind].get('holdout_rmse', math.nan) * 1e3:.4f} mm")
            parts.append(f.read_text())
    head = ("# Tuned filter parameters of the IMU-paper scenarios (imu2019_iso.toml,\n"
            "# imu2019_square.toml), included by both. Written by `flexfusion study imu --tune`\n"
            f"# (orchestration.study_tune.tune on the ISO path, noise seeds {list(seeds)}, held out "
            f"{list(holdout_seeds)}, maxiter {maxiter}, popsize {popsize}).\n\n")
    (out_dir / "imu2019_tuned.toml").write_text(head + "\n".join(parts))
    (out_dir / "tuning.json").write_text(json.dumps(result, indent=2))
    return result


# ---------------------------------------------------------------------------------------------
# CLI
# ---------------------------------------------------------------------------------------------
def main(args: argparse.Namespace) -> int:
    """``flexfusion study imu``."""
    out = Path(args.out)
    progress = not args.no_progress
    if args.tune:
        res = tune_filters(out, workers=args.workers, scheduler=args.scheduler, progress=progress,
                           maxiter=args.maxiter, stop_time=args.stop_time)
        print(f"tuned on the ISO path (seeds {res['seeds']}) in {res['wall_time']:.0f} s: "
              f"CF {res['cf']['params']} -> {res['cf']['rmse'] * 1e3:.4f} mm, "
              f"EKF {res['ekf']['params']} -> {res['ekf']['rmse'] * 1e3:.4f} mm")
        print(f"wrote {out / 'imu2019_tuned.toml'} (copy it to {TUNED_INCLUDE} to use it)")
        return 0
    res = run_study(out, stop_time=args.stop_time, workers=args.workers, scheduler=args.scheduler,
                    progress=progress, overrides=tuple(args.set or ()), against=args.against)
    print(format_table(res["table1"], judged_line(run_judge(res))), end="")
    if res["against"] != "truth":
        print("\n" + format_table(res["table1_truth"], "Against the plant's truth (plant.p_tool), which the paper "
                           "could not see:"), end="")
    for f in res["findings"]:
        print(f"[{f['reproduced']:>3}] {f['claim']}\n      ours: {f['ours']}"
              + (f"\n      why: {f['why']}" if f["why"] else ""))
    print(f"{len(res['table1'])} runs in {res['wall_time']['total_s']:.0f} s on {res['wall_time']['workers']} workers")
    print(f"wrote Table 1, metrics.json and {len(res['figures'])} figures to {out}")
    return 0


def register(subparsers: Any) -> None:
    """Add ``flexfusion study imu``."""
    p = subparsers.add_parser("imu", help="IMU paper: complementary filter vs IMU EKF vs forward "
                              "kinematics (Table 1, Figs. 2, 5, 6)", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--stop-time", type=float, default=None, help="shorter runs (s), for a quick look")
    p.add_argument("--tune", action="store_true", help="tune the filters instead (study_tune's "
                   "tuner) and write imu2019_tuned.toml into DIR")
    p.add_argument("--maxiter", type=int, default=6, help="generations of the tuning (default 6)")
    p.add_argument("--against", choices=("reference", "truth"), default="reference",
                   help="judge of Table 1 and the findings: the scenarios' laser tracker (default, as the "
                        "paper) or the plant's truth (always reported beside it)")
    p.add_argument("--set", action="append", metavar="COMP.PARAM=VALUE",
                   help="override for every run (repeatable), e.g. imu.acc_bias_rw=1e-3")
    add_executor_arguments(p)
    p.set_defaults(func=main)


__all__ = ["run_study", "judged_line", "tune_filters", "table1", "findings", "format_table", "plot_figures",
           "register", "PAPER_TABLE1", "ESTIMATES", "LABELS", "TUNED", "tuned_bounds"]

"""Robustness of the tool-position observers: the analogue of Table I and Figs. 4-6 of
Henriksson et al. (2009), section IV.

Rows (cases), each one scenario run:

* **Nominal** -- path P1 (``henriksson2009_p1.toml``), the observers tuned on it;
* **Tuning** -- path P2 (``henriksson2009_p2.toml``) with the tuning of P1;
* **Model errors** -- path P1 with every observer's joint stiffness 50 % below the plant's
  (``stiffness_scale = 0.5`` on every estimator that has that parameter; rigid kinematics has no
  dynamic model and is unchanged, as in the paper).

Columns: every estimator in the scenarios (components of a known estimator FMU type), rigid
kinematics included. For each: max and mean of the tool-position error norm over all
frequencies and after the zero-phase 3-30 Hz band-pass (:func:`orchestration.metrics.bandpass_errors`),
after the first ``after`` seconds.

Outputs in ``--out``: ``table.json`` (our numbers and the paper's), ``table.md`` (both side by
side, in millimetres) and ``fig4_nominal.png``, ``fig5_tuning.png``, ``fig6_model_errors.png``
(band-passed tool x-position of a part with a hammer strike, truth and estimates, like the
paper's figures) plus ``fig3_nominal_all.png`` (all frequencies, the paper's Fig. 3).

CLI: ``flexfusion study robustness --out DIR [--tuned FILE ...] [--stop-time S] [--workers K |
--scheduler ADDR]``.
"""
from __future__ import annotations

import argparse
import json
import time
import tomllib
from concurrent.futures import Executor
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .study import StudyError, add_executor_arguments, map_jobs, open_executor, simulate

SCENARIOS = Path(__file__).resolve().parent / "scenarios"

#: (key, row label, scenario file, stiffness scale of the observers)
CASES: tuple[tuple[str, str, str, float], ...] = (
    ("nominal", "Nominal", "henriksson2009_p1.toml", 1.0),
    ("tuning", "Tuning", "henriksson2009_p2.toml", 1.0),
    ("model_errors", "Model errors", "henriksson2009_p1.toml", 0.5),
)

#: Estimator FMU types and their column labels (the paper's names where it has them).
ESTIMATOR_TYPES = {
    "EkfComplete": "EKF Complete",
    "EkfMotor": "EKF Motor",
    "EkfIntegrated": "EKF Integrated",
    "AccelerationObserver": "Det. Observer",
    "RigidKinematics": "Rigid kinematics",
}
#: Estimator types with a ``stiffness_scale`` parameter (their model has joint stiffness).
STIFFNESS_TYPES = ("EkfComplete", "EkfMotor", "EkfIntegrated", "AccelerationObserver")

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
FIG_WINDOWS = {"nominal": (1.3, 2.5), "tuning": (1.0, 2.2), "model_errors": (1.3, 2.5)}


# ---------------------------------------------------------------------------------------------
# cases
# ---------------------------------------------------------------------------------------------
def _load(path: Path, tuned: Sequence[str | Path]) -> dict[str, Any]:
    from .study_tune import load_document
    doc = load_document(path)
    for f in tuned:
        try:
            inc = tomllib.loads(Path(f).read_text())
        except (OSError, tomllib.TOMLDecodeError) as exc:
            raise StudyError(f"cannot read tuned parameters {f}: {exc}") from None
        for cname, ctab in inc.get("components", {}).items():
            if cname in doc["components"]:
                doc["components"][cname].setdefault("parameters", {}).update(ctab.get("parameters", {}))
    return doc


def estimators(doc: dict[str, Any]) -> dict[str, str]:
    """``{component: FMU type}`` of the estimators in a scenario document, in file order."""
    out = {}
    for name, ctab in doc.get("components", {}).items():
        kind = Path(str(ctab.get("fmu", ""))).stem
        if kind in ESTIMATOR_TYPES:
            out[name] = kind
    return out


def column_labels(doc: dict[str, Any]) -> dict[str, str]:
    """``{component: table column}`` of the estimators: the paper's names, the observer's drift
    fix marked, ``[component]`` appended where two would share a name."""
    labels = {}
    for comp, kind in estimators(doc).items():
        label = ESTIMATOR_TYPES[kind]
        params = doc["components"][comp].get("parameters", {})
        if kind == "AccelerationObserver" and float(params.get("drift_crossover", 0.0)) > 0:
            label += f" + FK fusion ({float(params['drift_crossover']):g} Hz)"
        if kind == "EkfIntegrated" and params.get("drift_correction", "off") != "off":
            label += f" + drift correction ({params['drift_correction']})"
        labels[comp] = label
    values = list(labels.values())
    return {c: (f"{l} [{c}]" if values.count(l) > 1 else l) for c, l in labels.items()}


def case_jobs(tuned: Sequence[str | Path] = (), stop_time: float | None = None,
              cases: Sequence[tuple[str, str, str, float]] = CASES,
              scenario_dir: Path = SCENARIOS) -> list[tuple[dict[str, Any], list[str], list[str]]]:
    """One ``(document, overrides, variables)`` job per case."""
    jobs = []
    for key, _label, fname, scale in cases:
        doc = _load(scenario_dir / fname, tuned)
        est = estimators(doc)
        overrides = [f"scenario.stop_time={stop_time!r}"] if stop_time else []
        if scale != 1.0:
            overrides += [f"{c}.stiffness_scale={scale!r}" for c, k in est.items() if k in STIFFNESS_TYPES]
        variables = ["plant.p_tool"] + [f"{c}.p_tool_hat" for c in est]
        jobs.append((doc, overrides, variables))
    return jobs


def _run_case(job: tuple[dict[str, Any], list[str], list[str]]) -> dict[str, Any]:
    doc, overrides, variables = job
    run = simulate(doc, overrides, variables=variables)
    return {"time": run.time, "wall_time": run.wall_time,
            **{v: run[v] for v in variables}}


def error_stats(time_: np.ndarray, estimate: np.ndarray, truth: np.ndarray, after: float = 0.5
                ) -> dict[str, float]:
    """``all_max``, ``all_mean`` (error norm over all frequencies) and ``band_max``,
    ``band_mean`` (after the 3-30 Hz band-pass), metres, for ``time >= after``."""
    from .metrics import bandpass_errors
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
               cases: Sequence[tuple[str, str, str, float]] = CASES,
               scenario_dir: Path = SCENARIOS) -> dict[str, Any]:
    """Run the cases (in parallel on ``executor``; ``None``: here, one after the other) and
    return the table: ``{"cases": {key: {"label", "columns": {label: stats}, "wall_time"}},
    "paper": PAPER_TABLE, "series": {key: arrays for the figures}}``."""
    jobs = case_jobs(tuned, stop_time, cases, scenario_dir)
    t0 = time.perf_counter()
    if executor is None:
        results = [_run_case(j) for j in jobs]
    else:
        results = map_jobs(_run_case, jobs, executor, desc="robustness", progress=progress)
    wall = time.perf_counter() - t0
    table: dict[str, Any] = {"cases": {}, "paper": PAPER_TABLE, "wall_time": wall, "series": {}}
    for (key, label, fname, scale), (doc, overrides, variables), res in zip(cases, jobs, results):
        cols = {}
        labels = column_labels(doc)
        for comp, col in labels.items():
            cols[col] = error_stats(res["time"], res[f"{comp}.p_tool_hat"], res["plant.p_tool"], after)
        table["cases"][key] = {"label": label, "scenario": fname, "stiffness_scale": scale,
                               "overrides": overrides, "columns": cols, "wall_time": res["wall_time"]}
        table["series"][key] = {"time": res["time"], "truth": res["plant.p_tool"],
                                **{labels[c]: res[f"{c}.p_tool_hat"] for c in labels}}
    return table


def markdown(table: dict[str, Any]) -> str:
    """Table I with our numbers and the paper's (mm): one row per case and band, two columns
    (max, mean) per estimator, ``ours (paper)``."""
    cases = table["cases"]
    cols = list(dict.fromkeys(c for case in cases.values() for c in case["columns"]))
    head = "| Case | Band | " + " | ".join(f"{c} max | {c} mean" for c in cols) + " |"
    sep = "|---|---|" + "---|---|" * len(cols)
    lines = ["Tool-position error in mm: ours (paper's Table I in parentheses; the paper's column "
             "for a variant beyond it is its base observer's).", "", head, sep]
    for key, case in cases.items():
        for band, (imax, imean) in (("All", (0, 1)), ("3-30 Hz", (2, 3))):
            cells = []
            for c in cols:
                st = case["columns"].get(c)
                base = c.split(" + ")[0].split(" (")[0].split(" [")[0]
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
    lines += ["", "Band-limited mean error relative to rigid kinematics (3-30 Hz):", ""]
    for key, case in cases.items():
        rigid = case["columns"].get("Rigid kinematics")
        if not rigid:
            continue
        ratios = ", ".join(f"{c}: {rigid['band_mean'] / st['band_mean']:.2f}x lower"
                           for c, st in case["columns"].items() if c != "Rigid kinematics")
        lines.append(f"* {case['label']}: {ratios}")
    if "nominal" in cases and "model_errors" in cases:
        lines += ["", "Change of the 3-30 Hz mean error with 50 % stiffness error (model errors / nominal):", ""]
        nom, err = cases["nominal"]["columns"], cases["model_errors"]["columns"]
        for c in nom:
            if c in err:
                lines.append(f"* {c}: {err[c]['band_mean'] / nom[c]['band_mean']:.3f}")
    return "\n".join(lines) + "\n"


def _bandpass(x: np.ndarray, fs: float) -> np.ndarray:
    from scipy.signal import butter, filtfilt
    b, a = butter(4, [3.0, 30.0], btype="bandpass", fs=fs)
    padlen = min(len(x) - 1, int(np.ceil(3 * fs / 3.0)))
    return filtfilt(b, a, x, axis=0, padlen=padlen)


def figures(table: dict[str, Any], out: Path) -> list[Path]:
    """Figs. 4-6 (band-passed x-position in a window with a hammer strike) and Fig. 3 (all
    frequencies, nominal case) as PNG."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = []
    names = {"nominal": ("fig4_nominal.png", "Fig. 4: P1, 3-30 Hz"),
             "tuning": ("fig5_tuning.png", "Fig. 5: P2 (tuned on P1), 3-30 Hz"),
             "model_errors": ("fig6_model_errors.png", "Fig. 6: P1, 50 % stiffness error, 3-30 Hz")}
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
        truth_bp = _bandpass(s["truth"], fs)
        ax.plot(t[w], 1e3 * truth_bp[w, 0], "k", lw=2.0, label="true position")
        for label, est in s.items():
            if label in ("time", "truth"):
                continue
            est_bp = _bandpass(est, fs)
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
    (out / "table.json").write_text(json.dumps(js, indent=1))
    (out / "table.md").write_text(markdown(table))
    return [out / "table.json", out / "table.md"] + figures(table, out)


def main(args: argparse.Namespace) -> int:
    out = Path(args.out)
    with open_executor(args.workers, args.scheduler) as ex:
        table = robustness(args.tuned or (), executor=ex, stop_time=args.stop_time,
                           progress=not args.no_progress)
    files = write(table, out)
    print(markdown(table))
    print(f"robustness study: {len(table['cases'])} cases in {table['wall_time']:.1f} s; "
          f"wrote {', '.join(f.name for f in files)} to {out}")
    return 0


def register(subparsers: Any) -> None:
    """Add ``flexfusion study robustness``."""
    p = subparsers.add_parser("robustness", help="Table I of Henriksson et al. 2009: observers on "
                              "P1, P2 and with 50 % stiffness error", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--tuned", action="append", metavar="FILE",
                   help="TOML include file(s) with tuned estimator parameters (from `study tune`)")
    p.add_argument("--stop-time", type=float, default=None, help="shorter runs (s)")
    add_executor_arguments(p)
    p.set_defaults(func=main)


__all__ = ["robustness", "error_stats", "markdown", "figures", "write", "case_jobs", "estimators", "column_labels",
           "CASES", "PAPER_TABLE", "register"]

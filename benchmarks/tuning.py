"""A 30-evaluation tuning run (issue 16: "under 20 s"), on the batched engine and through the FMUs.

What is tuned: the user guide's tuning (docs/user_guide.md), ``flexfusion study tune
orchestration/scenarios/henriksson2009_p1.toml --estimator observer``, the deterministic observer
of Henriksson et al. (2009, section III-B) over its eight pole parameters (four pole pairs,
frequency and damping, :data:`orchestration.study_tune.DEFAULT_BOUNDS`), cost the 3-30 Hz mean
tool-position error (``--metric bandpass_mean``) on 2.5 s of path P1 (``--stop-time 2.5``), as
the shipped include file's command; ``--maxiter 1 --popsize 2``: 2 x 16 = 32 candidates on the
scenario's seed (``--seeds``/``--holdout-seeds`` add seeds, as the include file's full command
``--seeds 1,2 --holdout-seeds 3,4``). Each evaluation is one candidate on every training seed.

Prints, on ``--workers`` workers:

* one evaluation: a co-simulation of the FMUs (the FMU engine's cost per candidate and seed),
  and on the batched engine the truth's tape (once per seed) and one candidate replayed on it;
* the whole tuning run (:func:`orchestration.study_tune.tune`, with its FMU checks and the
  scenario's own values) on each engine, its wall time against the goal (under 20 s), and the
  ratio. The machine is shared: the load average is printed beside the figures, and the CPU
  time of the whole run (this process and the pool's workers, read from /proc before the pool
  closes), which the load does not stretch: on idle cores the wall time is at least CPU / workers.

Run: ``.venv/bin/python benchmarks/tuning.py [--workers 2] [--seeds 1,2 --holdout-seeds 3,4]
[--no-fmu] [--estimator ekf_motor --popsize 3]``.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from orchestration import study_tune as st  # noqa: E402
from orchestration.study import open_executor  # noqa: E402

SCENARIO = REPO / "orchestration" / "scenarios" / "henriksson2009_p1.toml"
#: a candidate other than the scenario's values, per estimator FMU type (for one evaluation)
CANDIDATE = {"AccelerationObserver": "pole_freq[1]=15.0", "EkfComplete": "lambda1=2.0", "EkfMotor": "lambda1=2.0",
             "EkfIntegrated": "lambda1=2.0"}
OVERRIDES = ["scenario.stop_time=2.5"]
METRIC = "bandpass_mean"


def one_evaluation(component: str) -> tuple[float, float, float]:
    """Seconds of one candidate on the FMUs, of one seed's tape (the scenario's own values),
    and of the candidate replayed on it (in this process; the same cost both ways)."""
    # judged as the tuner does by default: the scenario's tracker, its fresh samples at their stamps
    score = st.Score(f"{component}.p_tool_hat", "tracker.p_tool_meas", "tracker.t_meas", METRIC, 0.5)
    doc = st.prune(st.load_document(SCENARIO), score.variables)
    est, judge, stamp = score.estimate, score.judge, score.stamp
    candidate = OVERRIDES + [f"{component}.{CANDIDATE[st.fmu_type(doc, component)]}"]
    st.evaluate(doc, OVERRIDES, est, judge, 0.5, METRIC, stamp)          # imports, extraction: not timed
    t = time.perf_counter()
    fmu_cost = st.evaluate(doc, candidate, est, judge, 0.5, METRIC, stamp)
    t_fmu = time.perf_counter() - t
    t = time.perf_counter()
    tape, _ = st._tape_job(doc, OVERRIDES, score)
    t_tape = time.perf_counter() - t
    t = time.perf_counter()
    costs, _ = st._candidates_job(doc, tape, [candidate], score)
    t_replay = time.perf_counter() - t
    assert costs[0] == fmu_cost, (costs, fmu_cost)
    return t_fmu, t_tape, t_replay


def _cpu_seconds(pids: list[int]) -> float:
    """User + system CPU seconds of the processes ``pids`` so far (Linux /proc)."""
    total = 0
    for pid in pids:
        try:
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        total += int(fields[11]) + int(fields[12])          # utime, stime (fields 14, 15)
    return total / os.sysconf("SC_CLK_TCK")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--estimator", default="observer", help="component tuned (default observer; e.g. "
                    "ekf_motor, with --popsize 3 for 30 evaluations of its 5 parameters)")
    ap.add_argument("--maxiter", type=int, default=1)
    ap.add_argument("--popsize", type=int, default=2)
    ap.add_argument("--seeds", default=None, help="training seeds, e.g. 1,2 (default: the scenario's)")
    ap.add_argument("--holdout-seeds", default=None, help="held-out seeds, e.g. 3,4")
    ap.add_argument("--no-fmu", action="store_true", help="skip the tuning run on the FMU engine")
    a = ap.parse_args()
    seeds, holdout = st.parse_seeds(a.seeds), st.parse_seeds(a.holdout_seeds)
    load0 = os.getloadavg()[0]
    t_fmu, t_tape, t_replay = one_evaluation(a.estimator)
    walls, cpus, results = {}, {}, {}
    for engine in ("batched",) + (() if a.no_fmu else ("fmu",)):
        t, c = time.perf_counter(), time.process_time()
        with open_executor(workers=a.workers) as ex:
            results[engine] = st.tune(SCENARIO, a.estimator, overrides=OVERRIDES, metric=METRIC, maxiter=a.maxiter,
                                      popsize=a.popsize, executor=ex, progress=False, seeds=seeds,
                                      holdout_seeds=holdout, engine=engine)
            workers = _cpu_seconds(list(ex._pool._processes or {}))    # no public API for the pids
        walls[engine] = time.perf_counter() - t
        cpus[engine] = time.process_time() - c + workers
    load1 = os.getloadavg()[0]
    res = results["batched"]
    n_seeds = max(1, len(seeds))
    print(f"tuning '{a.estimator}' of henriksson2009_p1 ({len(res.bounds)} parameters, {METRIC}, 2.5 s of P1, "
          f"--maxiter {a.maxiter} --popsize {a.popsize}: {res.n_evals} evaluations on {n_seeds} seed(s)"
          + (f", held out {holdout}" if holdout else "") + f"), {a.workers} workers; load average "
          f"{load0:.1f} -> {load1:.1f} on {os.cpu_count()} cores")
    print(f"  one evaluation (one seed, in one process): FMUs {t_fmu:.2f} s; batched: the seed's truth "
          f"taped once {t_tape:.2f} s, then a candidate replayed {t_replay:.2f} s ({t_fmu / t_replay:.1f}x)")
    worst = max(c["max_relative_difference"] for c in res.engine["checked"])
    print(f"  batched engine: {walls['batched']:.1f} s wall for the tuning run (pool start-up included), "
          f"{cpus['batched']:.1f} s CPU (>= {cpus['batched'] / a.workers:.1f} s wall on {a.workers} idle cores); "
          f"cost {res.cost * 1e3:.5g} mm (scenario's values {res.initial_cost * 1e3:.5g} mm); "
          f"{len(res.engine['checked'])} candidates through the FMUs agree to {worst:.2g} relative")
    if "fmu" in results:
        ref = results["fmu"]
        same = ref.params == res.params and ref.cost == res.cost
        print(f"  FMU engine: {walls['fmu']:.1f} s wall, {cpus['fmu']:.1f} s CPU; the same tuned values and cost: {same}; "
              f"ratio FMU / batched {walls['fmu'] / walls['batched']:.1f}x")
    print(f"  goal: a 30-evaluation tuning run under 20 s ({'met' if walls['batched'] < 20 else 'NOT met'}: "
          f"{walls['batched']:.1f} s)")


if __name__ == "__main__":
    main()

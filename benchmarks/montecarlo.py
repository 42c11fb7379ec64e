"""The 500-run Monte Carlo of the 2012 paper's section 4 (Axelsson, Karlsson, Norrlöf 2012):
the batched study engine against the FMU path, in one run.

* Batched: the study exactly as ``flexfusion study montecarlo
  orchestration/scenarios/axelsson2012.toml --runs N --no-plots`` runs it (N runs, the q_jerk
  sweep 8 x 10 runs, the CRLB, its validation case of 50 runs, and 3 seeds checked through the
  FMUs on the workers while the engine runs): wall time, and the CPU time of this process.
* FMU path: ``--fmu-runs`` runs of the same scenario through the FMUs on ``--workers`` workers
  (``--engine fmu``), timed, and **extrapolated** linearly to the study's N + 80 simulations,
  plus the study's other parts (CRLB and validation) as measured in the batched run.

Prints the figures and the ratio FMU path / batched. Target: the 500 runs under 20 s wall on
2 cores. The machine is shared: the load average is printed beside the figures (wall times
stretch with it; the CPU time of the engine does not).

Run: ``.venv/bin/python benchmarks/montecarlo.py [--runs 500] [--fmu-runs 6] [--workers 2]``.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from orchestration import study_montecarlo  # noqa: E402

SCENARIO = REPO / "orchestration" / "scenarios" / "axelsson2012.toml"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=500)
    ap.add_argument("--fmu-runs", type=int, default=6, help="runs timed on the FMU path")
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        load0 = os.getloadavg()[0]
        t, c = time.perf_counter(), time.process_time()
        data = study_montecarlo.run_study(SCENARIO, a.runs, Path(tmp) / "batched", workers=a.workers,
                                          progress=False, plots=False)
        wall_b, cpu_b = time.perf_counter() - t, time.process_time() - c
        fmu = study_montecarlo.run_study(SCENARIO, a.fmu_runs, Path(tmp) / "fmu", workers=a.workers,
                                         progress=False, plots=False, crlb=False, sweep_runs=0,
                                         validation_runs=0, engine="fmu")
        load1 = os.getloadavg()[0]
    w = data["wall_time_s"]
    eng = data["engine"]
    per_run_fmu = fmu["wall_time_s"]["runs_and_sweep"] / a.fmu_runs
    jobs = w["jobs"]
    wall_f = per_run_fmu * jobs + w["crlb"] + w["crlb_validation"]
    print(f"2012 section-4 Monte Carlo, {a.runs} runs + sweep ({jobs} simulations), {a.workers} workers; "
          f"load average {load0:.1f} -> {load1:.1f} on {os.cpu_count()} cores")
    print(f"  batched engine: {wall_b:.1f} s wall for the whole study, {cpu_b:.1f} s CPU in this process "
          f"(runs and sweep {w['runs_and_sweep']:.1f} s wall, of which the engine {eng['engine_wall_time_s']:.1f} s; "
          f"CRLB {w['crlb']:.1f} s; validation {w['crlb_validation']:.1f} s); seeds {eng['checked_seeds']} "
          f"through the FMUs agree to {eng['max_relative_difference']:.2g} relative")
    print(f"  FMU path: {per_run_fmu:.2f} s wall per run on {a.workers} workers ({a.fmu_runs} runs timed), "
          f"extrapolated to {jobs} simulations + CRLB + validation: {wall_f:.0f} s wall")
    print(f"  ratio FMU path / batched: {wall_f / wall_b:.1f}x; target: {a.runs} runs under 20 s wall "
          f"({'met' if wall_b < 20 else 'NOT met'}: {wall_b:.1f} s)")


if __name__ == "__main__":
    main()

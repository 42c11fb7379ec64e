"""Wall time of the four paper studies, run back to back at their shipped sizes.

The studies and their sizes are those of the measured figures (docs/figures.md) (the goal: the whole set
under 15 minutes on 2 cores):

* 2012 (Axelsson et al.): ``flexfusion study montecarlo orchestration/scenarios/axelsson2012.toml
  --runs 100`` (the q_jerk sweep 10 runs per value, the CRLB validation 50 runs);
* 2009 (Henriksson et al.): ``flexfusion study robustness`` (five cases, full paths);
* IMU paper: ``flexfusion study imu`` (ISO path and square, full length);
* contact (force observer and impedance control): ``flexfusion study contact``.

Each study's own output records its wall time on the workers (``study.json``'s
``wall_time_s``, ``table.json``'s ``wall_time``, ``metrics.json``'s ``wall_time``); this script
prints those beside the wall time of the whole call (output files and figures included) and the
total. ``--tiny`` runs each study at the size of its fast test (a few short runs) to check that
the script works; its times say nothing about the goal.

Run on an idle machine: ``.venv/bin/python benchmarks/paper_studies.py [--workers 2] [--out DIR]
[--tiny]``.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable

REPO = Path(__file__).resolve().parent.parent
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from orchestration import study_contact, study_imu, study_montecarlo, study_robustness   # noqa: E402
from orchestration.study import open_executor                                         # noqa: E402

GOAL_S = 15 * 60.0
SCENARIO_2012 = REPO / "orchestration" / "scenarios" / "axelsson2012.toml"


def axelsson2012(out: Path, workers: int, tiny: bool) -> float:
    if tiny:
        data = study_montecarlo.run_study(SCENARIO_2012, 3, out, ["scenario.stop_time=0.5"], workers=workers,
                                          progress=False, after=0.2, sweep=(1.0,), sweep_runs=2,
                                          validation_runs=3)
    else:
        data = study_montecarlo.run_study(SCENARIO_2012, 100, out, workers=workers, progress=False)
    return data["wall_time_s"]["total"]


def henriksson2009(out: Path, workers: int, tiny: bool) -> float:
    with open_executor(workers=workers) as ex:
        table = study_robustness.robustness(executor=ex, progress=False, workers=workers,
                                            **({"stop_time": 0.3, "after": 0.05} if tiny else {}))
    study_robustness.write(table, out)
    return table["wall_time"]


def imu(out: Path, workers: int, tiny: bool) -> float:
    res = study_imu.run_study(out, workers=workers, progress=False, stop_time=0.8 if tiny else None)
    return res["wall_time"]["total_s"]


def contact(out: Path, workers: int, tiny: bool) -> float:
    small = dict(structures=("paper",), mass_errors=(0.0,), rigid_tool=False, compliant=False) if tiny else {}
    m = study_contact.run_study(out, workers=workers, progress=False, **small)
    return m["wall_time"]["total_s"]


STUDIES: dict[str, Callable[[Path, int, bool], float]] = {
    "2012 Monte Carlo (axelsson2012)": axelsson2012, "2009 robustness (henriksson2009)": henriksson2009,
    "IMU paper (imu2019)": imu, "contact (force observer)": contact}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--workers", type=int, default=2, help="worker processes of each study (default 2)")
    ap.add_argument("--out", type=Path, default=None, help="output folder (default: a temporary one)")
    ap.add_argument("--tiny", action="store_true", help="the studies at their fast tests' size "
                    "(checks the script, not the goal)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        root = args.out or Path(tmp)
        rows: list[tuple[str, float, float]] = []
        for i, (name, fn) in enumerate(STUDIES.items()):
            t0 = time.perf_counter()
            recorded = fn(root / f"study{i + 1}", args.workers, args.tiny)
            rows.append((name, recorded, time.perf_counter() - t0))
            print(f"{name:<34} {recorded:7.1f} s on the workers, {rows[-1][2]:7.1f} s with its output",
                  flush=True)
    total = sum(r[2] for r in rows)
    size = "tiny size (not the goal's)" if args.tiny else "shipped sizes, Monte Carlo 100 runs"
    print(f"{'total':<34} {sum(r[1] for r in rows):7.1f} s on the workers, {total:7.1f} s with output "
          f"({size}; {args.workers} workers)"
          + ("" if args.tiny else f"; goal < {GOAL_S:.0f} s: " + ("met" if total < GOAL_S else "NOT met")))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

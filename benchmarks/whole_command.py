"""The whole flagship command's CPU time (issue 26's goal: at least 10x faster than real time).

``flexfusion run orchestration/scenarios/flagship.toml`` from the shell, everything counted: the
interpreter's start-up, imports, the scenario and FMUs, stepping, writing the CSV, the metrics and
exit (CPU time of the child process, user + system). The least of ``--repeat`` runs after one
warm-up run (which fills the caches: FMU folders, the C loop, the band-pass design, the
compiled kernels), and the real-time factor (simulated seconds / CPU seconds).

Run: ``.venv/bin/python benchmarks/whole_command.py [--repeat N] [--scenario PATH]``
(needs the FMUs: ``make build``).
"""
from __future__ import annotations

import argparse
import resource
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def _cpu_of(command: list[str]) -> float:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run(command, check=True, capture_output=True, cwd=REPO)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5, help="timed runs (the least counts)")
    ap.add_argument("--scenario", default="orchestration/scenarios/flagship.toml")
    args = ap.parse_args()
    stop = tomllib.loads((REPO / args.scenario).read_text())["scenario"]["stop_time"]
    exe = str(Path(sys.executable).with_name("flexfusion"))
    with tempfile.TemporaryDirectory(prefix="ff_whole_") as tmp:
        command = [exe, "run", args.scenario, "--out", f"{tmp}/run", "--force", "-q"]
        _cpu_of(command)                                   # warm-up: the caches
        cpu = min(_cpu_of(command) for _ in range(args.repeat))
    print(f"{args.scenario}: {stop:g} s simulated, whole command {cpu:.2f} s CPU (least of {args.repeat}): "
          f"{stop / cpu:.1f}x faster than real time (goal: 10x)")


if __name__ == "__main__":
    main()

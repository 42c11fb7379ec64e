"""Peak memory of a flagship run against its simulated time (issue 27: flat memory).

Each run is ``flexfusion run`` of the flagship in a fresh process (no progress bar, into a
temporary folder), after a 1 s run that fills the caches (the first run after a build
extracts the FMUs and computes the reference table, 60 MB more); its peak resident set (``ru_maxrss`` of that process, from ``wait4``) is
printed with the recorded columns' own size (rows x columns x 8 bytes) and the ratio of each
peak to the first's. Target: the 120 s run's peak within 1.3 x the 10 s run's.

Run: ``.venv/bin/python benchmarks/memory.py [--seconds 10 120]``
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
FLAGSHIP = REPO / "orchestration" / "scenarios" / "flagship.toml"


def peak_rss(seconds: float, out: Path) -> tuple[float, int, int]:
    """Peak RSS (MB) of a flagship run of ``seconds`` simulated seconds into ``out``, and the
    rows and columns it recorded."""
    cmd = [sys.executable, "-m", "orchestration.cli", "run", str(FLAGSHIP), "--stop-time", str(seconds),
           "--out", str(out), "--force", "--no-progress", "-q"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL)
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise SystemExit(f"the run of {seconds:g} s failed (exit {proc.returncode})")
    info = json.loads((out / "run.json").read_text())
    with open(out / "results.csv") as f:
        columns = len(f.readline().split(",")) - 1
    return usage.ru_maxrss / 1024.0, int(info["rows"]), columns


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, nargs="+", default=[10.0, 120.0])
    args = ap.parse_args()
    first = None
    with tempfile.TemporaryDirectory() as tmp:
        peak_rss(1.0, Path(tmp) / "warm-up")     # the first run after a build fills the caches
        for s in args.seconds:
            mb, rows, columns = peak_rss(s, Path(tmp) / f"run{s:g}")
            first = first or mb
            print(f"flagship {s:6g} s: peak RSS {mb:7.1f} MB ({mb / first:.2f} x the first); "
                  f"{rows} rows x {columns} columns = {rows * columns * 8 / 2 ** 20:.1f} MB of columns")


if __name__ == "__main__":
    main()

"""Every FMU as FMI 3.0 against its FMI 2.0 build under fmpy.simulate_fmu.

Builds (incrementally) every FMU as FMI 2.0 and 3.0 into a folder (default ``dist/fmus``,
the FMI 3.0 ones in ``fmi3/``), then runs each from its start values for ``--seconds`` at a
1 ms step in both versions and prints, per FMU, whether every output at every step is equal
bit for bit and the wall time of each run (fmpy extracts the FMU afresh for each).

Run: ``.venv/bin/python benchmarks/fmi3_vs_fmi2.py [--seconds 1] [--dest dist/fmus]``.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import fmpy
import numpy as np

from orchestration.build import DEFAULT_DEST, build_all


def main() -> None:
    """Parse the arguments, build, run and print (see the module docstring)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=1.0, help="simulated time of each run")
    parser.add_argument("--dest", type=Path, default=DEFAULT_DEST, help="the build folder")
    args = parser.parse_args()
    built = build_all(args.dest, fmi=("2", "3"), quiet=True)
    fmi2 = [p for p in built if p.parent == args.dest]
    unequal = 0
    for two in fmi2:
        three = args.dest / "fmi3" / two.name
        t0 = time.perf_counter()
        a = fmpy.simulate_fmu(str(two), stop_time=args.seconds, step_size=1e-3, output_interval=1e-3)
        t1 = time.perf_counter()
        b = fmpy.simulate_fmu(str(three), stop_time=args.seconds, step_size=1e-3, output_interval=1e-3)
        t2 = time.perf_counter()
        equal = a.dtype.names == b.dtype.names and all(np.array_equal(a[c], b[c]) for c in a.dtype.names)
        unequal += not equal
        print(f"{two.stem:22s} {len(a.dtype.names) - 1:3d} outputs x {len(a)} rows  "
              f"{'equal' if equal else 'DIFFERENT':9s}  FMI 2.0 {t1 - t0:5.2f} s  FMI 3.0 {t2 - t1:5.2f} s")
    print(f"{len(fmi2) - unequal} of {len(fmi2)} FMUs give the same outputs bit for bit")


if __name__ == "__main__":
    main()

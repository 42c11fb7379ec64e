"""Start-up of a flagship run, phase by phase: this tree against a baseline commit, in one run.

A fresh process from ``import orchestration.master`` to the first step of the flagship
(``master.run``, as ``benchmarks/flagship.py`` times it), CPU and wall time of each phase:

* ``import``: ``orchestration.master`` (numpy with it);
* ``scenario``: loading the scenario (the FMUs' model descriptions);
* ``extract``: the FMUs' folders (extraction, or the cache's);
* ``instantiate``: the FMUs' libraries and scripts (the first imports the bundled package, and
  with just-in-time kernels numba);
* ``setup``: ``fmi2ExitInitializationMode`` of every FMU (the models' setup; with just-in-time
  kernels numba's target initialisation and cached-kernel loads);
* ``first step``: the total to the first recorded row.

``--numba-outside`` imports numba and initialises its CPU target before the clock starts (the
part of start-up that ahead-of-time kernels remove; what is left of numba inside is the
cached kernels' loading). Every figure is the least over ``--repeat`` runs of each tree,
measured interleaved (the machine is shared: compare within one run of this script).

Run: ``.venv/bin/python benchmarks/startup.py [--baseline REV] [--repeat N] [--numba-outside]``
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from flagship import BASELINE, _baseline_tree, run_to_first_row

PHASES = ("import", "scenario", "extract", "instantiate", "setup", "first step")


def measure(numba_outside: bool) -> dict[str, tuple[float, float]]:
    """CPU and wall seconds of each phase in this (fresh) process."""
    if numba_outside:
        import fmus.common.dynamics  # noqa: F401 - kernels first: they name numba's cache folder (fmus.common.jit)
        import numba
        numba.njit("float64(float64)")(lambda x: x + 1.0)
    spent: dict[str, list[float]] = {p: [0.0, 0.0] for p in PHASES}

    def clocks() -> tuple[float, float]:
        return time.process_time(), time.perf_counter()

    def timed(owner, name: str, phase: str) -> None:
        f = getattr(owner, name)

        def wrapper(*args, **kwargs):
            c0, w0 = clocks()
            try:
                return f(*args, **kwargs)
            finally:
                c1, w1 = clocks()
                spent[phase][0] += c1 - c0
                spent[phase][1] += w1 - w0
        setattr(owner, name, wrapper)

    start = clocks()
    from orchestration import master, scenario
    end = clocks()
    spent["import"] = [end[0] - start[0], end[1] - start[1]]
    from fmpy import fmi2
    timed(scenario, "load_scenario", "scenario")
    try:                                  # the FMU store (a baseline before it: the master's own)
        from orchestration import fmu_store
        timed(fmu_store, "folder", "extract")
    except ImportError:
        timed(master, "_extracted", "extract")
    timed(master, "_instantiate", "instantiate")
    timed(fmi2.FMU2Slave, "exitInitializationMode", "setup")

    def first_step() -> None:
        now = clocks()
        spent["first step"] = [now[0] - start[0], now[1] - start[1]]
    run_to_first_row(first_step)
    spent["instantiate"] = [a - b for a, b in zip(spent["instantiate"], spent["extract"])]
    return {p: tuple(v) for p, v in spent.items()}


def _in_tree(tree: Path, numba_outside: bool) -> dict[str, list[float]]:
    env = dict(os.environ, PYTHONPATH=str(tree))
    env.pop("FLEXFUSION_FMU_DIR", None)
    argv = [sys.executable, str(Path(__file__).resolve()), "--measure"] + (["--numba-outside"] if numba_outside else [])
    out = subprocess.run(argv, cwd=tree, env=env, check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", default=BASELINE, help="commit to compare with (default %(default)s)")
    ap.add_argument("--repeat", type=int, default=3, help="runs of each tree, interleaved (the least counts)")
    ap.add_argument("--numba-outside", action="store_true",
                    help="import numba and initialise its CPU target before the clock starts")
    ap.add_argument("--measure", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.measure:
        print(json.dumps(measure(args.numba_outside)))
        return
    repo = Path(__file__).resolve().parent.parent
    with tempfile.TemporaryDirectory(prefix="ff_baseline_") as tmp:
        trees = {args.baseline: _baseline_tree(args.baseline, Path(tmp)), "this tree": repo}
        for tree in trees.values():      # a first run fills the caches (kernels, FMU folders, tables)
            _in_tree(tree, args.numba_outside)
        runs: dict[str, list] = {name: [] for name in trees}
        for _ in range(args.repeat):
            for name, tree in trees.items():
                runs[name].append(_in_tree(tree, args.numba_outside))
    best = {name: {p: [min(r[p][i] for r in rs) for i in (0, 1)] for p in PHASES} for name, rs in runs.items()}
    print(f"flagship start-up [ms], least of {args.repeat}" + (" (numba imported before)" if args.numba_outside else ""))
    print(f"  {'phase':12s} " + "".join(f"{name[:12]:>12s} CPU  wall" for name in trees))
    for p in PHASES:
        print(f"  {p:12s} " + "".join(f"{best[n][p][0] * 1e3:13.0f} {best[n][p][1] * 1e3:5.0f}" for n in trees))


if __name__ == "__main__":
    main()

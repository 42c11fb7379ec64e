"""The flagship on FMUs with ahead-of-time compiled kernels against the same tree's FMUs without
them (``FLEXFUSION_NO_AOT=1``: numba compiles, or loads its cache, in each process), in one run.

Prints, for each: the start-up (a fresh process from the first import to the first step, CPU
and wall; goal 0.5 s), the CPU time per simulated second and the split of one step, each the
best of ``--repeat`` measurements taken alternately (``benchmarks/flagship.py --measure``); the
machine is shared: compare the columns of one run, not runs. Also the build time of each.

Run: ``.venv/bin/python benchmarks/aot.py [--seconds 3] [--repeat 5]``
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "benchmarks"))
from flagship import _fastest  # noqa: E402 - the benchmark's own "best of" rule


def _build(dest: Path, **env: str) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "orchestration.cli", "build", "--dest", str(dest)], cwd=REPO,
                   env={**os.environ, "PYTHONPATH": str(REPO), **env}, check=True, capture_output=True)
    return time.perf_counter() - t0


def _measure(fmus: Path, seconds: float) -> dict:
    env = {**os.environ, "PYTHONPATH": str(REPO), "FLEXFUSION_FMU_DIR": str(fmus)}
    out = subprocess.run([sys.executable, str(REPO / "benchmarks" / "flagship.py"), "--measure", str(seconds)],
                         cwd=REPO, env=env, check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3.0, help="simulated seconds of the long run")
    ap.add_argument("--repeat", type=int, default=5, help="measurements of each, alternately")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="ff_aot_") as tmp:
        dirs = {"JIT": Path(tmp) / "jit", "AOT": Path(tmp) / "aot"}
        built = {"JIT": _build(dirs["JIT"], FLEXFUSION_NO_AOT="1"), "AOT": _build(dirs["AOT"])}
        runs: dict[str, list[dict]] = {k: [] for k in dirs}
        for _ in range(args.repeat):
            for k, d in dirs.items():
                runs[k].append(_measure(d, args.seconds))
    best = {k: _fastest(r) for k, r in runs.items()}
    print(f"flagship, FMUs of this tree without (JIT) and with (AOT) compiled kernels, best of {args.repeat}")
    print(f"  {'':36}{'JIT':>10}{'AOT':>10}")
    print(f"  {'build (flexfusion build) [s]':36}{built['JIT']:10.1f}{built['AOT']:10.1f}   (AOT: cached after the first)")
    for i, what in enumerate(("CPU", "wall")):
        print(f"  {'start-up to first step ' + what + ' [s]':36}" + "".join(
            f"{best[k]['startup_s'][i]:10.3f}" for k in dirs) + "   median " + " / ".join(
            f"{statistics.median(r['startup_s'][i] for r in runs[k]):.3f}" for k in dirs))
    print(f"  {'CPU per simulated second [s]':36}" + "".join(f"{best[k]['stepping'][0]:10.3f}" for k in dirs))
    for key in best["JIT"]["split"]:
        print(f"    {key + ' [us]':34}" + "".join(f"{best[k]['split'][key]:10.1f}" for k in dirs))


if __name__ == "__main__":
    main()

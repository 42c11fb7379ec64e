"""Start-up of a flagship run with the FMU store (``orchestration/fmu_store.py``) cold or warm.

At commit 6c15146 this script also ran the store with its shared packages (each FMU folder's
bundled packages a link to one shared copy, ``linked``) against folders extracted whole: the
measurement that dropped them (ARCHITECTURE.md, "The FMU store"). The store now extracts every
folder whole, the one mode measured here.

Each figure is a fresh process from its first line to the flagship's first recorded row
(``master.run``, as ``benchmarks/flagship.py`` times it), CPU and wall time. Cold: the store's
``fmus/`` removed before the run, every other cache (kernels, C loop, tables, model
descriptions) warm; warm: the run right after. Least and median over ``--repeat`` interleaved
runs (the machine is shared: compare within one run of this script), then the store's size.

Run: ``.venv/bin/python benchmarks/fmu_store.py [--repeat N]``
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
CHILD = r'''
import sys, time, json
c0, w0 = time.process_time(), time.perf_counter()
sys.path.insert(0, sys.argv[2])
from flagship import run_to_first_row
out = []
run_to_first_row(lambda: out.extend((time.process_time() - c0, time.perf_counter() - w0)))
print(json.dumps(out))
'''
MODES = ("whole",)


def _run(mode: str, cache: Path) -> list[float]:
    env = dict(os.environ, FLEXFUSION_CACHE_DIR=str(cache))
    env.pop("FLEXFUSION_FMU_DIR", None)
    done = subprocess.run([sys.executable, "-c", CHILD, mode, str(REPO / "benchmarks")], cwd=REPO, env=env,
                          capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def _size(folder: Path) -> tuple[float, int]:
    files = [f for f in folder.rglob("*") if f.is_file() and not f.is_symlink()] if folder.is_dir() else []
    return sum(f.stat().st_size for f in files) / 1e6, len(files)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5, help="cold and warm runs of each mode, interleaved")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="ff_store_bench_") as tmp:
        caches = {m: Path(tmp) / m for m in MODES}
        for mode, cache in caches.items():
            _run(mode, cache)                     # every cache warm
        runs: dict[tuple[str, str], list[list[float]]] = {(m, s): [] for m in MODES for s in ("cold", "warm")}
        for _ in range(args.repeat):
            for mode, cache in caches.items():
                shutil.rmtree(cache / "fmus", ignore_errors=True)
                runs[(mode, "cold")].append(_run(mode, cache))
                runs[(mode, "warm")].append(_run(mode, cache))
        print(f"flagship start-up to the first row [ms], least / median of {args.repeat}")
        for (mode, state), values in runs.items():
            cpu, wall = (sorted(v[i] * 1e3 for v in values) for i in (0, 1))
            print(f"  {mode:6s} {state}: CPU {cpu[0]:6.0f} / {cpu[len(cpu) // 2]:6.0f}   "
                  f"wall {wall[0]:6.0f} / {wall[len(wall) // 2]:6.0f}")
        for mode, cache in caches.items():
            fmb, fn = _size(cache / "fmus")
            print(f"  {mode:6s} store: fmus/ {fmb:.1f} MB in {fn} files")


if __name__ == "__main__":
    main()

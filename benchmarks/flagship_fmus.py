"""Each FMU's cost in one flagship base step (issue 16): this tree against a baseline commit.

Per component of ``orchestration/scenarios/flagship.toml``, the median time of each of its
three FMI calls per base step through our master (``fmi2SetReal``, ``fmi2DoStep``,
``fmi2GetReal``: the native bridge, our adapter and the model together), summed, in us: the
figure the adapters' work changes, one FMU at a time (``benchmarks/flagship.py`` splits one
step into the models' ``step`` and the rest). A median per call is little disturbed by the
other processes of a shared machine; both trees are measured ``--repeat`` times, interleaved,
and each figure is the best of them.

Run (this tree's FMUs built: ``flexfusion build``):
``.venv/bin/python benchmarks/flagship_fmus.py [--baseline REV] [--seconds 2] [--repeat 2]``
"""
from __future__ import annotations

import argparse
import gc
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

from flagship import REPO, SCENARIO, _baseline_tree

CALLS = ("c_set", "c_step", "c_get")


def measure(seconds: float) -> dict[str, float]:
    """us per base step of each component's FMI calls (the median of each call, summed)."""
    from orchestration.master import simulate
    from orchestration.scenario import load_scenario

    clock = time.perf_counter_ns
    spent: dict[tuple[str, str], list[int]] = {}

    def timer(key: tuple[str, str], f):
        calls = spent.setdefault(key, [])

        def timed(*args):
            t0 = clock()
            result = f(*args)
            calls.append(clock() - t0)
            return result
        return timed

    probe = timer(("probe", ""), lambda: None)
    for _ in range(20000):
        probe()
    overhead = statistics.median(spent.pop(("probe", "")))

    def instrument(t, values):
        if t != 0.0:
            return
        for obj in gc.get_objects():
            kind = type(obj)
            if kind.__name__ == "_Instance" and kind.__module__ == "orchestration.master":
                for call in CALLS:
                    setattr(obj, call, timer((obj.name, call), getattr(obj, call)))

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        simulate(load_scenario(str(Path.cwd() / SCENARIO), ["scenario.stop_time=0.2"]), lambda t, v: None)
        sc = load_scenario(str(Path.cwd() / SCENARIO), [f"scenario.stop_time={seconds}"])
        simulate(sc, instrument)
    out: dict[str, float] = {}
    for (name, _), calls in spent.items():
        per_step = len(calls) / sc.n_steps
        out[name] = out.get(name, 0.0) + (statistics.median(calls) - overhead) * per_step / 1000.0
    return out


def _in_tree(tree: Path, seconds: float) -> dict[str, float]:
    env = dict(os.environ, PYTHONPATH=str(tree))
    env.pop("FLEXFUSION_FMU_DIR", None)
    out = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--measure", str(seconds)],
                         cwd=tree, env=env, check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", default="c530927", help="commit to compare with (default %(default)s)")
    ap.add_argument("--seconds", type=float, default=2.0, help="simulated seconds")
    ap.add_argument("--repeat", type=int, default=2, help="measure both trees this many times, interleaved")
    ap.add_argument("--measure", type=float, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.measure:
        print(json.dumps(measure(args.measure)))
        return
    with tempfile.TemporaryDirectory(prefix="ff_baseline_") as tmp:
        tree = _baseline_tree(args.baseline, Path(tmp))
        runs = [(_in_tree(tree, args.seconds), _in_tree(REPO, args.seconds)) for _ in range(args.repeat)]
    base, new = ({k: min(r[i][k] for r in runs) for k in runs[0][i]} for i in (0, 1))
    print(f"flagship: FMI calls per base step [us] (set + step + get, median per call, best of {args.repeat})")
    print(f"  {'component':12s} {args.baseline:>9s} {'this tree':>10s}")
    for name in base:
        print(f"  {name:12s} {base[name]:9.2f} {new[name]:10.2f}   {base[name] / new[name]:5.2f}x")
    total = [sum(d.values()) for d in (base, new)]
    print(f"  {'all':12s} {total[0]:9.2f} {total[1]:10.2f}   {total[0] / total[1]:5.2f}x")


if __name__ == "__main__":
    main()

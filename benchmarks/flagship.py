"""Speed of the flagship scenario (issue 16): this tree against a baseline commit, in one run.

Prints, for this tree and for the baseline (default: a611ae4, before issue 16's work; its tree
is exported with ``git archive`` to a temporary folder and its FMUs built there):

* **CPU time per simulated second** of the flagship's stepping (``process_time`` of a 4 s run
  minus a 1 s run, so instantiation and initialisation cancel) and the real-time factor
  (goal: 10x on one core; the FMI floor is about 48 us per step for six FMUs, 21x);
* **start-up**: a fresh process from ``import orchestration.master`` and the scenario load to
  the first step, CPU and wall time (goal: under 0.5 s);
* the **split** of one step (CPU time): each FMU's ``step`` (model math and the adapter's own
  body), the rest of the FMI calls (our adapter's ``do_step``, ``set_real``, ``get_real``
  around it, the native bridge and ctypes) and the master's own loop (see :func:`_split`);
* the **kernels**, old (the baseline's module, loaded from git) against new, in us per call:
  the rigid kinematics inversion with gravity compensation, an encoder's sensor channels and
  an IMU's (bias walk, range and resolution on), the plant's RK4 step and outputs (realistic
  plant), the motion controller's law, the tracker's update and the 2012 EKF's update and
  prediction (its estimation model loaded from the baseline too).

Every ratio is measured in this one run (the machine is shared: compare ratios, not runs).

Run: ``.venv/bin/python benchmarks/flagship.py [--baseline REV] [--seconds 4] [--repeat N]``
(``--repeat``: both trees measured N times, interleaved, each figure the best of N).
"""
from __future__ import annotations

import argparse
import gc
import json
import math
import os
import subprocess
import sys
import tempfile
import time
import types
import warnings
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
SCENARIO = "orchestration/scenarios/flagship.toml"
BASELINE = "a611ae4"


# ---- measurements inside one tree (run in a subprocess with that tree first on the path) -----
def _startup() -> tuple[float, float]:
    """CPU and wall seconds from the first import to the first step, in this (fresh) process
    (a run long enough for the flagship's metric windows, which start at 0.5 s)."""
    t0, w0 = time.process_time(), time.perf_counter()
    from orchestration import master
    first: list[float] = []
    simulate = master.simulate

    def timed(sc, sink, *rest):
        def row(t, values):
            if not first:
                first.extend((time.process_time(), time.perf_counter()))
            sink(t, values)
        return simulate(sc, row, *rest)

    master.simulate = timed
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        master.run(str(Path.cwd() / SCENARIO), ["scenario.stop_time=0.6"],
                   out_dir=tempfile.mkdtemp(prefix="ff_bench_"))
    return first[0] - t0, first[1] - w0


def _stepping(seconds: float) -> tuple[float, float]:
    """CPU seconds per simulated second, and the real-time factor."""
    from orchestration.master import simulate
    from orchestration.scenario import load_scenario

    def cpu(stop: float) -> float:
        sc = load_scenario(str(Path.cwd() / SCENARIO), [f"scenario.stop_time={stop}"])
        t0 = time.process_time()
        simulate(sc, lambda t, v: None)
        return time.process_time() - t0

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cpu(0.2)                                        # warm the FMU extraction and imports
        per_s = min((cpu(seconds) - cpu(1.0)) / (seconds - 1.0) for _ in range(2))
    return per_s, 1.0 / per_s


def _split(seconds: float) -> dict[str, float]:
    """CPU us per base step: each FMU's step(), the rest of its FMI calls, and the master.

    Timers on each slave's ``step`` (called by its ``do_step``) and on the master's raw FMI
    calls of each instance (both looked up per call), set at the first row. A CPU clock costs
    a system call (about 1 us, what a call here may cost itself): the timers' own cost, measured
    on an empty call, is taken off each timed call, and off the total.
    """
    from orchestration.master import simulate
    from orchestration.scenario import load_scenario

    clock = time.process_time
    spent: dict[str, float] = {}
    calls: dict[str, int] = {}

    def timer(key: str, f):
        def timed(*args):
            t0 = clock()
            try:
                return f(*args)
            finally:
                spent[key] = spent.get(key, 0.0) + clock() - t0
                calls[key] = calls.get(key, 0) + 1
        return timed

    # the timers' cost: inside a timed empty call (c_in), and in all (c_all)
    probe, n = timer("probe", lambda: None), 20000
    t0 = clock()
    for _ in range(n):
        probe()
    c_all, c_in = (clock() - t0) / n, spent.pop("probe") / n
    calls.pop("probe")

    start: list[float] = []

    def instrument(t, v):
        if t != 0.0:
            return
        for obj in gc.get_objects():
            kind = type(obj)
            if any(c.__name__ == "FlexFusionSlave" for c in kind.__mro__[1:]):
                obj.step = timer(f"step {obj.instance_name}", obj.step)
            elif kind.__name__ == "_Instance" and kind.__module__ == "orchestration.master":
                for m in ("c_set", "c_step", "c_get"):
                    setattr(obj, m, timer("fmi", getattr(obj, m)))
        start.append(clock())                   # the stepping starts

    sc = load_scenario(str(Path.cwd() / SCENARIO), [f"scenario.stop_time={seconds}"])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        simulate(sc, instrument)
        total = clock() - start[0]
    n = sc.n_steps
    steps = {k: (spent[k] - calls[k] * c_in) / n * 1e6 for k in sorted(spent) if k.startswith("step ")}
    n_step_calls = sum(calls[k] for k in steps)
    fmi = (spent["fmi"] - calls["fmi"] * c_in - n_step_calls * c_all) / n * 1e6
    out = {"total": (total - (calls["fmi"] + n_step_calls) * c_all) / n * 1e6, **steps}
    out["FMI calls around step (adapter, bridge)"] = fmi - sum(steps.values())
    out["master (the rest)"] = out["total"] - fmi
    return out


def measure(seconds: float) -> dict:
    return {"startup_s": _startup(), "stepping": _stepping(seconds), "split": _split(seconds)}


# ---- kernels, old (git) against new (this tree) ---------------------------------------------
def _old_module(rev: str, path: str) -> types.ModuleType:
    """The module at ``path`` as it was in ``rev`` (it imports the rest from this tree)."""
    return old_modules(rev, [path])[0]


def old_modules(rev: str, paths: list[str]) -> list[types.ModuleType]:
    """The modules at ``paths`` as they were in ``rev``, each importing the ones before it from
    ``rev`` too (under their own names, while it loads) and the rest from this tree."""
    loaded: dict[str, types.ModuleType] = {}
    for path in paths:
        src = subprocess.run(["git", "show", f"{rev}:{path}"], cwd=REPO, check=True, capture_output=True,
                             text=True).stdout
        name = f"_old_{path.replace('/', '_')[:-3]}"
        module = types.ModuleType(name)
        module.__package__ = path[:-3].replace("/", ".").rpartition(".")[0]     # its relative imports
        sys.modules[name] = module           # dataclasses look their module up
        saved = {real: sys.modules.get(real) for real in loaded}
        sys.modules.update(loaded)
        try:
            exec(compile(src, f"{rev}:{path}", "exec"), module.__dict__)   # noqa: S102 - our own history
        finally:
            for real, m in saved.items():
                if m is None:
                    sys.modules.pop(real)
                else:
                    sys.modules[real] = m
        loaded[path[:-3].replace("/", ".")] = module
    return list(loaded.values())


def _in_rev(rev: str, path: str) -> bool:
    """Whether ``path`` exists in ``rev``."""
    return subprocess.run(["git", "cat-file", "-e", f"{rev}:{path}"], cwd=REPO,
                          capture_output=True).returncode == 0


def _us(f, n: int = 3000) -> float:
    import timeit
    return min(timeit.repeat(f, number=n, repeat=5)) / n * 1e6


def kernels(rev: str) -> list[tuple[str, float, float]]:
    sys.path.insert(0, str(REPO))
    import numpy as np

    from fmus.common import dynamics
    from fmus.common.robot_params import RobotParameters
    from fmus.estimators import rigid_kinematics_model as rigid
    from fmus.robot_plant import plant_dynamics, sensor_model
    from fmus.robot_plant.plant_model import PlantParameters

    rows = []
    p = RobotParameters()
    q_m = dynamics.static_equilibrium([0.3, -0.2], p)[2:4] + 0.01
    old = _old_module(rev, "fmus/estimators/rigid_kinematics_model.py")
    rows.append(("rigid inversion (gravity compensation)", _us(lambda: old.arm_angles(q_m, p, True)),
                 _us(lambda: rigid.arm_angles(q_m, p, True))))
    old = old_modules(rev, ["fmus/common/noise.py", "fmus/robot_plant/sensor_model.py"])[-1]
    for label, n, kw, x in (
            ("encoder channels (2)", 2, dict(seed=1, stream="encoder", noise=2e-5, resolution=9.6e-5),
             np.array([30.0, -20.0])),
            ("IMU channels (3)", 3, dict(seed=1, stream="imu/acc", noise=0.02, bias_rw=1e-3,
                                         resolution=1e-3, range=160.0), np.array([1.0, 0.5, 9.81]))):
        a, b = old.SensorChannels(n, **kw), sensor_model.SensorChannels(n, **kw)
        rows.append((label, _us(lambda: a.step(x, 1e-3, 0.0)), _us(lambda: b.step(x, 1e-3, 0.0))))
    old = _old_module(rev, "fmus/robot_plant/plant_dynamics.py")
    plants = [m.plant_model(PlantParameters()) for m in (old, plant_dynamics)]
    s0 = plants[1].state

    def step(plant):
        plant._s = s0
        plant.step((1.0, 2.0), (0.0, 0.0), 1e-3)
    rows.append((f"plant RK4 step (realistic, {plants[1].substeps} substeps)",
                 *(_us(lambda: step(plant)) for plant in plants)))
    rows.append(("plant outputs", *(_us(lambda: plant.outputs(0.0, 0.0)) for plant in plants)))
    old = _old_module(rev, "fmus/robot_plant/motion_control_model.py")
    from fmus.robot_plant import motion_control_model as mc
    controllers = [m.build_controller(m.MotionControllerParameters()) for m in (old, mc)]
    zero, clock = np.zeros(2), [0.1]

    def evaluate(c):                     # a new time per call, as in the FMU
        clock[0] += 1e-4
        c.evaluate(clock[0], zero, zero, zero)
    rows.append(("controller evaluate", *(_us(lambda: evaluate(c)) for c in controllers)))
    old = old_modules(rev, ["fmus/common/noise.py", "fmus/robot_plant/tracker_model.py"])[-1]
    from fmus.robot_plant import tracker_model
    trackers = [m.TrackerModel(2e-5, 1000.0, 1e-3, seed=4) for m in (old, tracker_model)]
    p_tool = np.array([1.0, 0.6])
    for tr in trackers:
        tr.start(0.0, p_tool)

    def update(tr):
        tr.update(tr.t_meas + 1e-3, p_tool)
    rows.append(("tracker update", *(_us(lambda: update(tr)) for tr in trackers)))
    paths = ["fmus/common/kalman.py"] + [f"fmus/estimators/{m}.py" for m in ("axelsson2012_model",
                                                                             "ekf_accelerometer_model")]
    old = old_modules(rev, [path for path in paths if _in_rev(rev, path)])[-1]   # one module before
    from fmus.estimators import ekf_accelerometer_model as em
    filters = [m.EkfAccelerometerModel(m.EkfAccelerometerParameters()) for m in (old, em)]
    y = filters[1].meas.h(filters[1].x) + 1e-3

    def ekf_step(f):
        f.update(y)
        f.predict((0.1, -0.2), 1e-3)
    rows.append(("2012 EKF update + predict (6 states)", _us(lambda: ekf_step(filters[0])),
                 _us(lambda: ekf_step(filters[1]))))
    return rows


# ---- driver ---------------------------------------------------------------------------------
def _in_tree(tree: Path, seconds: float) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree))
    env.pop("FLEXFUSION_FMU_DIR", None)
    out = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--measure", str(seconds)],
                         cwd=tree, env=env, check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def _fastest(runs: list[dict]) -> dict:
    """Each figure's best over ``runs`` of :func:`measure` (the least disturbed by the other
    processes of a shared machine): the least CPU time, the highest real-time factor."""
    per_s = min(r["stepping"][0] for r in runs)
    return {"startup_s": tuple(min(r["startup_s"][i] for r in runs) for i in (0, 1)),
            "stepping": (per_s, 1.0 / per_s),
            "split": {k: min(r["split"][k] for r in runs) for k in runs[0]["split"]}}


def _baseline_tree(rev: str, dest: Path) -> Path:
    archive = subprocess.run(["git", "archive", rev], cwd=REPO, check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
    env = dict(os.environ, PYTHONPATH=str(dest))
    env.pop("FLEXFUSION_FMU_DIR", None)
    subprocess.run([sys.executable, "-m", "orchestration.cli", "build"], cwd=dest, env=env, check=True,
                   capture_output=True)
    return dest


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", default=BASELINE, help="commit to compare with (default %(default)s)")
    ap.add_argument("--seconds", type=float, default=4.0, help="simulated seconds of the long run")
    ap.add_argument("--repeat", type=int, default=1,
                    help="measure both trees this many times, interleaved, and keep each figure's best")
    ap.add_argument("--measure", type=float, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.measure:
        print(json.dumps(measure(args.measure)))
        return
    with tempfile.TemporaryDirectory(prefix="ff_baseline_") as tmp:
        tree = _baseline_tree(args.baseline, Path(tmp))
        runs = [(_in_tree(tree, args.seconds), _in_tree(REPO, args.seconds)) for _ in range(args.repeat)]
    base, new = (_fastest([r[i] for r in runs]) for i in (0, 1))
    print(f"flagship (7 FMUs at 1 kHz), baseline {args.baseline} vs this tree")
    print(f"  CPU per simulated second   {base['stepping'][0]:7.3f} s   {new['stepping'][0]:7.3f} s   "
          f"speed-up {base['stepping'][0] / new['stepping'][0]:.2f}x")
    print(f"  real-time factor           {base['stepping'][1]:7.2f}x    {new['stepping'][1]:7.2f}x    "
          "(goal 10x, FMI floor about 21x)")
    print(f"  start-up to first step CPU {base['startup_s'][0]:7.3f} s   {new['startup_s'][0]:7.3f} s   "
          "(goal 0.5 s)")
    print(f"                        wall {base['startup_s'][1]:7.3f} s   {new['startup_s'][1]:7.3f} s")
    print("  split of one step [us]          baseline   this tree")
    for key in new["split"]:
        print(f"    {key:38s} {base['split'].get(key, math.nan):8.1f}  {new['split'][key]:8.1f}")
    print("kernels [us per call]                   old       new     ratio")
    for label, old, now in kernels(args.baseline):
        print(f"  {label:36s} {old:8.2f}  {now:8.2f}  {old / now:7.1f}x")


if __name__ == "__main__":
    main()

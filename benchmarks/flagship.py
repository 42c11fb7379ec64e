"""Speed of the flagship scenario (issue 16): this tree against a baseline commit, in one run.

Prints, for the baseline (default: 166d721, the start of session 5; its tree is exported with
``git archive`` to a temporary folder and its FMUs built there) and for this tree with the
master's C loop (orchestration/cosim_loop.c) and with its Python loop (``FLEXFUSION_PYTHON_LOOP=1``):

* **CPU time per simulated second** of the flagship's stepping (``process_time`` from the first
  recorded row, t = 0 after initialisation, to the last; the best of two runs of ``--seconds``)
  and the real-time factor (goal: 10x on one core);
* **start-up**: a fresh process from ``import orchestration.master`` and the scenario load to
  the first step, CPU and wall time (goal: under 0.5 s);
* the **split** of one step (CPU time): each FMU's ``step`` (model math and the adapter's own
  body), the FMI calls and the master together (the rest), and of those, with the Python loop,
  the FMI calls around the steps (our adapter's ``do_step``, ``set_real``, ``get_real``, the
  native bridge and ctypes) and the master's own loop; with the C loop, whose FMI calls no
  Python timer sees, the master's Python outside the loop (between its chunks: see
  :func:`_split`);
* the **kernels**, old (the baseline's module, loaded from git) against new, in us per call:
  the rigid kinematics inversion with gravity compensation, an encoder's sensor channels and
  an IMU's (bias walk, range and resolution on), the plant's RK4 step and outputs (realistic
  plant), the motion controller's law, the tracker's update and the 2012 EKF's update and
  prediction (its estimation model loaded from the baseline too); a kernel that cannot be
  loaded from the baseline (an older module that needs what this tree no longer has) is shown
  as n/a with the reason.

Every ratio is measured in this one run (the machine is shared: compare ratios, not runs).

Run: ``.venv/bin/python benchmarks/flagship.py [--baseline REV] [--seconds 4] [--repeat N]``
(``--repeat``: the three measured N times, interleaved, each figure the best of N).
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
BASELINE = "166d721"


# ---- measurements inside one tree (run in a subprocess with that tree first on the path) -----
def run_to_first_row(at_first_row) -> None:
    """Run the flagship (``master.run``, 0.6 s: long enough for its metric windows, which start
    at 0.5 s) and call ``at_first_row()`` at its first recorded row: the first step."""
    from orchestration import master
    simulate = master.simulate

    def timed(sc, sink, *rest):
        seen: list[bool] = []

        def row(t, values):
            if not seen:
                seen.append(True)
                at_first_row()
            sink(t, values)
        return simulate(sc, row, *rest)

    master.simulate = timed
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            master.run(str(Path.cwd() / SCENARIO), ["scenario.stop_time=0.6"],
                       out_dir=tempfile.mkdtemp(prefix="ff_bench_"))
    finally:
        master.simulate = simulate


def _startup() -> tuple[float, float]:
    """CPU and wall seconds from the first import to the first step, in this (fresh) process."""
    t0, w0 = time.process_time(), time.perf_counter()
    first: list[float] = []
    run_to_first_row(lambda: first.extend((time.process_time(), time.perf_counter())))
    return first[0] - t0, first[1] - w0


def _stepping(seconds: float) -> tuple[float, float]:
    """CPU seconds per simulated second, and the real-time factor."""
    from orchestration.master import simulate
    from orchestration.scenario import load_scenario

    def cpu(stop: float) -> float:
        """CPU seconds from the first recorded row (t = 0, after initialisation) to the last
        (t = stop): the stepping alone, with no set-up or teardown to subtract."""
        sc = load_scenario(str(Path.cwd() / SCENARIO), [f"scenario.stop_time={stop}"])
        marks: list[float] = []

        def sink(t: float, values: object) -> None:
            if not marks or t >= stop:
                marks.append(time.process_time())
        simulate(sc, sink)
        return marks[-1] - marks[0]

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cpu(0.2)                                        # warm the FMU extraction and imports
        per_s = min(cpu(seconds) / seconds for _ in range(2))
    return per_s, 1.0 / per_s


def _split(seconds: float) -> dict[str, float]:
    """CPU us per base step: each FMU's step(), the FMI calls and the master; with the Python
    loop, the FMI calls and the master apart; with the C loop, the master outside the loop.

    From the first row to the last (not the instances' teardown). Timers on each slave's
    ``step`` (called by its ``do_step``), set at the first row; with the Python loop, on its raw
    FMI calls of each instance too (looked up per call; the C loop calls them through pointers,
    unseen); on the master's chunks of base steps (``_stepper``'s callable: the C loop, or the
    Python one), where the master has them. A CPU clock costs a
    system call (about 1 us, what a call here may cost itself): the timers' own cost, measured
    on an empty call, is taken off each timed call, and off the total.
    """
    from orchestration import master
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

    try:
        from orchestration import cloop
        python_loop = cloop.library() is None
    except ImportError:                         # a tree before the C loop
        python_loop = True
    stepper = getattr(master, "_stepper", None)
    if stepper is not None:
        master._stepper = lambda *args: timer("chunks", stepper(*args))
    sc = load_scenario(str(Path.cwd() / SCENARIO), [f"scenario.stop_time={seconds}"])
    start: list[float] = []
    end: list[float] = []

    def instrument(t, v):
        if t != 0.0:
            if t > sc.stop_time - sc.base_step / 2:      # the last row (not the instances' teardown)
                end.append(clock())
            return
        for obj in gc.get_objects():
            kind = type(obj)
            if any(c.__name__ == "FlexFusionSlave" for c in kind.__mro__[1:]):
                obj.step = timer(f"step {obj.instance_name}", obj.step)
            elif python_loop and kind.__name__ == "_Instance" and kind.__module__ == "orchestration.master":
                for m in ("c_set", "c_step", "c_get"):
                    setattr(obj, m, timer("fmi", getattr(obj, m)))
        start.append(clock())                   # the stepping starts

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        master.simulate(sc, instrument)
    total = end[0] - start[0]
    n = sc.n_steps
    own = {k: calls[k] * c_in for k in calls}                 # the timers' cost inside each
    steps = {k: (spent[k] - own[k]) / n * 1e6 for k in sorted(spent) if k.startswith("step ")}
    n_timed = sum(calls.values())
    out = {"total": (total - n_timed * c_all) / n * 1e6, **steps}
    out["FMI calls and master (the rest)"] = out["total"] - sum(steps.values())
    if "fmi" in spent:
        n_step_calls = sum(calls[k] for k in steps)
        fmi = (spent["fmi"] - own["fmi"] - n_step_calls * c_all) / n * 1e6
        out["FMI calls around step (adapter, bridge)"] = fmi - sum(steps.values())
        out["master (the rest)"] = out["total"] - fmi
    if "chunks" in spent:
        inside = (spent["chunks"] - own["chunks"] - (n_timed - calls["chunks"]) * c_all) / n * 1e6
        out["master outside its loop (between chunks)"] = out["total"] - inside
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


def kernels(rev: str) -> list[tuple[str, float | str, float]]:
    """Rows ``(label, old us, new us)``; a kernel the baseline's module cannot give (it needs what
    this tree no longer has) is ``(label, the reason, nan)``, and the others are still measured."""
    sys.path.insert(0, str(REPO))
    import numpy as np

    from fmus.common import dynamics
    from fmus.common.robot_params import RobotParameters
    from fmus.estimators import rigid_kinematics_model as rigid
    from fmus.robot_plant import plant_dynamics, sensor_model
    from fmus.robot_plant.plant_model import PlantParameters

    p = RobotParameters()

    def rigid_inversion():
        q_m = dynamics.static_equilibrium([0.3, -0.2], p)[2:4] + 0.01
        old = _old_module(rev, "fmus/estimators/rigid_kinematics_model.py")
        return [("rigid inversion (gravity compensation)", _us(lambda: old.arm_angles(q_m, p, True)),
                 _us(lambda: rigid.arm_angles(q_m, p, True)))]

    def sensors():
        old = old_modules(rev, ["fmus/common/noise.py", "fmus/robot_plant/sensor_model.py"])[-1]
        rows = []
        for label, n, kw, x in (
                ("encoder channels (2)", 2, dict(seed=1, stream="encoder", noise=2e-5, resolution=9.6e-5),
                 np.array([30.0, -20.0])),
                ("IMU channels (3)", 3, dict(seed=1, stream="imu/acc", noise=0.02, bias_rw=1e-3,
                                             resolution=1e-3, range=160.0), np.array([1.0, 0.5, 9.81]))):
            a, b = old.SensorChannels(n, **kw), sensor_model.SensorChannels(n, **kw)
            rows.append((label, _us(lambda: a.step(x, 1e-3, 0.0)), _us(lambda: b.step(x, 1e-3, 0.0))))
        return rows

    def plant():
        old = _old_module(rev, "fmus/robot_plant/plant_dynamics.py")
        plants = [m.plant_model(PlantParameters()) for m in (old, plant_dynamics)]
        s0 = plants[1].state

        def step(plant):
            plant._s = s0
            plant.step((1.0, 2.0), (0.0, 0.0), 1e-3)
        return [(f"plant RK4 step (realistic, {plants[1].substeps} substeps)",
                 *(_us(lambda: step(plant)) for plant in plants)),
                ("plant outputs", *(_us(lambda: plant.outputs(0.0, 0.0)) for plant in plants))]

    def controller():
        old = _old_module(rev, "fmus/robot_plant/motion_control_model.py")
        from fmus.robot_plant import motion_control_model as mc
        controllers = [m.build_controller(m.MotionControllerParameters()) for m in (old, mc)]
        zero, clock = np.zeros(2), [0.1]

        def evaluate(c):                     # a new time per call, as in the FMU
            clock[0] += 1e-4
            c.evaluate(clock[0], zero, zero, zero)
        return [("controller evaluate", *(_us(lambda: evaluate(c)) for c in controllers))]

    def tracker():
        old = old_modules(rev, ["fmus/common/noise.py", "fmus/robot_plant/tracker_model.py"])[-1]
        from fmus.robot_plant import tracker_model
        trackers = [m.TrackerModel(2e-5, 1000.0, 1e-3, seed=4) for m in (old, tracker_model)]
        p_tool = np.array([1.0, 0.6])
        for tr in trackers:
            tr.start(0.0, p_tool)

        def update(tr):
            tr.update(tr.t_meas + 1e-3, p_tool)
        return [("tracker update", *(_us(lambda: update(tr)) for tr in trackers))]

    def ekf():
        paths = ["fmus/common/kalman.py"] + [f"fmus/estimators/{m}.py" for m in ("axelsson2012_model",
                                                                                 "ekf_accelerometer_model")]
        old = old_modules(rev, [path for path in paths if _in_rev(rev, path)])[-1]   # one module before
        from fmus.estimators import ekf_accelerometer_model as em
        filters = [m.EkfAccelerometerModel(m.EkfAccelerometerParameters()) for m in (old, em)]
        y = filters[1].meas.h(filters[1].x) + 1e-3

        def ekf_step(f):
            f.update(y)
            f.predict((0.1, -0.2), 1e-3)
        return [("2012 EKF update + predict (6 states)", _us(lambda: ekf_step(filters[0])),
                 _us(lambda: ekf_step(filters[1])))]

    rows: list[tuple[str, float | str, float]] = []
    for label, measure_rows in (("rigid inversion", rigid_inversion), ("sensor channels", sensors),
                                ("plant", plant), ("controller evaluate", controller),
                                ("tracker update", tracker), ("2012 EKF update + predict", ekf)):
        try:
            rows += measure_rows()
        except Exception as exc:  # noqa: BLE001 - an old module that does not load here: say why
            rows.append((label, f"{type(exc).__name__}: {exc}", math.nan))
    return rows


# ---- driver ---------------------------------------------------------------------------------
def _in_tree(tree: Path, seconds: float, python_loop: bool = False) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree))
    env.pop("FLEXFUSION_FMU_DIR", None)
    env.pop("FLEXFUSION_PYTHON_LOOP", None)
    if python_loop:
        env["FLEXFUSION_PYTHON_LOOP"] = "1"
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


SPLIT_REST = ["FMI calls and master (the rest)", "FMI calls around step (adapter, bridge)", "master (the rest)",
              "master outside its loop (between chunks)"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", default=BASELINE, help="commit to compare with (default %(default)s)")
    ap.add_argument("--seconds", type=float, default=4.0, help="simulated seconds of the long run")
    ap.add_argument("--repeat", type=int, default=1,
                    help="measure the three this many times, interleaved, and keep each figure's best")
    ap.add_argument("--measure", type=float, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.measure:
        print(json.dumps(measure(args.measure)))
        return
    with tempfile.TemporaryDirectory(prefix="ff_baseline_") as tmp:
        tree = _baseline_tree(args.baseline, Path(tmp))
        runs = [(_in_tree(tree, args.seconds), _in_tree(REPO, args.seconds), _in_tree(REPO, args.seconds, True))
                for _ in range(args.repeat)]
    columns = [_fastest([r[i] for r in runs]) for i in range(3)]
    base = columns[0]
    print(f"flagship (7 FMUs at 1 kHz): baseline {args.baseline}, this tree with the C loop, with the Python loop")
    print("                             baseline     C loop     Python loop")
    print("  CPU per simulated second  " + "".join(f"{c['stepping'][0]:9.3f} s  " for c in columns)
          + f"speed-up {base['stepping'][0] / columns[1]['stepping'][0]:.2f}x, C / Python loop "
          f"{columns[2]['stepping'][0] / columns[1]['stepping'][0]:.2f}x")
    print("  real-time factor          " + "".join(f"{c['stepping'][1]:9.2f}x   " for c in columns)
          + "(goal 10x)")
    print("  start-up to first step CPU" + "".join(f"{c['startup_s'][0]:9.3f} s  " for c in columns) + "(goal 0.5 s)")
    print("                        wall" + "".join(f"{c['startup_s'][1]:9.3f} s  " for c in columns))
    print("  split of one step [us]" + " " * 34 + "baseline   C loop   Python loop")
    for c in columns:        # a tree before the split had it: the FMI calls and the master together
        c["split"].setdefault(SPLIT_REST[0], c["split"]["total"]
                              - sum(v for k, v in c["split"].items() if k.startswith("step ")))
    steps = sorted({k for c in columns for k in c["split"] if k.startswith("step ")})
    for key in ["total", *steps, *SPLIT_REST]:
        label = key if key == "total" or key in steps or key == SPLIT_REST[0] else "  of which " + key
        print(f"    {label:52s}" + "".join(f"{c['split'].get(key, math.nan):9.1f}" for c in columns))
    print("kernels [us per call]                   old       new     ratio")
    for label, old, now in kernels(args.baseline):
        if isinstance(old, str):
            print(f"  {label:36s} n/a ({old})")
        else:
            print(f"  {label:36s} {old:8.2f}  {now:8.2f}  {old / now:7.1f}x")


if __name__ == "__main__":
    main()

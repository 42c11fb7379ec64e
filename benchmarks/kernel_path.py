"""The compiled kernels' cost per call: the Cython kernels of the working tree against the numba
ahead-of-time kernels they replace, taken from an FMU built before (``--baseline``).

The kernels move from numba to Cython module by module (ARCHITECTURE.md, "The kernel path"); a
moved kernel must cost no more than its numba form did. For each moved kernel this calls both on
the same arguments (realistic: the default plant's and sensors' constants and states) and
prints the CPU per call, best of ``--repeat`` rounds of ``--calls`` calls, interleaved; the
machine is shared: compare within a run. The baseline is any FMU of a build with the numba
kernels (its ``fmus_<hash>/_compiled.<EXT_SUFFIX>``), e.g. built from commit 60be548:
``git worktree add /tmp/old 60be548 && (cd /tmp/old && make env && .venv/bin/flexfusion build)``.

Run: ``.venv/bin/python benchmarks/kernel_path.py --baseline /tmp/old/dist/fmus/FlexibleRobot2DOF.fmu``
"""
from __future__ import annotations

import argparse
import importlib.util
import sys
import sysconfig
import tempfile
import time
import zipfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from fmus.common import cython_kernels, dynamics  # noqa: E402
from fmus.common.robot_params import RobotParameters  # noqa: E402
from fmus.estimators import rigid_kinematics_model  # noqa: E402
from fmus.robot_plant import plant_dynamics, sensor_model, tracker_model  # noqa: E402
from fmus.robot_plant.plant_model import PlantParameters  # noqa: E402

MODULE = "_compiled" + sysconfig.get_config_var("EXT_SUFFIX")


def _baseline(fmu: Path, folder: Path):
    """The numba kernels' module of the FMU ``fmu``, imported from a copy in ``folder``."""
    with zipfile.ZipFile(fmu) as z:
        name = next((n for n in z.namelist() if n.endswith("/" + MODULE)), None)
        if name is None:
            raise SystemExit(f"error: {fmu} has no numba kernels module ({MODULE})")
        (folder / MODULE).write_bytes(z.read(name))
    spec = importlib.util.spec_from_file_location("_compiled", folder / MODULE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _cases(old) -> dict[str, tuple]:
    """Kernel name -> (numba AOT function, Cython function, arguments)."""
    plant = cython_kernels.load("robot_plant.plant_kernels")
    arm = cython_kernels.load("common.dynamics_kernels")
    sensors = cython_kernels.load("robot_plant.sensor_kernels")
    tracker = cython_kernels.load("robot_plant.tracker_kernels")
    rigid = cython_kernels.load("estimators.rigid_kinematics_kernels")
    P = plant_dynamics.PlantChain(PlantParameters()).P
    s12 = tuple(plant_dynamics.plant_model(PlantParameters()).state)
    K = dynamics.ArmConstants(RobotParameters()).packed
    s8 = tuple(dynamics.FlexibleRobotModel(RobotParameters(), (0.3, -0.2)).state)
    out, at, tau, f = np.zeros(40), np.arange(26, dtype=np.int64), np.array([3.0, 1.0]), np.zeros(2)
    ch = sensor_model.SensorChannels(3, noise=0.01, cutoff=100.0)
    ch.step(np.ones(3), 1e-3)
    rows = np.random.default_rng(0).normal(size=(10 ** 6, 6))     # never used up by the rounds
    mount = sensor_model.mount_matrix((0.1, 0.2, 0.3))
    a = np.array([1.0, 2.0])
    pd, sm, dy = "robot_plant__plant_dynamics__", "robot_plant__sensor_model__", "common__dynamics__"
    tm, rk = "robot_plant__tracker_model__", "estimators__rigid_kinematics_model__"
    # the tracker: a held sample (no instant due), the history of two entries kept
    hist, state = np.array([[0.0, 1.0, 0.5], [1e-3, 1.0, 0.5]] + [[0.0] * 3] * 6), np.array([2.0, 2.0, 1e-3, 0.0])
    t_consts, t_rows = np.array([0.0, 1e-3, 0.0, 1e-5]), np.zeros((256, 2))
    r_consts = rigid_kinematics_model.constants(RobotParameters(), gravity_compensation=True)
    return {
        "chain4_advance": (getattr(old, pd + "chain4_advance"), plant.chain4_advance, (s12, tau, f, 1e-3, 1, P, out, at)),
        "chain4_step": (getattr(old, pd + "chain4_step"), plant.chain4_step, (s12, 3.0, 1.0, 0.0, 0.0, 1e-3, 1, P)),
        "chain4_outputs": (getattr(old, pd + "chain4_outputs"), plant.chain4_outputs, (s12, 0.0, 0.0, P)),
        "chain4_rates": (getattr(old, pd + "_chain4_rates"), plant.chain4_rates, (s12, 3.0, 1.0, 0.0, 0.0, P)),
        "flex_step": (getattr(old, dy + "flex_step"), arm.flex_step, (s8, 3.0, 1.0, 0.0, 0.0, 1e-3, 1, K)),
        "flex_rates": (getattr(old, dy + "flex_rates"), arm.flex_rates, (s8, 3.0, 1.0, 0.0, 0.0, K)),
        "channels_step": (getattr(old, sm + "_channels_step"), sensors.channels_step,
                          (np.ones(3), ch._work, np.zeros(3), rows)),
        "imu_reading_into": (getattr(old, sm + "imu_reading_into"), sensors.imu_reading_into,
                             (a, 0.3, 0.1, mount, 9.81, np.empty(3), np.empty(3))),
        "tracker_update": (getattr(old, tm + "tracker_update"), tracker.tracker_update,
                           (1.5e-3, a, False, hist, state, t_consts, t_rows, np.zeros(2))),
        "rigid estimate": (getattr(old, rk + "estimate"), rigid.estimate,
                           (np.array([30.0, -20.0]), 0.0, 0.0, r_consts, np.zeros(7), np.zeros(8), 2)),
        "spring_inverse": (getattr(old, dy + "spring_inverse"), arm.spring_inverse, (K[9], K[11], K[13], 120.0, 0.0, False)),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", type=Path, required=True, help="an FMU built with the numba kernels")
    ap.add_argument("--calls", type=int, default=20000, help="calls per round")
    ap.add_argument("--repeat", type=int, default=7, help="rounds of each, interleaved (the least counts)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        cases = _cases(_baseline(args.baseline, Path(tmp)))
        print(f"CPU per call, best of {args.repeat} x {args.calls} calls (numba AOT: {args.baseline.name})")
        for name, (old, new, call) in cases.items():
            best = {"numba AOT": float("inf"), "Cython": float("inf")}
            for _ in range(args.repeat):
                for label, fn in (("numba AOT", old), ("Cython", new)):
                    if name == "channels_step":
                        call[1][sensor_model._ROW] = 0.0
                    t0 = time.process_time()
                    for _ in range(args.calls):
                        fn(*call)
                    best[label] = min(best[label], (time.process_time() - t0) / args.calls * 1e6)
            print(f"  {name:18s} numba AOT {best['numba AOT']:6.3f} us   Cython {best['Cython']:6.3f} us   "
                  f"({best['Cython'] / best['numba AOT']:.2f}x)")


if __name__ == "__main__":
    main()

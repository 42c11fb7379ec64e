"""Speed of the force observer and the impedance controller, direct and through their FMUs.

Prints, for each observer kind and for the controller, the cost of one step at h = 4 ms (the
paper's sample time) and at 1 kHz: calling the math directly and through the FMU with fmpy
(one batched setReal, doStep, one batched getReal per step). Then the contact scenarios'
real-time factor (simulated time / wall-clock time of the master's stepping; both scenarios of
``orchestration/scenarios/contact_*.toml``, 5.5 s simulated, nine FMUs, 1 ms base step, observer
and controller at 4 ms), with FMUs built from this checkout.

Usage: ``.venv/bin/python benchmarks/force_control.py [--steps N] [--no-scenario]``
"""
from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from fmus.common.frames import G  # noqa: E402
from fmus.force_observer import force_observer_math as fom  # noqa: E402
from fmus.force_observer import impedance_math as imp  # noqa: E402


def _fmu(path: Path, params: dict):
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    md = read_model_description(str(path))
    unzip = extract(str(path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    types = {v.name: v.type for v in md.modelVariables}
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzip, modelIdentifier=md.coSimulation.modelIdentifier,
                    instanceName="bench")
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    for k, v in params.items():
        if types[k] == "String":
            fmu.setString([vr[k]], [v])
        else:
            fmu.setReal([vr[k]], [float(v)])
    fmu.exitInitializationMode()
    return fmu, vr, unzip


def bench_observer_fmu(path: Path, kind: str, h: float, steps: int) -> float:
    fmu, vr, unzip = _fmu(path, {"observer": kind})
    ins = [vr[f"f_s[{i}]"] for i in (1, 2, 3)] + [vr[f"acc_s[{i}]"] for i in (1, 2, 3)] + \
          [vr["p_tool[1]"], vr["p_tool[2]"], vr["phi_tool"]]
    outs = [vr["f_contact_hat[1]"], vr["f_contact_hat[2]"], vr["fault"]]
    rng = np.random.default_rng(0)
    vals = np.column_stack([rng.normal(0, 5, (steps, 1)), np.zeros((steps, 1)), 117.7 + rng.normal(0, 5, (steps, 1)),
                            rng.normal(0, 0.5, (steps, 1)), np.zeros((steps, 1)), G + rng.normal(0, 0.5, (steps, 1)),
                            1.2 + rng.normal(0, 1e-3, (steps, 1)), 0.9 + np.zeros((steps, 1)), np.zeros((steps, 1))])
    t0 = time.perf_counter()
    t = 0.0
    for k in range(steps):
        fmu.setReal(ins, list(vals[k]))
        fmu.doStep(currentCommunicationPoint=t, communicationStepSize=h)
        fmu.getReal(outs)
        t += h
    dt = (time.perf_counter() - t0) / steps
    fmu.terminate()
    fmu.freeInstance()
    shutil.rmtree(unzip, ignore_errors=True)
    return dt


def bench_observer_math(kind: str, h: float, steps: int) -> float:
    core = fom.ForceObserverCore(fom.ForceObserverParameters(observer=kind))
    rng = np.random.default_rng(0)
    f_s = rng.normal(0, 5, (steps, 2)) + [0, 117.7]
    acc = rng.normal(0, 0.5, (steps, 2)) + [0, G]
    x = np.array([1.2, 0.9])
    t0 = time.perf_counter()
    for k in range(steps):
        u, a = fom.world_readings(f_s[k], acc[k], 0.0, 12.0)
        core.output(u, a, x)
        core.advance(u, a, x, h)
    return (time.perf_counter() - t0) / steps


def bench_controller_fmu(path: Path, h: float, steps: int) -> float:
    fmu, vr, unzip = _fmu(path, {})
    ins = [vr["f_contact_hat[1]"], vr["f_contact_hat[2]"], vr["p_tool[1]"], vr["p_tool[2]"],
           vr["p_ref[1]"], vr["p_ref[2]"], vr["f_desired"], vr["force_fault"]]
    outs = [vr["dp_ref[1]"], vr["dp_ref[2]"], vr["fault"]]
    rng = np.random.default_rng(0)
    t0 = time.perf_counter()
    t = 0.0
    for k in range(steps):
        fmu.setReal(ins, [20 + rng.normal(), 0.0, 1.3 + 1e-4 * rng.normal(), 0.9, 1.31, 0.9, 0.0, 0.0])
        fmu.doStep(currentCommunicationPoint=t, communicationStepSize=h)
        fmu.getReal(outs)
        t += h
    dt = (time.perf_counter() - t0) / steps
    fmu.terminate()
    fmu.freeInstance()
    shutil.rmtree(unzip, ignore_errors=True)
    return dt


def bench_controller_math(h: float, steps: int) -> float:
    d = imp.ImpedanceControllerParameters()
    law = imp.ImpedanceLaw(imp.design_gains(d), d.K_z, d.D_z)
    rng = np.random.default_rng(0)
    t0 = time.perf_counter()
    for k in range(steps):
        F, x = 20 + rng.normal(), 1.3 + 1e-4 * rng.normal()
        law.output(F, x, 1.31, 0.0, h)
        law.advance(F, x, 1.31, 0.0, h, h)
    return (time.perf_counter() - t0) / steps


def bench_scenario(fmu_dir: Path) -> None:
    """Real-time factor of the contact scenarios (FMUs of this checkout, built into ``fmu_dir``),
    run one after the other in this process; the stepping only (loading excluded)."""
    import os

    from orchestration import study_contact

    os.environ["FLEXFUSION_FMU_DIR"] = str(fmu_dir)
    print(f"load average (1 min) before the scenarios: {os.getloadavg()[0]:.2f}, {os.cpu_count()} cores")
    rtf = study_contact.real_time_factor()
    for name, (sim_t, wall, cpu) in rtf.items():
        print(f"scenario {name:<18} simulated {sim_t:5.2f} s in {wall:6.2f} s wall-clock: real-time "
              f"factor {sim_t / wall:5.2f} (>1: faster than real time); CPU {cpu:5.2f} s incl. "
              f"loading: {sim_t / cpu:5.2f} x real time on an idle core")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=5000)
    ap.add_argument("--no-scenario", action="store_true")
    args = ap.parse_args(argv)
    from orchestration.build import build_all

    with tempfile.TemporaryDirectory(prefix="ff_bench_") as tmp:
        dest = Path(tmp)
        only = ["ForceObserver", "ImpedanceController"]
        if not args.no_scenario:
            only += ["FlexibleRobot2DOF", "MotionController", "Encoder", "Imu", "ForceTorqueSensor",
                     "ContactEnvironment"]
        build_all(dest, only=only, quiet=True)
        print(f"cost per step (mean of {args.steps} steps), microseconds")
        print(f"{'component':<28}{'h':>8}{'direct':>10}{'FMU':>10}")
        for h, hl in ((0.004, "4 ms"), (0.001, "1 kHz")):
            for kind in fom.OBSERVER_KINDS:
                d = bench_observer_math(kind, h, args.steps)
                f = bench_observer_fmu(dest / "ForceObserver.fmu", kind, h, args.steps)
                print(f"{'ForceObserver/' + kind:<28}{hl:>8}{1e6 * d:10.1f}{1e6 * f:10.1f}")
            d = bench_controller_math(h, args.steps)
            f = bench_controller_fmu(dest / "ImpedanceController.fmu", h, args.steps)
            print(f"{'ImpedanceController':<28}{hl:>8}{1e6 * d:10.1f}{1e6 * f:10.1f}")
        if not args.no_scenario:
            bench_scenario(dest)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Motion controller: setup time, per-step cost (direct and through FMI), closed-loop figures.

Prints, for the ISO 9283 path at 1 kHz:
* setup time of the reference table (trajectory sampling, IK, feed-forward);
* per-step cost of the controller called directly (evaluate + advance) and of the FMU through
  fmpy's FMU2Slave (set inputs + get outputs + doStep, batched);
* closed-loop figures with the flexible plant (dynamics.FlexibleRobotModel, called directly):
  motor-side error, tool tracking error vs p_ref, and the tool's deviation from the rigid
  kinematics of the motor angles (total, and minus the static gravity deflection at the start).

Run: ``.venv/bin/python benchmarks/motion_controller.py [path]``.
"""
from __future__ import annotations

import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from fmus.common import dynamics, kinematics  # noqa: E402
from fmus.robot_plant import motion_control_model as mcm  # noqa: E402

DT = 1e-3


def closed_loop(params: mcm.MotionControllerParameters) -> tuple[dict[str, float], float, float]:
    t0 = time.perf_counter()
    ctrl = mcm.build_controller(params)
    t_setup = time.perf_counter() - t0
    plant_p = params.robot()
    plant = dynamics.FlexibleRobotModel(plant_p, ctrl.model.q_a_ref0)
    r = np.asarray(plant_p.gear_ratio, float)
    n = int(round((ctrl.model.trajectory.duration + 0.3) / DT))
    zero = np.zeros(2)
    dev, trk, em = np.empty((n, 2)), np.empty((n, 2)), np.empty((n, 2))
    t_ctrl = 0.0
    for k in range(n):
        x = plant.x
        c0 = time.perf_counter()
        q_m = np.array(x[2:4])
        ctrl.measure(k * DT, q_m)                                 # the drive's speeds from q_m
        tau = ctrl.evaluate(k * DT, q_m, ctrl.law_speed(k * DT), zero)
        ctrl.advance(DT)
        t_ctrl += time.perf_counter() - c0
        p_tool = kinematics.tool_position(x[0:2], plant_p)
        dev[k] = p_tool - kinematics.tool_position(x[2:4] / r, plant_p)
        trk[k] = p_tool - ctrl.p_ref
        em[k] = ctrl.error
        plant.step(tau, zero, DT)
    dn, dd, tn = np.hypot(*dev.T), np.hypot(*(dev - dev[0]).T), np.hypot(*trk.T)
    fig = {"deviation tool vs rigid(q_m/r), peak [mm]": dn.max() * 1e3,
           "deviation tool vs rigid(q_m/r), RMS [mm]": math.sqrt((dn ** 2).mean()) * 1e3,
           "  same minus static deflection at t=0, peak [mm]": dd.max() * 1e3,
           "  same minus static deflection at t=0, RMS [mm]": math.sqrt((dd ** 2).mean()) * 1e3,
           "tool tracking error vs p_ref, peak [mm]": tn.max() * 1e3,
           "tool tracking error vs p_ref, RMS [mm]": math.sqrt((tn ** 2).mean()) * 1e3,
           "motor error, peak [mrad motor side]": np.abs(em).max() * 1e3,
           "motor error, RMS [mrad motor side]": math.sqrt((em ** 2).mean()) * 1e3}
    return fig, t_setup, t_ctrl / n


def fmi_cost(path: str, n_steps: int = 3000) -> float:
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    from orchestration.build import build_all

    with tempfile.TemporaryDirectory() as tmp:
        build_all(Path(tmp), only=["MotionController"], quiet=True)
        fmu = str(Path(tmp) / "MotionController.fmu")
        md = read_model_description(fmu)
        vr = {v.name: v.valueReference for v in md.modelVariables}
        s = FMU2Slave(guid=md.guid, unzipDirectory=extract(fmu),
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="mc")
        s.instantiate()
        s.setupExperiment(startTime=0.0)
        s.enterInitializationMode()
        s.setString([vr["path"]], [path])
        s.exitInitializationMode()
        ins = [vr[f"{n}[{i}]"] for n in ("q_m", "dp_ref") for i in (1, 2)]
        outs = [v.valueReference for v in md.modelVariables if v.causality == "output"]
        u = [0.0] * 4
        t0 = time.perf_counter()
        for k in range(n_steps):
            s.setReal(ins, u)
            s.getReal(outs)
            s.doStep(currentCommunicationPoint=k * DT, communicationStepSize=DT)
        cost = (time.perf_counter() - t0) / n_steps
        s.terminate()
        s.freeInstance()
    return cost


def main() -> None:
    path = sys.argv[1] if len(sys.argv) > 1 else "iso9283"
    params = mcm.MotionControllerParameters(path=path)
    fig, t_setup, t_step = closed_loop(params)
    print(f"path {path}: reference table setup {t_setup * 1e3:.0f} ms")
    print(f"controller step called directly (evaluate + advance): {t_step * 1e6:.1f} us")
    print(f"controller step through FMI (setReal + getReal of all outputs + doStep): "
          f"{fmi_cost(path) * 1e6:.1f} us")
    print("closed loop with FlexibleRobotModel at 1 kHz (controller model = plant):")
    for k, v in fig.items():
        print(f"  {k:<52} {v:8.3f}")


if __name__ == "__main__":
    main()

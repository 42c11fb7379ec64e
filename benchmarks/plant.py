"""Flexible robot plant: lowest locked-motor resonance, per-step cost, real-time factor.

Prints

* the locked-motor resonances at a few working poses (the start points of the controller's
  paths and the home pose), from the finite-difference linearisation of
  ``dynamics.derivatives`` at static equilibrium with the motor states removed (motors locked):
  natural frequency and damping ratio of each mode, and the undamped frequency of
  ``dynamics.locked_motor_frequencies`` as a cross-check;
* the realistic plant's locked-motor modes (``plant_dynamics.PlantChain.linearised_modes``) at the
  same poses, and the range of its bending mode (20-40 Hz goal) over a grid of the workspace;
* the per-step cost of the plant model called directly (``step`` at 1 ms with the plant FMU's
  default RK4 substeps), realistic (default) and ``ideal`` (today's 8-state model), their ratio,
  and through its FMU with fmpy's FMU2Slave (one setReal of tau_m and f_ext, doStep, one getReal
  of every output), the FMU / direct ratio, and the FMU's real-time factor at a 1 kHz
  communication step (goal: at least 20).

Run: ``.venv/bin/python benchmarks/plant.py``.
"""
from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from fmus.common import dynamics, kinematics  # noqa: E402
from fmus.common.parameters import as_array, replace  # noqa: E402
from fmus.robot_plant import plant_dynamics  # noqa: E402
from fmus.robot_plant.plant_model import PlantParameters  # noqa: E402

DT = 1e-3
POSES = {"home q=(0,0)": None, "P1 start (1.10, 0.80)": (1.10, 0.80), "P2 start (1.45, 0.55)": (1.45, 0.55),
         "(1.00, 0.60)": (1.00, 0.60), "far (1.60, 0.20)": (1.60, 0.20)}
#: the ISO 9283 path starts at (1.20, 0.90), which is the home pose q = (0, 0)


def locked_motor_modes(q_a, p) -> tuple[np.ndarray, np.ndarray]:
    """Natural frequencies [Hz] and damping ratios of the arm with the motors locked, from the
    finite-difference linearisation of ``dynamics.derivatives`` at static equilibrium."""
    x0 = dynamics.static_equilibrium(q_a, p)
    arm = [0, 1, 4, 5]
    A = np.empty((4, 4))
    zero = np.zeros(2)
    for j, i in enumerate(arm):
        h = 1e-7
        e = np.zeros(8)
        e[i] = h
        A[:, j] = ((dynamics.derivatives(x0 + e, zero, zero, p) - dynamics.derivatives(x0 - e, zero, zero, p))
                   / (2 * h))[arm]
    lam = np.linalg.eigvals(A)
    lam = lam[lam.imag > 0] if np.count_nonzero(lam.imag > 0) == 2 else lam[:2]
    wn = np.abs(lam)
    order = np.argsort(wn)
    return wn[order] / (2 * np.pi), (-lam.real / wn)[order]


def direct_cost(p: PlantParameters, n: int) -> float:
    model = plant_dynamics.plant_model(p)
    tau = as_array(model.spring_torques()) / as_array(p.gear_ratio)
    f = np.zeros(2)
    t0 = time.perf_counter()
    for _ in range(n):
        model.step(tau, f, DT)
    return (time.perf_counter() - t0) / n


def fmu_cost(fmu: Path, p: PlantParameters, n: int) -> tuple[float, ...]:
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    md = read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    s = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(fmu)),
                  modelIdentifier=md.coSimulation.modelIdentifier, instanceName="plant")
    s.instantiate()
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    s.setBoolean([vr["ideal"]], [p.ideal])
    s.exitInitializationMode()
    u = list(map(float, s.getReal([vr["tau_s[1]"], vr["tau_s[2]"]]) / as_array(p.gear_ratio))) + [0.0, 0.0]
    ins = [vr[f"{name}[{i}]"] for name in ("tau_m", "f_ext") for i in (1, 2)]
    outs = [v.valueReference for v in md.modelVariables if v.causality == "output"]
    clock = time.perf_counter
    t_set = t_step = t_get = 0.0
    t0 = clock()
    for k in range(n):
        a = clock()
        s.setReal(ins, u)
        b = clock()
        s.doStep(currentCommunicationPoint=k * DT, communicationStepSize=DT)
        c = clock()
        s.getReal(outs)
        t_set, t_step, t_get = t_set + b - a, t_step + c - b, t_get + clock() - c
    cost = (clock() - t0) / n
    s.terminate()
    s.freeInstance()
    return cost, t_set / n, t_step / n, t_get / n


def main() -> None:
    p = PlantParameters()
    robot = p.robot()
    print("Lowest locked-motor resonances (linearised at static equilibrium, motors locked):")
    print(f"  {'pose':<24} {'q_a [rad]':>16}  {'f1 [Hz]':>7} {'zeta1':>6}  {'f2 [Hz]':>7} {'zeta2':>6}"
          f"  {'undamped f1, f2 [Hz]':>20}")
    for name, target in POSES.items():
        q = np.zeros(2) if target is None else kinematics.inverse_kinematics(target, robot)
        f, z = locked_motor_modes(q, robot)
        fu = dynamics.locked_motor_frequencies(q, robot)
        print(f"  {name:<24} ({q[0]:6.3f}, {q[1]:6.3f})  {f[0]:7.2f} {z[0]:6.3f}  {f[1]:7.2f} {z[1]:6.3f}"
              f"  {fu[0]:9.2f} {fu[1]:9.2f}")

    chain = plant_dynamics.PlantChain(p)
    arm = list(range(chain.n))
    print("\nRealistic plant (link bending), motors locked: natural frequencies [Hz] (damping ratio):")
    for name, target in POSES.items():
        q = np.zeros(2) if target is None else kinematics.inverse_kinematics(target, robot)
        f, z = chain.linearised_modes(chain.static_equilibrium(q), arm)
        print(f"  {name:<24} " + "  ".join(f"{a:6.1f} ({b:.3f})" for a, b in zip(f, z)))
    bending = []
    for q1 in np.linspace(-0.9, 0.9, 7):
        for q2 in np.linspace(-0.9, 0.9, 7):
            f, _ = chain.linearised_modes(chain.static_equilibrium((q1, q2)), arm)
            bending.append(f[2])           # gearbox modes, the bending mode, the inner-link mode
    print(f"  bending mode over the workspace grid q1, q2 in [-0.9, 0.9] rad (49 poses): "
          f"{min(bending):.1f}-{max(bending):.1f} Hz (goal 20-40 Hz)")
    print(f"  stiffest mode at the default initial pose: {plant_dynamics.plant_model(p).highest_frequency:.0f} Hz "
          f"(the step check: RK4 needs 2 pi f h <= 2 sqrt(2))")

    n = 5000
    ideal = replace(p, ideal=True)
    costs = {}
    for label, params in (("realistic", p), ("ideal", ideal)):
        direct_cost(params, 500)   # warm-up
        costs[label] = direct_cost(params, n)
    dist = REPO / "dist" / "fmus" / "FlexibleRobot2DOF.fmu"
    with tempfile.TemporaryDirectory() as tmp:
        fmu = dist
        if not dist.exists():
            from orchestration.build import build_all
            build_all(Path(tmp), only=["FlexibleRobot2DOF"], quiet=True)
            fmu = Path(tmp) / "FlexibleRobot2DOF.fmu"
        fmu_costs = {}
        for label, params in (("realistic", p), ("ideal", ideal)):
            fmu_cost(fmu, params, 500)   # warm-up
            fmu_costs[label] = fmu_cost(fmu, params, n)
    print(f"\nPer-step cost at dt = {DT * 1e3:g} ms, RK4 with {p.substeps} substeps ({n} steps, {fmu.name}):")
    for label in ("realistic", "ideal"):
        t_direct = costs[label]
        t_fmu, t_set, t_step, t_get = fmu_costs[label]
        print(f"  {label}:")
        print(f"    plant model called directly (step): {t_direct * 1e6:8.1f} us")
        print(f"    through the FMU (setReal tau_m+f_ext, doStep, getReal of all outputs): {t_fmu * 1e6:8.1f} us")
        print(f"      of which setReal {t_set * 1e6:.1f} us, doStep {t_step * 1e6:.1f} us (model step, NaN check "
              f"and update_outputs), getReal {t_get * 1e6:.1f} us")
        print(f"    ratio FMU / direct: {t_fmu / t_direct:.1f}")
        rtf = DT / t_fmu
        print(f"    FMU real-time factor at a 1 kHz communication step: {rtf:.1f}x faster than real time "
              f"(goal >= 20x: {'met' if rtf >= 20 else 'NOT met'})")
    print(f"  realism cost ratio realistic / ideal: direct {costs['realistic'] / costs['ideal']:.2f}, "
          f"through the FMU {fmu_costs['realistic'][0] / fmu_costs['ideal'][0]:.2f}")


if __name__ == "__main__":
    main()

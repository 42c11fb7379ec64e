"""The realistic plant (fmus/robot_plant/plant_dynamics.py): link bending, motor torque errors and
static kinematic errors that no estimator's model has; ``ideal = true`` is today's 8-state plant."""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract
from numpy.testing import assert_allclose, assert_array_equal

from fmus.common import dynamics, kinematics
from fmus.common.parameters import ParameterError, as_array, replace
from fmus.robot_plant import plant_dynamics
from fmus.robot_plant.plant_model import PlantParameters
from fmu_host import Slave

P = PlantParameters()
#: no damping, no friction anywhere (gearboxes, bending joints, motors)
CONSERVATIVE = replace(P, d=(0.0, 0.0), f_v=(0.0, 0.0), f_c=(0.0, 0.0), bend_damping=(0.0, 0.0))
#: the realistic plant with every feature off but for its own formulation (rigid links)
NO_REALISM = replace(P, link_bending=False, ripple_amplitude=(0.0, 0.0), torque_constant_error=(0.0, 0.0),
                     dl=(0.0, 0.0), q_offset=(0.0, 0.0), sensor_offset_error=(0.0, 0.0))
R = as_array(P.gear_ratio)
DT = 1e-3
WORK_POINTS = [(1.10, 0.80), (1.45, 0.55), (1.00, 0.60), (1.20, 0.90), (1.60, 0.20)]


def _perturbed(chain: plant_dynamics.PlantChain, rng: np.random.Generator) -> tuple:
    """A state near static equilibrium somewhere in the workspace, moving."""
    x = np.array(chain.static_equilibrium(rng.uniform(-1.0, 1.0, 2)))
    n = chain.n
    x[:n] += rng.uniform(-1e-3, 1e-3, n)
    x[n:n + 2] += rng.uniform(-0.2, 0.2, 2)
    x[n + 2:2 * n + 2] += rng.uniform(-1.0, 1.0, n)
    x[2 * n + 2:] += rng.uniform(-100.0, 100.0, 2)
    return tuple(x)


# ---- the formulation against the 8-state model ---------------------------------------------
def test_rigid_chain_without_errors_is_the_8_state_model() -> None:
    """Independent check of the chain equations (absolute angles, Cholesky) against dynamics.py's
    relative-angle closed form, and of the output kinematics against kinematics.point_motion."""
    chain = plant_dynamics.PlantChain(NO_REALISM)
    robot = P.robot()
    rng = np.random.default_rng(1)
    for _ in range(10):
        x = _perturbed(chain, rng)
        tau, f = rng.uniform(-5.0, 5.0, 2), rng.uniform(-300.0, 300.0, 2)
        xd = dynamics.derivatives(x, tau, f, robot)
        assert_allclose(chain.derivatives(x, *tau, *f), xd, rtol=1e-10, atol=1e-9)
        assert_allclose(chain.energy(x), dynamics.energy(x, robot), rtol=1e-12)
        q, dq, ddq = x[0:2], x[4:6], xd[4:6]
        tool = kinematics.point_motion(q, dq, ddq, robot, "tool")
        sensor = kinematics.point_motion(q, dq, ddq, robot, "sensor")
        expected = (*q, *dq, *ddq, *x[2:4], *x[6:8], *tool, q[0] + q[1], dq[0] + dq[1], *sensor[0:2],
                    *sensor[4:6], *dynamics.spring_torque(q, x[2:4], robot))
        assert_allclose(chain.outputs(x, *f), expected, rtol=1e-10, atol=1e-9)


def _generator_rk4(f, s, t1, t2, h):
    """The RK4 step as written before issue 16 (generators), the reference of the faster one."""
    k1 = f(s, t1, t2, 0.0, 0.0)
    k2 = f(tuple(a + 0.5 * h * b for a, b in zip(s, k1)), t1, t2, 0.0, 0.0)
    k3 = f(tuple(a + 0.5 * h * b for a, b in zip(s, k2)), t1, t2, 0.0, 0.0)
    k4 = f(tuple(a + h * b for a, b in zip(s, k3)), t1, t2, 0.0, 0.0)
    return tuple(a + h / 6.0 * (b1 + 2 * b2 + 2 * b3 + b4) for a, b1, b2, b3, b4 in zip(s, k1, k2, k3, k4))


@pytest.mark.parametrize("ideal", [False, True])
def test_rk4_step_is_bit_identical_to_the_generator_version(ideal) -> None:
    rng = np.random.default_rng(5)
    model = plant_dynamics.plant_model(replace(P, ideal=ideal, substeps=3))
    f = model._k.derivatives
    for _ in range(50):
        s = _perturbed(model._k, rng) if not ideal else tuple(
            dynamics.static_equilibrium(rng.uniform(-1.0, 1.0, 2), model.p) + rng.normal(0.0, 1e-3, 8))
        tau = rng.normal(0.0, 20.0, 2)
        ref = s
        for _ in range(3):
            ref = _generator_rk4(f, ref, tau[0], tau[1], DT / 3)
        model.x = s
        model.step(tau, (0.0, 0.0), DT)
        assert_array_equal(model.state, ref)


def test_written_out_four_body_solve_equals_the_general_chain() -> None:
    chain = plant_dynamics.PlantChain(P)
    rng = np.random.default_rng(2)
    for _ in range(5):
        x = _perturbed(chain, rng)
        fast = chain.arm(x, 120.0, -70.0)
        general = plant_dynamics.PlantChain.arm(chain, x, 120.0, -70.0)
        for a, b in zip(fast, general):
            assert_allclose(a, b, rtol=1e-12, atol=1e-9)


# ---- energy -----------------------------------------------------------------------------------
@pytest.mark.parametrize("q0, dq0, substeps, periods, steps", [
    ((math.pi, -math.pi / 2), (0.6, -0.4), P.substeps, P.ripple_periods, 10000),   # hanging, swinging: 10 s
    ((0.3, 0.2), (0.0, 0.0), 4, (3.0, 3.0), 3000),                                 # the arm falls: 3 s
], ids=["hanging", "falling"])
def test_energy_is_conserved_without_damping_and_friction(q0, dq0, substeps, periods, steps) -> None:
    """Bending, ripple (with its potential) and kinematic errors on. The falling arm's motors reach
    700 rad/s: 3 ripple periods per revolution keep the ripple (then 330 Hz) resolved by 4 substeps;
    at the default 24 periods it would be 2.7 kHz."""
    p = replace(CONSERVATIVE, ripple_periods=periods)
    m = plant_dynamics.ExtendedRobotModel(p, q0, substeps=substeps)
    x = m.x
    x[4:6] += (0.05, -0.03)              # motor angles: excites the gearbox modes
    x[6] += dq0[0]                       # arm (q1, q2) and motors swing together
    x[8] += dq0[1]
    x[10:12] += R * np.asarray(dq0)
    m.x = x
    energy = m._k.energy
    E0 = energy(m.state)
    drift = travel = 0.0
    for _ in range(steps):
        m.step((0.0, 0.0), (0.0, 0.0), DT)
        drift = max(drift, abs(energy(m.state) - E0))
        travel = max(travel, abs(m.state[0] - q0[0]), abs(m.state[2] - q0[1]))
    assert travel > 0.1
    print(f"relative energy drift: {drift / abs(E0):.2e}")
    assert drift / abs(E0) < 1e-6, drift / abs(E0)


def test_energy_balance_with_inputs_damping_and_friction() -> None:
    """dE/dt = (1 + e_kt) tau_m dq_m + f_ext . v_tool - damping and friction power, with E including
    the ripple's potential: ripple, torque-constant error, tool force and bending enter right."""
    chain = plant_dynamics.PlantChain(P)
    robot = P.robot()
    rng = np.random.default_rng(3)
    kt = 1.0 + as_array(P.torque_constant_error)
    for _ in range(10):
        x = np.array(_perturbed(chain, rng))
        tau, f = rng.uniform(-5.0, 5.0, 2), rng.uniform(-300.0, 300.0, 2)
        xd = np.array(chain.derivatives(tuple(x), *tau, *f))
        h = 1e-7
        dEdt = (chain.energy(tuple(x + h * xd)) - chain.energy(tuple(x - h * xd))) / (2 * h)
        q_dot, dqm = x[6:10], x[10:12]
        v_tool = np.array(chain.outputs(tuple(x), *f)[12:14])
        Ddot = dqm / R - q_dot[[0, 2]]
        power = (kt * tau @ dqm + f @ v_tool - np.sum(as_array(P.d) * Ddot ** 2)
                 - np.sum(as_array(P.bend_damping) * q_dot[[1, 3]] ** 2) - dynamics.motor_friction(dqm, robot) @ dqm)
        assert_allclose(dEdt, power, rtol=1e-6, atol=1e-6 * float(np.abs(xd).max()))


# ---- the structural mode ----------------------------------------------------------------------
def _locked_motor_modes(chain: plant_dynamics.PlantChain, q) -> tuple:
    s = chain.static_equilibrium(q)
    return s, chain.linearised_modes(s, list(range(chain.n)), shapes=True)


@pytest.mark.parametrize("target", WORK_POINTS)
def test_a_bending_mode_at_20_to_40_hz_beyond_the_gearbox(target) -> None:
    """Motors locked, linearised at rest: one mode in 20-40 Hz, with over 80 % of its strain
    energy in the bending joints, not in the gearbox springs; the lowest mode stays a gearbox mode."""
    chain = plant_dynamics.PlantChain(P)
    q = kinematics.inverse_kinematics(target, P)
    s, (f, zeta, shapes) = _locked_motor_modes(chain, q)
    in_band = np.flatnonzero((f > 20.0) & (f < 40.0))
    assert in_band.size == 1, f
    v = shapes[:, in_band[0]]
    v = np.real(v / v[np.argmax(np.abs(v))])
    K_gear = dynamics.spring_stiffness(np.array(s[4:6]) / R - np.array(s[0:4:2]), P.robot())
    strain_gear = 0.5 * np.sum(K_gear * v[[0, 2]] ** 2)
    strain_bend = 0.5 * np.sum(as_array(P.bend_stiffness) * v[[1, 3]] ** 2)
    assert strain_bend > 0.8 * (strain_bend + strain_gear), (strain_bend, strain_gear)
    assert 0.005 < zeta[in_band[0]] < 0.1
    assert 6.0 < f[0] < 15.0


@pytest.mark.parametrize("target", WORK_POINTS[:2])
def test_hammer_response_peaks_at_the_linearised_frequency(target) -> None:
    """Independent check of the linearisation: a 1 ms tool-force pulse on the nonlinear model with
    the motors locked (their rates and accelerations held at zero), the spectrum of the tool
    acceleration over 2 s peaks at the damped frequency of the 20-40 Hz mode (within the 0.5 Hz
    resolution of the record)."""
    chain = plant_dynamics.PlantChain(P)
    q = kinematics.inverse_kinematics(target, P)
    s, (f, zeta, _) = _locked_motor_modes(chain, q)
    i = int(np.flatnonzero((f > 20.0) & (f < 40.0))[0])
    f_damped = f[i] * math.sqrt(1.0 - zeta[i] ** 2)

    def locked(x, fx, fz):
        d = list(chain.derivatives(x, 0.0, 0.0, fx, fz))
        d[4] = d[5] = d[10] = d[11] = 0.0
        return d

    h, n = 5e-4, 4000
    x = s
    acc = np.empty(n)
    for k in range(n):
        fx, fz = (300.0, -300.0) if k < 2 else (0.0, 0.0)
        k1 = locked(x, fx, fz)
        k2 = locked(tuple(a + 0.5 * h * b for a, b in zip(x, k1)), fx, fz)
        k3 = locked(tuple(a + 0.5 * h * b for a, b in zip(x, k2)), fx, fz)
        k4 = locked(tuple(a + h * b for a, b in zip(x, k3)), fx, fz)
        x = tuple(a + h / 6 * (b1 + 2 * b2 + 2 * b3 + b4) for a, b1, b2, b3, b4 in zip(x, k1, k2, k3, k4))
        acc[k] = chain.outputs(x, 0.0, 0.0)[15]          # a_tool z
    spectrum = np.abs(np.fft.rfft(acc * np.hanning(n), 16 * n))
    freq = np.fft.rfftfreq(16 * n, h)
    band = (freq > 20.0) & (freq < 45.0)
    peak = freq[band][np.argmax(spectrum[band])]
    assert abs(peak - f_damped) < 0.5, (peak, f_damped)


# ---- integration ------------------------------------------------------------------------------
def test_halving_the_step_converges_at_fourth_order() -> None:
    """Closed loop at 1 kHz (zero-order hold) with a force step; RK4 with 1, 2, 4, 8 substeps: the
    tool-path differences between successive halvings fall by about 2^4."""
    q0 = kinematics.inverse_kinematics(WORK_POINTS[0], P)
    models = [plant_dynamics.ExtendedRobotModel(P, q0, substeps=n) for n in (1, 2, 4, 8)]
    kp, kd = np.array([20.0, 10.0]), np.array([0.5, 0.3])
    f = np.zeros(2)
    diff = np.zeros(3)
    for k in range(1500):
        q_ref = q0 + np.array([0.3, -0.2]) * (1 - math.cos(math.pi * min(k * DT, 1.0))) / 2
        x = models[0].x
        tau = dynamics.gravity_torque(q_ref, P) / R + kp * (R * q_ref - x[4:6]) - kd * x[10:12]
        if k == 1200:
            f = np.array([150.0, -80.0])
        tools = []
        for m in models:
            m.step(tau, f, DT)
            tools.append(np.array(m.outputs(*f)[10:12]))
        diff = np.maximum(diff, [np.linalg.norm(a - b) for a, b in zip(tools, tools[1:])])
    order = np.log2(diff[:-1] / diff[1:])
    print(f"tool path change on halving the step: {diff} m, observed orders {order}")
    assert np.all((order > 3.3) & (order < 4.7)), order
    assert diff[0] < 3e-6          # the default (1 substep at 1 ms) is within a few micrometres


# ---- motor torque errors ------------------------------------------------------------------------
def test_ripple_stiffens_the_locked_arm_motor_mode_as_its_gradient() -> None:
    """Arm held, motor free: J_m w^2 = K_gear / r^2 - A n cos(n q_m) at the equilibrium (the ripple
    A sin(n q_m) has the gradient A n cos(n q_m))."""
    chain = plant_dynamics.PlantChain(P)
    for q in ((0.0, 0.0), (0.4, -0.3)):
        s = chain.static_equilibrium(q)
        qm = np.array(s[4:6])
        K = dynamics.spring_stiffness(qm / R - np.array(s[0:4:2]), P.robot())
        A, n = as_array(P.ripple_amplitude), as_array(P.ripple_periods)
        w2 = (K / R ** 2 - A * n * np.cos(n * qm)) / as_array(P.J_m)
        for i in range(2):
            f, _ = chain.linearised_modes(s, [4 + i])
            undamped = f[0]
            assert_allclose(undamped, math.sqrt(w2[i]) / (2 * math.pi), rtol=1e-5)
        assert np.abs(A * n * np.cos(n * qm) / (K / R ** 2)).max() > 0.01   # the ripple matters here


def test_static_equilibrium_is_held_by_the_compensated_torque() -> None:
    """At rest, the command that holds is (tau_s / r - ripple) / (1 + e_kt)."""
    chain = plant_dynamics.PlantChain(P)
    for q in ((0.0, 0.0), (0.5, 0.3)):
        s = chain.static_equilibrium(q)
        tau_s = np.array(chain.outputs(s, 0.0, 0.0)[22:24])
        qm = np.array(s[4:6])
        ripple = as_array(P.ripple_amplitude) * np.sin(as_array(P.ripple_periods) * qm)
        hold = (tau_s / R - ripple) / (1.0 + as_array(P.torque_constant_error))
        assert_allclose(chain.derivatives(s, *hold, 0.0, 0.0), 0.0, atol=1e-9)
        assert np.abs(chain.derivatives(s, *(tau_s / R), 0.0, 0.0)[10:12]).min() > 1.0


# ---- static kinematic errors -----------------------------------------------------------------
def test_kinematic_errors_move_tool_and_sensor_as_specified() -> None:
    """Rigid links: the tool and sensor outputs are the forward kinematics of the true lengths and
    the offset joint angles; each default error moves the tool (or the sensor) by 0.1-0.5 mm."""
    p = replace(P, link_bending=False)
    chain = plant_dynamics.PlantChain(p)
    true = replace(P.robot(), l1=P.l1 + P.dl[0], l2=P.l2 + P.dl[1],
                   sensor_offset=as_array(P.sensor_offset) + as_array(P.sensor_offset_error))
    for target in WORK_POINTS:
        q = kinematics.inverse_kinematics(target, P)
        s = chain.static_equilibrium(q)
        out = chain.outputs(s, 0.0, 0.0)
        q_true = np.array(out[0:2]) + as_array(P.q_offset)
        assert_allclose(out[0:2], q, atol=1e-15)          # q_a: the gearbox output, encoder zero
        assert_allclose(out[10:12], kinematics.tool_position(q_true, true), atol=1e-12)
        assert_allclose(out[18:20], kinematics.sensor_position(q_true, true), atol=1e-12)
        assert_allclose(out[16], q_true.sum(), atol=1e-15)
        nominal = kinematics.tool_position(q, P)
        for name, value in (("dl", P.dl), ("q_offset", P.q_offset)):
            alone = plant_dynamics.PlantChain(replace(NO_REALISM, **{name: value}))
            moved = np.linalg.norm(np.array(alone.outputs(alone.static_equilibrium(q), 0.0, 0.0)[10:12]) - nominal)
            assert 1e-4 < moved < 5e-4, (name, moved)
    assert 1e-4 < np.linalg.norm(P.sensor_offset_error) < 5e-4


# ---- parameters ---------------------------------------------------------------------------------
@pytest.mark.parametrize("changes, fragment", [
    ({"ripple_amplitude": (-0.1, 0.1)}, "parameter 'ripple_amplitude[1]'"),
    ({"bend_stiffness": (3e6, -1.0)}, "parameter 'bend_stiffness[2]'"),
    ({"bend_damping": (-1.0, 8.0)}, "parameter 'bend_damping[1]'"),
    ({"torque_constant_error": (0.5, 0.0)}, "parameter 'torque_constant_error[1]'"),
    ({"dl": (0.0, 0.02)}, "parameter 'dl[2]'"),
    ({"q_offset": (0.1, 0.0)}, "parameter 'q_offset[1]'"),
    ({"sensor_offset_error": (0.0, -0.05)}, "parameter 'sensor_offset_error[2]'"),
    ({"bend_location": (1.0, 0.5)}, "parameter 'bend_location[1]'"),
    ({"bend_mass_fraction": (0.5, 0.8)}, "parameter 'bend_mass_fraction[2]'"),
])
def test_bad_parameters_are_rejected_naming_the_parameter(changes, fragment) -> None:
    with pytest.raises(ParameterError, match=re.escape(fragment)):
        plant_dynamics.plant_model(replace(P, **changes))


def test_a_step_too_coarse_for_the_stiffest_mode_is_rejected_naming_substeps() -> None:
    m = plant_dynamics.plant_model(P)
    assert 100.0 < m.highest_frequency < 400.0
    m.check_step(1e-3)                                   # the default: fine
    with pytest.raises(ParameterError, match="parameter 'substeps' = 1.*raise 'substeps' to at least 3"):
        m.check_step(5e-3)
    plant_dynamics.plant_model(replace(P, substeps=3)).check_step(5e-3)


# ---- the FMU ------------------------------------------------------------------------------------
OUTPUTS = ("q_a", "dq_a", "ddq_a", "q_m", "dq_m", "p_tool", "v_tool", "a_tool", "phi_tool", "omega_tool",
           "p_sensor", "a_sensor", "tau_s")


@pytest.fixture(scope="module")
def fmu(every_fmu: dict[str, Path]) -> Path:
    return every_fmu["FlexibleRobot2DOF"]


@pytest.fixture(scope="module")
def unzipped(fmu: Path) -> str:
    return extract(str(fmu))


def _output_refs(s: Slave) -> list[int]:
    return [s.vr[n] if n in s.vr else s.vr[f"{n}[{i}]"] for n in OUTPUTS for i in ((None,) if n in s.vr else (1, 2))]


def _run_against(s: Slave, model, steps: int) -> None:
    """Drive the FMU and ``model`` with the same random inputs; outputs must be bit-identical."""
    rng = np.random.default_rng(42)
    refs = _output_refs(s)
    tau0 = np.array(s.get("tau_s", 2)) / R
    for k in range(steps):
        tau = tau0 + rng.normal(0.0, 2.0, 2)
        f = rng.normal(0.0, 100.0, 2) if k > 100 else np.zeros(2)
        s.fmu.setReal(s.vec("tau_m") + s.vec("f_ext"), list(map(float, np.r_[tau, f])))
        s.fmu.doStep(currentCommunicationPoint=k * DT, communicationStepSize=DT)
        model.step(tau, f, DT)
        assert_array_equal(s.fmu.getReal(refs), model.outputs(float(f[0]), float(f[1])))
        assert_array_equal(s.get("tau_applied", 2), model.applied_torques(float(tau[0]), float(tau[1])))


def test_ideal_fmu_is_bit_identical_to_the_8_state_model(fmu: Path, unzipped: str) -> None:
    """ideal = true: today's plant, dynamics.FlexibleRobotModel and the rigid kinematics of the
    nominal robot (the expected values are computed here as the FMU computed them before)."""
    s = Slave(fmu, {"p_tool0[1]": 1.2, "p_tool0[2]": 0.9, "ideal": True}, unzip_dir=unzipped, instance_name="plant")
    s.fmu.exitInitializationMode()
    p = PlantParameters(p_tool0=(1.2, 0.9))
    robot = p.robot()
    model = dynamics.FlexibleRobotModel(robot, p.initial_angles(), substeps=p.substeps)
    rng = np.random.default_rng(42)
    refs = _output_refs(s)
    tau0 = dynamics.gravity_torque(p.initial_angles(), robot) / R
    for k in range(300):
        tau = tau0 + rng.normal(0.0, 2.0, 2)
        f = rng.normal(0.0, 100.0, 2) if k > 100 else np.zeros(2)
        s.fmu.setReal(s.vec("tau_m") + s.vec("f_ext"), list(map(float, np.r_[tau, f])))
        s.fmu.doStep(currentCommunicationPoint=k * DT, communicationStepSize=DT)
        model.step(tau, f, DT)
        st = model.state
        q, qm, dq, dqm = st[0:2], st[2:4], st[4:6], st[6:8]
        ddq = model.arm_acceleration(float(f[0]), float(f[1]))
        tool = kinematics.point_motion(q, dq, ddq, robot, "tool")
        sensor = kinematics.point_motion(q, dq, ddq, robot, "sensor")
        expected = [*q, *dq, *ddq, *qm, *dqm, *tool, q[0] + q[1], dq[0] + dq[1], *sensor[0:2], *sensor[4:6],
                    *model.spring_torques()]
        assert_array_equal(s.fmu.getReal(refs), expected)
        assert_array_equal(s.get("tau_applied", 2), tau)
    assert np.abs(model.x[0:2] - p.initial_angles()).max() > 1e-4      # it moved
    s.close()


def test_realistic_fmu_is_the_plain_extended_model(fmu: Path, unzipped: str) -> None:
    s = Slave(fmu, {"p_tool0[1]": 1.1, "p_tool0[2]": 0.8}, unzip_dir=unzipped, instance_name="plant")
    s.fmu.exitInitializationMode()
    p = PlantParameters(p_tool0=(1.1, 0.8))
    model = plant_dynamics.ExtendedRobotModel(p, p.initial_angles(), substeps=p.substeps)
    # the real robot starts elsewhere than the nominal kinematics say (bending sag and static
    # errors, partly cancelling here: 0.07 mm); the ideal plant starts there to 1e-12 m
    offset = np.linalg.norm(s.get("p_tool", 2) - np.array([1.1, 0.8]))
    assert 1e-5 < offset < 2e-3, offset
    _run_against(s, model, 300)
    s.close()


def test_fmu_holds_still_only_with_the_torque_errors_compensated(fmu: Path, unzipped: str) -> None:
    """The locked analytic case through the FMU: commanding (tau_s / r - ripple(q_m)) / (1 + e_kt)
    keeps the robot at rest; the nominal holding torque tau_s / r does not."""
    results = []
    for compensate in (True, False):
        s = Slave(fmu, {"q_a0[1]": 0.5, "q_a0[2]": 0.3}, unzip_dir=unzipped, instance_name="plant")
        s.fmu.exitInitializationMode()
        qm0, tau_s = s.get("q_m", 2), s.get("tau_s", 2)
        tau = tau_s / R
        if compensate:
            ripple = as_array(P.ripple_amplitude) * np.sin(as_array(P.ripple_periods) * qm0)
            tau = (tau - ripple) / (1.0 + as_array(P.torque_constant_error))
        s.set(tau_m=tau)
        for _ in range(300):
            s.step(DT)
        assert_allclose(s.get("tau_applied", 2), tau_s / R if compensate else
                        (1.0 + as_array(P.torque_constant_error)) * tau
                        + as_array(P.ripple_amplitude) * np.sin(as_array(P.ripple_periods) * s.get("q_m", 2)),
                        rtol=1e-9, atol=1e-12)
        results.append(np.abs(s.get("q_m", 2) - qm0).max())
        s.close()
    assert results[0] < 1e-9, results
    assert results[1] > 1e-3, results


@pytest.mark.parametrize("params, fragment", [
    ({"ripple_amplitude[1]": -0.1}, "parameter 'ripple_amplitude[1]'"),
    ({"bend_stiffness[2]": -1.0}, "parameter 'bend_stiffness[2]'"),
    ({"bend_mass_fraction[2]": 0.8}, "parameter 'bend_mass_fraction[2]'"),
])
def test_fmu_rejects_bad_parameters_naming_them(fmu: Path, unzipped: str, params: dict, fragment: str) -> None:
    s = Slave(fmu, params, unzip_dir=unzipped, instance_name="plant")
    with pytest.raises(Exception):
        s.fmu.exitInitializationMode()
    assert any(fragment in m for m in s.log), s.log
    s.fmu.freeInstance()


def test_fmu_rejects_a_step_too_coarse_at_the_first_step(fmu: Path, unzipped: str) -> None:
    s = Slave(fmu, unzip_dir=unzipped, instance_name="plant", init=True)
    with pytest.raises(Exception):
        s.fmu.doStep(currentCommunicationPoint=0.0, communicationStepSize=5e-3)
    assert s.log.has("parameter 'substeps'", "Hz"), s.log
    s.fmu.freeInstance()


# ---- the compliant tool (force paper's Optidrive) ---------------------------------------------
COMPLIANT = replace(P, tool_compliance=1e-4)


def test_compliant_tool_conserves_energy() -> None:
    p = replace(CONSERVATIVE, tool_compliance=1e-4, tool_damping=0.0)
    m = plant_dynamics.ExtendedRobotModel(p, (math.pi, -math.pi / 2), substeps=P.substeps)
    x = m.x
    x[4:6] += (0.05, -0.03)
    x[6], x[8] = x[6] + 0.6, x[8] - 0.4
    x[10:12] += R * np.array([0.6, -0.4])
    x[14] += 0.3                          # the tool swings on its mount
    m.x = x
    E0 = m._k.energy(m.state)
    drift = 0.0
    for _ in range(5000):
        m.step((0.0, 0.0), (0.0, 0.0), DT)
        drift = max(drift, abs(m._k.energy(m.state) - E0))
    assert drift / abs(E0) < 1e-6, drift / abs(E0)


def test_compliant_tool_hangs_on_its_mount_and_the_wrist_force_is_the_mount_force() -> None:
    """At rest the tool hangs m_t g c below the flange; in motion, m_t (a_tool - g_vec) - f_ext
    (what the ForceTorqueSensor computes) is the force the mount exerts on the tool, -(k u + d u_dot)."""
    rigid = plant_dynamics.ExtendedRobotModel(P, (0.3, 0.2))
    model = plant_dynamics.ExtendedRobotModel(COMPLIANT, (0.3, 0.2))
    chain = model._k
    s = model.state
    sag = P.tool_mass * P.g * COMPLIANT.tool_compliance
    flange = chain.chain.outputs(s[:chain.size], 0.0, 0.0)
    assert_allclose(np.array(model.outputs(0.0, 0.0)[10:12]) - flange[10:12], [0.0, -sag], atol=1e-15)
    assert_allclose(model.outputs(0.0, 0.0)[14:16], 0.0, atol=1e-9)
    # the tool's weight bends the robot a little more than without the mount
    assert flange[11] < rigid.outputs(0.0, 0.0)[11] - 1e-5
    rng = np.random.default_rng(4)
    x = np.array(s)
    x[chain.size:] += np.r_[rng.uniform(-1e-3, 1e-3, 2), rng.uniform(-0.1, 0.1, 2)]
    x[10:12] += rng.uniform(-50.0, 50.0, 2)
    f = np.array([40.0, -25.0])
    out = chain.outputs(tuple(x), *f)
    fl = chain.chain.outputs(tuple(x[:chain.size]), 0.0, 0.0)
    u, u_dot = x[chain.size:chain.size + 2] - fl[10:12], x[chain.size + 2:] - fl[12:14]
    wrist = P.tool_mass * (np.array(out[14:16]) - [0.0, -P.g]) - f
    assert_allclose(wrist, -(u / COMPLIANT.tool_compliance + COMPLIANT.tool_damping * u_dot), rtol=1e-9)
    assert_allclose(out[10:14], x[chain.size:], rtol=0, atol=0)


def test_compliant_tool_fmu_runs(fmu: Path, unzipped: str) -> None:
    s = Slave(fmu, {"tool_compliance": 1e-4, "q_a0[1]": 0.3, "q_a0[2]": 0.2}, unzip_dir=unzipped,
              instance_name="plant", init=True)
    model = plant_dynamics.ExtendedRobotModel(replace(COMPLIANT, q_a0=(0.3, 0.2)), (0.3, 0.2))
    assert_allclose(s.get("p_tool", 2), model.outputs(0.0, 0.0)[10:12], rtol=0, atol=0)
    s.set(f_ext=[30.0, 0.0])
    for _ in range(50):
        s.step(DT)
        model.step((0.0, 0.0), (30.0, 0.0), DT)
    assert_allclose(s.get("a_tool", 2), model.outputs(30.0, 0.0)[14:16], rtol=0, atol=0)
    s.close()

"""The six-axis arm (fmus/common/irb4600.py) against what nobody here wrote: Pinocchio built from
the same parameters through its URDF parser, ROS-Industrial's transcription of the data sheet,
finite differences of the arm's energy, and the planar two-axis arm it must reduce to."""
from __future__ import annotations

import math

import numpy as np
import pytest

from fmus.common import dynamics, irb4600, kinematics, quaternion
from fmus.common.robot_params import RobotParameters

ARM = irb4600.arm()
RNG_SEED = 20261201


def random_configurations(n: int, margin: float = 0.0, seed: int = RNG_SEED) -> np.ndarray:
    """``n`` joint configurations inside the working ranges (shrunk by ``margin`` rad)."""
    rng = np.random.default_rng(seed)
    return rng.uniform(ARM.q_min + margin, ARM.q_max - margin, size=(n, 6))


def same_rotation(qa, qb) -> float:
    """Distance of two unit quaternions as rotations (``q`` and ``-q`` are the same)."""
    return min(np.abs(np.asarray(qa) - qb).max(), np.abs(np.asarray(qa) + qb).max())


# ---- the data sheet, as ROS-Industrial transcribed it ------------------------------------------
# ROS-Industrial abb_experimental, abb_irb4600_support/urdf/irb4600_60_205_macro.xacro, commit
# 20b9cf86ad274e4f98540b9c9efe59f94245d2d1: joint origins (parent frame, all rpy 0), axes,
# limits lower/upper and velocity [rad, rad/s], three decimals. Numbers compared, nothing copied.
ROSI_ORIGINS = [(0, 0, 0.495), (0.175, 0, 0), (0, 0, 0.9), (0, 0, 0.175), (0.960, 0, 0), (0.135, 0, 0)]
ROSI_AXES = [(0, 0, 1), (0, 1, 0), (0, 1, 0), (1, 0, 0), (0, 1, 0), (1, 0, 0)]
ROSI_LIMITS = [(-3.141, 3.141, 3.054), (-1.570, 2.617, 3.054), (-3.141, 1.308, 3.054),
               (-6.981, 6.981, 4.363), (-2.181, 2.094, 4.363), (-6.981, 6.981, 6.283)]


def test_kinematics_and_ranges_match_ros_industrial() -> None:
    """Link offsets exactly; ranges and speeds within ROS-I's three truncated decimals (< 1e-3)."""
    assert np.array_equal(ARM.origins, np.array(ROSI_ORIGINS, float))
    assert np.array_equal(ARM.axes, np.array(ROSI_AXES, float))
    lo, hi, v = np.array(ROSI_LIMITS).T
    for mine, theirs in ((ARM.q_min, lo), (ARM.q_max, hi), (ARM.dq_max, v)):
        assert np.abs(mine - theirs).max() < 1e-3


def test_masses_add_up_to_the_data_sheet() -> None:
    """Base, links and (without the tool) 435 kg; the reference tool within the 60 kg rating."""
    assert ARM.mass.sum() - ARM.tool_mass + irb4600.BASE_MASS == pytest.approx(irb4600.ROBOT_MASS, abs=1e-9)
    assert 0 < ARM.tool_mass <= irb4600.HANDLING_CAPACITY
    for I in ARM.inertia:
        ev = np.linalg.eigvalsh(I)
        assert ev[0] > 0 and ev[2] <= ev[0] + ev[1]


def test_bad_parameters_are_refused_naming_the_cause() -> None:
    with pytest.raises(ValueError, match="tool mass 61 kg"):
        irb4600.arm(tool_mass=61.0)
    with pytest.raises(ValueError, match="l1 = 1"):
        irb4600.arm(RobotParameters(l1=1.0))
    with pytest.raises(ValueError, match="link 3"):
        irb4600.arm(RobotParameters(m2=30.0))


# ---- the planar arm it reduces to ------------------------------------------------------------
def planar_configurations(n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """(six-axis q with axes 4-6 at zero and axis 1 anywhere, planar q) pairs."""
    qs = random_configurations(n, seed=7)
    return [(np.array([q[0], q[1], q[2], 0, 0, 0]), q[1:3]) for q in qs]


def test_planar_kinematics_is_the_six_axis_arm_with_axes_4_to_6_at_zero() -> None:
    """Tool point and tool angle of the planar arm (origin at axis 2, in the plane that axis 1
    turns) equal the six-axis arm's to round-off (1e-15 m on 2 m)."""
    p = RobotParameters()
    for q6, q2 in planar_configurations(20):
        pos, quat = irb4600.tool_pose(q6, ARM)
        c, s = math.cos(q6[0]), math.sin(q6[0])
        x = c * pos[0] + s * pos[1] - ARM.origins[1, 0]
        y = -s * pos[0] + c * pos[1]
        z = pos[2] - ARM.origins[0, 2]
        assert np.abs(np.array([x, z]) - kinematics.tool_position(q2, p)).max() < 1e-14
        assert abs(y) < 1e-14
        planar = quaternion.multiply(quaternion.from_matrix(irb4600.rotation(2, q6[0])),
                                     quaternion.from_angle_y(q2[0] + q2[1]))
        assert same_rotation(quat, planar) < 1e-14


def mass_matrix_from_energy(q) -> np.ndarray:
    """``M_ij`` by polarisation of the kinetic energy, exact for a quadratic form:
    ``M_ii = 2 T(e_i)``, ``M_ij = T(e_i + e_j) - T(e_i) - T(e_j)``."""
    e = np.eye(6)
    t = [irb4600.kinetic_energy(q, e[i], ARM) for i in range(6)]
    M = np.diag(2.0 * np.array(t))
    for i in range(6):
        for j in range(i + 1, 6):
            M[i, j] = M[j, i] = irb4600.kinetic_energy(q, e[i] + e[j], ARM) - t[i] - t[j]
    return M


def gravity_from_energy(q, h: float = 1e-5) -> np.ndarray:
    """``dV/dq`` by central differences."""
    e = np.eye(6)
    return np.array([(irb4600.potential_energy(q + h * e[k], ARM)
                      - irb4600.potential_energy(q - h * e[k], ARM)) / (2 * h) for k in range(6)])


def test_planar_dynamics_is_the_six_axis_arm_with_axes_4_to_6_at_zero() -> None:
    """Mass matrix and gravity torque of axes 2-3, from the six-axis arm's energy, equal the
    planar model's (dynamics.py) wherever axis 1 stands. M by polarisation: round-off of
    ~1e3 J sums, 1e-10 relative; G by central differences (h = 1e-5): truncation h^2 V''' ~
    1e-7 N m and round-off eps V / h ~ 1e-8 N m on ~1e3 N m, so 1e-6 N m."""
    p = RobotParameters()
    for q6, q2 in planar_configurations(5):
        M = mass_matrix_from_energy(q6)
        assert np.abs(M[1:3, 1:3] - dynamics.mass_matrix(q2, p)).max() < 1e-10 * np.abs(M).max()
        assert np.abs(gravity_from_energy(q6)[1:3] - dynamics.gravity_torque(q2, p)).max() < 1e-6


# ---- Jacobian and inverse kinematics (own, no library) -----------------------------------------
def test_jacobian_is_the_derivative_of_the_forward_kinematics() -> None:
    """Central differences (h = 1e-6) of position and orientation: truncation h^2 * 2 m ~ 1e-12,
    round-off eps * 2 m / h ~ 4e-10, so 1e-8."""
    h = 1e-6
    for q in random_configurations(10):
        J = irb4600.jacobian(q, ARM, point=(0.02, -0.03, 0.05))
        for k in range(6):
            dq = np.zeros(6)
            dq[k] = h
            pp, qp = irb4600.tool_pose(q + dq, ARM, point=(0.02, -0.03, 0.05))
            pm, qm = irb4600.tool_pose(q - dq, ARM, point=(0.02, -0.03, 0.05))
            assert np.abs((pp - pm) / (2 * h) - J[:3, k]).max() < 1e-8
            # angular velocity: R_dot R^T = [w]x
            Rd = (irb4600.tool_rotation(q + dq, ARM) - irb4600.tool_rotation(q - dq, ARM)) / (2 * h)
            W = Rd @ irb4600.tool_rotation(q, ARM).T
            assert np.abs(np.array([W[2, 1], W[0, 2], W[1, 0]]) - J[3:, k]).max() < 1e-8


def test_inverse_kinematics_finds_every_configuration_of_a_pose() -> None:
    """Every solution reproduces the pose (1e-12: FK round-off, ~1e-14 measured); the
    configuration the pose came from is among them (axes 4, 6 modulo a turn) and is the one
    nearest itself; generic poses have 8 solutions when axis 1 can reach back, else 4."""
    for q in random_configurations(200):
        pos, quat = irb4600.tool_pose(q, ARM)
        sols = irb4600.ik_solutions(pos, quat, ARM, within_limits=False)
        assert len(sols) in (4, 8)
        for s in sols:
            p2, q2 = irb4600.tool_pose(s, ARM)
            assert np.abs(p2 - pos).max() < 1e-12 and same_rotation(q2, quat) < 1e-12
        d = sols - q
        d[:, [3, 5]] = (d[:, [3, 5]] + np.pi) % (2 * np.pi) - np.pi
        assert np.abs(d).max(axis=1).min() < 1e-8
        assert np.abs(irb4600.inverse_kinematics(pos, quat, q, ARM) - q).max() < 1e-8


def test_the_wrist_singularity_keeps_axis_4_where_it_was() -> None:
    q = np.array([0.3, 0.2, -0.4, 0.7, 0.0, -0.2])
    pos, quat = irb4600.tool_pose(q, ARM)
    sol = irb4600.inverse_kinematics(pos, quat, q, ARM)
    assert np.abs(sol - q).max() < 1e-9
    p2, q2 = irb4600.tool_pose(sol, ARM)
    assert np.abs(p2 - pos).max() < 1e-12


def test_the_arm_stretched_out_is_still_reached() -> None:
    """Forearm and upper arm in line (the edge of the workspace, where the elbow's sine is 1 up
    to round-off): the pose is found again, not refused. The elbow angle comes back only to
    ~sqrt(eps) = 1e-8 rad there, but the position error is second order in it (1.9 m x 1e-16):
    1e-12 m."""
    beta = math.atan2(ARM.origins[3, 2], ARM.origins[4, 0])
    for q2 in (-0.5, 0.0, 0.7):
        q = np.array([0.4, q2, beta - math.pi / 2, 0.3, 0.6, -0.2])
        pos, quat = irb4600.tool_pose(q, ARM)
        sol = irb4600.inverse_kinematics(pos, quat, q, ARM)
        assert np.abs(irb4600.tool_pose(sol, ARM)[0] - pos).max() < 1e-12


def test_unreachable_poses_raise_naming_the_pose() -> None:
    with pytest.raises(ValueError, match=r"tool pose at \(3, 0, 0.5\) m.*out of reach"):
        irb4600.ik_solutions([3.0, 0.0, 0.5], [1.0, 0.0, 0.0, 0.0], ARM)
    # a configuration outside the ranges of axes 2, 3 and 5 whose pose no in-range one reaches
    q = np.array([-4.12, 3.328, 1.861, -5.47, -2.641, 0.983])
    pos, quat = irb4600.tool_pose(q, ARM)
    with pytest.raises(ValueError, match=r"tool pose at \(0\.03.*working ranges? of axes 2, 3, 5$"):
        irb4600.inverse_kinematics(pos, quat, np.zeros(6), ARM)
    with pytest.raises(ValueError, match="quaternion"):
        irb4600.ik_solutions([1.0, 0.0, 1.0], [0.0, 0.0, 0.0, 0.0], ARM)


# ---- Pinocchio, built from the same parameters --------------------------------------------------
@pytest.fixture(scope="module")
def pin():
    return pytest.importorskip("pinocchio", reason="Pinocchio (`pin`, the test extra) is not installed")


@pytest.fixture(scope="module")
def model(pin):
    m = pin.buildModelFromXML(irb4600.urdf(ARM))
    m.gravity.linear[:] = (0.0, 0.0, -ARM.g)
    assert m.nq == 6 and [m.inertias[i].mass for i in range(1, 7)] == list(ARM.mass)
    return m


def test_pinocchio_forward_kinematics_and_jacobian_equal_ours(pin, model) -> None:
    """To round-off: 1e-13 (products of O(1) numbers over 6 joints, ~2e-16 each)."""
    data = model.createData()
    tool = model.getFrameId("tool")
    for q in random_configurations(50):
        pin.forwardKinematics(model, data, q)
        pin.updateFramePlacements(model, data)
        pos, quat = irb4600.tool_pose(q, ARM)
        assert np.abs(data.oMf[tool].translation - pos).max() < 1e-13
        assert same_rotation(quaternion.from_matrix(data.oMf[tool].rotation), quat) < 1e-13
        J = pin.computeFrameJacobian(model, data, q, tool, pin.LOCAL_WORLD_ALIGNED)
        assert np.abs(J - irb4600.jacobian(q, ARM)).max() < 1e-13


def test_inverse_kinematics_round_trip_through_pinocchio(pin, model) -> None:
    """Pinocchio's tool pose at a random in-range configuration, our IK nearest it, Pinocchio's
    pose again: equal to 1e-12 m; and the configuration back to 1e-8 rad (away from the wrist
    singularity, |q5| > 0.05, where the angles' condition number stays below ~1e3)."""
    data = model.createData()
    tool = model.getFrameId("tool")
    for q in random_configurations(100, seed=3):
        if abs(q[4]) < 0.05:
            continue
        pin.framesForwardKinematics(model, data, q)
        M = data.oMf[tool].copy()
        sol = irb4600.inverse_kinematics(M.translation, M.rotation, q, ARM)
        assert np.abs(sol - q).max() < 1e-8
        pin.framesForwardKinematics(model, data, sol)
        assert np.abs(data.oMf[tool].translation - M.translation).max() < 1e-12
        assert np.abs(data.oMf[tool].rotation - M.rotation).max() < 1e-12


def test_pinocchio_mass_matrix_gravity_and_rnea_against_the_energy(pin, model) -> None:
    """Our energy, differentiated, is the second implementation of Pinocchio's CRBA, gravity and
    RNEA (Lagrange: tau = M ddq + M_dot dq - dT/dq + dV/dq). M: polarisation, 1e-10 relative.
    G: central differences, 1e-6 N m (as above). RNEA: M_dot dq and dT/dq by central differences
    (h = 1e-5 rad) of energies ~1e2 J: truncation and round-off ~1e-7 N m, so 1e-6 N m."""
    data = model.createData()
    rng = np.random.default_rng(11)
    h = 1e-5
    for q in random_configurations(4, seed=5):
        M = mass_matrix_from_energy(q)
        assert np.abs(pin.crba(model, data, q) - M).max() < 1e-10 * np.abs(M).max()
        G = gravity_from_energy(q)
        assert np.abs(pin.computeGeneralizedGravity(model, data, q) - G).max() < 1e-6
        dq, ddq = rng.uniform(-1, 1, 6), rng.uniform(-3, 3, 6)
        Mdot_dq = (mass_matrix_from_energy(q + h * dq) - mass_matrix_from_energy(q - h * dq)) / (2 * h) @ dq
        e = np.eye(6)
        dT = np.array([(irb4600.kinetic_energy(q + h * e[k], dq, ARM)
                        - irb4600.kinetic_energy(q - h * e[k], dq, ARM)) / (2 * h) for k in range(6)])
        tau = M @ ddq + Mdot_dq - dT + G
        tau_pin = pin.rnea(model, data, q, dq, ddq).copy()
        assert np.abs(tau_pin - tau).max() < 1e-6
        assert pin.computeKineticEnergy(model, data, q, dq) == pytest.approx(
            irb4600.kinetic_energy(q, dq, ARM), rel=1e-12)
        # the forward dynamics the plant will integrate is RNEA's inverse: round-off of ~1e3 N m
        # torques through M^-1 (condition ~1e4), 1e-9 rad/s^2
        assert np.abs(pin.aba(model, data, q, dq, tau_pin) - ddq).max() < 1e-9


def test_pinocchio_on_the_locked_arm_is_the_planar_model(pin, model) -> None:
    """Axes 1, 4-6 still: Pinocchio's axis-2/3 torque for any motion of axes 2-3 equals the
    planar ``M ddq + C dq + G`` (dynamics.py) to round-off of ~1e3 N m sums (1e-9 N m)."""
    data = model.createData()
    p = RobotParameters()
    rng = np.random.default_rng(2)
    for q6, q2 in planar_configurations(10):
        dq2, ddq2 = rng.uniform(-2, 2, 2), rng.uniform(-5, 5, 2)
        tau = pin.rnea(model, data, q6, np.r_[0, dq2, 0, 0, 0], np.r_[0, ddq2, 0, 0, 0])
        assert np.abs(tau[1:3] - dynamics.inverse_dynamics_rigid(q2, dq2, ddq2, p)).max() < 1e-9

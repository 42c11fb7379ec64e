"""Planar kinematics of the arm: Jacobians, accelerations and the accelerometer model (2012
paper, eqs. 17-19) against finite differences, and the inverse kinematics."""
from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from fmus.common import dynamics, kinematics
from fmus.common.robot_params import RobotParameters

P = RobotParameters()
RNG = np.random.default_rng(20240502)
POSES = [RNG.uniform([-1.5, -1.5], [1.5, 1.5]) for _ in range(5)] + [np.array([0.0, 0.0])]
RATES = [RNG.uniform(-2.0, 2.0, 2) for _ in POSES]


@pytest.mark.parametrize("point", kinematics.POINTS)
@pytest.mark.parametrize("k", range(len(POSES)))
def test_jacobian_matches_finite_differences(point: str, k: int) -> None:
    q, h = POSES[k], 1e-6
    fd = np.column_stack([(kinematics.position(q + h * e, P, point) - kinematics.position(q - h * e, P, point))
                          / (2 * h) for e in np.eye(2)])
    assert_allclose(kinematics.jacobian(q, P, point), fd, atol=1e-8)


@pytest.mark.parametrize("point", kinematics.POINTS)
@pytest.mark.parametrize("k", range(len(POSES)))
def test_jacobian_dot_matches_finite_differences(point: str, k: int) -> None:
    q, dq, h = POSES[k], RATES[k], 1e-6
    fd = (kinematics.jacobian(q + h * dq, P, point) - kinematics.jacobian(q - h * dq, P, point)) / (2 * h)
    assert_allclose(kinematics.jacobian_dot(q, dq, P, point), fd, atol=1e-7)


def _q(t: float) -> np.ndarray:
    """A smooth analytic joint trajectory."""
    return np.array([0.3 + 0.4 * math.sin(2.0 * t), -0.2 + 0.5 * math.cos(3.0 * t) + 0.1 * t * t])


def _dq(t: float) -> np.ndarray:
    return np.array([0.8 * math.cos(2.0 * t), -1.5 * math.sin(3.0 * t) + 0.2 * t])


def _ddq(t: float) -> np.ndarray:
    return np.array([-1.6 * math.sin(2.0 * t), -4.5 * math.cos(3.0 * t) + 0.2])


@pytest.mark.parametrize("point", kinematics.POINTS)
def test_point_acceleration_matches_second_difference_of_position(point: str) -> None:
    h = 1e-4
    for t in (0.0, 0.37, 1.1, 2.5):
        pos = [kinematics.position(_q(t + s * h), P, point) for s in (-1, 0, 1)]
        fd_a = (pos[0] - 2 * pos[1] + pos[2]) / h ** 2
        fd_v = (pos[2] - pos[0]) / (2 * h)
        assert_allclose(kinematics.velocity(_q(t), _dq(t), P, point), fd_v, atol=1e-7)
        assert_allclose(kinematics.point_acceleration(_q(t), _dq(t), _ddq(t), P, point), fd_a, atol=1e-5)


def test_sensor_offset_is_in_the_tool_frame() -> None:
    """At q = 0 the forearm points along +x, so the tool frame is the world frame."""
    assert_allclose(kinematics.sensor_position([0.0, 0.0], P) - kinematics.tool_position([0.0, 0.0], P),
                    P.sensor_offset, atol=1e-15)
    q = np.array([0.4, 0.3])
    d = kinematics.sensor_position(q, P) - kinematics.tool_position(q, P)
    assert_allclose(d, kinematics.rotation(0.7) @ np.asarray(P.sensor_offset), atol=1e-15)


@pytest.mark.parametrize("k", range(len(POSES)))
def test_specific_force_at_rest_is_g_up_in_the_sensor_frame(k: int) -> None:
    q = POSES[k]
    f = kinematics.specific_force(q, [0.0, 0.0], [0.0, 0.0], P)
    # world up (0, g) expressed in the sensor frame: R^T (0, g)
    phi = q[0] + q[1]
    assert_allclose(f, [-P.g * math.sin(phi), P.g * math.cos(phi)], atol=1e-12)
    assert_allclose(np.linalg.norm(f), P.g, rtol=1e-14)
    assert_allclose(kinematics.rotation(phi) @ f, [0.0, P.g], atol=1e-12)


def test_specific_force_matches_the_plants_own_trajectory() -> None:
    """Eqs. 17-19 against second differences of the sensor position of the simulated plant."""
    m = dynamics.FlexibleRobotModel(P, [0.4, 0.2], substeps=1)
    dt = 1e-4                  # second differences are O(dt^2) accurate: 1e-5 relative here
    x0 = m.x
    x0[6] += 30.0              # excite the flexible modes with motor velocities
    x0[7] -= 40.0
    m.x = x0
    tau = np.array([3.0, -2.0])
    zero = np.zeros(2)
    xs = [m.x]
    for _ in range(3000):
        m.step(tau, zero, dt)
        xs.append(m.x)
    ps = np.array([kinematics.sensor_position(x[0:2], P) for x in xs])
    fd = (ps[:-2] - 2 * ps[1:-1] + ps[2:]) / dt ** 2
    a = np.array([kinematics.point_acceleration(x[0:2], x[4:6], dynamics.arm_acceleration(x, zero, P), P, "sensor")
                  for x in xs[1:-1]])
    scale = np.abs(a).max()
    assert scale > 1.0            # the motion is not trivial
    assert_allclose(fd, a, atol=3e-5 * scale)
    # the specific force is R^T (a - g_vec) of that acceleration
    for x, ak in zip(xs[1:-1:500], a[::500]):
        f = kinematics.specific_force(x[0:2], x[4:6], dynamics.arm_acceleration(x, zero, P), P)
        assert_allclose(f, kinematics.rotation(x[0] + x[1]).T @ (ak - np.array([0.0, -P.g])), atol=1e-12)


@pytest.mark.parametrize("target", [(1.2, 0.9), (1.5, 0.2), (0.8, 1.6), (1.9, -0.3), (0.3, 1.2)])
def test_inverse_kinematics_round_trip(target) -> None:
    q = kinematics.inverse_kinematics(target, P)
    assert abs(q[1]) <= math.pi / 2 + 1e-12
    assert_allclose(kinematics.tool_position(q, P), target, atol=1e-12)


@pytest.mark.parametrize("k", range(len(POSES)))
def test_inverse_kinematics_recovers_the_home_branch(k: int) -> None:
    q = np.array([POSES[k][0], np.clip(POSES[k][1], -1.4, 1.4)])
    q_ik = kinematics.inverse_kinematics(kinematics.tool_position(q, P), P)
    # q1 comes from a difference of two atan2, so it is determined modulo 2 pi
    assert_allclose(np.angle(np.exp(1j * (q_ik - q))), [0.0, 0.0], atol=1e-9)


@pytest.mark.parametrize("target", [(5.0, 0.0), (0.0, 2.2), (0.1, 0.1)])
def test_inverse_kinematics_out_of_reach(target) -> None:
    with pytest.raises(ValueError, match="out of reach"):
        kinematics.inverse_kinematics(target, P)


def test_unknown_point_is_named() -> None:
    with pytest.raises(ValueError, match="unknown point 'wrist'"):
        kinematics.position([0.0, 0.0], P, "wrist")


def test_vectorised_kinematics_agree_with_the_scalar_functions() -> None:
    """tool_position_many, jacobian_many and inverse_kinematics_many (trajectory tables) are the
    scalar tool_position, jacobian and inverse_kinematics over many poses."""
    p = RobotParameters()
    rng = np.random.default_rng(7)
    q = np.column_stack([rng.uniform(-1.0, 1.0, 50), rng.uniform(-1.2, 1.2, 50)])
    P = kinematics.tool_position_many(q, p.l1, p.l2)
    assert_allclose(P, [kinematics.tool_position(qk, p) for qk in q], rtol=0, atol=1e-14)
    assert_allclose(kinematics.jacobian_many(q, p.l1, p.l2), [kinematics.jacobian(qk, p) for qk in q],
                    rtol=0, atol=1e-14)
    q_back, s2 = kinematics.inverse_kinematics_many(P, p.l1, p.l2)
    assert_allclose(q_back, [kinematics.inverse_kinematics(pk, p) for pk in P], rtol=0, atol=1e-12)
    assert_allclose(q_back, q, rtol=0, atol=1e-12)          # |q2| < pi/2: the home branch
    assert np.all(np.abs(s2) <= 1.0)


def test_compiled_tool_point_and_jacobian_are_the_numpy_ones():
    """kinematics.tool_point / tool_jacobian (floats, compiled; the rigid baseline and the
    controller's Cartesian offset) against tool_position / jacobian, random poses, two robots."""
    rng = np.random.default_rng(4)
    for p in (RobotParameters(), RobotParameters(l1=1.1, l2=0.8)):
        for q in rng.uniform(-2.0, 2.0, (200, 2)):
            assert_allclose(kinematics.tool_point(q[0], q[1], p.l1, p.l2), kinematics.tool_position(q, p), rtol=1e-15, atol=0)
            assert_allclose(np.reshape(kinematics.tool_jacobian(q[0], q[1], p.l1, p.l2), (2, 2)), kinematics.jacobian(q, p),
                            rtol=1e-15, atol=1e-16)

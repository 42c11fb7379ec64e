"""Complementary filter (IMU paper, eqs. 1-2): distortionless, its split, the FMU."""
import math
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.signal import lfilter

from fmus.common import quaternion as qt
from fmus.common.frames import G, planar_pose, rot_rpy
from fmus.common.parameters import ParameterError, replace, validate
from fmus.estimators import complementary_filter_model as cfm

G_VEC = np.array([0.0, 0.0, -G])


def exact_motion(t, lever, mount_rpy, axis=(0.2, 1.0, -0.3)):
    """Noise-free tool pose and IMU readings for which the filter's integration is exact.

    The IMU point moves on a cubic (acceleration linear in time), the tool turns about a fixed
    body axis with a rate linear in time; the tool point is derived through the lever arm.
    Returns tool positions (n, 3), tool quaternions (n, 4), acc_s (n, 3), gyro_s (n, 3).
    """
    u = np.asarray(axis, float) / np.linalg.norm(axis)
    r_mount = rot_rpy(mount_rpy)
    q_mount = qt.from_matrix(r_mount)
    q0 = qt.normalise([0.95, 0.05, 0.3, -0.1])
    c0, c1, c2, c3 = (np.array([1.0, 0.1, 0.6]), np.array([0.05, -0.02, 0.1]),
                      np.array([0.3, 0.1, -0.2]), np.array([-0.08, 0.05, 0.04]))
    p_tool, q_tool, acc, gyro = [], [], [], []
    for tk in t:
        phi, dphi = 0.4 * tk - 0.15 * tk * tk, 0.4 - 0.3 * tk
        qt_k = qt.multiply(q0, qt.from_rotation_vector(u * phi))
        qs_k = qt.multiply(qt_k, q_mount)
        ps = c0 + c1 * tk + c2 * tk ** 2 + c3 * tk ** 3
        a_s = 2 * c2 + 6 * c3 * tk
        p_tool.append(ps - qt.rotate(qt_k, lever))
        q_tool.append(qt_k)
        acc.append(qt.rotate_inverse(qs_k, a_s - G_VEC))
        gyro.append(r_mount.T @ (u * dphi))
    return np.array(p_tool), np.array(q_tool), np.array(acc), np.array(gyro)


def run_model(params, p_tool, q_tool, acc, gyro, dt, p0=None, q0=None):
    m = cfm.ComplementaryFilterModel(params)
    m.reset(p_tool[0] if p0 is None else p0, q_tool[0] if q0 is None else q0, acc[0], gyro[0])
    ps, qs = [m.p_tool], [m.q_tool]
    for k in range(1, len(p_tool)):
        m.step(p_tool[k], q_tool[k], acc[k], gyro[k], dt)
        ps.append(m.p_tool)
        qs.append(m.q_tool)
    return np.array(ps), np.array(qs), m


def orientation_error(qa, qb):
    return np.array([np.linalg.norm(qt.to_rotation_vector(qt.multiply(qt.conjugate(a), b)))
                     for a, b in zip(qa, qb)])


@pytest.mark.parametrize("cutoff,damping,t_end", [(28.0, 0.7, 0.6), (2.0, 0.7, 5.0), (5.0, 1.5, 3.0)])
def test_noiseless_inputs_give_the_true_pose(cutoff, damping, t_end):
    """Complementary constraint: with noise-free kinematics and IMU the estimate is the truth
    (to rounding) once the start transient (wrong initial velocity, pose and gyro bias) is over;
    with a lever arm, a mounting rotation and a turning tool."""
    dt = 1e-3
    lever, mount = np.array([-0.15, 0.02, 0.05]), (0.3, -0.2, 1.0)
    t = np.arange(0.0, t_end, dt)
    p_tool, q_tool, acc, gyro = exact_motion(t, lever, mount)
    params = cfm.ComplementaryFilterParameters(cutoff=cutoff, damping=damping, lever_arm=tuple(lever),
                                               mount_rpy=mount)
    # start off the truth: 5 mm, 0.01 rad, and at rest while the truth moves
    p0 = p_tool[0] + [0.005, -0.003, 0.002]
    q0 = qt.multiply(q_tool[0], qt.from_rotation_vector([0.01, 0.0, -0.005]))
    ps, qs, _ = run_model(params, p_tool, q_tool, acc, gyro, dt, p0, q0)
    err = np.linalg.norm(ps - p_tool, axis=1)
    assert err[0] > 1e-3                       # there was a transient
    late = t > t_end - 0.1
    assert_allclose(ps[late], p_tool[late], atol=1e-11, rtol=0)
    assert_allclose(orientation_error(qs[late], q_tool[late]), 0.0, atol=1e-11)


def test_split_is_complementary_and_matches_the_recursion():
    """G + (1 - G) = 1 (eq. 2); G(1) = 1; the time-domain filter is G on the kinematics."""
    dt, fc, zeta = 1e-3, 3.0, 0.7
    f = np.array([0.0, 0.5, 3.0, 30.0, 300.0])
    g, h = cfm.split_response(f, fc, zeta, dt)
    assert_allclose(g + h, 1.0, atol=1e-15)
    assert_allclose(g[0], 1.0, atol=1e-14)
    assert abs(g[-1]) < 0.1 and abs(h[1]) < 0.05
    # kinematics only (IMU at rest, constant orientation): the estimate is G applied to p_fk
    t = np.arange(0.0, 2.0, dt)
    x = 0.01 * np.sin(2 * np.pi * 2.0 * t) * (t > 0.1) + 0.004 * (t > 0.7)
    n = len(t)
    p_tool = np.column_stack([1.0 + x, np.zeros(n), np.full(n, 0.5)])
    q_tool = np.tile(qt.IDENTITY, (n, 1))
    acc = np.tile(-G_VEC, (n, 1))
    gyro = np.zeros((n, 3))
    params = cfm.ComplementaryFilterParameters(cutoff=fc, damping=zeta, lever_arm=(0.0, 0.0, 0.0))
    ps, _, _ = run_model(params, p_tool, q_tool, acc, gyro, dt)
    l1, l2 = cfm.discrete_gains(fc, zeta, dt)
    expected = lfilter([l1, l2 - l1], [1.0, -(2.0 - l1 - l2), 1.0 - l1], x)
    assert_allclose(ps[:, 0] - 1.0, expected, atol=1e-14)


def test_discrete_gains_place_the_poles():
    dt, fc, zeta = 1e-3, 28.0, 0.7
    l1, l2 = cfm.discrete_gains(fc, zeta, dt)
    a = np.array([[1 - l1, (1 - l1) * dt], [-l2 / dt, 1 - l2]])
    wc = 2 * math.pi * fc
    s = np.roots([1, 2 * zeta * wc, wc * wc])
    assert_allclose(np.sort_complex(np.linalg.eigvals(a)), np.sort_complex(np.exp(s * dt)), atol=1e-12)


def test_constant_gyro_bias_is_estimated():
    """The orientation split's integral state converges to a constant gyro bias."""
    dt = 1e-3
    t = np.arange(0.0, 1.0, dt)
    lever, mount = np.zeros(3), (0.0, 0.0, 0.0)
    p_tool, q_tool, acc, gyro = exact_motion(t, lever, mount)
    bias = np.array([0.01, -0.02, 0.005])
    _, qs, m = run_model(cfm.ComplementaryFilterParameters(lever_arm=(0.0, 0.0, 0.0)),
                         p_tool, q_tool, acc, gyro + bias, dt)
    assert_allclose(m.b_gyro, bias, atol=1e-9)


def test_bad_parameters_are_named():
    with pytest.raises(ParameterError, match="'cutoff'"):
        validate(cfm.ComplementaryFilterParameters(cutoff=0.0))
    with pytest.raises(ParameterError, match="'lever_arm'"):
        replace(cfm.ComplementaryFilterParameters(), lever_arm=[0.1, 0.2])


# ---- the FMU -------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def cf_fmu(every_fmu: dict[str, Path]) -> Path:
    return every_fmu["ComplementaryFilter"]


def planar_signals(n, dt, lever_xz=(-0.15, 0.05)):
    """A planar tool motion (x, z, phi) with noise-free IMU readings at a lever arm."""
    from fmus.robot_plant.sensor_model import imu_reading
    t = np.arange(n) * dt
    phi = 0.3 + 0.05 * np.sin(2 * np.pi * 1.3 * t)
    dphi = 0.05 * 2 * np.pi * 1.3 * np.cos(2 * np.pi * 1.3 * t)
    ddphi = -0.05 * (2 * np.pi * 1.3) ** 2 * np.sin(2 * np.pi * 1.3 * t)
    w = 2 * np.pi * 2.0
    p = np.column_stack([1.1 + 0.02 * np.sin(w * t), 0.7 + 0.01 * np.cos(w * t)])
    a = np.column_stack([-0.02 * w * w * np.sin(w * t), -0.01 * w * w * np.cos(w * t)])
    ox, oz = lever_xz
    acc, gyro = [], []
    for k in range(n):
        c, s = math.cos(phi[k]), math.sin(phi[k])
        r = np.array([c * ox + s * oz, -s * ox + c * oz])          # R(phi) o, world x z
        # a_s = a + alpha x r + w x (w x r), rotation about +y maps r to (r_z, -r_x)
        a_s = a[k] + ddphi[k] * np.array([r[1], -r[0]]) - dphi[k] ** 2 * r
        f, g = imu_reading(a_s, phi[k], dphi[k], (0.0, 0.0, 0.0))
        acc.append(f)
        gyro.append(g)
    return t, p, phi, np.array(acc), np.array(gyro)


def test_fmu_matches_the_model_and_tracks_a_planar_motion(cf_fmu):
    from fmu_host import Slave
    dt, n = 1e-3, 1500
    t, p, phi, acc, gyro = planar_signals(n, dt)
    params = cfm.ComplementaryFilterParameters(cutoff=5.0)
    s = Slave(cf_fmu, {"cutoff": 5.0})
    s.set(p_fk=p[0], phi_fk=phi[0], acc_s=acc[0], gyro_s=gyro[0])
    s.init()
    m = cfm.ComplementaryFilterModel(params)
    m.reset(*planar_pose(p[0], phi[0]), acc[0], gyro[0])
    out, ref, phis = [], [], []
    for k in range(1, n):
        s.set(p_fk=p[k], phi_fk=phi[k], acc_s=acc[k], gyro_s=gyro[k])
        s.step(dt)
        m.step(*planar_pose(p[k], phi[k]), acc[k], gyro[k], dt)
        out.append(s.get("p_tool_hat", 2))
        phis.append(s.get("phi_tool_hat"))
        ref.append(m.p_tool[[0, 2]])
    out, ref = np.array(out), np.array(ref)
    assert_allclose(out, ref, atol=1e-15, rtol=0)
    assert_allclose(np.linalg.norm(s.get("q_hat", 4)), 1.0, atol=1e-15)
    # a smooth but not piecewise-linear motion: distortion-free up to the discretisation. The
    # trapezoidal gyro integral errs by T^3/12 |phi'''| = 2.3e-9 rad per step, which the loop
    # (L1 = 0.043 at 5 Hz) leaves as about 5e-8 rad; the position's error is of the same kind.
    late = slice(n // 2, None)
    assert_allclose(out[late], p[1:][late], atol=2e-7, rtol=0)
    assert_allclose(np.array(phis)[late], phi[1:][late], atol=1e-7, rtol=0)


def test_fmu_rejects_a_bad_cutoff(cf_fmu):
    from fmu_host import Slave
    s = Slave(cf_fmu, {"cutoff": -1.0})
    with pytest.raises(Exception):
        s.init()
    assert s.log.has("cutoff")


def test_prediction_holds_the_last_rate_and_acceleration():
    """Analytic case of ComplementaryFilterModel.predict (the output between samples): with the
    last world acceleration a, velocity v and gyro rate w (bias b removed) held, after dt the
    sensor point is at p + v dt + a dt^2 / 2, moves at v + a dt, and has turned by (w - b) dt
    about its own axes."""
    m = cfm.ComplementaryFilterModel(cfm.ComplementaryFilterParameters(lever_arm=(0.0, 0.0, 0.0)))
    m.reset(np.array([1.0, 0.0, 0.5]), qt.from_angle_y(0.2), np.array([0.0, 0.0, G]), np.zeros(3))
    m.v_s, m._a_prev = np.array([0.1, 0.0, -0.2]), np.array([0.5, 0.0, 0.3])
    m._w_prev, m.b_gyro = (0.0, 0.4, 0.0), np.array([0.0, 0.1, 0.0])
    p0, v0, q0 = m.p_s.copy(), m.v_s.copy(), m.q_s.copy()
    dt = 0.02
    m.predict(dt)
    assert_allclose(m.p_s, p0 + v0 * dt + 0.5 * np.array([0.5, 0.0, 0.3]) * dt * dt, rtol=0, atol=1e-15)
    assert_allclose(m.v_s, v0 + np.array([0.5, 0.0, 0.3]) * dt, rtol=0, atol=1e-15)
    assert_allclose(qt.angle_y(m.q_s), 0.2 + 0.3 * dt, rtol=0, atol=1e-14)

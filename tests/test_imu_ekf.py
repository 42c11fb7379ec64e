"""IMU EKF (IMU paper, eqs. 3-4): bias states track bias steps, it converges on noise-free
data, the FMU matches the plain model, divergence is reported."""
import math
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from fmus.common import quaternion as qt
from fmus.common.frames import G, planar_pose
from fmus.common.kalman import FilterDivergence
from fmus.common.parameters import ParameterError, validate
from fmus.estimators import imu_ekf_model as iem

G_VEC = np.array([0.0, 0.0, -G])
B_GYRO = np.array([0.01, -0.02, 0.005])
B_ACC = np.array([0.05, -0.03, 0.04])


def circle_motion(n, dt, lever, t_bias=math.inf):
    """The IMU point on a 50 mm circle at 0.7 Hz while the tool rocks about y; noise-free IMU
    readings with bias steps (B_ACC, B_GYRO) from ``t_bias`` on. Yields
    (t, p_tool, q_tool, acc_s, gyro_s, (v_sensor, a_sensor))."""
    w = 2 * np.pi * 0.7
    centre = np.array([1.0, 0.0, 0.8])
    for k in range(n):
        t = k * dt
        phi = 0.3 + 0.2 * math.sin(2 * np.pi * 0.5 * t)
        dphi = 0.2 * 2 * np.pi * 0.5 * math.cos(2 * np.pi * 0.5 * t)
        q = qt.from_angle_y(phi)
        ps = centre + 0.05 * np.array([math.cos(w * t), 0.0, math.sin(w * t)])
        vs = 0.05 * w * np.array([-math.sin(w * t), 0.0, math.cos(w * t)])
        acc = qt.rotate_inverse(q, -w * w * (ps - centre) - G_VEC)
        gyro = np.array([0.0, dphi, 0.0])
        if t >= t_bias:
            acc, gyro = acc + B_ACC, gyro + B_GYRO
        yield t, ps - qt.rotate(q, lever), q, acc, gyro, (vs, -w * w * (ps - centre))


def run_model(params, n, dt, t_bias=math.inf):
    m = iem.ImuEkfModel(params)
    rows = []
    for k, (t, p, q, acc, gyro, (vs, a_s)) in enumerate(
            circle_motion(n, dt, np.array(params.lever_arm), t_bias)):
        if k == 0:
            m.reset(p, q, acc, gyro)
            m.v, m.a = vs.copy(), a_s.copy()      # start on the motion: no start transient
            continue
        m.step(p, q, acc, gyro, dt)
        rows.append((t, *m.b_acc, *m.b_gyro, np.linalg.norm(m.p_tool - p),
                     np.linalg.norm(qt.to_rotation_vector(qt.multiply(qt.conjugate(m.q_tool), q)))))
    return np.array(rows)


def test_bias_steps_are_tracked_by_the_bias_states():
    """Accelerometer and gyro bias steps at t = 2 s: the bias states follow them."""
    out = run_model(iem.ImuEkfParameters(), 9000, 1e-3, t_bias=2.0)
    t = out[:, 0]
    before = t < 2.0          # the circle's jerk, which the model calls noise, leaks a little
    assert_allclose(out[before, 1:4], 0.0, atol=2e-3)       # into the biases: < 5 % of the steps
    assert_allclose(out[before, 4:7], 0.0, atol=2e-4)
    k4, k_end = np.searchsorted(t, 4.5), -1
    assert_allclose(out[k4, 1:4], B_ACC, rtol=0.05)         # accelerometer: within 2.5 s
    assert_allclose(out[k_end, 4:7], B_GYRO, rtol=0.1)      # gyro: within 7 s
    # ... and once they are tracked the position estimate is back on the truth
    assert out[t > 8.0, 7].max() < 2e-5


def test_converges_on_noise_free_data():
    out = run_model(iem.ImuEkfParameters(), 3000, 1e-3)
    late = out[:, 0] > 1.5
    assert out[late, 7].max() < 2e-5          # position, m
    assert out[late, 8].max() < 1e-5          # orientation, rad


def test_divergence_is_reported():
    m = iem.ImuEkfModel(iem.ImuEkfParameters())
    m.reset(np.zeros(3), qt.IDENTITY)
    m.P[0, 0] = np.nan
    with pytest.raises(FilterDivergence, match="^EKF diverged in the time update: non-finite"):
        m.step(np.zeros(3), qt.IDENTITY, -G_VEC, np.zeros(3), 1e-3)
    m.reset(np.zeros(3), qt.IDENTITY)
    with pytest.raises(FilterDivergence, match="^EKF diverged in the measurement update: non-finite innovation"):
        m.step(np.zeros(3), qt.IDENTITY, np.array([0.0, np.inf, 0.0]), np.zeros(3), 1e-3)
    assert np.isfinite(m.P).all()             # the estimate before the failed update is kept


def test_bad_parameters_are_named():
    with pytest.raises(ParameterError, match="'r_position'"):
        validate(iem.ImuEkfParameters(r_position=0.0))


# ---- the FMU -------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def ekf_fmu(every_fmu: dict[str, Path]) -> Path:
    return every_fmu["ImuEkf"]


def test_fmu_matches_the_model(ekf_fmu):
    from fmu_host import Slave
    dt, n = 1e-3, 800
    rng = np.random.default_rng(3)
    params = iem.ImuEkfParameters(sigma_jerk=100.0)
    s = Slave(ekf_fmu, {"sigma_jerk": 100.0})
    m = iem.ImuEkfModel(params)
    out, ref = [], []
    for k, (t, p, q, acc, gyro, _) in enumerate(circle_motion(n, dt, np.array(params.lever_arm))):
        p_xz = np.array([p[0], p[2]]) + 1e-4 * rng.standard_normal(2)
        phi = qt.angle_y(q) + 1e-4 * rng.standard_normal()
        acc = acc + 0.02 * rng.standard_normal(3)
        gyro = gyro + 0.005 * rng.standard_normal(3)
        s.set(p_fk=p_xz, phi_fk=phi, acc_s=acc, gyro_s=gyro)
        if k == 0:
            s.init()
            m.reset(*planar_pose(p_xz, phi), acc, gyro)
            continue
        s.step(dt)
        m.step(*planar_pose(p_xz, phi), acc, gyro, dt)
        out.append(np.r_[s.get("p_tool_hat", 2), s.get("b_acc_hat", 3), s.get("phi_tool_hat")])
        ref.append(np.r_[m.p_tool[[0, 2]], m.b_acc, qt.angle_y(m.q_tool)])
    assert_allclose(np.array(out), np.array(ref), atol=1e-14, rtol=0)
    assert_allclose(np.linalg.norm(s.get("q_hat", 4)), 1.0, atol=1e-15)
    assert s.get("std_position") > 0.0

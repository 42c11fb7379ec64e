"""Sample-time fusion: sensors stamp their samples (``t_meas``), estimators fuse each measurement
at its stamp, so an estimate does not depend on when the master hands the measurement over.

The FMU classes are driven in this process through their FMI methods (``set_real``,
``do_step``, ``get_real``): the logic under test is the adapters'; the built FMUs run in
``test_fmi_libcosim.py`` and the sensor and estimator FMU suites.
"""
from __future__ import annotations

import copy
import math

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from fmus.common.frames import G
from fmus.estimators import axelsson2012_model as am

from fmus.estimators import ekf_accelerometer_model as em
from fmus.estimators.ekf_accelerometer_fmu import EkfAccelerometer
from fmus.estimators.rigid_kinematics_fmu import RigidKinematics
from fmus.estimators.rigid_kinematics_model import RigidKinematicsParameters
from fmus.robot_plant.encoder_fmu import Encoder
from fmus.robot_plant.flexible_robot_fmu import FlexibleRobot2DOF
from fmus.robot_plant.imu_fmu import Imu
from fmus.robot_plant.sensor_model import SensorChannels, input_time
from fmus.robot_plant.tracker_fmu import Tracker
from toys import InProcess

T = 1e-3


# ---- sensors -------------------------------------------------------------------------------
def test_sample_and_hold_stamps_the_time_its_input_stands_for() -> None:
    """Analytic case: a ramp input x(t) = a t sampled at 250 Hz with 1 ms steps. The input set
    before doStep(t, T) is the value at t + T (input_time); a sample is taken at the first step
    and every fourth after, so the held reading is a t_meas with t_meas = T (1 + 4 floor(k / 4))
    after step k, and the start time before the first step."""
    a = np.array([2.0, -3.0])
    ch = SensorChannels(2, sample_rate=250.0)
    assert_array_equal(ch.initial(a * 0.0, 0.0), 0.0)
    assert ch.t_meas == 0.0
    for k in range(12):
        t_in = input_time(k * T, T)
        y = ch.step(a * t_in, T, t_in)
        expected = T * (1 + 4 * (k // 4))
        assert_allclose(ch.t_meas, expected, rtol=1e-12)
        assert_allclose(y, a * ch.t_meas, rtol=1e-12)


@pytest.mark.parametrize("cls, inputs", [(Encoder, {"q_m": (1.0, 2.0)}),
                                         (Imu, {"a_sensor": (0.5, 0.1), "phi_tool": 0.3,
                                                "omega_tool": 0.2})])
def test_sensor_fmus_publish_the_sample_time(cls, inputs) -> None:
    """Encoder and Imu at 500 Hz with 1 ms steps: t_meas is the start time after
    initialisation, then the time the sampled input stands for, held between samples."""
    s = InProcess(cls, sample_rate=500.0)
    s.set(**inputs)
    s.init()
    assert s.get("t_meas") == 0.0
    stamps = []
    for _ in range(6):
        s.step()
        stamps.append(s.get("t_meas"))
    assert_allclose(stamps, [0.001, 0.001, 0.003, 0.003, 0.005, 0.005], rtol=1e-12)


def test_plant_stamps_its_outputs() -> None:
    """The plant's t_state: its start time in Initialization Mode, t + dt after doStep(t, dt)
    (the time its outputs stand for, whatever the host)."""
    plant = InProcess(FlexibleRobot2DOF, start=0.25)
    assert plant.get("t_state") == 0.25
    plant.init()
    for k in range(3):
        plant.step()
        assert plant.get("t_state") == input_time(0.25 + k * T, T)


@pytest.mark.parametrize("cls, inputs", [(Encoder, {}),
                                         (Imu, {"a_sensor": (0.5, 0.1), "phi_tool": 0.3,
                                                "omega_tool": 0.2})])
def test_sensor_stamps_its_sample_with_the_producers_time(cls, inputs) -> None:
    """Analytic case, a Jacobi host starting at 0.2 s: before doStep(t, T) the sensor gets the
    plant's outputs of t and the plant's stamp t_truth = t. Sampled at 500 Hz, t_meas is that
    stamp at a sample, held in between (unconnected it would say t + T); the Encoder's reading
    of the ramp q_m = a t (no noise, no quantisation) is a t_meas."""
    a = np.array([2.0, -3.0])
    params = {"noise": 0.0, "resolution": 0.0} if cls is Encoder else {}
    s = InProcess(cls, start=0.2, sample_rate=500.0, **params)
    s.set(t_truth=0.2, q_m=a * 0.2) if cls is Encoder else s.set(t_truth=0.2, **inputs)
    s.init()
    stamps = [s.get("t_meas")]
    for _ in range(6):
        s.set(t_truth=s.t, **({"q_m": a * s.t} if cls is Encoder else {}))
        s.step()
        stamps.append(s.get("t_meas"))
        if cls is Encoder:
            assert_allclose(s.get("q_m_meas", 2), a * s.get("t_meas"), rtol=1e-12)
    assert_allclose(stamps, [0.2, 0.2, 0.2, 0.202, 0.202, 0.204, 0.204], rtol=1e-12)


def test_tracker_measures_at_the_producers_time() -> None:
    """Analytic case, a Jacobi host: the tool on a ramp p(t) = p0 + v t, handed over one step
    late (the value of t before doStep(t, T)) with its stamp t_truth = t. The tracker (no noise,
    1 kHz, clock 1 ms behind) measures exactly p(t_meas - skew), linear interpolation being exact
    on a ramp; unconnected, it takes the late position as of t + T: off by v T."""
    p0, v = np.array([1.0, 0.6]), np.array([0.2, -0.1])
    runs = {}
    for stamped in (True, False):
        s = InProcess(Tracker, noise=0.0, p_tool=tuple(p0))
        if stamped:
            s.set(t_truth=0.0)
        s.init()
        for _ in range(8):
            s.set(p_tool=p0 + v * s.t, **({"t_truth": s.t} if stamped else {}))
            s.step()
        runs[stamped] = (s.get("t_meas"), s.get("p_tool_meas", 2))
    t_meas, p_meas = runs[True]
    assert_allclose(t_meas, 7 * T, rtol=1e-12)          # the newest sample instant by t_truth
    assert_allclose(p_meas, p0 + v * (t_meas - 1e-3), rtol=1e-12)
    t_meas, p_meas = runs[False]
    assert_allclose(p_meas - (p0 + v * (t_meas - 1e-3)), -v * T, rtol=1e-9)


@pytest.mark.parametrize("cls, inputs", [
    (Encoder, lambda t: {"q_m": (1.0 + 2.0 * t, -3.0 * t)}),
    (Imu, lambda t: {"a_sensor": (0.5 + t, 0.1), "phi_tool": 0.3 * t, "omega_tool": 0.3}),
    (Tracker, lambda t: {"p_tool": (1.0 + 0.2 * t, 0.6 - 0.1 * t)})])
def test_sensor_with_the_plants_stamp_is_bit_identical_under_our_master(cls, inputs) -> None:
    """Our Gauss-Seidel master steps the plant before the sensor: the plant's t_state is then
    t + T, what the unconnected input assumes. Wired to a plant's t_state, a sensor (default
    noise) gives every output bit for bit as unconnected: the scenarios' results do not change."""
    plant = InProcess(FlexibleRobot2DOF)
    plant.init()
    wired, alone = InProcess(cls), InProcess(cls)
    for s in (wired, alone):
        s.set(**inputs(0.0))
    wired.set(t_truth=plant.get("t_state"))
    names = [n for n in wired.vr if wired.s.vars[wired.vr[n]].causality.name == "output"]
    for s in (wired, alone):
        s.init()
    for _ in range(12):
        plant.step()
        for s in (wired, alone):
            s.set(**inputs(plant.t))
        wired.set(t_truth=plant.get("t_state"))
        wired.step()
        alone.step()
        assert_array_equal([wired.get(n) for n in names], [alone.get(n) for n in names])


# ---- estimators ----------------------------------------------------------------------------
def _measurements(n: int, p: am.EkfAccelerometerParameters, seed: int = 3):
    """Motor angles and accelerometer readings (eq. 15 plus noise) of a smooth motion at the
    sample times k T, k = 0..n (jerk reference zero: the test isolates the measurement timing)."""
    rng = np.random.default_rng(seed)
    model = am.MeasurementModel(p.robot(), am.Layout(True, False))
    t = np.arange(n + 1) * T
    q0 = np.array(p.initial_angles())
    w = 2 * math.pi * 1.5
    amp = np.array([0.05, -0.03])
    q = q0 + amp * np.sin(w * t)[:, None]
    dq = amp * w * np.cos(w * t)[:, None]
    ddq = -amp * w * w * np.sin(w * t)[:, None]
    y = np.array([model.h(np.concatenate([q[k], dq[k], ddq[k]])) for k in range(n + 1)])
    y += rng.normal(0.0, [3e-5, 3e-5, 2e-2, 2e-2], y.shape)
    return y


def _ekf(p: am.EkfAccelerometerParameters, y0, t0: float | None) -> InProcess:
    s = InProcess(EkfAccelerometer, q_a0=tuple(p.q_a0))
    s.set(q_m_meas=y0[0:2], acc_s=(y0[2], 0.0, y0[3]))
    if t0 is not None:
        s.set(t_meas=t0)
    s.init()
    return s


def test_ekf_fuses_a_late_measurement_at_its_stamp() -> None:
    """The same measurements, on time (set before doStep(t, T) with stamp t + T: our
    Gauss-Seidel master) and one step late with their stamps (a Jacobi master): the late run's
    estimate at t + T is the on-time run's estimate at t predicted by T. Without the stamp the
    late measurement would be fused as if taken at t + T (about 0.2 mrad off here)."""
    p = am.EkfAccelerometerParameters(q_a0=(0.3, -0.2))
    n = 60
    y = _measurements(n, p)
    on_time, late = _ekf(p, y[0], 0.0), _ekf(p, y[0], 0.0)
    ekf = em.EkfAccelerometerModel(p)           # the plain model, fused on time
    posterior = [ekf.update(y[0]).copy()]
    late_estimates = []
    for k in range(n):
        yk = y[k + 1]
        on_time.set(q_m_meas=yk[0:2], acc_s=(yk[2], 0.0, yk[3]), t_meas=(k + 1) * T)
        on_time.step()
        ekf.predict((0.0, 0.0), T)
        posterior.append(ekf.update(yk).copy())
        assert_allclose(on_time.get("q_a_hat", 2), posterior[-1][0:2], rtol=1e-12, atol=1e-15)
        yl = y[k]                                 # one step late, with its own stamp
        late.set(q_m_meas=yl[0:2], acc_s=(yl[2], 0.0, yl[3]), t_meas=k * T)
        late.step()
        late_estimates.append(np.concatenate([late.get("q_a_hat", 2), late.get("dq_a_hat", 2)]))
    F, _, _ = am.transition_matrices(T, ekf.layout)
    for k in range(1, n):
        expected = F @ posterior[k]              # the estimate at t_k predicted to t_{k+1}
        assert_allclose(late_estimates[k], expected[0:4], rtol=1e-9, atol=1e-12)
    # and the late run without stamps is measurably worse: it fuses y_k as at t_{k+1}
    unstamped = _ekf(p, y[0], None)
    for k in range(n):
        unstamped.set(q_m_meas=y[k][0:2], acc_s=(y[k][2], 0.0, y[k][3]))
        unstamped.step()
    assert np.abs(unstamped.get("q_a_hat", 2) - late_estimates[-1][0:2]).max() > 1e-5


@pytest.mark.parametrize("ratio", [1, 10])
def test_ekf_stamped_on_time_is_bit_identical_to_unstamped(ratio: int) -> None:
    """Under our master the sensors stamp t + T, which the unconnected input assumes: the
    results must not change by a bit when the stamp is wired, also for a filter at 100 Hz fed
    by a 1 kHz sensor (whose stamp, t_k + 1 ms, differs from the filter's t + 10 ms in the last
    bits)."""
    p = am.EkfAccelerometerParameters(q_a0=(0.3, -0.2))
    y = _measurements(30, p)
    a, b = _ekf(p, y[0], 0.0), _ekf(p, y[0], None)
    for k in range(30):
        yk = y[k + 1]
        for s in (a, b):
            s.set(q_m_meas=yk[0:2], acc_s=(yk[2], 0.0, yk[3]), dddq_a_ref=(0.3 * k, -0.1 * k))
        a.set(t_meas=input_time(((k + 1) * ratio - 1) * T, T))    # the sensor's last step
        a.step(ratio * T)
        b.step(ratio * T)
        for name in ("q_a_hat", "dq_a_hat", "ddq_a_hat", "p_tool_hat"):
            assert_array_equal(a.get(name, 2), b.get(name, 2))
        assert a.get("trace_P_q") == b.get("trace_P_q")


def test_ekf_does_not_fuse_a_held_sample_twice() -> None:
    """A sensor at 500 Hz, the filter at 1 kHz: the held sample (same stamp) is not fused
    again; between samples the output is the prediction from the last one."""
    p = am.EkfAccelerometerParameters(q_a0=(0.3, -0.2))
    y = _measurements(20, p)
    s = _ekf(p, y[0], 0.0)
    ekf = em.EkfAccelerometerModel(p)
    ekf.update(y[0])
    for k in range(20):
        j = k - k % 2 + 1                         # sample instants 1, 3, 5 ... ms
        s.set(q_m_meas=y[j][0:2], acc_s=(y[j][2], 0.0, y[j][3]), t_meas=j * T)
        s.step()
        ekf.predict((0.0, 0.0), T)
        if k % 2 == 0:
            xf = ekf.update(y[j])
            assert_allclose(s.get("q_a_hat", 2), xf[0:2], rtol=1e-12, atol=1e-15)
        else:
            assert_allclose(s.get("q_a_hat", 2), ekf.x[0:2], rtol=1e-12, atol=1e-15)


def test_rigid_kinematics_extrapolates_a_late_sample_to_the_output_time() -> None:
    """RigidKinematics with stamps: on time (stamp = output time) the plain forward kinematics;
    one step late, the arm angles extrapolated with the velocity of the last two samples: exact
    for a motion at constant velocity."""
    r = np.asarray(RigidKinematicsParameters().robot().gear_ratio, float)
    q_a = lambda t: np.array([0.3 + 0.2 * t, -0.2 - 0.1 * t])    # noqa: E731
    on_time, late = InProcess(RigidKinematics), InProcess(RigidKinematics)
    for s in (on_time, late):
        s.set(q_m_meas=tuple(r * q_a(0.0)), t_meas=0.0)
        s.init()
    for k in range(5):
        on_time.set(q_m_meas=tuple(r * q_a((k + 1) * T)), t_meas=(k + 1) * T)
        late.set(q_m_meas=tuple(r * q_a(k * T)), t_meas=k * T)
        on_time.step()
        late.step()
        assert_allclose(on_time.get("q_a_hat", 2), q_a((k + 1) * T), rtol=1e-13)
        if k >= 1:       # two samples give the velocity
            assert_allclose(late.get("q_a_hat", 2), q_a((k + 1) * T), rtol=1e-12)
            assert_allclose(late.get("p_tool_hat", 2), on_time.get("p_tool_hat", 2), rtol=1e-12)


def test_2009_ekf_fuses_a_late_measurement_at_its_stamp() -> None:
    """EkfMotor (Henriksson et al. 2009; the base shared with EkfComplete and EkfIntegrated):
    one step late with its stamp, the estimate at t + T is the on-time filter's estimate at t
    predicted by T with the torque set with that measurement (the plain model's steps)."""
    from fmus.estimators import ekf_flexible_model as fm
    from fmus.estimators.ekf_motor_fmu import EkfMotor
    p = fm.EkfMotorParameters()
    ekf = fm.EkfFlexibleModel(p, "motor")
    n = 30
    t = np.arange(n + 1) * T
    q_m = ekf.x[2:4] + np.array([0.02, -0.01]) * np.sin(2 * math.pi * 3 * t)[:, None]
    tau = np.array([1.0, -0.5]) * np.cos(2 * math.pi * 2 * t)[:, None]
    runs = []
    for _ in range(2):
        s = InProcess(EkfMotor)
        s.set(q_m_meas=q_m[0], tau_m=tau[0], t_meas=0.0)
        s.init()
        runs.append(s)
    on_time, late = runs
    ekf.update(q_m[0], None, tau[0])
    for k in range(n):
        on_time.set(q_m_meas=q_m[k + 1], tau_m=tau[k + 1], t_meas=(k + 1) * T)
        late.set(q_m_meas=q_m[k], tau_m=tau[k], t_meas=k * T)
        on_time.step()
        late.step()
        if k >= 1:
            expected = copy.copy(ekf).predict(T)      # the estimate at t_k, predicted to t_{k+1}
            assert_allclose(late.get("q_a_hat", 2), expected[0:2], rtol=1e-10, atol=1e-13)
            assert_allclose(late.get("q_m_hat", 2), expected[2:4], rtol=1e-10, atol=1e-13)
        ekf.predict(T)
        ekf.update(q_m[k + 1], None, tau[k + 1])
        assert_allclose(on_time.get("q_a_hat", 2), ekf.x[0:2], rtol=1e-12, atol=1e-15)


# ---- the other estimators: the same property through the one adapter base ------------------
def _imu_pose_signals(t: float) -> dict:
    """A smooth tool motion as forward kinematics and IMU readings (consistency does not matter:
    the test compares the filter with itself, fed on time and late)."""
    w = 2 * math.pi * 1.5
    return {"p_fk": (1.2 + 0.05 * math.sin(w * t), 0.8 + 0.03 * math.cos(w * t)),
            "phi_fk": 0.1 * math.sin(w * t),
            "acc_s": (0.4 * math.sin(w * t), 0.01, G + 0.2 * math.cos(w * t)),
            "gyro_s": (0.002, 0.1 * w * math.cos(w * t), -0.001)}


def _imu_model_args(sig: dict) -> tuple:
    from fmus.common.frames import planar_pose
    return (*planar_pose(sig["p_fk"], sig["phi_fk"]), np.array(sig["acc_s"]), np.array(sig["gyro_s"]))


def _observer_signals(t: float) -> dict:
    """Motor angles about the observer's start pose, the torque that holds it and a tool
    accelerometer at rest, with small oscillations."""
    from fmus.common import dynamics
    from fmus.estimators import acceleration_observer_model as om
    p = om.AccelerationObserverParameters()
    robot = om.model_robot(p)
    x0 = dynamics.static_equilibrium(p.initial_angles(), robot)
    r = np.asarray(robot.gear_ratio, float)
    s = math.sin(2 * math.pi * 2.0 * t)
    return {"q_m_meas": tuple(x0[2:4] + r * np.array([0.01, -0.005]) * s),
            "tau_m": tuple(dynamics.gravity_torque(x0[0:2], robot) / r * (1.0 + 0.1 * s)),
            "acc_s": (0.3 * s, 0.0, G - 0.2 * s)}


def _plain_cf(sig0: dict):
    from fmus.estimators import complementary_filter_model as cfm
    m = cfm.ComplementaryFilterModel(cfm.ComplementaryFilterParameters())
    args = _imu_model_args(sig0)
    m.reset(args[0], args[1], args[2], args[3])
    return m


def _plain_imu_ekf(sig0: dict):
    from fmus.estimators import imu_ekf_model as iem
    m = iem.ImuEkfModel(iem.ImuEkfParameters())
    args = _imu_model_args(sig0)
    m.reset(args[0], args[1], args[2], args[3])
    return m


def _plain_observer(sig0: dict):
    from fmus.estimators import acceleration_observer_model as om
    return om.AccelerationObserverModel(om.AccelerationObserverParameters())


def _cf_outputs(m) -> np.ndarray:
    return np.concatenate(m.mount.tool_pose(m.p_s, m.q_s))


def _imu_ekf_outputs(m) -> np.ndarray:
    return np.concatenate(m.mount.tool_pose(m.p, m.q))


def _observer_outputs(m) -> np.ndarray:
    return np.concatenate([m.q_a, m.dq_a])


def _cf_step(m, sig: dict) -> None:
    m.step(*_imu_model_args(sig), T)


def _observer_step(m, sig: dict) -> None:
    m.step(np.array(sig["q_m_meas"]), np.array(sig["acc_s"]), np.array(sig["tau_m"]), T)


def _fmu_outputs(s: InProcess, kind: str) -> np.ndarray:
    if kind == "observer":
        return np.concatenate([s.get("q_a_hat", 2), s.get("dq_a_hat", 2)])
    return np.concatenate([s.get("p_hat", 3), s.get("q_hat", 4)])


def _estimator_cases():
    from fmus.estimators.acceleration_observer_fmu import AccelerationObserver
    from fmus.estimators.complementary_filter_fmu import ComplementaryFilter
    from fmus.estimators.imu_ekf_fmu import ImuEkf
    return [
        pytest.param(ComplementaryFilter, _imu_pose_signals, _plain_cf, _cf_step, _cf_outputs, "pose",
                     id="ComplementaryFilter"),
        pytest.param(ImuEkf, _imu_pose_signals, _plain_imu_ekf, _cf_step, _imu_ekf_outputs, "pose",
                     id="ImuEkf"),
        pytest.param(AccelerationObserver, _observer_signals, _plain_observer, _observer_step,
                     _observer_outputs, "observer", id="AccelerationObserver"),
    ]


@pytest.mark.parametrize("cls, signals, plain, plain_step, plain_outputs, kind", _estimator_cases())
def test_filters_without_feedthrough_fuse_a_late_measurement_at_its_stamp(
        cls, signals, plain, plain_step, plain_outputs, kind) -> None:
    """ComplementaryFilter, ImuEkf, AccelerationObserver (no direct feedthrough): on time
    (inputs of t + T with their stamp before doStep(t, T)) the FMU is the plain model stepped
    sample by sample; one step late with their stamps (a Jacobi master), its output at t + T is
    the plain model's estimate at t predicted by T (the model's own prediction, last inputs
    held). Without stamps the late run fuses each sample a step too late and differs."""
    n = 25
    sig = [signals(k * T) for k in range(n + 1)]
    on_time, late, unstamped = InProcess(cls), InProcess(cls), InProcess(cls)
    for s in (on_time, late, unstamped):
        s.set(**sig[0])
    for s in (on_time, late):
        s.set(t_meas=0.0)
    for s in (on_time, late, unstamped):
        s.init()
    model = plain(sig[0])
    for k in range(n):
        on_time.set(**sig[k + 1], t_meas=(k + 1) * T)
        late.set(**sig[k], t_meas=k * T)
        unstamped.set(**sig[k])
        for s in (on_time, late, unstamped):
            s.step()
        expected_late = copy.copy(model)        # the estimate at t_k predicted to t_{k+1}
        expected_late.predict(T)
        assert_allclose(_fmu_outputs(late, kind), plain_outputs(expected_late), rtol=1e-12, atol=1e-14)
        plain_step(model, sig[k + 1])
        assert_allclose(_fmu_outputs(on_time, kind), plain_outputs(model), rtol=1e-12, atol=1e-15)
    assert np.abs(_fmu_outputs(unstamped, kind) - _fmu_outputs(late, kind)).max() > 1e-7


def test_particle_filter_fuses_a_late_measurement_at_its_stamp() -> None:
    """ParticleFilter (direct feedthrough, as the EKF): one step late with their stamps, the
    estimate at t + T is the plain filter's estimate at t predicted by T, with the same random
    draws (the generator state belongs to the estimate); the on-time run is the plain filter."""
    from fmus.estimators import particle_filter_model as pm
    from fmus.estimators.particle_filter_fmu import ParticleFilter
    p = pm.ParticleFilterParameters(q_a0=(0.3, -0.2), n_particles=200)
    n = 20
    y = _measurements(n, p)
    runs = []
    for _ in range(3):
        s = InProcess(ParticleFilter, q_a0=p.q_a0, n_particles=p.n_particles)
        s.set(q_m_meas=y[0][0:2], acc_s=(y[0][2], 0.0, y[0][3]))
        runs.append(s)
    on_time, late, unstamped = runs
    for s in (on_time, late):
        s.set(t_meas=0.0)
    for s in runs:
        s.init()
    pf = pm.ParticleFilterModel(p)
    pf.update(y[0])
    for k in range(n):
        on_time.set(q_m_meas=y[k + 1][0:2], acc_s=(y[k + 1][2], 0.0, y[k + 1][3]), t_meas=(k + 1) * T)
        late.set(q_m_meas=y[k][0:2], acc_s=(y[k][2], 0.0, y[k][3]), t_meas=k * T)
        unstamped.set(q_m_meas=y[k][0:2], acc_s=(y[k][2], 0.0, y[k][3]))
        for s in runs:
            s.step()
        expected_late = copy.copy(pf).predict((0.0, 0.0), T)
        assert_allclose(late.get("q_a_hat", 2), expected_late[0:2], rtol=1e-12, atol=1e-15)
        assert_allclose(late.get("dq_a_hat", 2), expected_late[2:4], rtol=1e-12, atol=1e-12)
        pf.predict((0.0, 0.0), T)
        x = pf.update(y[k + 1])
        assert_allclose(on_time.get("q_a_hat", 2), x[0:2], rtol=1e-12, atol=1e-15)
    assert np.abs(unstamped.get("q_a_hat", 2) - late.get("q_a_hat", 2)).max() > 1e-6


def test_particle_filter_predicts_over_periods_without_a_new_sample() -> None:
    """A sensor at 500 Hz, the particle filter at 1 kHz: the held sample is not fused again, and
    the next update's prior is two periods ahead: its means are F^2 x + ..., and its noise factor
    L has L L^T = F Gw Q Gw^T F^T + Gw Q Gw^T (eq. 14 twice)."""
    from fmus.estimators import ekf_accelerometer_model as em
    from fmus.estimators import particle_filter_model as pm
    p = pm.ParticleFilterParameters(q_a0=(0.3, -0.2), n_particles=100)
    pf = pm.ParticleFilterModel(p)
    pf.update(_measurements(1, p)[0])
    x0 = pf.x.copy()
    pf.predict((0.0, 0.0), T)
    x2 = pf.predict((0.0, 0.0), T)
    F, _, Gw = am.transition_matrices(T, pf.layout)
    assert_allclose(x2, F @ F @ x0, rtol=1e-13, atol=1e-15)
    GQG = Gw @ pf.Q @ Gw.T
    assert_allclose(pf.L @ pf.L.T, F @ GQG @ F.T + GQG, rtol=1e-10, atol=1e-18)


@pytest.mark.parametrize("cls, signals, plain, plain_step, plain_outputs, kind", _estimator_cases())
def test_filters_without_feedthrough_stamped_on_time_are_bit_identical(
        cls, signals, plain, plain_step, plain_outputs, kind) -> None:
    """Under our master a sensor stamps t + T (input_time), which the unconnected input assumes:
    ComplementaryFilter, ImuEkf and AccelerationObserver give every output bit for bit the same
    with the stamp wired as without (the shipped scenarios do not change)."""
    a, b = InProcess(cls), InProcess(cls)
    for s in (a, b):
        s.set(**signals(0.0))
    a.set(t_meas=0.0)
    names = [n for n in a.vr if a.s.vars[a.vr[n]].causality.name == "output"]
    for s in (a, b):
        s.init()
    for k in range(20):
        for s in (a, b):
            s.set(**signals((k + 1) * T))
        a.set(t_meas=input_time(k * T, T))
        a.step()
        b.step()
        assert_array_equal([a.get(n) for n in names], [b.get(n) for n in names])


def test_particle_filter_stamped_on_time_is_bit_identical_to_unstamped() -> None:
    """As for the EKF: the ParticleFilter with the sensors' on-time stamps wired gives the same
    bits as unstamped (same updates, same random draws)."""
    from fmus.estimators import particle_filter_model as pm
    from fmus.estimators.particle_filter_fmu import ParticleFilter
    p = pm.ParticleFilterParameters(q_a0=(0.3, -0.2), n_particles=100)
    y = _measurements(15, p)
    a, b = (InProcess(ParticleFilter, q_a0=p.q_a0, n_particles=p.n_particles) for _ in range(2))
    for s in (a, b):
        s.set(q_m_meas=y[0][0:2], acc_s=(y[0][2], 0.0, y[0][3]))
    a.set(t_meas=0.0)
    for s in (a, b):
        s.init()
    for k in range(15):
        for s in (a, b):
            s.set(q_m_meas=y[k + 1][0:2], acc_s=(y[k + 1][2], 0.0, y[k + 1][3]), dddq_a_ref=(0.3 * k, -0.1 * k))
        a.set(t_meas=input_time(k * T, T))
        a.step()
        b.step()
        for name in ("q_a_hat", "dq_a_hat", "ddq_a_hat", "p_tool_hat"):
            assert_array_equal(a.get(name, 2), b.get(name, 2))
        assert a.get("trace_P_q") == b.get("trace_P_q") and a.get("ess") == b.get("ess")

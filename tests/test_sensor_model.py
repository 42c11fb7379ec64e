"""Sensor imperfections, ideal sensor readings and contact forces (plain math, no FMI)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from fmus.common.frames import G
from fmus.common.noise import make_rng
from fmus.robot_plant import sensor_model as sm



# ---- noise helpers -------------------------------------------------------------------------
def test_make_rng_is_deterministic_and_streams_differ():
    a = make_rng(7, "imu/acc").standard_normal(5)
    assert_array_equal(a, make_rng(7, "imu/acc").standard_normal(5))
    assert not np.allclose(a, make_rng(7, "imu/gyro").standard_normal(5))
    assert not np.allclose(a, make_rng(8, "imu/acc").standard_normal(5))
    with pytest.raises(ValueError, match="seed"):
        make_rng(-1)


# ---- SensorChannels ------------------------------------------------------------------------
def run(ch: sm.SensorChannels, x: np.ndarray, dt: float) -> np.ndarray:
    """Step ``ch`` through the rows of ``x``; the readings as rows."""
    return np.array([ch.step(xi, dt).copy() for xi in x])


def test_white_noise_std_within_5_percent():
    # 1e5 samples: the sample std has a relative spread of 1/sqrt(2e5) = 0.2 %, so 5 % cannot
    # fail by chance; a wrong scaling (e.g. variance instead of std) fails it.
    sigma = np.array([0.02, 0.5, 3.0])
    ch = sm.SensorChannels(3, seed=1, noise=sigma)
    y = run(ch, np.zeros((100_000, 3)), 1e-3)
    assert_allclose(y.std(axis=0), sigma, rtol=0.05)
    assert np.all(np.abs(y.mean(axis=0)) < 5 * sigma / math.sqrt(1e5))
    lag1 = [np.corrcoef(y[:-1, i], y[1:, i])[0, 1] for i in range(3)]
    assert np.all(np.abs(lag1) < 0.02)          # white: 0.02 is 6 standard errors of 1/sqrt(1e5)


def test_bias_random_walk_variance_grows_linearly():
    # 20 000 independent channels: the sample variance has relative std sqrt(2/20000) = 1 %,
    # so the 5 % tolerance is 5 standard errors (and the three times are tested separately).
    n, dt, sigma = 20_000, 1e-3, 0.3
    ch = sm.SensorChannels(n, seed=3, bias_rw=sigma)
    checks = {100: None, 400: None, 1000: None}
    for k in range(1, 1001):
        y = ch.step(np.zeros(n), dt)
        if k in checks:
            checks[k] = y.copy()
    for k, y in checks.items():
        # the walk takes its k-th increment at the k-th sample, i.e. after k * dt seconds
        assert_allclose(y.var(), sigma ** 2 * k * dt, rtol=0.05)
        assert abs(y.mean()) < 5 * sigma * math.sqrt(k * dt / n)


def test_constant_bias_and_scale():
    ch = sm.SensorChannels(2, bias=[0.1, -0.2], scale=[0.01, -0.02])
    y = ch.step(np.array([10.0, 10.0]), 1e-3)
    assert_allclose(y, [10.1 + 0.1, 9.8 - 0.2], rtol=1e-12)


def test_quantisation_error_bounded_and_on_grid():
    res = 0.01
    ch = sm.SensorChannels(1, resolution=res)
    x = np.random.default_rng(0).uniform(-3.0, 3.0, (5000, 1))
    y = run(ch, x, 1e-3)
    assert np.max(np.abs(y - x)) <= res / 2 * (1 + 1e-9)
    assert np.max(np.abs(y - x)) > 0.45 * res                  # it really quantises
    assert_allclose(y / res, np.round(y / res), atol=1e-9)


def test_saturation_clips_and_flags():
    ch = sm.SensorChannels(3, range=5.0)
    y = ch.step(np.array([7.0, -9.0, 1.0]), 1e-3)
    assert_allclose(y, [5.0, -5.0, 1.0])
    assert_array_equal(ch.saturated, [True, True, False])


def test_sample_and_hold_holds_between_samples():
    ch = sm.SensorChannels(1, sample_rate=100.0)
    t = np.arange(50) * 1e-3
    y = run(ch, t[:, None], 1e-3)[:, 0]
    # every 10 steps a new sample of the input at that step, held for 10 steps
    assert_allclose(y, np.repeat(t[::10], 10), rtol=0, atol=1e-15)


def test_sample_rate_not_multiple_of_step_is_rejected():
    ch = sm.SensorChannels(1, sample_rate=300.0, names={"sample_rate": "sample_rate"})
    with pytest.raises(ValueError, match="sample_rate"):
        ch.step(np.zeros(1), 1e-3)
    with pytest.raises(ValueError, match="sample_rate"):       # faster than the step
        sm.SensorChannels(1, sample_rate=2000.0).step(np.zeros(1), 1e-3)


def test_cutoff_above_nyquist_is_rejected():
    with pytest.raises(ValueError, match="acc_cutoff"):
        sm.SensorChannels(1, cutoff=600.0, names={"cutoff": "acc_cutoff"}).step(np.zeros(1), 1e-3)


@pytest.mark.parametrize("order", [1, 2])
def test_lowpass_magnitude_matches_analytic(order):
    dt, fc = 1e-3, 50.0
    freqs = np.array([5.0, 20.0, fc, 120.0, 300.0])
    t = np.arange(4000) * dt
    ch = sm.SensorChannels(len(freqs), cutoff=fc, filter_order=order)
    x = np.sin(2 * np.pi * np.outer(t, freqs))
    y = np.array([ch.step(xi, dt) for xi in x])                 # no other imperfection: the filter
    tail = slice(2000, None)                                    # after the transient
    gain = y[tail].std(axis=0) / x[tail].std(axis=0)            # amplitude ratio of the sines
    assert_allclose(gain, sm.butterworth_magnitude(freqs, fc, dt, order), rtol=2e-3)
    assert_allclose(gain[2], 1 / math.sqrt(2.0), rtol=2e-3)     # -3 dB at the cut-off
    # and close to the analog Butterworth well below Nyquist
    assert_allclose(gain[0], 1 / math.sqrt(1 + (5.0 / fc) ** (2 * order)), rtol=1e-3)


def test_lowpass_starts_in_steady_state():
    ch = sm.SensorChannels(2, cutoff=30.0)
    y = run(ch, np.tile([G, -1.0], (20, 1)), 1e-3)
    assert_allclose(y, np.tile([G, -1.0], (20, 1)), rtol=1e-12)


def test_same_seed_identical_different_seed_different():
    def make(seed):
        return sm.SensorChannels(3, seed=seed, stream="x", noise=0.1, bias_rw=0.05, resolution=1e-4)
    x = np.ones((200, 3))
    a, b, c = run(make(4), x, 1e-3), run(make(4), x, 1e-3), run(make(5), x, 1e-3)
    assert_array_equal(a, b)
    assert np.mean(a != c) > 0.9


# ---- ideal readings ------------------------------------------------------------------------
def test_imu_at_rest_reads_plus_g_on_z():
    acc, gyro = sm.imu_reading([0.0, 0.0], 0.0, 0.0, (0.0, 0.0, 0.0))
    assert_allclose(acc, [0.0, 0.0, G], atol=1e-12)
    assert_allclose(gyro, 0.0, atol=1e-12)


def test_imu_rotated_mount_and_tool():
    # sensor rolled 90 deg about tool x: R_mount = Rx(90) maps sensor y to tool z, so the
    # gravity reaction +g is read on sensor y, and the rate about world y on sensor -z.
    acc, gyro = sm.imu_reading([0.0, 0.0], 0.0, 2.0, (math.pi / 2, 0.0, 0.0))
    assert_allclose(acc, [0.0, G, 0.0], atol=1e-12)
    assert_allclose(gyro, [0.0, 0.0, -2.0], atol=1e-12)      # world y is sensor -z
    # tool pitched by phi about y with zero mount: R_s^T (a_x, 0, a_z + g)
    phi, a = 0.3, np.array([1.5, -2.0])
    acc, gyro = sm.imu_reading(a, phi, 0.7, (0.0, 0.0, 0.0))
    c, s = math.cos(phi), math.sin(phi)
    expected = np.array([c * a[0] - s * (a[1] + G), 0.0, s * a[0] + c * (a[1] + G)])
    assert_allclose(acc, expected, rtol=1e-12)
    assert_allclose(gyro, [0.0, 0.7, 0.0], atol=1e-12)


def test_imu_reading_is_the_matrix_products():
    """The written-out reading against ``R_s^T (a - g_vec)``, ``R_s^T (0, omega, 0)`` with
    ``R_s = sensor_rotation(phi, mount)`` (numpy's matrix products, the former code), random
    poses and a general mount: equal to round-off of the vector's size."""
    from fmus.common.frames import sensor_rotation
    rng = np.random.default_rng(7)
    mount = (0.004, 0.003, -0.003)
    for _ in range(2000):
        a, phi, omega = rng.normal(0.0, 5.0, 2), rng.uniform(-4.0, 4.0), rng.normal(0.0, 3.0)
        acc, gyro = sm.imu_reading(a, phi, omega, mount, G)
        rs = sensor_rotation(phi, mount)
        want_acc = rs.T @ (np.array([a[0], 0.0, a[1]]) - np.array([0.0, 0.0, -G]))
        want_gyro = rs.T @ np.array([0.0, omega, 0.0])
        assert_allclose(acc, want_acc, rtol=0, atol=1e-15 * np.abs(want_acc).max())
        assert_allclose(gyro, want_gyro, rtol=0, atol=1e-15 * np.abs(want_gyro).max())


def test_force_sensor_at_rest_reads_tool_weight():
    f = sm.force_sensor_reading([0.0, 0.0], [0.0, 0.0], 0.0, 12.0, (0.0, 0.0, 0.0))
    assert_allclose(f, [0.0, 0.0, 12.0 * G], atol=1e-12)
    # a contact force ON the tool pushing up (+z) unloads the sensor; acceleration adds m a
    f = sm.force_sensor_reading([10.0, 30.0], [2.0, 0.0], 0.0, 12.0, (0.0, 0.0, 0.0))
    assert_allclose(f, [24.0 - 10.0, 0.0, 12.0 * G - 30.0], atol=1e-12)


# ---- environment ---------------------------------------------------------------------------
def test_contact_force_zero_outside_spring_inside_never_pulls():
    wall = sm.ContactEnvironmentParameters(wall_point=(1.0, 0.5), wall_normal=(-1.0, 0.0), stiffness=5000.0,
                                           damping=100.0)
    assert_allclose(sm.contact_force([0.99, 0.5], [1.0, 0.0], wall), 0.0)
    assert_allclose(sm.contact_force([1.002, 7.0], [0.0, 0.3], wall), [-5000.0 * 0.002, 0.0])
    # moving into the wall adds damping
    assert_allclose(sm.contact_force([1.002, 0.0], [0.1, 0.0], wall), [-(10.0 + 10.0), 0.0])
    # retracting fast: spring-damper would pull; the wall lets go instead
    assert_allclose(sm.contact_force([1.002, 0.0], [-0.5, 0.0], wall), 0.0)
    assert sm.penetration([1.002, 0.0], wall) == pytest.approx(0.002)
    off = sm.ContactEnvironmentParameters(wall_point=(1.0, 0.5), wall_normal=(-1.0, 0.0), enabled=False)
    assert_allclose(sm.contact_force([1.1, 0.0], [0.0, 0.0], off), 0.0)
    # an oblique wall: force along the (normalised) normal
    tilted = sm.ContactEnvironmentParameters(wall_point=(0.0, 0.0), wall_normal=(0.0, 2.0), stiffness=1000.0,
                                             damping=0.0)
    assert_allclose(sm.contact_force([0.3, -0.01], [0.0, 0.0], tilted), [0.0, 10.0])


def test_hammer_pulse_integral_and_unused_times():
    duration, force = 0.005, np.array([300.0, -100.0])
    t = np.linspace(0.0, 0.1, 200_001)
    f = np.array([sm.hammer_force(ti, [0.02, 0.0, float("nan"), 0.06], force, duration) for ti in t])
    dt = t[1] - t[0]
    first = f[t < 0.04].sum(axis=0) * dt
    assert_allclose(first, force * duration * 2 / math.pi, rtol=1e-3)
    assert_allclose(f.sum(axis=0) * dt, 2 * force * duration * 2 / math.pi, rtol=1e-3)
    assert_allclose(f[(t < 0.02) | ((t > 0.0251) & (t < 0.06))], 0.0)
    assert_allclose(sm.hammer_force(0.0225, [0.02], force, duration), force)   # the peak


def test_reseed_draws_new_numbers_from_now_and_keeps_the_state():
    """A reseed (fmus/common/noise.py) changes the random numbers to come, not the bias walk so
    far; its streams are not those of any seed, so a fork reseeded with the run's own seed does
    not replay the numbers the run drew from its start."""
    def channels() -> sm.SensorChannels:
        return sm.SensorChannels(2, seed=5, stream="s", noise=0.1, bias_rw=0.2)
    plain, reseeded, fresh = channels(), channels(), channels()
    x = np.zeros(2)
    before = [plain.step(x, 0.01) for _ in range(10)]
    assert_array_equal([reseeded.step(x, 0.01) for _ in range(10)], before)
    walk = reseeded.walk.copy()
    sm.reseed(5, reseeded)
    assert_array_equal(reseeded.walk, walk)
    after = np.array([reseeded.step(x, 0.01) for _ in range(200)])
    assert not np.any(after == np.array([plain.step(x, 0.01) for _ in range(200)]))
    assert not np.any(after == np.array([fresh.step(x, 0.01) for _ in range(200)]))
    # the walk goes on from where it was: its increments are the reseeded stream's
    expected = walk + np.cumsum(0.2 * math.sqrt(0.01) * make_rng(5, "s/bias_rw/reseed").standard_normal((200, 2)), axis=0)
    assert_allclose(reseeded.walk, expected[-1], rtol=1e-12)
    state = plain._rng_noise
    sm.reseed(-1, plain)                 # -1: the parameter's "never"
    assert plain._rng_noise is state

"""fmus/common/noise.py directly: stable stream keys, seed checks, white-noise variance and
random-walk growth against their declared values with statistical bounds, and the stream
position independent of the noise level; and quantisation noise (sensor_model.quantise, the
sensors' other noise source) against the uniform-error theory. make_rng's determinism and
stream independence: test_sensor_model.py."""
from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from fmus.common.noise import make_rng, random_walk_increment, stream_key, white_noise
from fmus.robot_plant.sensor_model import quantise


def test_stream_key_is_crc32_and_does_not_change_between_processes() -> None:
    assert stream_key("123456789") == 0xCBF43926       # CRC-32's published check value
    assert stream_key("") == 0
    assert stream_key("imu/acc") != stream_key("imu/gyro")


@pytest.mark.parametrize("seed", [-1, 1.5, True, "3"])
def test_bad_seed_is_refused(seed) -> None:  # noqa: ANN001 - deliberately wrong types
    with pytest.raises((ValueError, TypeError)):
        make_rng(seed)


def test_seed_may_be_an_integral_float_and_gives_the_integer_stream() -> None:
    assert_array_equal(make_rng(4.0, "s").standard_normal(3), make_rng(4, "s").standard_normal(3))


def test_white_noise_has_the_declared_standard_deviation_per_channel() -> None:
    # n draws of 3 channels: the sample variance has relative std sqrt(2 / n) = 0.45 %, so a
    # bound of 5 of those (2.2 %) fails by chance with probability below 1e-6.
    n = 100_000
    sigma = np.array([1e-4, 0.3, 7.0])
    rng = make_rng(11, "white")
    x = np.array([white_noise(rng, sigma, 3) for _ in range(n)])
    assert_allclose(x.var(axis=0) / sigma ** 2, 1.0, atol=5 * math.sqrt(2 / n))
    assert np.all(np.abs(x.mean(axis=0)) < 5 * sigma / math.sqrt(n))
    assert abs(np.corrcoef(x[:, 0], x[:, 1])[0, 1]) < 5 / math.sqrt(n)   # channels independent


def test_zero_noise_draws_anyway_so_the_stream_does_not_shift() -> None:
    a, b = make_rng(2, "s"), make_rng(2, "s")
    assert_array_equal(white_noise(a, 0.0, 4), np.zeros(4))
    white_noise(b, 1.0, 4)
    assert_array_equal(a.standard_normal(5), b.standard_normal(5))


def test_random_walk_variance_grows_as_sigma_squared_times_time() -> None:
    # 40 000 independent walks of 250 steps of 2 ms (t = 0.5 s): Var = sigma^2 t within 5
    # standard errors of a sample variance (sqrt(2 / 40000) = 0.7 %).
    walks, steps, dt, sigma = 40_000, 250, 2e-3, 0.8
    rng = make_rng(5, "walk")
    end = sum(random_walk_increment(rng, sigma, dt, walks) for _ in range(steps))
    assert_allclose(end.var() / (sigma ** 2 * steps * dt), 1.0, atol=5 * math.sqrt(2 / walks))
    # the same walk on a 4x coarser step has the same spread (the increments scale with sqrt(dt))
    coarse = sum(random_walk_increment(rng, sigma, 4 * dt, walks) for _ in range(steps // 4))
    assert_allclose(coarse.var() / end.var(), 1.0, atol=10 * math.sqrt(2 / walks))


def test_quantisation_error_is_uniform_with_variance_step_squared_over_12() -> None:
    step = np.array([1e-3, 0.25])
    x = make_rng(9, "q").uniform(-50.0, 50.0, (200_000, 2))
    e = quantise(x, step) - x
    assert np.all(np.abs(e) <= step / 2 * (1 + 1e-9))
    # uniform on [-q/2, q/2]: variance q^2/12, relative std of the estimate sqrt(0.8 / n) = 0.2 %
    assert_allclose(e.var(axis=0) / (step ** 2 / 12), 1.0, atol=0.02)
    assert_allclose(np.round((x + e) / step), (x + e) / step, atol=1e-6)   # on the grid
    assert_array_equal(quantise(x[:5], 0.0), x[:5])                          # 0 = off

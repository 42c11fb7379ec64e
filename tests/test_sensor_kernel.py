"""SensorChannels' faster step (issue 16: random numbers drawn in blocks, the limit computed
once, fewer numpy calls) against its stored behaviour (first recorded from the numpy
``SensorChannels`` of commit a611ae4): every imperfection on, random inputs.

``tests/data/sensor_channels_reference.npz`` is re-recorded from the working tree by ``python tests/references.py sensor_channels``
(tests/references.py: what it guards, and why not bit for bit). The
readings to 1e-12 of each column's scale (the anti-aliasing filter's coefficients come from
elementary functions); saturation flags and stamps exactly (comparisons and sums of the step).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from fmus.robot_plant.sensor_model import SensorChannels

from references import KERNEL_RTOL, assert_near, save_cases

REFERENCE = Path(__file__).parent / "data" / "sensor_channels_reference.npz"

# (channels, constructor keywords, step, input amplitude): each imperfection and their mixes
CASES = {
    "encoder": (2, dict(seed=1, stream="encoder", noise=2e-5, resolution=2 * math.pi / 2 ** 16), 1e-3, 50.0),
    "imu_acc": (3, dict(seed=5, stream="imu/acc", noise=0.02, bias=(0.01, -0.02, 0.03), bias_rw=1e-3,
                        scale=(0.003, -0.002, 0.001), resolution=1e-3, range=20.0, sample_rate=500.0,
                        cutoff=100.0, filter_order=2), 1e-3, 25.0),
    "first_order": (3, dict(seed=2, stream="x", noise=(0.0, 0.1, 1.0), bias_rw=(0.0, 0.05, 0.0),
                            resolution=(0.0, 1e-2, 0.5), range=(math.inf, 3.0, 10.0), cutoff=40.0,
                            filter_order=1), 2e-3, 8.0),
    "sampled": (1, dict(seed=9, stream="y", noise=0.3, sample_rate=250.0), 1e-3, 1.0),
}


def record(name: str, n_steps: int = 400) -> dict[str, np.ndarray]:
    """Initial reading, then the readings, saturation flags and stamps of ``n_steps`` steps on
    a random walk input (crossing the ranges) from a fixed seed."""
    n, kw, dt, amplitude = CASES[name]
    ch = SensorChannels(n, **kw)
    x = amplitude * np.cumsum(np.random.default_rng(11).normal(0.0, 0.1, (n_steps, n)), axis=0)
    y, sat, stamp = [ch.initial(x[0], 0.0).copy()], [ch.saturated.copy()], [ch.t_meas]
    for k in range(n_steps):
        y.append(ch.step(x[k], dt, (k + 1) * dt).copy())
        sat.append(ch.saturated.copy())
        stamp.append(ch.t_meas)
    return {"y": np.array(y), "saturated": np.array(sat), "t_meas": np.array(stamp),
            "walk": ch.walk.copy()}


def save() -> None:
    save_cases(REFERENCE, CASES, record)


@pytest.mark.parametrize("name", sorted(CASES))
def test_readings_are_their_reference(name) -> None:
    stored = np.load(REFERENCE)
    now = record(name)
    for key in ("y", "walk"):
        assert_near(now[key], stored[f"{name}/{key}"], rtol=KERNEL_RTOL, err_msg=key)
    for key in ("saturated", "t_meas"):
        assert_array_equal(now[key], stored[f"{name}/{key}"], err_msg=key)
    # the cases exercise what they claim: noise moved the readings, the ranges clipped
    assert np.ptp(now["y"]) > 0 and (name not in ("imu_acc", "first_order") or now["saturated"].any())


def test_block_draws_are_the_per_sample_draws() -> None:
    """The premise of the blocks: one draw of n k numbers = k draws of n, bit for bit, across
    blocks."""
    from fmus.common.noise import make_rng, normal_rows
    blocks, rng = make_rng(3, "s"), make_rng(3, "s")
    rows = np.concatenate([normal_rows(blocks, 3, 7) for _ in range(3)])
    assert_array_equal(rows, [rng.standard_normal(3) for _ in range(21)])

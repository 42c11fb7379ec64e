"""The tracker's plain-float update (issue 16: a history of floats, the noise drawn in blocks)
against its stored behaviour (first recorded from the numpy version before it, commit f04d4a7):
samples and stamps at rates that are and are not multiples of the step, with a clock skew
between updates.

``tests/data/tracker_reference.npz`` is re-recorded from the working tree by ``python tests/references.py tracker``
(tests/references.py: what it guards, and why not bit for bit). 1e-12: an
interpolation of a path of sines and cosines, whose last bits differ between machines.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fmus.robot_plant.tracker_model import TrackerModel

from references import KERNEL_RTOL, assert_near, save_cases

REFERENCE = Path(__file__).parent / "data" / "tracker_reference.npz"

# noise, sample rate, skew, update step
CASES = {"flagship": (2e-5, 1000.0, 1e-3, 1e-3), "slow_skewed": (1e-4, 300.0, 2.5e-3, 1e-3),
         "fast": (0.0, 4000.0, 1e-4, 2e-3)}


def record(name: str, n_steps: int = 300) -> dict[str, np.ndarray]:
    noise, rate, skew, dt = CASES[name]
    model = TrackerModel(noise, rate, skew, seed=4)
    path = lambda t: (1.0 + 0.2 * np.sin(3.0 * t), 0.6 + 0.1 * np.cos(5.0 * t))    # noqa: E731
    model.start(0.0, path(0.0))
    out = [[*model.p_meas, model.t_meas]]
    for k in range(1, n_steps + 1):
        model.update(k * dt, path(k * dt))
        out.append([*model.p_meas, model.t_meas])
    return {"values": np.array(out)}


def save() -> None:
    save_cases(REFERENCE, CASES, record)


@pytest.mark.parametrize("name", sorted(CASES))
def test_tracker_is_its_reference(name) -> None:
    stored = np.load(REFERENCE)[f"{name}/values"]
    now = record(name)["values"]
    assert_near(now, stored, rtol=KERNEL_RTOL)
    assert np.ptp(now[:, 0]) > 0.01                   # the position moved

"""The tracker's plain-float update (issue 16: a history of floats, the noise drawn in blocks)
against the stored behaviour of the numpy version before it: samples and stamps at rates that
are and are not multiples of the step, with a clock skew between updates, the same numbers to
1e-12 (the same operations: expected bit for bit).

``tests/data/tracker_reference.npz`` was recorded by :func:`record` with the code of commit
f04d4a7 (in that tree, with this file copied to its tests/: ``PYTHONPATH=. python -c
"import sys; sys.path.insert(0, 'tests'); from test_tracker_scalar import save; save()"``).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from fmus.robot_plant.tracker_model import TrackerModel

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
    np.savez_compressed(REFERENCE, **{f"{name}/{key}": v for name in CASES for key, v in record(name).items()})


@pytest.mark.parametrize("name", sorted(CASES))
def test_tracker_is_the_numpy_version_before(name) -> None:
    stored = np.load(REFERENCE)[f"{name}/values"]
    now = record(name)["values"]
    assert_allclose(now, stored, rtol=1e-12, atol=0)
    assert np.ptp(now[:, 0]) > 0.01                   # the position moved

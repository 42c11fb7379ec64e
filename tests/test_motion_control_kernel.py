"""The motion controller's compiled law (``motion_control_model._control_law``; issue 16)
against its stored behaviour (first recorded from the numpy law before it, commit f04d4a7):
references, errors, torques and the integral of runs with a Cartesian offset (both sides of the
exact Newton step), the identification multisine and the torque limit (wind-up guard).

``tests/data/motion_control_reference.npz`` is re-recorded from the working tree by ``python tests/references.py motion_control``
(tests/references.py: what it guards, and why not bit for bit). 1e-12 of
each column's scale, the inverse Jacobian's four entries sharing one: on this stretch of the
square one entry cancels to zero, 0.0 on one machine and 6e-18 on another (the matrix's scale
is 1.1).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from references import KERNEL_RTOL, assert_near, save_cases

from fmus.robot_plant.motion_control_model import MotionControllerParameters, build_controller

REFERENCE = Path(__file__).parent / "data" / "motion_control_reference.npz"
JINV = slice(22, 26)        #: the inverse Jacobian's four entries in the table's row (one scale)

CASES = {
    "iso_offset": (dict(), 2e-3),                                    # dp_ref up to 2 mm: Newton step
    "square_small_offset": (dict(path="square"), 5e-5),              # below 0.1 mm: Jacobian only
    "excited_saturated": (dict(excitation_amplitude=(1.0, 0.5), tau_max=(4.0, 3.0)), 0.0),
}


def record(name: str, n_steps: int = 120, dt: float = 1e-3) -> dict[str, np.ndarray]:
    """As the FMU drives it: the law at t with the new measurement, the integral over the step,
    the outputs at t + dt; the measurement is the reference plus a random-walk error."""
    kwargs, offset = CASES[name]
    c = build_controller(MotionControllerParameters(**kwargs))
    rng = np.random.default_rng(3)
    err = np.cumsum(rng.normal(0.0, 2e-3, (n_steps, 2)), axis=0)
    derr = rng.normal(0.0, 0.05, (n_steps, 2))
    dp = offset * np.sin(np.arange(n_steps)[:, None] * np.array([0.05, 0.08]))
    rows = []
    for k in range(n_steps):
        t = 0.3 + k * dt
        ref = c.model.sample(t)
        q_m, dq_m = ref[14:16] + err[k], ref[16:18] + derr[k]
        for when in (t, t + dt):
            tau = c.evaluate(when, q_m, dq_m, dp[k])
            rows.append(np.concatenate([c.row, c.q_a_ref, c.q_m_ref, c.p_ref, c.error, tau, c.integral]))
            if when == t:
                c.advance(dt)
    return {"rows": np.array(rows)}


def save() -> None:
    save_cases(REFERENCE, CASES, record)


@pytest.mark.parametrize("name", sorted(CASES))
def test_law_is_its_reference(name) -> None:
    stored = np.load(REFERENCE)[f"{name}/rows"]
    now = record(name)["rows"]
    assert_near(now, stored, rtol=KERNEL_RTOL, groups=(JINV,))
    tau = now[:, 26 + 8:26 + 10]
    if name == "excited_saturated":                  # the limit acted, and the guard with it
        assert (np.abs(tau) >= np.array([4.0, 3.0]) - 1e-12).any()


def test_a_copied_state_continues_as_the_original() -> None:
    """The FMU state (deep copy, pickle) of a controller, a sensor and the plant mid-run: the
    copy goes on exactly as the original (no in-place buffer is shared or left stale)."""
    import copy
    import pickle

    from fmus.robot_plant import plant_dynamics
    from fmus.robot_plant.plant_model import PlantParameters
    from fmus.robot_plant.sensor_batched import RunSensorChannels
    from fmus.robot_plant.sensor_model import SensorChannels

    ctrl = build_controller(MotionControllerParameters(tau_max=(4.0, 3.0)))
    sensors = [SensorChannels(3, seed=1, noise=0.1, bias_rw=0.01, resolution=1e-3, range=2.0, cutoff=100.0),
               RunSensorChannels(3, [1, 2], noise=0.1, bias_rw=0.01, cutoff=100.0)]
    plant = plant_dynamics.plant_model(PlantParameters())
    zero = np.zeros(2)

    def run(c, chans, m, k0, n):
        out = []
        for k in range(k0, k0 + n):
            t = 0.3 + 1e-3 * k
            tau = c.evaluate(t, c.q_m_ref - 0.01 * np.sin(k), zero, zero).copy()
            c.advance(1e-3)
            m.step(tau, zero, 1e-3)
            readings = [ch.step(np.full(3, np.sin(0.1 * k)), 1e-3).copy() for ch in chans]
            out.append(np.concatenate([tau, c.integral, *[r.ravel() for r in readings],
                                       [ch.walk.sum() for ch in chans], m.state]))
        return np.array(out)

    state = (ctrl, sensors, plant)
    run(*state, 0, 20)
    snapshots = [copy.deepcopy(state), pickle.loads(pickle.dumps(state))]
    original = run(*state, 20, 30)
    for snapshot in snapshots:
        assert_allclose(run(*snapshot, 20, 30), original, rtol=0, atol=0)

"""The realistic plant's compiled four-body chain (``plant_dynamics.chain4_step``,
``chain4_outputs``; issue 16) against its stored behaviour: states, outputs and applied torques
of a run with varying torques and tool forces (first recorded from the plain-Python chain before
the kernels, commit f04d4a7, and equal to it to 1e-12).

``tests/data/plant_kernel_reference.npz`` is re-recorded from the working tree by ``python tests/references.py plant_kernel`` (tests/references.py:
what it guards, and why the comparison is to 1e-12 of each column's scale, not bit for bit).
1e-12: across machines only the last bits of the elementary functions differ, amplified over 80
steps by at most 3e-14 of a column's scale (measured: tests/test_other_machine.py's settings).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from fmus.robot_plant import plant_dynamics
from fmus.robot_plant.plant_model import PlantParameters
from references import KERNEL_RTOL, assert_near, save_cases

REFERENCE = Path(__file__).parent / "data" / "plant_kernel_reference.npz"

# the default plant (compiled), more substeps from another pose, and the compliant tool (its
# own Python RK4 over the compiled chain's outputs and rates)
CASES = {"default": dict(), "substeps3": dict(substeps=3, p_tool0=(1.3, 0.2)), "ideal": dict(ideal=True, substeps=2),
         "compliant": dict(tool_compliance=1e-4, substeps=4)}


def record(name: str, n_steps: int = 80) -> dict[str, np.ndarray]:
    """Initial state and outputs, then per step of 1 ms the state, outputs and applied torques,
    under a random-walk torque and a random tool force from step 41 on."""
    m = plant_dynamics.plant_model(PlantParameters(**CASES[name]))
    rng = np.random.default_rng(5)
    tau = np.cumsum(rng.normal(0.0, 0.5, (n_steps, 2)), axis=0) + np.array([2.0, 1.0])
    f = np.where(np.arange(n_steps)[:, None] > 40, rng.normal(0.0, 30.0, (n_steps, 2)), 0.0)
    states, outs, applied = [m.state], [m.outputs(0.0, 0.0)], []
    for k in range(n_steps):
        m.check_step(1e-3)
        m.step(tau[k], f[k], 1e-3)
        states.append(m.state)
        outs.append(m.outputs(float(f[k, 0]), float(f[k, 1])))
        applied.append(m.applied_torques(float(tau[k, 0]), float(tau[k, 1])))
    return {"tau": tau, "f": f, "state": np.array(states), "outputs": np.array(outs),
            "applied": np.array(applied)}


def save() -> None:
    save_cases(REFERENCE, CASES, record)


@pytest.mark.parametrize("name", sorted(CASES))
def test_plant_is_its_reference(name) -> None:
    stored = np.load(REFERENCE)
    now = record(name)
    for key in ("tau", "f"):
        assert_array_equal(now[key], stored[f"{name}/{key}"])     # the same inputs (a seeded generator)
    for key in ("state", "outputs", "applied"):
        assert_near(now[key], stored[f"{name}/{key}"], rtol=KERNEL_RTOL, err_msg=key)
    # the run moves the arm: the comparison is not of a plant at rest
    assert np.ptp(now["state"][:, 0]) > 1e-5 and np.ptp(now["outputs"][:, 12]) > 1e-3


def test_rigid_links_stay_on_the_python_loops() -> None:
    """Without bending (two bodies: the Python loops) the plant still integrates: the kernels
    serve only the four-body chain, the loops the rest."""
    m = plant_dynamics.plant_model(PlantParameters(link_bending=False))
    assert m._k.P is None
    m.step((2.0, 1.0), (0.0, 0.0), 1e-3)
    assert len(m.outputs(0.0, 0.0)) == 24


def test_the_8_state_rates_take_a_tuple_or_an_array_alike() -> None:
    """ArmConstants.derivatives (compiled flex_rates) is called with tuples (the plant) and
    arrays (the 2009 observers): the same numbers either way."""
    from fmus.common.dynamics import ArmConstants
    from fmus.common.robot_params import RobotParameters
    k = ArmConstants(RobotParameters())
    x = np.random.default_rng(1).normal(0.0, 0.5, 8) + np.array([0.3, -0.2, 36.0, -30.0, 0, 0, 0, 0])
    assert k.derivatives(tuple(map(float, x)), 1.0, -2.0, 3.0, 4.0) == k.derivatives(x, 1.0, -2.0, 3.0, 4.0)

"""The rigid-kinematics baseline compiled (``rigid_kinematics_model.arm_angles`` on the
``dynamics`` spring and gravity kernels, ``kinematics.tool_point``; issue 16) against the
stored behaviour (first recorded from the plain-Python code before it, commit f04d4a7): arm
angles with and without the gravity compensation and the tool position, over the workspace and
two robot models.

``tests/data/rigid_kinematics_reference.npz`` is re-recorded from the working tree by ``python tests/references.py rigid_kinematics``
(tests/references.py: what it guards, and why not bit for bit). 1e-12:
a few Newton steps on trigonometric functions, whose last bits differ between machines.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fmus.common import dynamics, kinematics
from fmus.common.robot_params import RobotParameters
from fmus.estimators.rigid_kinematics_model import arm_angles

from references import KERNEL_RTOL, assert_near, save_cases

REFERENCE = Path(__file__).parent / "data" / "rigid_kinematics_reference.npz"

CASES = {"nominal": dict(), "soft": dict(k_lo=(2.0e5, 6.0e4), k_hi=(4.0e5, 1.2e5), l2=1.3)}


def record(name: str, n: int = 300) -> dict[str, np.ndarray]:
    """Arm angles (plain, compensated) and their tool positions for motor angles at random
    poses with the static deflection of the model added (what an encoder reads at rest)."""
    robot = RobotParameters(**CASES[name])
    rng = np.random.default_rng(2)
    q = np.column_stack([rng.uniform(-0.6, 1.2, n), rng.uniform(-1.2, 0.6, n)])
    out = []
    for qa in q:
        q_m = dynamics.static_equilibrium(qa, robot)[2:4] + rng.normal(0.0, 0.01, 2)
        plain, comp = arm_angles(q_m, robot, False), arm_angles(q_m, robot, True)
        out.append([*q_m, *plain, *comp, *kinematics.tool_position(comp, robot)])
    return {"values": np.array(out)}


def save() -> None:
    save_cases(REFERENCE, CASES, record)


@pytest.mark.parametrize("name", sorted(CASES))
def test_rigid_kinematics_is_its_reference(name) -> None:
    stored = np.load(REFERENCE)[f"{name}/values"]
    now = record(name)["values"]
    assert_near(now, stored, rtol=KERNEL_RTOL)
    assert np.abs(now[:, 4:6] - now[:, 2:4]).min() > 1e-6      # the compensation moved every pose
    robot = RobotParameters(**CASES[name])                     # the adapter's forward kinematics
    fk = np.array([kinematics.tool_point(q1, q2, robot.l1, robot.l2) for q1, q2 in now[:, 4:6]])
    assert_near(fk, stored[:, 6:8], rtol=KERNEL_RTOL)

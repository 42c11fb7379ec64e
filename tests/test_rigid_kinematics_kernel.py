"""The rigid-kinematics baseline compiled (``rigid_kinematics_model.arm_angles`` on the
``dynamics`` spring and gravity kernels, ``kinematics.tool_point``; issue 16) against the
stored behaviour of the plain-Python code before it: arm angles with and without the gravity
compensation and the tool position, over the workspace and two robot models, to 1e-12.

``tests/data/rigid_kinematics_reference.npz`` was recorded by :func:`record` with the code of
commit f04d4a7 (in that tree, with this file copied to its tests/: ``PYTHONPATH=. python -c
"import sys; sys.path.insert(0, 'tests'); from test_rigid_kinematics_kernel import save; save()"``).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from fmus.common import dynamics, kinematics
from fmus.common.robot_params import RobotParameters
from fmus.estimators.rigid_kinematics_model import arm_angles

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
    np.savez_compressed(REFERENCE, **{f"{name}/{key}": v for name in CASES for key, v in record(name).items()})


@pytest.mark.parametrize("name", sorted(CASES))
def test_rigid_kinematics_is_the_python_code_before(name) -> None:
    stored = np.load(REFERENCE)[f"{name}/values"]
    now = record(name)["values"]
    assert_allclose(now, stored, rtol=1e-12, atol=0)
    assert np.abs(now[:, 4:6] - now[:, 2:4]).min() > 1e-6      # the compensation moved every pose
    robot = RobotParameters(**CASES[name])                     # the adapter's forward kinematics
    fk = np.array([kinematics.tool_point(q1, q2, robot.l1, robot.l2) for q1, q2 in now[:, 4:6]])
    assert_allclose(fk, stored[:, 6:8], rtol=1e-12, atol=0)

"""Rigid forward kinematics of the motor angles: the baseline every estimator must beat.

The arm angles a robot controller believes in are the motor angles over the gear ratio,
``q_a = q_m / r``, optionally corrected for the static gearbox deflection under gravity
(``q_m / r = q_a + D``, ``tau_s(D) = G(q_a)``; 2012 paper eq. 16 without the dynamic terms), as
industrial controllers do. The tool position is then the forward kinematics ``p(q_a)``.

The compensation needs a gearbox stiffness, and it is the estimator's MODEL stiffness (its
``k_lo``, ``k_hi``, ``delta`` parameters: the nominal robot, later an identified one), never the
plant's by construction. It is off by default, as in the 2009 paper (Henriksson et al., "rigid
robot kinematics" of the motor angles, Table I) and the 2012 paper (Axelsson et al., eq. 29,
``T_tcp(q_m)``), whose baselines do not remove the gravity sag; a scenario that wants it says
so (``gravity_compensation = true``) and which stiffness it uses.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fmus.common import cython_kernels, dynamics, kinematics
from fmus.common.parameters import param
from fmus.common.robot_params import RobotParameters


@dataclass(frozen=True)
class RigidKinematicsParameters(RobotParameters):
    """The estimator's model of the robot, and whether it removes the static gravity deflection."""

    gravity_compensation: bool = param(False, "1", "subtract the static gearbox deflection under "
                                       "gravity, computed with this model's stiffness, from q_m / r "
                                       "(as an industrial controller does)",
                                       source="off: the 2009 and 2012 papers' rigid-kinematics baseline")


def arm_angles(q_m, robot: RobotParameters, gravity_compensation: bool = False) -> tuple[float, float]:
    """Arm angles [rad] from the motor angles ``q_m`` [rad, motor side]: ``q_m / r``, minus the
    gravity deflection ``D(G(q_a))`` when ``gravity_compensation`` is on; ``robot`` is the
    estimator's model of the robot (gear ratios, and the stiffness the compensation uses).

    The fixed point ``q_a = q_m / r - D(G(q_a))`` contracts fast (``|dD/dq| ~ 1e-3``): each
    iteration gains three digits (so the error left after a change ``c`` is about ``1e-3 c``), and
    each spring inversion starts from the last one. Plain floats: this runs every step of the
    baseline, compiled (:func:`_compensated`; benchmarks/flagship.py).
    """
    k = dynamics.arm_constants(robot)
    m1, m2 = float(q_m[0]) / k.r[0], float(q_m[1]) / k.r[1]
    if not gravity_compensation:
        return m1, m2
    return _compensated(m1, m2, k.static)


# compiled (estimators/rigid_kinematics_kernels.pyx): the fixed point of arm_angles, the FMU's estimate
_kernels = cython_kernels.load("estimators.rigid_kinematics_kernels")
_compensated = _kernels.compensated


def constants(robot: RobotParameters, gravity_compensation: bool = False) -> np.ndarray:
    """The constants :func:`estimate` takes: gear ratios, ``gravity_compensation`` (0 or 1),
    link lengths, then :attr:`fmus.common.dynamics.ArmConstants.static` (``robot``: the
    estimator's model of the robot)."""
    k = dynamics.arm_constants(robot)
    return np.array([k.r[0], k.r[1], float(bool(gravity_compensation)), float(robot.l1), float(robot.l2),
                     *k.static])


#: ``estimate(q_m, t_m, now, consts, samples, out, first)``: the RigidKinematics FMU's estimate
#: at ``now`` [s] from the motor angles ``q_m`` [rad] stamped ``t_m`` [s] (:func:`arm_angles` with
#: the ``consts`` of :func:`constants`, extrapolated to ``now`` from the last two distinct
#: ``samples``, then the tool position) into ``out[first:first + 4]``; returns the tool angle
estimate = _kernels.estimate


def tool_position(q_m, robot: RobotParameters, gravity_compensation: bool = False) -> np.ndarray:
    """Tool position (world x, z) [m] by rigid forward kinematics of the motor angles ``q_m``
    [rad], with the arm angles of :func:`arm_angles` (``robot``, ``gravity_compensation``)."""
    return kinematics.tool_position(arm_angles(q_m, robot, gravity_compensation), robot)

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

from fmus.common import dynamics, kinematics
from fmus.common.jit import kernel
from fmus.common.parameters import param
from fmus.common.robot_params import RobotParameters
from fmus.common.sample_time import TIME_TOL


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


@kernel(aot="UniTuple(float64, 2)(float64, float64, float64[:])")
def _compensated(m1: float, m2: float, K: np.ndarray) -> tuple[float, float]:
    """The fixed point of :func:`arm_angles` from ``q_m / r = (m1, m2)``, with the constants
    ``K`` of :attr:`fmus.common.dynamics.ArmConstants.static`."""
    q1, q2, D1, D2, guess = m1, m2, 0.0, 0.0, False
    for _ in range(8):
        G1, G2 = dynamics.gravity_torques(K[0], K[1], q1, q2)
        D1 = dynamics.spring_inverse(K[2], K[4], K[6], G1, D1, guess)
        D2 = dynamics.spring_inverse(K[3], K[5], K[7], G2, D2, guess)
        guess = True                             # each inversion starts from the last one
        n1, n2 = m1 - D1, m2 - D2
        if abs(n1 - q1) <= 1e-11 and abs(n2 - q2) <= 1e-11:      # error left: about 1e-14 rad
            return n1, n2
        q1, q2 = n1, n2
    return q1, q2


def constants(robot: RobotParameters, gravity_compensation: bool = False) -> np.ndarray:
    """The constants :func:`estimate` takes: gear ratios, ``gravity_compensation`` (0 or 1),
    link lengths, then :attr:`fmus.common.dynamics.ArmConstants.static` (``robot``: the
    estimator's model of the robot)."""
    k = dynamics.arm_constants(robot)
    return np.array([k.r[0], k.r[1], float(bool(gravity_compensation)), float(robot.l1), float(robot.l2),
                     *k.static])


@kernel(aot="float64(float64[:], float64, float64, float64[:], float64[:], float64[:], int64)")
def estimate(q_m, t_m, now, consts, samples, out, first):
    """The RigidKinematics FMU's estimate at ``now`` [s] from the motor angles ``q_m`` [rad]
    stamped ``t_m`` [s]: :func:`arm_angles` (``consts`` of :func:`constants`), extrapolated to
    ``now`` at the velocity of the last two distinct samples when the sample is older (the
    latency compensation of a robot controller; ``samples``: their count, then (time, q_a) of
    the one before and of the last, updated), then the tool position
    (:func:`fmus.common.kinematics.tool_point`). Writes ``q_a_hat``, ``p_tool_hat`` into
    ``out[first:first + 4]``; returns the tool angle ``q_a_hat[0] + q_a_hat[1]``."""
    q1, q2 = q_m[0] / consts[0], q_m[1] / consts[1]
    if consts[2] != 0.0:
        q1, q2 = _compensated(q1, q2, consts[5:])
    if samples[0] > 0 and t_m <= samples[4] + TIME_TOL:       # the same sample (or set again)
        samples[4], samples[5], samples[6] = t_m, q1, q2
    else:
        samples[1], samples[2], samples[3] = samples[4], samples[5], samples[6]
        samples[4], samples[5], samples[6] = t_m, q1, q2
        samples[0] = min(samples[0] + 1.0, 2.0)
    if now > t_m + TIME_TOL and samples[0] == 2.0:
        t0, a0, b0, t1, a1, b1 = samples[1], samples[2], samples[3], samples[4], samples[5], samples[6]
        f = (now - t1) / (t1 - t0)
        q1, q2 = a1 + (a1 - a0) * f, b1 + (b1 - b0) * f
    x, z = kinematics.tool_point(q1, q2, consts[3], consts[4])
    out[first], out[first + 1], out[first + 2], out[first + 3] = q1, q2, x, z
    return q1 + q2


def tool_position(q_m, robot: RobotParameters, gravity_compensation: bool = False) -> np.ndarray:
    """Tool position (world x, z) [m] by rigid forward kinematics of the motor angles ``q_m``
    [rad], with the arm angles of :func:`arm_angles` (``robot``, ``gravity_compensation``)."""
    return kinematics.tool_position(arm_angles(q_m, robot, gravity_compensation), robot)

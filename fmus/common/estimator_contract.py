"""The estimator contract: the signals an estimator FMU may take and must give (plain data).

One table, used by the :class:`~fmus.robot_plant.log_replay_fmu.LogReplay` FMU (whose outputs
are exactly the inputs an estimator may take, so a recorded log plugs into any estimator) and by
``flexfusion check-estimator`` (:mod:`orchestration.contract`), which checks an FMU's
modelDescription against it. The names, sizes and units are those of our sensors, controller
and estimators (docs/estimator_contract.md), SI units as in every FlexFusion FMU.
"""
from __future__ import annotations

from typing import NamedTuple


class Signal(NamedTuple):
    """A variable of the contract: name, vector size (None = scalar), unit, description."""

    name: str
    size: int | None
    unit: str
    description: str

    def scalars(self) -> list[str]:
        """The FMI scalar names: ``name`` or ``name[1] .. name[size]``."""
        return [self.name] if self.size is None else [f"{self.name}[{i + 1}]" for i in range(self.size)]


#: What an estimator may take as inputs (all optional; measured or commanded signals only).
INPUTS: tuple[Signal, ...] = (
    Signal("q_m_meas", 2, "rad", "measured motor angles of joints 2 and 3, motor side (Encoder)"),
    Signal("acc_s", 3, "m/s2", "accelerometer specific force, sensor frame, with gravity (Imu)"),
    Signal("gyro_s", 3, "rad/s", "gyroscope angular rate, sensor frame (Imu)"),
    Signal("f_s", 3, "N", "wrist force, sensor frame (ForceTorqueSensor)"),
    Signal("tau_m", 2, "N.m", "commanded motor torques (MotionController)"),
    Signal("q_a_ref", 2, "rad", "arm angle reference (MotionController)"),
    Signal("dq_a_ref", 2, "rad/s", "arm angular velocity reference (MotionController)"),
    Signal("ddq_a_ref", 2, "rad/s2", "arm angular acceleration reference (MotionController)"),
    Signal("dddq_a_ref", 2, "rad/s3", "arm jerk reference (MotionController)"),
    Signal("p_fk", 2, "m", "tool position by forward kinematics of the motor angles, world x, z"),
    Signal("phi_fk", None, "rad", "tool angle by forward kinematics of the motor angles"),
    Signal("t_meas", None, "s", "time the measurement inputs were sampled (the sensors' t_meas; "
           "start value -1: unstamped)"),
)

#: What every estimator must output.
REQUIRED_OUTPUTS: tuple[Signal, ...] = (
    Signal("p_tool_hat", 2, "m", "estimated tool position, world x and z"),
)

#: What an estimator may output besides (checked for size and unit when present).
OPTIONAL_OUTPUTS: tuple[Signal, ...] = (
    Signal("q_a_hat", 2, "rad", "estimated arm angles"),
    Signal("dq_a_hat", 2, "rad/s", "estimated arm angular velocities"),
    Signal("ddq_a_hat", 2, "rad/s2", "estimated arm angular accelerations"),
    Signal("phi_tool_hat", None, "rad", "estimated tool angle"),
    Signal("P_x", 21, "1", "covariance of (q_a, dq_a, ddq_a), lower triangle row by row "
           "(numpy.tril_indices(6)), for NEES"),
    Signal("innovation_norm", None, "1", "normalised innovation norm sqrt(nu^T S^-1 nu) of the "
           "last update, for NIS (= its square)"),
    Signal("nis", None, "1", "normalised innovation squared nu^T S^-1 nu of the last update"),
)

#: The truth a recorded log may carry besides the measurements (for metrics only: never
#: connect it to an estimator), named as the plant's outputs.
TRUTH: tuple[Signal, ...] = (
    Signal("q_a", 2, "rad", "true arm angles (for metrics only)"),
    Signal("dq_a", 2, "rad/s", "true arm angular velocities (for metrics only)"),
    Signal("ddq_a", 2, "rad/s2", "true arm angular accelerations (for metrics only)"),
    Signal("p_tool", 2, "m", "true tool position, world x and z (for metrics only)"),
)

#: What a recorded log's reference measurement system (the papers' laser tracker) gives besides
#: the measurements (for metrics only: the judge of a study, never an estimator's input): the
#: Tracker's measured position, and its sample stamps under their own name (``t_meas`` is the
#: sensors').
REFERENCE: tuple[Signal, ...] = (
    Signal("p_tool_meas", 2, "m", "tool position measured by the reference system (laser tracker), "
           "world x and z (for metrics only)"),
    Signal("t_tool_meas", None, "s", "time stamp of the reference system's held sample (for metrics only)"),
)

__all__ = ["Signal", "INPUTS", "REQUIRED_OUTPUTS", "OPTIONAL_OUTPUTS", "TRUTH", "REFERENCE"]

"""FMU adapter of the robot's motion controller (path, inverse kinematics, feed-forward, motor PID).

The math is in :mod:`fmus.robot_plant.motion_control_model` and :mod:`fmus.robot_plant.trajectory`.
"""
from __future__ import annotations

import numpy as np

from fmus.common.fmi import FlexFusionSlave
from fmus.robot_plant.motion_control_model import COLUMNS, MotionControllerParameters, build_controller

# outputs of the controller's results, in their order (MotionController.step), and outputs
# copied straight from the reference-table row
_LAW_OUTPUTS = ("q_a_ref", "q_m_ref", "p_ref", "e_m", "tau_m", "dq_m_hat")
_ROW_OUTPUTS = ("dq_a_ref", "ddq_a_ref", "dddq_a_ref", "v_ref", "a_ref", "dq_m_ref", "tau_ff")


class MotionController(FlexFusionSlave):
    """Motion controller of the flexible two-axis robot.

    Follows a Cartesian tool path (parameter ``path``: ``p1``, ``p2``, ``iso9283``, ``square`` or
    ``csv`` with ``csv_file``), plus a Cartesian offset ``dp_ref`` from an impedance controller.
    Outputs the motor torque from a motor-side PID with rigid-body and flexible-joint
    feed-forward, and the arm references including the jerk (the 2012 paper's EKF input). The
    robot parameters are the controller's own model of the robot: set them differently from the
    plant's to study model errors. The drive reads its motor encoder (``q_m``: connect an
    Encoder's ``q_m_meas``) and forms the motor speed from it, as a servo drive does: the
    backward difference over its communication step through a first-order low-pass
    (``velocity_cutoff``; output ``dq_m_hat``, see
    :mod:`~fmus.robot_plant.motion_control_model`); the PID's derivative term compares it with
    the reference speed formed the same way. The encoder should sample at least once per
    controller step. The torque is computed from the measurement at the start of each
    communication step and held over it. Identification mode: ``excitation_amplitude`` > 0
    adds a random-phase multisine torque (``excitation_band``, ``excitation_period``,
    ``excitation_seed``) to the PID output.
    """
    role = "controller"

    parameters_class = MotionControllerParameters
    description = "Motion controller: smooth Cartesian paths, IK, flexible-joint feed-forward, motor PID"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.input("q_m", 2, unit="rad", description="motor angle from the drive's encoder, motor side")
        self.input("dp_ref", 2, unit="m", description="Cartesian offset of the tool reference, world x and z")
        meas = ("q_m", "dp_ref")
        off = ("dp_ref",)
        self.output("tau_m", 2, unit="N.m", description="motor torque command, motor side", depends_on=meas)
        self.output("q_a_ref", 2, unit="rad", description="arm angle reference (with the dp_ref offset)",
                    depends_on=off)
        self.output("dq_a_ref", 2, unit="rad/s", description="arm angular velocity reference")
        self.output("ddq_a_ref", 2, unit="rad/s2", description="arm angular acceleration reference")
        self.output("dddq_a_ref", 2, unit="rad/s3", description="arm angular jerk reference (EKF input)")
        self.output("p_ref", 2, unit="m", description="tool position reference, world x and z (with dp_ref)",
                    depends_on=off)
        self.output("v_ref", 2, unit="m/s", description="tool velocity reference, world x and z")
        self.output("a_ref", 2, unit="m/s2", description="tool acceleration reference, world x and z")
        self.output("q_m_ref", 2, unit="rad", description="motor angle reference, motor side (with deflection)",
                    depends_on=off)
        self.output("dq_m_ref", 2, unit="rad/s", description="motor angular velocity reference, motor side")
        self.output("tau_ff", 2, unit="N.m", description="feed-forward motor torque, motor side")
        self.output("e_m", 2, unit="rad", description="motor angle error q_m_ref - q_m, motor side",
                    depends_on=meas)
        self.output("dq_m_hat", 2, unit="rad/s", description="the drive's motor speed from its encoder "
                    "(backward difference, first-order low-pass), motor side")
        # where the step writes its results and the row's columns in the output buffer
        # (MotionController.step)
        row_at = np.full(max(c.stop for c in COLUMNS.values()), -1)
        for name in _ROW_OUTPUTS:
            row_at[COLUMNS[name]] = np.r_[self.output_span(name, name)]
        self._at = np.concatenate([np.r_[tuple(self.output_span(n, n) for n in _LAW_OUTPUTS)], row_at])

    def setup(self, params: MotionControllerParameters) -> None:
        self.ctrl = build_controller(params)
        self.update_outputs()

    def update_outputs(self) -> None:
        c = self.ctrl
        c.evaluate(self._time, self.q_m, c.law_speed(self._time), self.dp_ref)
        results = np.concatenate([c.q_a_ref, c.q_m_ref, c.p_ref, c.error, c.tau, c.velocity, c.row])
        shown = self._at >= 0
        self._outputs[self._at[shown]] = results[shown]

    def step(self, t: float, dt: float) -> None:
        # the speed from the encoder reading just set, the torque for it, whose error the
        # integrator takes, then the outputs at t + dt (one compiled call)
        self.ctrl.step(t, dt, self.q_m, self.dp_ref, self._outputs, self._at)

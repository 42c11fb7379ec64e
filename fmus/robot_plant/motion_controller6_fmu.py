"""FMU adapter of the six-axis robot's motion controller (paths through the analytic IK,
nominal-model feed-forward, six motor PIDs on their encoders; math in
:mod:`fmus.robot_plant.motion_control6_model` and :mod:`fmus.robot_plant.trajectory6`)."""
from __future__ import annotations

import numpy as np

from fmus.common.fmi import FlexFusionSlave
from fmus.robot_plant.motion_control6_model import (MotionController6Parameters, MotionControl6Model,
                                                    build_controller)

_ROW_OUTPUTS = (("q_a_ref", "q"), ("dq_a_ref", "dq"), ("ddq_a_ref", "ddq"), ("dddq_a_ref", "dddq"),
                ("q_m_ref", "q_m"), ("dq_m_ref", "dq_m"), ("tau_ff", "tau_ff"), ("p_ref", "p"))


class MotionController6(FlexFusionSlave):
    """Motion controller of the six-axis flexible robot (``FlexibleRobot6DOF``).

    Follows the six-axis path ``path`` (``iso_cube``, ``square``, ``p1``, ``p2``, ``p1_moving``,
    ``p2_moving``; :mod:`~fmus.robot_plant.trajectory6`): joint references through the analytic
    inverse kinematics, feed-forward from the controller's own nominal rigid-body model with
    the gearbox deflection compensated on its nominal stiffness, and six motor PIDs, each
    closing its loop on the drive's encoder reading ``q_m`` (connect an Encoder6's
    ``q_m_meas``; never the plant's truth) and forming its speed from it (backward difference,
    first-order low-pass ``velocity_cutoff``, output ``dq_m_hat``). Outputs the motor torques
    and the references the estimators take (arm angles, their acceleration and jerk, the tool
    position). The plant's initial pose ``q0`` must be the path's start, ``q_a_ref`` at the
    start time. The torque is computed from the reading set before each step (the plant's at
    the step's end) and held over the next step.
    """
    role = "controller"

    parameters_class = MotionController6Parameters
    description = ("Six-axis motion controller: 3-D paths through the analytic IK, nominal-model "
                   "feed-forward, motor PIDs on their encoders")

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.input("q_m", 6, unit="rad", description="motor angles of axes 1-6 from the drives' encoders, motor side")
        meas = ("q_m",)
        self.output("tau_m", 6, unit="N.m", description="motor torque commands of axes 1-6, motor side",
                    depends_on=meas)
        self.output("q_a_ref", 6, unit="rad", description="arm angle references of axes 1-6")
        self.output("dq_a_ref", 6, unit="rad/s", description="arm angular velocity references")
        self.output("ddq_a_ref", 6, unit="rad/s2", description="arm angular acceleration references")
        self.output("dddq_a_ref", 6, unit="rad/s3", description="arm angular jerk references (EKF input)")
        self.output("q_m_ref", 6, unit="rad", description="motor angle references, motor side (with the "
                    "nominal gearbox deflection)")
        self.output("dq_m_ref", 6, unit="rad/s", description="motor angular velocity references, motor side")
        self.output("tau_ff", 6, unit="N.m", description="feed-forward motor torques, motor side")
        self.output("e_m", 6, unit="rad", description="motor angle errors q_m_ref - q_m, motor side",
                    depends_on=meas)
        self.output("dq_m_hat", 6, unit="rad/s", description="the drives' motor speeds from their encoders "
                    "(backward difference, first-order low-pass), motor side")
        self.output("p_ref", 3, unit="m", description="tool centre point reference, world x, y, z")

    def setup(self, params: MotionController6Parameters) -> None:
        self.ctrl = build_controller(params)
        self.ctrl.start(self._time, self.q_m)
        self._show()

    def _show(self) -> None:
        c = self.ctrl
        for out, col in _ROW_OUTPUTS:
            getattr(self, out)[:] = MotionControl6Model.column(c.row, col)
        self.tau_m[:] = c.tau
        self.e_m[:] = c.error
        self.dq_m_hat[:] = c.velocity

    def update_outputs(self) -> None:
        if self._phase == "stepping":
            self.ctrl.law(np.asarray(self.q_m, float))
        else:                         # the initial reading, set in Initialization Mode
            self.ctrl.start(self._time, self.q_m)
        self._show()

    def step(self, t: float, dt: float) -> None:
        self.ctrl.step(t, dt, self.q_m)
        self._show()

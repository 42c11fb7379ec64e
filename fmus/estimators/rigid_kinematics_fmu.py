"""FMU adapter of the rigid-kinematics baseline (tool position from the motor angles)."""
from __future__ import annotations

from fmus.common import kinematics
from fmus.common.fmi import FlexFusionSlave
from fmus.estimators.rigid_kinematics_model import RigidKinematicsParameters, arm_angles


class RigidKinematics(FlexFusionSlave):
    """Baseline estimator: tool position by rigid forward kinematics of the measured motor angles."""

    parameters_class = RigidKinematicsParameters
    description = "Rigid forward kinematics of the motor angles (baseline estimator)"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.input("q_m_meas", 2, unit="rad", description="measured motor angle, motor side")
        feed = ("q_m_meas",)
        self.output("q_a_hat", 2, unit="rad", description="arm angle estimate", depends_on=feed)
        self.output("p_tool_hat", 2, unit="m", description="tool position estimate, world x and z",
                    depends_on=feed)
        self.output("phi_tool_hat", unit="rad", description="tool angle estimate about world y "
                    "(q_a_hat[1] + q_a_hat[2])", depends_on=feed)

    def setup(self, params: RigidKinematicsParameters) -> None:
        self.robot = params.robot()
        self.compensate = bool(params.gravity_compensation)

    def step(self, t: float, dt: float) -> None:
        self.update_outputs()

    def update_outputs(self) -> None:
        q = arm_angles(self.q_m_meas, self.robot, self.compensate)
        self.q_a_hat[:] = q
        self.p_tool_hat[:] = kinematics.tool_position(q, self.robot)
        self.phi_tool_hat = float(q[0] + q[1])

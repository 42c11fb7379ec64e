"""FMU adapter of the flexible two-axis robot (2012 paper eqs. 10-11, 2009 paper eq. 2)."""
from __future__ import annotations

from fmus.common import dynamics, kinematics
from fmus.common.fmi import FlexFusionSlave
from fmus.robot_plant.plant_model import PlantParameters


class FlexibleRobot2DOF(FlexFusionSlave):
    """Flexible-joint model of axes 2 and 3 of a large industrial robot.

    Every physical parameter is an FMU parameter, so a scenario can give the estimators a model
    that differs from the plant. The arm starts at rest in static equilibrium under gravity at
    ``q_a0``. Outputs at the end of a step use the state at that time and the inputs held over
    the step; the accelerations depend directly on ``f_ext``.
    """

    parameters_class = PlantParameters
    description = "Flexible two-axis industrial robot (axes 2 and 3), nonlinear gearbox springs"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.input("tau_m", 2, unit="N.m", description="motor torque, motor side")
        self.input("f_ext", 2, unit="N", description="external force on the tool, world x and z")
        acc = ("f_ext",)
        self.output("q_a", 2, unit="rad", description="arm angle")
        self.output("dq_a", 2, unit="rad/s", description="arm angular velocity")
        self.output("ddq_a", 2, unit="rad/s2", description="arm angular acceleration", depends_on=acc)
        self.output("q_m", 2, unit="rad", description="motor angle, motor side")
        self.output("dq_m", 2, unit="rad/s", description="motor angular velocity, motor side")
        self.output("p_tool", 2, unit="m", description="tool position, world x and z")
        self.output("v_tool", 2, unit="m/s", description="tool velocity, world x and z")
        self.output("a_tool", 2, unit="m/s2", description="tool acceleration, world x and z", depends_on=acc)
        self.output("phi_tool", unit="rad", description="tool angle about world y")
        self.output("omega_tool", unit="rad/s", description="tool angular rate about world y")
        self.output("p_sensor", 2, unit="m", description="accelerometer mount position, world x and z")
        self.output("a_sensor", 2, unit="m/s2", description="accelerometer mount acceleration, world x and z",
                    depends_on=acc)
        self.output("tau_s", 2, unit="N.m", description="gearbox spring torque, arm side")

    def setup(self, params: PlantParameters) -> None:
        self.robot = params.robot()
        self.model = dynamics.FlexibleRobotModel(self.robot, params.initial_angles(), substeps=params.substeps)
        self.update_outputs()

    def step(self, t: float, dt: float) -> None:
        self.model.step(self.tau_m, self.f_ext, dt)
        self.update_outputs()

    def update_outputs(self) -> None:
        # plain floats throughout: this runs every step
        p = self.robot
        s = self.model.state
        q, qm, dq, dqm = s[0:2], s[2:4], s[4:6], s[6:8]
        ddq = self.model.arm_acceleration(float(self.f_ext[0]), float(self.f_ext[1]))
        for out, values in ((self.q_a, q), (self.dq_a, dq), (self.ddq_a, ddq), (self.q_m, qm),
                            (self.dq_m, dqm), (self.tau_s, self.model.spring_torques())):
            out[0], out[1] = values
        x, z, vx, vz, ax, az = kinematics.point_motion(q, dq, ddq, p, "tool")
        self.p_tool[0], self.p_tool[1] = x, z
        self.v_tool[0], self.v_tool[1] = vx, vz
        self.a_tool[0], self.a_tool[1] = ax, az
        x, z, _, _, ax, az = kinematics.point_motion(q, dq, ddq, p, "sensor")
        self.p_sensor[0], self.p_sensor[1] = x, z
        self.a_sensor[0], self.a_sensor[1] = ax, az
        self.phi_tool = q[0] + q[1]
        self.omega_tool = dq[0] + dq[1]

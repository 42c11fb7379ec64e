"""Test stand-in of the six-axis plant FMU (FlexibleRobot6DOF, issue 23) until it lands: the
numpy reference model fmus/robot_plant/six_axis_model.py behind the agreed interface (those of
its outputs the sensors and the controller read). Slow (numpy: a few ms per 1 ms step); for the
tests of the six-axis controller and sensors in a co-simulation only."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fmus.common import quaternion
from fmus.common.fmi import FlexFusionSlave
from fmus.common.parameters import param
from fmus.robot_plant.six_axis_model import SixAxisParameters, SixAxisPlant


@dataclass(frozen=True)
class StandInParameters:
    q0: tuple = param((0.0, 0.3, -0.2, 0.4, 0.5, 0.3), "rad", "initial arm angles of axes 1-6")
    ideal: bool = param(True, "1", "the plant's ideal switch (no passive joints, no realism)")
    sensor_offset: tuple = param((0.0, 0.0, 0.0), "m", "the IMU's mount point in the tool frame")


class SixAxisStandIn(FlexFusionSlave):
    """The six-axis plant's reference model as an FMU (test stand-in)."""
    role = "plant"

    parameters_class = StandInParameters
    description = "six-axis plant stand-in (tests)"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.input("tau_m", 6, unit="N.m", description="motor torques, motor side")
        self.input("f_ext", 3, unit="N", description="force on the tool, world")
        self.output("q_m", 6, unit="rad", description="motor angles, motor side")
        self.output("q_a", 6, unit="rad", description="arm angles")
        self.output("p_tool", 3, unit="m", description="tool position, world")
        self.output("quat_tool", 4, unit="1", description="tool orientation (w, x, y, z), tool to world",
                    start=(1.0, 0.0, 0.0, 0.0))
        self.output("omega_tool", 3, unit="rad/s", description="tool angular velocity, world")
        self.output("a_sensor", 3, unit="m/s2", description="acceleration of the IMU's mount point, world")
        self.output("t_state", unit="s", description="time of the outputs")

    def setup(self, p):
        self.plant = SixAxisPlant(SixAxisParameters(q0=tuple(p.q0), ideal=bool(p.ideal)))
        self._v = np.zeros(3)
        self._show(None)

    def _pose(self, q):
        k = self.plant.dyn.kinematics(q)
        t = self.plant.tree.tool
        R = k["R"][t]
        return k["o"][t] + R @ (self.plant.tree.tcp + np.asarray(self.params.sensor_offset, float)), R

    def _show(self, dt):
        pl = self.plant
        q, qm, dq, _, _ = pl.split(pl.x)
        self.q_m[:], self.q_a[:] = qm, q[pl.act]
        self.p_tool[:] = pl.tool_position(pl.x)
        # velocity and angular velocity of the mount point by central differences along dq
        h = 1e-6
        (pp, Rp), (pm, Rm) = self._pose(q + h * dq), self._pose(q - h * dq)
        p0, R = self._pose(q)
        v = (pp - pm) / (2 * h)
        W = (Rp - Rm) / (2 * h) @ R.T
        self.omega_tool[:] = (W[2, 1], W[0, 2], W[1, 0])
        self.quat_tool[:] = quaternion.from_matrix(R)
        self.a_sensor[:] = 0.0 if dt is None else (v - self._v) / dt     # one step's difference
        self._v = v
        self.t_state = pl.t

    def step(self, t, dt):
        f = np.zeros(6)
        f[:3] = self.f_ext
        self.plant.step(np.asarray(self.tau_m, float), f, dt)
        self._show(dt)

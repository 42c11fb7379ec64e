"""Parameters of the plant FMU: the robot plus its initial pose and integration settings."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fmus.common import kinematics
from fmus.common.parameters import ParameterError, fields, param
from fmus.common.robot_params import RobotParameters


@dataclass(frozen=True)
class PlantParameters(RobotParameters):
    """Robot parameters (the true plant), initial pose and RK4 substeps per communication step."""

    q_a0: tuple = param((0.0, 0.0), "rad", "initial arm angles (the robot starts at rest in static "
                        "equilibrium); ignored when p_tool0 is given")
    p_tool0: tuple = param((0.0, 0.0), "m", "initial tool position (x, z), through the inverse "
                           "kinematics; (0, 0) - the axis of joint 2, never reachable - uses q_a0")
    substeps: int = param(1, "1", "RK4 steps per communication step (1 ms steps are accurate to "
                        "well under 1 um: see tests/test_dynamics.py)", low=1, high=1000)

    def robot(self) -> RobotParameters:
        """The robot part of these parameters."""
        return RobotParameters(**{f.name: getattr(self, f.name) for f in fields(RobotParameters)})

    def initial_angles(self) -> np.ndarray:
        """Arm angles at t = 0."""
        if tuple(self.p_tool0) == (0.0, 0.0):
            return np.asarray(self.q_a0, float)
        try:
            return kinematics.inverse_kinematics(self.p_tool0, self)
        except ValueError as exc:
            raise ParameterError(f"parameter 'p_tool0' = {tuple(self.p_tool0)}: {exc}") from None

    def check(self) -> None:
        super().check()
        self.initial_angles()

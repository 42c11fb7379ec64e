"""Parameters of the plant FMU: the robot, its initial pose and integration settings."""
from __future__ import annotations

from dataclasses import dataclass

from fmus.common.parameters import param
from fmus.common.robot_params import RobotAtInitialPose


@dataclass(frozen=True)
class PlantParameters(RobotAtInitialPose):
    """Robot parameters (the true plant), initial pose and RK4 substeps per communication step."""

    substeps: int = param(1, "1", "RK4 steps per communication step (1 ms steps are accurate to "
                          "well under 1 um: see tests/test_dynamics.py)", low=1, high=1000)

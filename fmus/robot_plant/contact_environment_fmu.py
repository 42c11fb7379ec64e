"""FMU adapter of the contact environment: a one-sided spring-damper wall and rubber-hammer
pulses (math in :mod:`fmus.robot_plant.sensor_model`)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fmus.common.fmi import FlexFusionSlave
from fmus.common.parameters import ParameterError, param
from fmus.robot_plant.sensor_model import Wall, contact_force, hammer_force, penetration

PAPER = "García, Robertsson, Gómez Ortega, Johansson (impedance paper)"


@dataclass(frozen=True)
class ContactEnvironmentParameters:
    """Parameters of the ContactEnvironment FMU."""

    enabled: bool = param(True, "1", "whether the wall exists (false: only the hammer pulses act)")
    wall_point: tuple = param((1.30, 0.0), "m", "a point of the wall plane, world x and z",
                              source="the contact study's wall at x = 1.30 m")
    wall_normal: tuple = param((-1.0, 0.0), "1", "normal of the wall plane, world x and z, pointing out "
                               "of the wall into free space (normalised; must not be zero)",
                               low=-1.0, high=1.0)
    stiffness: float = param(5000.0, "N/m", "wall stiffness (5 N/mm)", low=0.0, low_inclusive=False,
                             source=f"{PAPER}, environment of 5 N/mm")
    damping: float = param(50.0, "N.s/m", "wall damping (acts only while in contact, never pulls)",
                           low=0.0, source="assumed: damping ratio about 0.1 with the 12 kg tool")
    hammer_times: tuple = param((0.0, 0.0, 0.0, 0.0), "s", "start times of up to four hammer "
                                "strikes (0 = unused)", low=0.0,
                                source="2009 paper, section IV: rubber-hammer strikes on the tool")
    hammer_force: tuple = param((300.0, 0.0), "N", "peak hammer force ON the tool, world x and z",
                                low=-1e4, high=1e4, source="assumed: a rubber-hammer blow of a few 100 N")
    hammer_duration: float = param(0.005, "s", "duration of a half-sine hammer pulse", low=0.0,
                                   low_inclusive=False, source="assumed: rubber hammer, a few ms")

    def check(self) -> None:
        if math.hypot(*self.wall_normal) < 1e-9:
            raise ParameterError(f"parameter 'wall_normal' = {self.wall_normal} must not be zero")

    def wall(self) -> Wall:
        """The math module's wall."""
        return Wall(point=self.wall_point, normal=self.wall_normal, stiffness=self.stiffness,
                    damping=self.damping, enabled=self.enabled)


class ContactEnvironment(FlexFusionSlave):
    """Force ``f_ext`` ON the tool (world x, z): the wall's one-sided spring-damper force plus the
    hammer pulses at time ``t``; ``penetration`` is the depth of the tool in the wall (0 outside).

    Both outputs depend directly on ``p_tool`` and ``v_tool`` and are recomputed whenever an input
    is set. The hammer pulse is evaluated at the output time, so a master holding ``f_ext``
    over a step samples the half-sine (a 5 ms pulse at a 1 ms step keeps its impulse within a
    few percent).
    """

    parameters_class = ContactEnvironmentParameters
    description = "Contact environment: one-sided spring-damper wall and rubber-hammer pulses"

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.input("p_tool", 2, unit="m", description="tool position, world x and z")
        self.input("v_tool", 2, unit="m/s", description="tool velocity, world x and z")
        self.output("f_ext", 2, unit="N", description="contact force ON the tool, world x and z",
                    depends_on=("p_tool", "v_tool"))
        self.output("penetration", unit="m", description="depth of the tool inside the wall "
                    "(0 outside or without wall)", depends_on=("p_tool",))
        self._wall: Wall | None = None

    def setup(self, p: ContactEnvironmentParameters) -> None:
        self._wall = p.wall()
        self.update_outputs()

    def update_outputs(self) -> None:
        p = self.params
        f = contact_force(self.p_tool, self.v_tool, self._wall)
        f = f + hammer_force(self._time, p.hammer_times, p.hammer_force, p.hammer_duration)
        self.f_ext[:] = f
        self.penetration = max(penetration(self.p_tool, self._wall), 0.0) if p.enabled else 0.0

    def step(self, t: float, dt: float) -> None:
        self._time = t + dt
        self.update_outputs()

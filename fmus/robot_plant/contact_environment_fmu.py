"""FMU adapter of the contact environment: a one-sided spring-damper wall and rubber-hammer
pulses (math in :mod:`fmus.robot_plant.sensor_model`)."""
from __future__ import annotations

from fmus.common.fmi import FlexFusionSlave
from fmus.robot_plant.sensor_model import (ContactEnvironmentParameters, contact_force, hammer_force,
                                           penetration)


class ContactEnvironment(FlexFusionSlave):
    """Force ``f_ext`` ON the tool (world x, z): the wall's one-sided spring-damper force plus the
    hammer pulses at time ``t``; ``penetration`` is the depth of the tool in the wall (0 outside).

    Both outputs depend directly on ``p_tool`` and ``v_tool`` and are recomputed whenever an input
    is set. The hammer pulse is evaluated at the output time, so a master holding ``f_ext``
    over a step samples the half-sine (a 5 ms pulse at a 1 ms step keeps its impulse within a
    few percent).
    """
    role = "environment"

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

    def setup(self, p: ContactEnvironmentParameters) -> None:
        self.update_outputs()

    def update_outputs(self) -> None:
        p = self.params
        f = contact_force(self.p_tool, self.v_tool, p)
        f = f + hammer_force(self._time, p.hammer_times, p.hammer_force, p.hammer_duration)
        self.f_ext[:] = f
        self.penetration = max(penetration(self.p_tool, p), 0.0) if p.enabled else 0.0

    def step(self, t: float, dt: float) -> None:
        self._time = t + dt
        self.update_outputs()

"""FMU adapter of the rubber-hammer force pulses (math in :mod:`fmus.robot_plant.force_pulse_model`)."""
from __future__ import annotations

from fmus.common.fmi import FlexFusionSlave
from fmus.robot_plant.force_pulse_model import ForcePulseParameters, mean_force


class ForcePulse(FlexFusionSlave):
    """Half-sine force pulses ON the tool (world x, z) at configurable times, plus an optional
    force ``f_in`` (e.g. a ContactEnvironment's ``f_ext``) passed through and added.

    After ``do_step(t, dt)`` the pulse part of ``f_ext`` is the mean of the pulses over the next
    step ``[t + dt, t + 2 dt]`` (the step assumed constant), so a master holding it over a step
    delivers each strike's impulse exactly; before the first step it is the value at the start
    time. ``f_ext`` depends directly on ``f_in``.
    """
    role = "environment"

    parameters_class = ForcePulseParameters
    description = "Rubber-hammer force pulses on the tool (half-sine), optionally added to f_in"

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.input("f_in", 2, unit="N", description="force ON the tool from elsewhere, world x and z "
                   "(added; 0 when unconnected)")
        self.output("f_ext", 2, unit="N", description="force ON the tool, world x and z: pulses plus f_in",
                    depends_on=("f_in",))
        self.output("f_pulse", unit="N", description="pulse force along the direction (mean over the step)")
        self._dt = 0.0

    def setup(self, p: ForcePulseParameters) -> None:
        self._n = p.unit_direction()
        self._pulse(self._time)

    def _pulse(self, t: float) -> None:
        p = self.params
        self.f_pulse = mean_force(t, self._dt, p.times, p.amplitudes, p.duration)
        self.update_outputs()

    def update_outputs(self) -> None:
        self.f_ext[:] = self.f_in + self.f_pulse * self._n

    def step(self, t: float, dt: float) -> None:
        self._dt = dt
        self._pulse(t + dt)

"""FMU adapter of the wrist force/torque sensor between the robot and the tool (force part;
math in :mod:`fmus.robot_plant.sensor_model`; the impedance paper's eq. 1)."""
from __future__ import annotations

from fmus.common.fmi import FlexFusionSlave
from fmus.common.frames import G
from fmus.robot_plant.sensor_model import (ForceTorqueSensorParameters, SensorChannels,
                                           force_sensor_reading, reseed, sensor_channels)


class ForceTorqueSensor(FlexFusionSlave):
    """Wrist force in the sensor frame ``f_s = R_s^T (m_tool (a_tool - g_vec) - f_ext)`` with the
    sensor imperfections; ``saturated`` is 1 when a component is at or beyond ``f_range``.

    No direct feedthrough: the reading at ``t + dt`` is the sample of the inputs held over
    ``[t, t + dt)``. Right after initialisation the output is the noise-free reading of the
    initial inputs (at rest in free space: ``m_tool g`` on sensor z). The sample-period and
    cut-off checks need the communication step and so happen at the first ``doStep``. The
    tunable ``reseed`` restarts the noise streams from a new seed (:mod:`fmus.common.noise`).
    """
    role = "sensor"

    parameters_class = ForceTorqueSensorParameters
    description = "Wrist force sensor: contact force + tool inertia + tool weight, sensor frame"

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.input("f_ext", 2, unit="N", description="contact force ON the tool, world x and z")
        self.input("a_tool", 2, unit="m/s2", description="tool acceleration, world x and z")
        self.input("phi_tool", unit="rad", description="tool angle about world y")
        self.output("f_s", 3, unit="N", description="measured wrist force, sensor frame",
                    start=(0.0, 0.0, 12.0 * G))
        self.output("saturated", unit="1", description="1 when a force component is at or beyond "
                    "the range f_range, else 0 (diagnostic)")
        self.channels: SensorChannels | None = None

    def _ideal(self):
        p = self.params
        return force_sensor_reading(self.f_ext, self.a_tool, self.phi_tool, p.m_tool, p.mount_rpy, p.g)

    def setup(self, p: ForceTorqueSensorParameters) -> None:
        self.channels = sensor_channels(p)
        self.f_s[:] = self.channels.initial(self._ideal())
        self.saturated = float(self.channels.saturated.any())
        self.tuned("reseed")

    def tuned(self, name: str) -> None:
        if name == "reseed":
            reseed(self.params.reseed, self.channels)

    def step(self, t: float, dt: float) -> None:
        self.f_s[:] = self.channels.step(self._ideal(), dt)
        self.saturated = float(self.channels.saturated.any())

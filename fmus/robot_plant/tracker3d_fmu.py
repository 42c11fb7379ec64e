"""FMU adapter of the reference measurement system, a laser tracker, for a tool moving in 3-D
(math in :mod:`fmus.robot_plant.tracker_model`)."""
from __future__ import annotations

from fmus.common.fmi import FlexFusionSlave
from fmus.robot_plant.sensor_model import T_TRUTH_DESCRIPTION, UNSTAMPED, input_time, reseed
from fmus.robot_plant.tracker_model import TrackerModel, TrackerParameters


class Tracker3D(FlexFusionSlave):
    """Measured tool position ``p_tool_meas = p_tool(t_meas - skew) + noise`` in world x, y, z,
    sampled at ``sample_rate`` and held; ``t_meas`` is the sample's time stamp on the
    controller's clock: the Tracker's model and timing (``t_truth``: the plant's ``t_state``;
    unconnected, the end of the step) with three coordinates. No direct feedthrough. The
    tunable ``reseed`` restarts the noise stream from a new seed.
    """
    role = "reference"

    parameters_class = TrackerParameters
    description = "Laser tracker (reference system) in 3-D: noisy, sampled, time-skewed tool position"

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.input("p_tool", 3, unit="m", description="true tool position, world x, y, z",
                   start=(1.2, 0.0, 0.9))
        self.input("t_truth", unit="s", start=UNSTAMPED, description=T_TRUTH_DESCRIPTION)
        self.output("p_tool_meas", 3, unit="m", description="measured tool position, world x, y, z",
                    start=(1.2, 0.0, 0.9))
        self.output("t_meas", unit="s", description="time stamp of the held measurement "
                    "(controller clock)")
        self.model: TrackerModel | None = None

    def setup(self, p: TrackerParameters) -> None:
        self.model = TrackerModel(p.noise, p.sample_rate, p.skew, seed=p.seed, out=self.p_tool_meas, dims=3)
        self.model.start(input_time(self._time, 0.0, self.t_truth), self.p_tool)
        self.t_meas = self.model.t_meas
        self.tuned("reseed")

    def tuned(self, name: str) -> None:
        if name == "reseed":
            reseed(self.params.reseed, self.model)

    def step(self, t: float, dt: float) -> None:
        self.model.update(input_time(t, dt, self.t_truth), self.p_tool)      # into p_tool_meas
        self.t_meas = self.model.t_meas

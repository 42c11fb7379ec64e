"""FMU adapter of the reference measurement system, a laser tracker (math in
:mod:`fmus.robot_plant.tracker_model`)."""
from __future__ import annotations

from fmus.common.fmi import FlexFusionSlave
from fmus.robot_plant.sensor_model import T_TRUTH_DESCRIPTION, UNSTAMPED, input_time, reseed
from fmus.robot_plant.tracker_model import TrackerModel, TrackerParameters


class Tracker(FlexFusionSlave):
    """Measured tool position ``p_tool_meas = p_tool(t_meas - skew) + noise``, sampled at
    ``sample_rate`` and held; ``t_meas`` is the sample's time stamp on the controller's clock.

    Timing: the input set before ``doStep(t, dt)`` is the position at the plant's ``t_state``
    when that is connected to ``t_truth``, right under any master; unconnected, at ``t + dt`` (a
    Gauss-Seidel master, ours, steps the plant first; the convention of every sensor,
    :func:`~fmus.robot_plant.sensor_model.input_time`), which a Jacobi master (libcosim, which
    hands over the position at ``t``) makes one communication step too new. After
    initialisation the input is the position at ``t_truth`` or the start time.
    No direct feedthrough. The tunable ``reseed`` restarts the noise stream from a new seed
    (:mod:`fmus.common.noise`).
    """
    role = "reference"

    parameters_class = TrackerParameters
    description = "Laser tracker (reference system): noisy, sampled, time-skewed tool position"

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.input("p_tool", 2, unit="m", description="true tool position, world x and z",
                   start=(1.2, 0.9))
        self.input("t_truth", unit="s", start=UNSTAMPED, description=T_TRUTH_DESCRIPTION)
        self.output("p_tool_meas", 2, unit="m", description="measured tool position, world x and z",
                    start=(1.2, 0.9))
        self.output("t_meas", unit="s", description="time stamp of the held measurement "
                    "(controller clock)")
        self.model: TrackerModel | None = None

    def setup(self, p: TrackerParameters) -> None:
        self.model = TrackerModel(p.noise, p.sample_rate, p.skew, seed=p.seed, out=self.p_tool_meas)
        self.model.start(input_time(self._time, 0.0, self.t_truth), self.p_tool)
        self.t_meas = self.model.t_meas
        self.tuned("reseed")

    def tuned(self, name: str) -> None:
        if name == "reseed":
            reseed(self.params.reseed, self.model)

    def step(self, t: float, dt: float) -> None:
        self.model.update(input_time(t, dt, self.t_truth), self.p_tool)      # into p_tool_meas
        self.t_meas = self.model.t_meas

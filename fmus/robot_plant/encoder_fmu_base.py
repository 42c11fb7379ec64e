"""The Encoder FMUs' adapter (:class:`EncoderSlave`), for any number of motor-side angle
encoders: the Encoder FMU (``encoder_fmu.py``, joints 2 and 3) and the Encoder6 FMU
(``encoder6_fmu.py``, axes 1-6) are it with their channel count (math in
:mod:`fmus.robot_plant.sensor_model`)."""
from __future__ import annotations

from fmus.common.fmi import FlexFusionSlave
from fmus.robot_plant.sensor_model import (EncoderParameters, SensorChannels, T_TRUTH_DESCRIPTION,
                                           UNSTAMPED, input_time, reseed)


class EncoderSlave(FlexFusionSlave):
    """Motor angle measurement ``q_m_meas`` of ``axes`` joints (class attribute) (quantised, noisy, sampled).

    No direct feedthrough: the reading at ``t + dt`` is the sample of the input set before
    ``doStep(t, dt)``, stamped in ``t_meas`` with the time that input stands for: the plant's
    ``t_state`` when connected to ``t_truth``, else ``t + dt``
    (:func:`~fmus.robot_plant.sensor_model.input_time`, the Tracker's convention); ``t_meas``
    holds with the reading between samples. Right after initialisation the output is the
    noise-free reading of the initial input, stamped with ``t_truth`` or the start time. The
    check that the sample period is a multiple of the communication step happens at the first
    ``doStep`` (an FMU does not know its step before), which then fails with a message naming
    ``sample_rate``. The tunable ``reseed`` restarts the noise streams from a new seed
    (:mod:`fmus.common.noise`).
    """
    role = "sensor"
    axes = 2                     #: the number of channels

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.input("q_m", self.axes, unit="rad", description="true motor angle, motor side")
        self.input("t_truth", unit="s", start=UNSTAMPED, description=T_TRUTH_DESCRIPTION)
        self.output("q_m_meas", self.axes, unit="rad", description="measured motor angle, motor side")
        self.output("t_meas", unit="s", description="time the held sample was taken (the time "
                    "its input stands for)")
        self.channels: SensorChannels | None = None

    def setup(self, p: EncoderParameters) -> None:
        self.channels = SensorChannels(
            self.axes, seed=p.seed, stream="encoder", noise=p.noise, bias=p.bias, bias_rw=p.bias_rw,
            scale=p.scale, resolution=p.resolution, sample_rate=p.sample_rate, cutoff=p.cutoff,
            filter_order=p.filter_order, out=self.q_m_meas)
        self.channels.initial(self.q_m, input_time(self._time, 0.0, self.t_truth))
        self.t_meas = self.channels.t_meas
        self.tuned("reseed")

    def tuned(self, name: str) -> None:
        if name == "reseed":
            reseed(self.params.reseed, self.channels)

    def step(self, t: float, dt: float) -> None:
        self.channels.step(self.q_m, dt, input_time(t, dt, self.t_truth))     # into q_m_meas
        self.t_meas = self.channels.t_meas

"""FMU adapter of the six-axis robot's motor-side angle encoders, axes 1-6:
:class:`fmus.robot_plant.encoder_fmu_base.EncoderSlave` with six channels (math in
:mod:`fmus.robot_plant.sensor_model`)."""
from __future__ import annotations

from fmus.robot_plant import encoder_fmu_base as base
from fmus.robot_plant.sensor_model import Encoder6Parameters


class Encoder6(base.EncoderSlave):
    """Motor angle measurement ``q_m_meas`` of axes 1-6 (quantised, noisy, sampled): the
    Encoder's channels, timing and stamps (``t_meas``), six of them; each drive of the
    MotionController6 reads its own."""
    role = "sensor"
    axes = 6

    parameters_class = Encoder6Parameters
    description = "Motor-side angle encoders of axes 1-6: quantisation, noise, sample-and-hold"

"""FMU adapter of the motor-side angle encoders of joints 2 and 3: :class:`fmus.robot_plant.
encoder_fmu_base.EncoderSlave` with two channels (math in :mod:`fmus.robot_plant.sensor_model`)."""
from __future__ import annotations

from fmus.robot_plant import encoder_fmu_base as base
from fmus.robot_plant.sensor_model import EncoderParameters


class Encoder(base.EncoderSlave):
    """Motor angle measurement ``q_m_meas`` of joints 2 and 3 (quantised, noisy, sampled).

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
    batched = "Encoder"
    axes = 2

    parameters_class = EncoderParameters
    description = "Motor-side angle encoders of joints 2 and 3: quantisation, noise, sample-and-hold"

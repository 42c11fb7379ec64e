"""FMU adapter of the tool-mounted IMU: 3-axis accelerometer (specific force) and 3-axis gyro in
the sensor frame (math in :mod:`fmus.robot_plant.sensor_model`; the 2012 paper's accelerometer
model, eqs. 17-19)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fmus.common.fmi import FlexFusionSlave
from fmus.common.parameters import param
from fmus.common.frames import G
from fmus.robot_plant.sensor_model import (T_TRUTH_DESCRIPTION, UNSTAMPED, SensorChannels, imu_reading,
                                           input_time)

MEMS = ("16-bit MEMS IMU class (e.g. Bosch BMI160 / TDK ICM-20948 data sheets: +-16 g, "
        "+-2000 deg/s, 16-bit output)")
CALIBRATION = ("assumed, no user calibration: within the sensitivity tolerances of MEMS data sheets "
               "(BMI160 / ICM-20948 class: about 0.5-1.5 %)")
MOUNTING = "assumed: mounting tolerance of a bracket on the tool, about 0.1-0.3 deg"
ACC_RANGE = 16.0 * G
GYRO_RANGE = math.radians(2000.0)


@dataclass(frozen=True)
class ImuParameters:
    """Parameters of the Imu FMU."""

    mount_rpy: tuple = param((0.004, 0.003, -0.003), "rad", "mounting roll, pitch, yaw of the sensor "
                             "on the tool (R_mount = Rz(yaw) Ry(pitch) Rx(roll), sensor to tool); the "
                             "default is a misalignment the filters do not know (0 = ideal)",
                             low=-math.pi, high=math.pi, source=MOUNTING)
    acc_noise: float = param(0.02, "m/s2", "accelerometer white noise std per sample", low=0.0,
                             source="about 150 ug/sqrt(Hz) over a 200 Hz bandwidth (MEMS class)")
    acc_bias: tuple = param((0.0, 0.0, 0.0), "m/s2", "accelerometer constant bias per axis "
                            "(after calibration: 0)", low=-ACC_RANGE, high=ACC_RANGE,
                            source="2012 paper: offset calibrated (Axelsson and Norrlof 2012)")
    acc_bias_rw: float = param(1e-3, "m/s2/s0.5", "accelerometer bias random-walk intensity per sqrt(s)",
                               low=0.0, source="assumed: a few mm/s2 drift over 10 s (MEMS class)")
    acc_scale: tuple = param((0.003, -0.004, 0.002), "1", "accelerometer scale-factor error per axis "
                             "(0 = ideal)", low=-0.5, high=0.5, source=CALIBRATION)
    acc_resolution: float = param(2.0 * ACC_RANGE / 2 ** 16, "m/s2", "accelerometer quantisation step "
                                  "(16 bit over +-16 g; 0 = off)", low=0.0, source=MEMS)
    acc_range: float = param(ACC_RANGE, "m/s2", "accelerometer range (16 g): readings saturate at it",
                             low=0.0, low_inclusive=False, source=MEMS)
    acc_cutoff: float = param(200.0, "Hz", "accelerometer anti-aliasing low-pass cut-off (0 = off); "
                              "must be below the Nyquist frequency of the communication step", low=0.0,
                              source="MEMS digital low-pass about ODR/4; the 2012 paper low-pass filters "
                              "the accelerometer")
    gyro_noise: float = param(0.005, "rad/s", "gyro white noise std per sample", low=0.0,
                              source="about 0.015 deg/s/sqrt(Hz) over 400 Hz (MEMS class)")
    gyro_bias: tuple = param((0.0, 0.0, 0.0), "rad/s", "gyro constant bias per axis (calibrated: 0)",
                             low=-GYRO_RANGE, high=GYRO_RANGE)
    gyro_bias_rw: float = param(1e-4, "rad/s/s0.5", "gyro bias random-walk intensity per sqrt(s)",
                                low=0.0, source="assumed, MEMS class")
    gyro_scale: tuple = param((-0.004, 0.005, 0.003), "1", "gyro scale-factor error per axis (0 = ideal)",
                              low=-0.5, high=0.5, source=CALIBRATION)
    gyro_resolution: float = param(2.0 * GYRO_RANGE / 2 ** 16, "rad/s", "gyro quantisation step "
                                   "(16 bit over +-2000 deg/s; 0 = off)", low=0.0, source=MEMS)
    gyro_range: float = param(GYRO_RANGE, "rad/s", "gyro range (2000 deg/s)", low=0.0,
                              low_inclusive=False, source=MEMS)
    gyro_cutoff: float = param(200.0, "Hz", "gyro anti-aliasing low-pass cut-off (0 = off)", low=0.0,
                               source=MEMS)
    filter_order: int = param(2, "1", "anti-aliasing filter order (1 or 2, Butterworth)", low=1, high=2)
    sample_rate: float = param(0.0, "Hz", "sample rate with sample-and-hold (0 = every communication "
                               "step; the papers sample at 2 kHz). Its period must be an integer "
                               "multiple of the communication step", low=0.0,
                               source="2009 and 2012 papers: 2 kHz")
    g: float = param(G, "m/s2", "gravity", low=0.0)
    seed: int = param(2, "1", "seed of the noise streams", low=0)


class Imu(FlexFusionSlave):
    """Specific force ``acc_s = R_s^T (a - g_vec)`` and rate ``gyro_s = R_s^T (0, omega, 0)`` in the
    sensor frame, ``R_s = Ry(phi_tool) R_mount``, with the sensor imperfections.

    No direct feedthrough: the reading at ``t + dt`` is the sample of the inputs set before
    ``doStep(t, dt)``, stamped in ``t_meas`` with the time they stand for: the plant's
    ``t_state`` when connected to ``t_truth``, else ``t + dt``
    (:func:`~fmus.robot_plant.sensor_model.input_time`; accelerometer and gyro sample together).
    Right after initialisation the outputs are the noise-free readings of the initial inputs
    (at rest: +g on sensor z), stamped with ``t_truth`` or the start time. The sample-period and
    cut-off checks need the communication step and so happen at the first ``doStep``.
    """

    parameters_class = ImuParameters
    description = "Tool IMU: 3-axis accelerometer (specific force) and 3-axis gyro, sensor frame"

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.input("a_sensor", 2, unit="m/s2", description="acceleration of the mount point, world x and z")
        self.input("phi_tool", unit="rad", description="tool angle about world y")
        self.input("omega_tool", unit="rad/s", description="tool angular velocity about world y")
        self.input("t_truth", unit="s", start=UNSTAMPED, description=T_TRUTH_DESCRIPTION)
        self.output("acc_s", 3, unit="m/s2", description="measured specific force, sensor frame",
                    start=(0.0, 0.0, G))
        self.output("gyro_s", 3, unit="rad/s", description="measured angular rate, sensor frame")
        self.output("t_meas", unit="s", description="time the held sample was taken (the time "
                    "its inputs stand for)")
        self.acc: SensorChannels | None = None
        self.gyro: SensorChannels | None = None

    def _ideal(self) -> tuple[np.ndarray, np.ndarray]:
        return imu_reading(self.a_sensor, self.phi_tool, self.omega_tool, self.params.mount_rpy, self.params.g)

    def setup(self, p: ImuParameters) -> None:
        self.acc = SensorChannels(
            3, seed=p.seed, stream="imu/acc", noise=p.acc_noise, bias=p.acc_bias, bias_rw=p.acc_bias_rw,
            scale=p.acc_scale, resolution=p.acc_resolution, range=p.acc_range, sample_rate=p.sample_rate,
            cutoff=p.acc_cutoff, filter_order=p.filter_order, names={"cutoff": "acc_cutoff"})
        self.gyro = SensorChannels(
            3, seed=p.seed, stream="imu/gyro", noise=p.gyro_noise, bias=p.gyro_bias,
            bias_rw=p.gyro_bias_rw, scale=p.gyro_scale, resolution=p.gyro_resolution,
            range=p.gyro_range, sample_rate=p.sample_rate, cutoff=p.gyro_cutoff,
            filter_order=p.filter_order, names={"cutoff": "gyro_cutoff"})
        acc, gyro = self._ideal()
        t0 = input_time(self._time, 0.0, self.t_truth)
        self.acc_s[:] = self.acc.initial(acc, t0)
        self.gyro_s[:] = self.gyro.initial(gyro, t0)
        self.t_meas = self.acc.t_meas

    def step(self, t: float, dt: float) -> None:
        acc, gyro = self._ideal()
        t_in = input_time(t, dt, self.t_truth)
        self.acc_s[:] = self.acc.step(acc, dt, t_in)
        self.gyro_s[:] = self.gyro.step(gyro, dt, t_in)
        self.t_meas = self.acc.t_meas

"""FMU adapter of the tool-mounted IMU: 3-axis accelerometer (specific force) and 3-axis gyro in
the sensor frame (math in :mod:`fmus.robot_plant.sensor_model`; the 2012 paper's accelerometer
model, eqs. 17-19)."""
from __future__ import annotations

import numpy as np

from fmus.common.fmi import FlexFusionSlave
from fmus.common.frames import G
from fmus.robot_plant.sensor_model import (ImuParameters, SensorChannels, T_TRUTH_DESCRIPTION, UNSTAMPED,
                                           imu_reading_into, input_time, mount_matrix, reseed)


class Imu(FlexFusionSlave):
    """Specific force ``acc_s = R_s^T (a - g_vec)`` and rate ``gyro_s = R_s^T (0, omega, 0)`` in the
    sensor frame, ``R_s = Ry(phi_tool) R_mount``, with the sensor imperfections.

    No direct feedthrough: the reading at ``t + dt`` is the sample of the inputs set before
    ``doStep(t, dt)``, stamped in ``t_meas`` with the time they stand for: the plant's
    ``t_state`` when connected to ``t_truth``, else ``t + dt``
    (:func:`~fmus.robot_plant.sensor_model.input_time`; accelerometer and gyro sample together).
    Right after initialisation the outputs are the noise-free readings of the initial inputs
    (at rest: +g on sensor z), stamped with ``t_truth`` or the start time. The sample-period and
    cut-off checks need the communication step and so happen at the first ``doStep``. The
    tunable ``reseed`` restarts both sensors' noise streams from a new seed
    (:mod:`fmus.common.noise`).
    """
    role = "sensor"
    batched = "Imu"

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
        imu_reading_into(self.a_sensor, self.phi_tool, self.omega_tool, self._mount, self.params.g, self._acc,
                         self._gyro)
        return self._acc, self._gyro

    def setup(self, p: ImuParameters) -> None:
        self._mount = mount_matrix(tuple(p.mount_rpy))
        self._acc, self._gyro = np.empty(3), np.empty(3)       # the ideal readings
        self.acc = SensorChannels(
            3, seed=p.seed, stream="imu/acc", noise=p.acc_noise, bias=p.acc_bias, bias_rw=p.acc_bias_rw,
            scale=p.acc_scale, resolution=p.acc_resolution, range=p.acc_range, sample_rate=p.sample_rate,
            cutoff=p.acc_cutoff, filter_order=p.filter_order, names={"cutoff": "acc_cutoff"}, out=self.acc_s)
        self.gyro = SensorChannels(
            3, seed=p.seed, stream="imu/gyro", noise=p.gyro_noise, bias=p.gyro_bias,
            bias_rw=p.gyro_bias_rw, scale=p.gyro_scale, resolution=p.gyro_resolution,
            range=p.gyro_range, sample_rate=p.sample_rate, cutoff=p.gyro_cutoff,
            filter_order=p.filter_order, names={"cutoff": "gyro_cutoff"}, out=self.gyro_s)
        acc, gyro = self._ideal()
        t0 = input_time(self._time, 0.0, self.t_truth)
        self.acc.initial(acc, t0)
        self.gyro.initial(gyro, t0)
        self.t_meas = self.acc.t_meas
        self.tuned("reseed")

    def tuned(self, name: str) -> None:
        if name == "reseed":
            reseed(self.params.reseed, self.acc, self.gyro)

    def step(self, t: float, dt: float) -> None:
        acc, gyro = self._ideal()
        t_in = input_time(t, dt, self.t_truth)
        self.acc.step(acc, dt, t_in)            # the readings into acc_s and gyro_s
        self.gyro.step(gyro, dt, t_in)
        self.t_meas = self.acc.t_meas

"""FMU adapter of the six-axis robot's tool-mounted IMU: 3-axis accelerometer (specific force)
and 3-axis gyro in the sensor frame of a tool moving in 3-D, and the same readings in the frame
of the axis-2/3 estimators (math in :mod:`fmus.robot_plant.sensor_model`)."""
from __future__ import annotations

import numpy as np

from fmus.common.fmi import FlexFusionSlave
from fmus.common.frames import G
from fmus.robot_plant.sensor_model import (ImuParameters, SensorChannels, T_TRUTH_DESCRIPTION, UNSTAMPED,
                                           imu_reading_3d, input_time, mount_matrix, reseed)


class Imu3D(FlexFusionSlave):
    """Specific force ``acc_s = R_s^T (a - g_vec)`` and rate ``gyro_s = R_s^T omega`` in the
    sensor frame, ``R_s = R_tool R_mount`` (``R_tool`` from ``quat_tool``), with the sensor
    imperfections and defaults of the two-axis Imu (noise, bias random walk, scale, resolution,
    range, anti-aliasing, sample-and-hold: :class:`~fmus.robot_plant.sensor_model.ImuParameters`).

    Timing as every sensor's: no direct feedthrough; the reading at ``t + dt`` is the sample of
    the inputs set before ``doStep(t, dt)``, stamped in ``t_meas`` with the plant's ``t_state``
    when connected to ``t_truth``, else ``t + dt``. After initialisation the outputs are the
    noise-free readings of the initial inputs. For the axis-2/3 estimators the readings are
    rotated into their frame by the wrist's measured angles, as on the real robots
    (:func:`~fmus.robot_plant.sensor_model.arm_plane_reading`, done by the estimator's side
    from the encoders, not here). The tunable ``reseed`` restarts both sensors' noise streams.
    """
    role = "sensor"

    parameters_class = ImuParameters
    description = "Six-axis tool IMU: 3-axis accelerometer (specific force) and 3-axis gyro in 3-D, sensor frame"

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.input("a_sensor", 3, unit="m/s2", description="kinematic acceleration of the mount point "
                   "(no gravity), world x, y, z")
        self.input("quat_tool", 4, unit="1", description="tool orientation, unit quaternion (w, x, y, z), "
                   "tool frame to world", start=(1.0, 0.0, 0.0, 0.0))
        self.input("omega_tool", 3, unit="rad/s", description="tool angular velocity, world x, y, z")
        self.input("t_truth", unit="s", start=UNSTAMPED, description=T_TRUTH_DESCRIPTION)
        self.output("acc_s", 3, unit="m/s2", description="measured specific force, sensor frame",
                    start=(0.0, 0.0, G))
        self.output("gyro_s", 3, unit="rad/s", description="measured angular rate, sensor frame")
        self.output("t_meas", unit="s", description="time the held sample was taken (the time "
                    "its inputs stand for)")
        self.acc: SensorChannels | None = None
        self.gyro: SensorChannels | None = None

    def _ideal(self) -> tuple[np.ndarray, np.ndarray]:
        q = np.asarray(self.quat_tool, float)
        n = float(np.sqrt(q @ q))
        if not n > 0.0:
            raise ValueError(f"input 'quat_tool' = {tuple(q)} is not a rotation")
        return imu_reading_3d(self.a_sensor, q / n, self.omega_tool, self._mount, self.params.g)

    def setup(self, p: ImuParameters) -> None:
        self._mount = mount_matrix(tuple(p.mount_rpy))
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

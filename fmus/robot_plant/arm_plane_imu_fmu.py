"""FMU adapter giving the axis-2/3 estimators the six-axis robot's IMU readings in their plane,
as on the real robots: the readings rotated by the wrist's measured angles (math in
:func:`fmus.robot_plant.sensor_model.arm_plane_reading`)."""
from __future__ import annotations

import numpy as np

from fmus.common.fmi import FlexFusionSlave
from fmus.common.frames import G
from fmus.robot_plant.sensor_model import ArmPlaneImuParameters, arm_plane_reading, mount_matrix


class ArmPlaneImu(FlexFusionSlave):
    """The Imu3D's readings ``acc_s``, ``gyro_s`` (sensor frame) in the frame of a tool with the
    wrist at zero (x along the forearm and z in the plane of axes 2-3, y along axes 2-3), the
    frame the axis-2/3 estimators' accelerometer model takes: rotated by the wrist's angles
    measured by the drives' encoders (``q_m`` of axes 1-6 from an Encoder6, axes 4-6 over
    their ``gear_ratio``) with the nominal ``mount_rpy``. Direct feedthrough; no state. A
    pre-processor on the estimators' side: it reads only sensors.
    """
    role = "estimator"

    parameters_class = ArmPlaneImuParameters
    description = "Six-axis IMU readings rotated by the measured wrist angles into the plane of axes 2-3"

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.input("acc_s", 3, unit="m/s2", description="measured specific force, sensor frame",
                   start=(0.0, 0.0, G))
        self.input("gyro_s", 3, unit="rad/s", description="measured angular rate, sensor frame")
        self.input("q_m", 6, unit="rad", description="measured motor angles of axes 1-6, motor side")
        feed = ("acc_s", "gyro_s", "q_m")
        self.output("acc_arm", 3, unit="m/s2", description="specific force in the frame of axes 2-3 "
                    "(x, z in their plane)", start=(0.0, 0.0, G), depends_on=feed)
        self.output("gyro_arm", 3, unit="rad/s", description="angular rate in the frame of axes 2-3 "
                    "(y along their axes)", depends_on=feed)

    def setup(self, p: ArmPlaneImuParameters) -> None:
        self._mount = mount_matrix(tuple(p.mount_rpy))
        self._ratio = np.asarray(p.gear_ratio, float)
        self.update_outputs()

    def update_outputs(self) -> None:
        acc, gyro = arm_plane_reading(self.acc_s, self.gyro_s, np.asarray(self.q_m[3:], float) / self._ratio,
                                      self._mount)
        self.acc_arm[:] = acc
        self.gyro_arm[:] = gyro

    def step(self, t: float, dt: float) -> None:
        self.update_outputs()

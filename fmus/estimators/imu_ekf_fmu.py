"""FMU adapter of the IMU EKF (IMU paper, section 4.2, eqs. 3-4).

The math is in :mod:`fmus.estimators.imu_ekf_model` (3-D, error-state quaternion); this adapter
maps the planar kinematic pose (world x, z and the angle about +y) to 3-D and back.

Timing: no direct feedthrough. ``do_step(t, T)`` fuses the inputs present at the call at the
time they were taken, the optional input ``t_meas`` (the Imu's output; the kinematic pose counts
as taken with it), and outputs the estimate predicted on to ``t + T``
(:mod:`fmus.common.filter_adapter`). Unconnected, the inputs count as the measurements at
``t + T``: on time under a Gauss-Seidel master. The initial inputs start the filter.
"""
from __future__ import annotations

import copy

import numpy as np

from fmus.estimators import imu_ekf_model as iem
from fmus.estimators.imu_pose_adapter import ImuPoseAdapter


class ImuEkf(ImuPoseAdapter):
    """Tool pose from forward kinematics and a tool IMU by an error-state EKF with position,
    velocity, acceleration, orientation, angular rate and IMU bias states.

    Divergence (a non-finite state, a covariance that is not positive definite) ends the step
    with an FMI error status naming the cause, and so does every later step; the outputs keep
    the last good estimate (never NaN) and stay readable.
    """

    parameters_class = iem.ImuEkfParameters
    description = "EKF of the tool pose from forward kinematics and a tool IMU (bias states)"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.output("b_acc_hat", 3, unit="m/s2", description="accelerometer bias estimate, sensor frame")
        self.output("b_gyro_hat", 3, unit="rad/s", description="gyro bias estimate, sensor frame")
        self.output("std_position", unit="m", description="filter's position standard deviation "
                    "(root of the trace of the position covariance)")
        self.output("nis", unit="1", description="normalised innovation squared of the last update")

    def setup(self, params: iem.ImuEkfParameters) -> None:
        ekf = iem.ImuEkfModel(params)
        ekf.reset(*self._pose(), self.acc_s, self.gyro_s)
        self.start_fusion(ekf)

    def _fused(self, prior: iem.ImuEkfModel) -> iem.ImuEkfModel:
        est = copy.copy(prior)
        est.update(*self._pose(), self.acc_s, self.gyro_s)
        return est

    def _show(self, e: iem.ImuEkfModel) -> None:
        self._show_pose(e.mount, e.p, e.q)
        self.b_acc_hat[:] = e.b_acc
        self.b_gyro_hat[:] = e.b_gyro
        self.std_position = float(np.sqrt(np.trace(e.P[0:3, 0:3])))
        self.nis = e.nis

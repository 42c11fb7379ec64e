"""FMU adapter of the complementary filter (IMU paper, section 4.1, eqs. 1-2).

The math is in :mod:`fmus.estimators.complementary_filter_model` (3-D, quaternions); this
adapter maps the planar kinematic pose (world x, z and the angle about +y) to 3-D and back.

Timing: no direct feedthrough. ``do_step(t, T)`` fuses the inputs present at the call at the
time they were taken, the optional input ``t_meas`` (the Imu's output; the kinematic pose counts
as taken with it), and outputs the estimate predicted on to ``t + T`` (the last rate and
acceleration held; :mod:`fmus.common.filter_adapter`). Unconnected, the inputs count as the
sample at ``t + T``: on time under a Gauss-Seidel master, which sets the producers' values of
``t + T`` before this step. At initialisation the filter starts at the kinematic pose of the
initial inputs, at rest.
"""
from __future__ import annotations

import copy
import math

from fmus.common.kalman import FilterDivergence
from fmus.common.sample_time import span
from fmus.estimators import complementary_filter_model as cfm
from fmus.estimators.imu_pose_adapter import ImuPoseAdapter


class ComplementaryFilter(ImuPoseAdapter):
    """Tool pose from forward kinematics and a tool IMU by a distortionless second-order
    complementary split (cut-off and damping are parameters)."""

    parameters_class = cfm.ComplementaryFilterParameters
    description = "Complementary filter: forward-kinematics pose fused with a tool IMU (distortionless)"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.output("v_hat", 3, unit="m/s", description="estimated velocity of the IMU point, world")
        self.output("b_gyro_hat", 3, unit="rad/s", description="gyro bias estimate, sensor frame")

    def setup(self, params: cfm.ComplementaryFilterParameters) -> None:
        model = cfm.ComplementaryFilterModel(params)
        model.reset(*self._pose(), self.acc_s, self.gyro_s)
        self.start_fusion(model)

    def _advanced(self, est: cfm.ComplementaryFilterModel, t0: float, t1: float) -> cfm.ComplementaryFilterModel:
        # one sample over the whole interval: the gyro and accelerometer readings enter the
        # prediction (trapezoidal, from the last sample), so it cannot run without them
        est = copy.copy(est)
        est.step(*self._pose(), self.acc_s, self.gyro_s, span(t0, t1))
        if not math.isfinite(float(est.p_s.sum() + est.q_s.sum())):
            raise FilterDivergence(f"the estimate became non-finite at t = {t1:.6g} s")
        return est

    def _show(self, m: cfm.ComplementaryFilterModel) -> None:
        self._show_pose(m.mount, m.p_s, m.q_s)
        self.v_hat[:] = m.v_s
        self.b_gyro_hat[:] = m.b_gyro

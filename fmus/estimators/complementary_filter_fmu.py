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

from fmus.common import quaternion as qt
from fmus.common.filter_adapter import FilterAdapter
from fmus.common.frames import G, planar_pose
from fmus.common.kalman import FilterDivergence
from fmus.common.sample_time import span
from fmus.estimators import complementary_filter_model as cfm


class ComplementaryFilter(FilterAdapter):
    """Tool pose from forward kinematics and a tool IMU by a distortionless second-order
    complementary split (cut-off and damping are parameters)."""

    parameters_class = cfm.ComplementaryFilterParameters
    description = "Complementary filter: forward-kinematics pose fused with a tool IMU (distortionless)"
    feedthrough = False

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.input("p_fk", 2, unit="m", description="forward-kinematics tool position, world x and z")
        self.input("phi_fk", unit="rad", description="forward-kinematics tool angle about world y")
        self.input("acc_s", 3, unit="m/s2", description="IMU specific force, sensor frame",
                   start=(0.0, 0.0, G))
        self.input("gyro_s", 3, unit="rad/s", description="IMU angular rate, sensor frame")
        self.declare_t_meas()
        self.output("p_tool_hat", 2, unit="m", description="estimated tool position, world x and z")
        self.output("phi_tool_hat", unit="rad", description="estimated tool angle about world y")
        self.output("p_hat", 3, unit="m", description="estimated tool position, world x, y, z")
        self.output("q_hat", 4, unit="1", description="estimated tool orientation, unit quaternion "
                    "(w, x, y, z), tool to world", start=(1.0, 0.0, 0.0, 0.0))
        self.output("v_hat", 3, unit="m/s", description="estimated velocity of the IMU point, world")
        self.output("b_gyro_hat", 3, unit="rad/s", description="gyro bias estimate, sensor frame")

    def _pose(self):
        return planar_pose(self.p_fk, self.phi_fk)

    def setup(self, params: cfm.ComplementaryFilterParameters) -> None:
        model = cfm.ComplementaryFilterModel(params)
        model.reset(*self._pose(), self.acc_s, self.gyro_s)
        self.start_fusion(model)

    def _predicted(self, est: cfm.ComplementaryFilterModel, T: float) -> cfm.ComplementaryFilterModel:
        est = copy.copy(est)          # shallow: the model replaces its arrays, never changes them
        est.predict(T)
        return est

    def _advanced(self, est: cfm.ComplementaryFilterModel, t0: float, t1: float) -> cfm.ComplementaryFilterModel:
        # one sample over the whole interval: the gyro and accelerometer readings enter the
        # prediction (trapezoidal, from the last sample), so it cannot run without them
        est = copy.copy(est)
        est.step(*self._pose(), self.acc_s, self.gyro_s, span(t0, t1))
        if not math.isfinite(float(est.p_s.sum() + est.q_s.sum())):
            raise FilterDivergence(f"the estimate became non-finite at t = {t1:.6g} s")
        return est

    def _show(self, m: cfm.ComplementaryFilterModel) -> None:
        p, q = m.mount.tool_pose(m.p_s, m.q_s)
        self.p_hat[:] = p
        self.p_tool_hat[0], self.p_tool_hat[1] = p[0], p[2]
        self.q_hat[:] = q
        self.phi_tool_hat = qt.angle_y(q)
        self.v_hat[:] = m.v_s
        self.b_gyro_hat[:] = m.b_gyro

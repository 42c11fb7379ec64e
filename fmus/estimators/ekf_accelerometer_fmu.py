"""FMU adapter of the accelerometer EKF (Axelsson, Karlsson, Norrlöf 2012, eqs. 3, 12-19, 26).

The math is in :mod:`fmus.estimators.ekf_accelerometer_model`. The filter runs once per
communication step, whose length is the sample period ``T`` of eqs. 13-14 (the paper: 100 Hz).

Timing: the outputs at time ``t`` are the filtered estimate ``x_{t|t}`` from the measurements
set at ``t`` (direct feedthrough from ``q_m_meas`` and ``acc_s``). ``do_step(t, T)`` commits the
last such update, predicts to ``t + T`` with the mean of the jerk
reference inputs at ``t`` and ``t + T`` and fuses the measurement inputs
as they are now, as the measurement at ``t + T``: under a Gauss-Seidel master, which sets the
producers' values of ``t + T`` before this step, the estimate is on time (like RigidKinematics);
a master that sets inputs at ``t`` and reads after the step sees both one step late.
"""
from __future__ import annotations

import numpy as np

from fmus.common.fmi import FlexFusionSlave
from fmus.common.robot_params import G
from fmus.estimators import ekf_accelerometer_model as em

_TRIL = np.tril_indices(6)     # the arm states' covariance, packed (output P_x)


class EkfAccelerometer(FlexFusionSlave):
    """Arm angles, velocities and accelerations from motor angles and a tool accelerometer (EKF).

    Divergence (a non-finite state or a covariance that is not positive definite) ends the step
    with an FMI error status and a message naming the cause, and so does every later step; the
    outputs keep the last good estimate (never NaN) and stay readable.
    """

    parameters_class = em.EkfAccelerometerParameters
    description = "EKF of arm angles from motor angles and a tool accelerometer (Axelsson et al. 2012)"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.input("q_m_meas", 2, unit="rad", description="measured motor angles, motor side")
        self.input("acc_s", 3, unit="m/s2", description="accelerometer specific force, sensor frame",
                   start=(0.0, 0.0, G))
        self.input("dddq_a_ref", 2, unit="rad/s3", description="arm jerk reference (the model's input u)")
        deps = ("q_m_meas", "acc_s")
        self.output("q_a_hat", 2, unit="rad", depends_on=deps, description="estimated arm angles")
        self.output("dq_a_hat", 2, unit="rad/s", depends_on=deps, description="estimated arm angular velocities")
        self.output("ddq_a_hat", 2, unit="rad/s2", depends_on=deps,
                    description="estimated arm angular accelerations")
        self.output("p_tool_hat", 2, unit="m", depends_on=deps,
                    description="tool position from the estimated arm angles (eq. 29), world x and z")
        self.output("trace_P_q", unit="rad2", depends_on=deps,
                    description="trace of the filtered covariance of the arm angles")
        self.output("innovation_norm", unit="1", depends_on=deps,
                    description="normalised innovation norm sqrt(nu^T S^-1 nu) of the last update")
        # the whole covariance, for consistency checks against the truth (NEES) in studies
        self.output("P_x", len(_TRIL[0]), unit="1", depends_on=deps,
                    description="filtered covariance of (q_a, dq_a, ddq_a), lower triangle row by row "
                    "(numpy.tril_indices(6)); SI units (rad, rad/s, rad/s2) of each product")

    def setup(self, params: em.EkfAccelerometerParameters) -> None:
        self.ekf = em.EkfAccelerometerModel(params)
        self._ix, self._iz = params.index_x - 1, params.index_z - 1
        self._pending: tuple | None = None
        self._diverged = ""
        self._u_start = self.dddq_a_ref.copy()     # the jerk input at the last step
        self.update_outputs()

    def _y(self) -> np.ndarray:
        return self.ekf.measurement_vector(self.q_m_meas, (self.acc_s[self._ix], self.acc_s[self._iz]))

    def update_outputs(self) -> None:
        if self._diverged:
            return                                      # hold the last good estimate
        try:
            xf, Pf, nu = self.ekf.filtered(self._y())
        except em.FilterDivergence as exc:
            self._diverged = f"{exc} (measurements at t = {self._time:.6g} s)"
            self._pending = None
            return
        self._pending = (xf, Pf, nu)
        self.q_a_hat[:] = xf[0:2]
        self.dq_a_hat[:] = xf[2:4]
        self.ddq_a_hat[:] = xf[4:6]
        self.p_tool_hat[:] = self.ekf.tool_position(xf)
        self.trace_P_q = float(Pf[0, 0] + Pf[1, 1])
        self.innovation_norm = nu
        self.P_x[:] = Pf[_TRIL]

    def step(self, t: float, dt: float) -> None:
        # Commit the estimate at t as last computed (from the measurements present then), not
        # from inputs set since: a Gauss-Seidel master sets the measurements of t + dt before
        # this doStep, and they are fused below, after the prediction to t + dt.
        if self._pending is None:
            self.update_outputs()
        if self._diverged:
            raise em.FilterDivergence(f"{self._diverged}; the outputs hold the last good estimate")
        self.ekf.x, self.ekf.P, self.ekf.innovation_norm = self._pending
        self._pending = None
        # the jerk over [t, t + dt]: the mean of its values at t and t + dt (the input now, under
        # our Gauss-Seidel master), not the end value alone, which would lead the model by dt / 2
        u_end = self.dddq_a_ref.copy()
        u = 0.5 * (self._u_start + u_end)
        self._u_start = u_end
        try:
            self.ekf.predict(u, dt)
        except em.FilterDivergence as exc:
            self._diverged = f"{exc} (at t = {t:.6g} s)"
            raise
        self.update_outputs()      # the inputs as the measurement at t + dt (re-fused if they change)

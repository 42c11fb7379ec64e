"""The FMU adapter shared by EkfComplete, EkfMotor and EkfIntegrated (Henriksson et al. 2009,
section III-A); the math is in :mod:`fmus.estimators.ekf_flexible_model`.

The filter runs once per communication step, whose length is the sample period ``T`` of the
Euler discretisation (the paper: 2 kHz).

Timing (as EkfAccelerometer's): the outputs at time ``t`` are the filtered estimate ``x_{t|t}``
from the measurements set at ``t`` (direct feedthrough from ``q_m_meas`` and ``acc_s``; the
motor torque ``tau_m`` set with them is kept as the input of the next prediction and has no
direct feedthrough). ``do_step(t, T)`` commits that update, predicts to ``t + T`` with the kept
torque, and fuses the inputs as they are now as the measurement at ``t + T``.
"""
from __future__ import annotations

from fmus.common.fmi import FlexFusionSlave
from fmus.common.robot_params import G
from fmus.estimators import ekf_flexible_model as em


class EkfFlexibleSlave(FlexFusionSlave):
    """Base of the three EKF FMUs; a subclass sets ``variant``, ``parameters_class`` and
    ``description``.

    Divergence (a non-finite state or a covariance that is not positive definite) ends the step
    with an FMI error status and a message naming the cause, and so does every later step; the
    outputs keep the last good estimate (never NaN) and stay readable.
    """

    variant = "motor"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.input("tau_m", 2, unit="N.m", description="motor torque, motor side (the model's input u)")
        self.input("q_m_meas", 2, unit="rad", description="measured motor angles, motor side")
        deps: tuple = ("q_m_meas",)
        if self.variant != "motor":
            self.input("acc_s", 3, unit="m/s2", description="accelerometer specific force, sensor frame",
                       start=(0.0, 0.0, G))
            deps = ("q_m_meas", "acc_s")
        self.output("q_a_hat", 2, unit="rad", depends_on=deps, description="estimated arm angles")
        self.output("dq_a_hat", 2, unit="rad/s", depends_on=deps,
                    description="estimated arm angular velocities")
        self.output("ddq_a_hat", 2, unit="rad/s2", depends_on=deps,
                    description="arm angular accelerations of the model (eq. 2) at the estimate")
        self.output("q_m_hat", 2, unit="rad", depends_on=deps,
                    description="estimated motor angles, motor side")
        self.output("p_tool_hat", 2, unit="m", depends_on=deps,
                    description="tool position from the estimated arm angles, world x and z")
        self.output("trace_P_p", unit="m2", depends_on=deps,
                    description="trace of the filtered tool-position covariance J P_qa J^T")
        self.output("innovation_norm", unit="1", depends_on=deps,
                    description="normalised innovation norm sqrt(nu^T S^-1 nu) of the last update")
        if self.variant != "motor":
            self.output("stiffness_factor_hat", unit="1", depends_on=deps,
                        description="estimated factor on the model's gearbox stiffness (EKF Integrated's "
                        "drift_correction = tilt_stiffness, EKF Complete's estimate_stiffness; else 1)",
                        start=1.0)
        if self.variant == "integrated":
            self.output("v_acc", 2, unit="m/s", depends_on=deps,
                        description="integrated accelerometer velocity of the sensor mount, world x and z "
                        "(the measurement of eq. 8)")

    def setup(self, params) -> None:
        self.ekf = em.EkfFlexibleModel(params, self.variant)
        self._pending: em.Filtered | None = None
        self._diverged = ""
        self.update_outputs()

    def update_outputs(self) -> None:
        if self._diverged:
            return                                      # hold the last good estimate
        try:
            r = self.ekf.filtered(self.q_m_meas, None if self.variant == "motor" else self.acc_s,
                                  self.tau_m)
        except em.FilterDivergence as exc:
            self._diverged = f"{exc} (measurements at t = {self._time:.6g} s)"
            self._pending = None
            return
        self._pending = r
        xf = r.x
        self.q_a_hat[:] = xf[0:2]
        self.dq_a_hat[:] = xf[4:6]
        self.ddq_a_hat[:] = self.ekf.model_derivatives(xf, r.u)[4:6]
        self.q_m_hat[:] = xf[2:4]
        self.p_tool_hat[:] = self.ekf.tool_position(xf)
        self.trace_P_p = self.ekf.tool_position_variance(xf, r.P)
        self.innovation_norm = r.innovation_norm
        if self.variant == "integrated":
            self.v_acc[:] = r.v_int
        if self.variant != "motor":
            self.stiffness_factor_hat = self.ekf.stiffness_factor(xf)

    def step(self, t: float, dt: float) -> None:
        # Commit the estimate at t as last computed (from the measurements present then), not
        # from inputs set since: a Gauss-Seidel master sets the measurements of t + dt before
        # this doStep, and they are fused below, after the prediction to t + dt.
        if self._pending is None:
            self.update_outputs()
        if self._diverged:
            raise em.FilterDivergence(f"{self._diverged}; the outputs hold the last good estimate")
        self.ekf.commit(self._pending)
        self._pending = None
        try:
            self.ekf.predict(dt)
        except em.FilterDivergence as exc:
            self._diverged = f"{exc} (at t = {t:.6g} s)"
            raise
        self.update_outputs()      # the inputs as the measurement at t + dt (re-fused if they change)

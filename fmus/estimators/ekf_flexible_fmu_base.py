"""The FMU adapter shared by EkfComplete, EkfMotor and EkfIntegrated (Henriksson et al. 2009,
section III-A); the math is in :mod:`fmus.estimators.ekf_flexible_model`.

The filter runs once per communication step, whose length is the sample period ``T`` of the
Euler discretisation (the paper: 2 kHz).

Timing (as EkfAccelerometer's): the outputs at time ``t`` are the estimate of the state at
``t``. Each measurement (``q_m_meas``, ``acc_s``) is fused at the time it was taken, the optional
input ``t_meas`` (the sensors' output), and predicted on to ``t``
(:mod:`fmus.common.filter_adapter`); the motor torque ``tau_m`` set with a measurement is
the input of the prediction that follows it. EKF Integrated's trapezoidal velocity integral uses
the last prediction period, so it assumes samples one filter period apart.
"""
from __future__ import annotations

import copy

from fmus.common.filter_adapter import FilterAdapter
from fmus.common.frames import G
from fmus.estimators import ekf_flexible_model as em


class EkfFlexibleSlave(FilterAdapter):
    """Base of the three EKF FMUs; a subclass sets ``variant``, ``parameters_class`` and
    ``description``. An estimate is an :class:`~fmus.estimators.ekf_flexible_model.EkfFlexibleModel`
    (copied before it changes)."""

    variant = "motor"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.input("tau_m", 2, unit="N.m", description="motor torque, motor side (the model's input u)")
        self.input("q_m_meas", 2, unit="rad", description="measured motor angles, motor side")
        self.declare_t_meas()
        deps: tuple = ("q_m_meas", "t_meas")
        if self.variant != "motor":
            self.input("acc_s", 3, unit="m/s2", description="accelerometer specific force, sensor frame",
                       start=(0.0, 0.0, G))
            deps = ("q_m_meas", "acc_s", "t_meas")
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
        self.start_fusion(em.EkfFlexibleModel(params, self.variant))

    def _fused(self, prior: em.EkfFlexibleModel) -> em.EkfFlexibleModel:
        r = prior.filtered(self.q_m_meas, None if self.variant == "motor" else self.acc_s, self.tau_m)
        est = copy.copy(prior)
        est.commit(r)
        return est

    def _show(self, est: em.EkfFlexibleModel) -> None:
        xf = est.x
        self.q_a_hat[:] = xf[0:2]
        self.dq_a_hat[:] = xf[4:6]
        self.ddq_a_hat[:] = est.model_derivatives(xf, est.u)[4:6]
        self.q_m_hat[:] = xf[2:4]
        self.p_tool_hat[:] = est.tool_position(xf)
        self.trace_P_p = est.tool_position_variance(xf, est.P)
        self.innovation_norm = est.innovation_norm
        if self.variant == "integrated":
            self.v_acc[:] = est.v_int
        if self.variant != "motor":
            self.stiffness_factor_hat = est.stiffness_factor(xf)

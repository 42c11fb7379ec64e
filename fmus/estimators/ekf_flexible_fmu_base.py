"""The FMU adapter shared by EkfComplete, EkfMotor and EkfIntegrated (Henriksson et al. 2009,
section III-A); the math is in :mod:`fmus.estimators.ekf_flexible_model`.

The filter runs once per communication step, whose length is the sample period ``T`` of the
Euler discretisation (the paper: 2 kHz).

Timing (as EkfAccelerometer's): the outputs at time ``t`` are the estimate of the state at
``t``. Each measurement (``q_m_meas``, ``acc_s``) is fused at the time it was taken, the optional
input ``t_meas`` (the sensors' output): the filter predicts from its last fused measurement to
``t_meas``, updates (eq. 4) with the motor torque ``tau_m`` set with the measurement (kept as the
input of the following prediction; no direct feedthrough) and outputs the prediction from there
to ``t``. The state stays anchored at the last fused measurement, so a late one (a Jacobi master)
is fused as if on time without a history; a held sample is not fused twice. Unconnected,
``t_meas`` makes the inputs the measurement at the current time: set before ``do_step(t, T)``,
they are fused at ``t + T`` after the prediction, as before (our Gauss-Seidel master). A
prediction over several filter periods runs period by period (eq. 5 is per sample); EKF
Integrated's trapezoidal velocity integral uses the last period, so it assumes samples one
period apart.
"""
from __future__ import annotations

import copy
import math

from fmus.common.fmi import FlexFusionSlave
from fmus.common.robot_params import G
from fmus.estimators import ekf_flexible_model as em
from fmus.estimators.sample_time import (T_MEAS_DESCRIPTION, TIME_TOL, UNSTAMPED, intervals,
                                         measurement_time)


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
        self.input("t_meas", unit="s", start=UNSTAMPED, description=T_MEAS_DESCRIPTION)
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
        self.ekf = em.EkfFlexibleModel(params, self.variant)    # the estimate at _t_state
        self._t_state = self._time
        self._t_fused = -math.inf       # the stamp of the last committed measurement
        self._pending: tuple | None = None   # fused, not committed: (t_m, Filtered, prior model)
        self._diverged = ""
        self._refresh(self._time)

    def update_outputs(self) -> None:
        self._refresh(self._time)

    def _commit(self) -> None:
        t_m, r, self.ekf = self._pending
        self.ekf.commit(r)
        self._t_state = self._t_fused = t_m
        self._pending = None

    def _predicted(self, model: em.EkfFlexibleModel, t0: float, t1: float) -> em.EkfFlexibleModel:
        """A copy of ``model`` predicted from ``t0`` to ``t1`` (``model`` itself if they are the
        same time); the copy is shallow: a prediction replaces arrays, never changes them."""
        if t1 <= t0 + TIME_TOL:
            return model
        model = copy.copy(model)
        n, T = intervals(t0, t1, self._step)
        for _ in range(n):
            model.predict(T)
        return model

    def _refresh(self, now: float) -> None:
        """Fuse the measurement inputs at their time (pending until the next step) and set the
        outputs to the estimate at ``now``."""
        if self._diverged:
            return                                      # hold the last good estimate
        t_m = measurement_time(self.t_meas, now)
        try:
            if t_m <= now + TIME_TOL:
                if self._pending is not None and t_m > self._pending[0] + TIME_TOL:
                    self._commit()                      # a newer sample: the pending one is final
                if t_m > self._t_fused + TIME_TOL:      # not fused yet: predict to t_m, update
                    prior = self._predicted(self.ekf, self._t_state, t_m)
                    r = prior.filtered(self.q_m_meas, None if self.variant == "motor" else self.acc_s,
                                       self.tau_m)
                    self._pending = (t_m, r, prior)
            if self._pending is not None:
                t, r, est = self._pending
                est = copy.copy(est)
                est.commit(r)
            else:
                t, est = self._t_state, self.ekf
            est = self._predicted(est, t, now)
        except em.FilterDivergence as exc:
            self._diverged = f"{exc} (measurements of t = {t_m:.6g} s)"
            self._pending = None
            return
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

    def step(self, t: float, dt: float) -> None:
        # Commit the measurement fused before this step (as last computed, from the inputs
        # present then), not one set since: a Gauss-Seidel master sets the measurements of
        # t + dt before this doStep; they are fused below, after the prediction to t + dt.
        if self._pending is None and not self._diverged:
            self._refresh(t)
        if self._diverged:
            raise em.FilterDivergence(f"{self._diverged}; the outputs hold the last good estimate")
        if self._pending is not None:
            self._commit()
        self._refresh(t + dt)
        if self._diverged:
            raise em.FilterDivergence(self._diverged)

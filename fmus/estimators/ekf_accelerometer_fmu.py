"""FMU adapter of the accelerometer EKF (Axelsson, Karlsson, Norrlöf 2012, eqs. 3, 12-19, 26).

The math is in :mod:`fmus.estimators.ekf_accelerometer_model`. The filter runs once per
communication step, whose length is the sample period ``T`` of eqs. 13-14 (the paper: 100 Hz).

Timing: the outputs at time ``t`` are the estimate of the state at ``t``. Each measurement
(``q_m_meas`` and ``acc_s``, sampled together as in the paper) is fused at the time it was taken,
``t_meas`` (the sensors' output of that name): the filter predicts from its last fused
measurement to ``t_meas`` (eq. 3a, the jerk reference over that interval), updates (eq. 3b) and
outputs the prediction from there to ``t``. The state is anchored at the last fused measurement,
so a measurement that arrives late (a Jacobi master such as libcosim hands it over one or two
steps after it was taken) is fused exactly as if it had come on time, with no history to keep or
re-filter: each sensor's stamps only grow, and a stamp not newer than the last fused one (a held
sample, e.g. a sensor slower than the filter) is not fused again. A measurement stamped after
``t`` waits for the step that reaches it.

With ``t_meas`` unconnected (its start value, negative) the inputs count as the measurement at
the current time: set before ``doStep(t, T)`` they are fused at ``t + T``, as the sensors'
convention says (a Gauss-Seidel master, ours, sets the producers' values of ``t + T``). Under our
master the sensors stamp exactly that, so the connected and unconnected cases give the same
numbers. Inputs set between steps (time ``t``) are fused at ``t`` and, until the next step,
replace one another (direct feedthrough from ``q_m_meas``, ``acc_s`` and ``t_meas``).
"""
from __future__ import annotations

import math

import numpy as np

from fmus.common.fmi import FlexFusionSlave
from fmus.common.robot_params import G
from fmus.estimators import ekf_accelerometer_model as em
from fmus.estimators.sample_time import (T_MEAS_DESCRIPTION, TIME_TOL, UNSTAMPED, intervals,
                                         measurement_time)


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
        self.input("t_meas", unit="s", start=UNSTAMPED, description=T_MEAS_DESCRIPTION)
        deps = ("q_m_meas", "acc_s", "t_meas")
        self.output("q_a_hat", 2, unit="rad", depends_on=deps, description="estimated arm angles")
        self.output("dq_a_hat", 2, unit="rad/s", depends_on=deps, description="estimated arm angular velocities")
        self.output("ddq_a_hat", 2, unit="rad/s2", depends_on=deps,
                    description="estimated arm angular accelerations")
        self.output("p_tool_hat", 2, unit="m", depends_on=deps,
                    description="tool position from the estimated arm angles (eq. 29), world x and z")
        self.output("trace_P_q", unit="rad2", depends_on=deps,
                    description="trace of the covariance of the estimated arm angles")
        self.output("innovation_norm", unit="1", depends_on=deps,
                    description="normalised innovation norm sqrt(nu^T S^-1 nu) of the last update")

    def setup(self, params: em.EkfAccelerometerParameters) -> None:
        self.ekf = em.EkfAccelerometerModel(params)
        self._ix, self._iz = params.index_x - 1, params.index_z - 1
        self._t_state = self._time      # the time of ekf.x, ekf.P (the prior at the start)
        self._t_fused = -math.inf       # the stamp of the last committed measurement
        self._u_start = self.dddq_a_ref.copy()     # the jerk input at _t_state
        self._u = self._u_start.copy()             # ... at the last step (no feedthrough)
        self._pending: tuple | None = None         # fused, not committed: (t_m, u, x, P, nu)
        self._diverged = ""
        self._refresh(self._time)

    def _y(self) -> np.ndarray:
        return self.ekf.measurement_vector(self.q_m_meas, (self.acc_s[self._ix], self.acc_s[self._iz]))

    def _commit(self) -> None:
        t_m, u, self.ekf.x, self.ekf.P, self.ekf.innovation_norm = self._pending
        self._t_state = self._t_fused = t_m
        self._u_start = u
        self._pending = None

    def update_outputs(self) -> None:
        self._refresh(self._time)

    def _refresh(self, now: float) -> None:
        """Fuse the measurement inputs at their time (pending until the next step) and set the
        outputs to the estimate at ``now``."""
        if self._diverged:
            return                                      # hold the last good estimate
        t_m = measurement_time(self.t_meas, now)
        u = self._u
        try:
            if t_m <= now + TIME_TOL:
                if self._pending is not None and t_m > self._pending[0] + TIME_TOL:
                    self._commit()                      # a newer sample: the pending one is final
                if t_m > self._t_fused + TIME_TOL:      # not fused yet: predict to t_m, update
                    # the jerk over the interval: the mean of its values at both ends, not the end
                    # value alone, which would lead the model by half the interval
                    x, P = self._predicted(0.5 * (self._u_start + u), self._t_state, t_m)
                    self._pending = (t_m, u, *self.ekf.filtered(self._y(), x, P))
            if self._pending is not None:
                t, _, x, P, nu = self._pending
            else:
                t, x, P, nu = self._t_state, self.ekf.x, self.ekf.P, self.ekf.innovation_norm
            x, P = self._predicted(u, t, now, x, P)
        except em.FilterDivergence as exc:
            self._diverged = f"{exc} (measurements of t = {t_m:.6g} s)"
            self._pending = None
            return
        self.q_a_hat[:] = x[0:2]
        self.dq_a_hat[:] = x[2:4]
        self.ddq_a_hat[:] = x[4:6]
        self.p_tool_hat[:] = self.ekf.tool_position(x)
        self.trace_P_q = float(P[0, 0] + P[1, 1])
        self.innovation_norm = nu

    def _predicted(self, u: np.ndarray, t0: float, t1: float, x=None, P=None) -> tuple:
        """The state predicted from ``t0`` to ``t1`` (unchanged if they are the same time)."""
        if t1 <= t0 + TIME_TOL:
            return (self.ekf.x, self.ekf.P) if x is None else (x, P)
        x, P = (self.ekf.x, self.ekf.P) if x is None else (x, P)
        n, T = intervals(t0, t1, self._step)
        for _ in range(n):
            x, P = self.ekf.predicted(u, T, x, P)
        return x, P

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
        self._u = self.dddq_a_ref.copy()
        self._refresh(t + dt)
        if self._diverged:
            raise em.FilterDivergence(self._diverged)

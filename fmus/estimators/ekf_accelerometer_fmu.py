"""FMU adapter of the accelerometer EKF (Axelsson, Karlsson, Norrlöf 2012, eqs. 3, 12-19, 26).

The math is in :mod:`fmus.estimators.ekf_accelerometer_model`. The filter runs once per
communication step, whose length is the sample period ``T`` of eqs. 13-14 (the paper: 100 Hz).

Timing: the outputs at time ``t`` are the estimate of the state at ``t``. Each measurement
(``q_m_meas`` and ``acc_s``, sampled together as in the paper) is fused at the time it was taken,
the optional input ``t_meas`` (the sensors' output of that name), and predicted on to ``t``
(:mod:`fmus.common.filter_adapter`); the prediction over an interval uses the mean of the
jerk reference at its ends (the input at the step and at the last fused measurement), not the
end value alone, which would lead the model by half the interval. Direct feedthrough from
``q_m_meas``, ``acc_s`` and ``t_meas``.

A fusion (the prediction to the stamp, the update and the outputs) is one compiled call,
:func:`~fmus.estimators.ekf_accelerometer_model.fusion_step_kernel`, on the estimate packed in
one array (:func:`~fmus.estimators.ekf_accelerometer_model.packed_estimate`): the adapter's
Python is the fusion schedule and the call (issue 16: a few microseconds per step).
"""
from __future__ import annotations

import numpy as np

from fmus.common.filter_adapter import FilterAdapter
from fmus.common.frames import G
from fmus.common.kalman import OK, raise_for
from fmus.common.sample_time import TIME_TOL, intervals
from fmus.estimators import axelsson2012_model as am
from fmus.estimators import ekf_accelerometer_model as em

_WHERE = {em.TIME_UPDATE: "EKF diverged in the time update",
          em.MEASUREMENT_UPDATE: "EKF diverged in the measurement update"}


class EkfAccelerometer(FilterAdapter):
    """Arm angles, velocities and accelerations from motor angles and a tool accelerometer (EKF)."""
    batched = "EkfAccelerometer"

    parameters_class = am.EkfAccelerometerParameters
    description = "EKF of arm angles from motor angles and a tool accelerometer (Axelsson et al. 2012)"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.input("q_m_meas", 2, unit="rad", description="measured motor angles, motor side")
        self.input("acc_s", 3, unit="m/s2", description="accelerometer specific force, sensor frame",
                   start=(0.0, 0.0, G))
        self.input("dddq_a_ref", 2, unit="rad/s3", description="arm jerk reference (the model's input u)")
        self.declare_t_meas()
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
        # the whole covariance, for consistency checks against the truth (NEES) in studies
        self.output("P_x", 21, unit="1", depends_on=deps,
                    description="filtered covariance of (q_a, dq_a, ddq_a), lower triangle row by row "
                    "(numpy.tril_indices(6)); SI units (rad, rad/s, rad/s2) of each product")
        # the vector outputs in the kernel's order (em.SHOWN_SIZE; the scalars are not in the buffer)
        shown = self.output_span("q_a_hat", "P_x")
        assert shown.stop - shown.start == em.SHOWN_SIZE
        self._first_shown = shown.start

    def setup(self, params: am.EkfAccelerometerParameters) -> None:
        self.ekf = ekf = em.EkfAccelerometerModel(params)
        robot = ekf.meas.p
        # the kernel's constant arguments: the accelerometer's axes, the measurement model, the links
        self._fixed = (params.index_x - 1, params.index_z - 1, ekf.R, ekf.meas.constants, *ekf.meas.switches,
                       float(robot.l1), float(robot.l2))
        self._no_prediction = (0, *ekf.transition(0.0))
        self._periods_of: dict[tuple[float, float], tuple] = {}
        self._u = self.dddq_a_ref.copy()           # the jerk input at the last step
        self.start_fusion(em.packed_estimate(ekf.x, ekf.P, 0.0, self._u))

    def _before_step(self) -> None:
        self._u = self.dddq_a_ref.copy()     # read at the step only: no direct feedthrough

    def _periods(self, t0: float, t1: float) -> tuple:
        """The prediction from ``t0`` to ``t1``: the number of sample periods and their
        matrices (:meth:`~.ekf_accelerometer_model.EkfAccelerometerModel.transition`), kept
        per length and step (a run meets a few: the stamps' differences vary in the last bits)."""
        if t1 <= t0 + TIME_TOL:
            return self._no_prediction
        key = (t1 - t0, self._step)
        periods = self._periods_of.get(key)
        if periods is None:
            n, T = intervals(t0, t1, self._step)
            periods = (n, *self.ekf.transition(T))
            if len(self._periods_of) < 256:
                self._periods_of[key] = periods
        return periods

    def _run(self, est: np.ndarray, t0: float, t1: float, fuse: bool, now: float) -> np.ndarray:
        """:func:`~.ekf_accelerometer_model.fusion_step_kernel`: ``est`` (time ``t0``) carried
        to ``t1``, updated with the measurement inputs if ``fuse``, shown predicted to ``now``;
        the estimate at ``t1``."""
        new = np.empty(est.size)
        status, stage, trace, norm = em.fusion_step_kernel(
            est, self._u, *self._periods(t0, t1), fuse, self.q_m_meas, self.acc_s, *self._periods(t1, now), new,
            self._outputs, self._first_shown, *self._fixed)
        if status != OK:
            raise_for(status, _WHERE[stage], em.packed_covariance(new, self.ekf.layout.n))
        self.trace_P_q, self.innovation_norm = trace, norm
        return new

    def _advanced_and_shown(self, est: np.ndarray, t0: float, t1: float, now: float) -> np.ndarray:
        return self._run(est, t0, t1, True, now)

    def _show_at(self, est: np.ndarray, t: float, now: float) -> None:
        self._run(est, t, t, False, now)

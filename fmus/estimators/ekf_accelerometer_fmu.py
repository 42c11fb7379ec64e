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
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fmus.common.filter_adapter import FilterAdapter
from fmus.common.frames import G
from fmus.estimators import axelsson2012_model as am
from fmus.estimators import ekf_accelerometer_model as em

# the arm states' covariance, packed (output P_x): the flat positions of its lower triangle
_TRIL = np.ravel_multi_index(np.tril_indices(6), (6, 6))


class Estimate(NamedTuple):
    """The filter's state and covariance, the innovation norm of its last update and the jerk
    reference at its time."""

    x: np.ndarray
    P: np.ndarray
    innovation_norm: float
    u: np.ndarray


class EkfAccelerometer(FilterAdapter):
    """Arm angles, velocities and accelerations from motor angles and a tool accelerometer (EKF)."""

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
        self.output("P_x", len(_TRIL), unit="1", depends_on=deps,
                    description="filtered covariance of (q_a, dq_a, ddq_a), lower triangle row by row "
                    "(numpy.tril_indices(6)); SI units (rad, rad/s, rad/s2) of each product")
        self._states = self.output_span("q_a_hat", "ddq_a_hat")     # the arm states x[0:6]

    def setup(self, params: am.EkfAccelerometerParameters) -> None:
        self.ekf = em.EkfAccelerometerModel(params)
        self._ix, self._iz = params.index_x - 1, params.index_z - 1
        self._u = self.dddq_a_ref.copy()           # the jerk input at the last step
        self.start_fusion(Estimate(self.ekf.x, self.ekf.P, 0.0, self._u))

    def _before_step(self) -> None:
        self._u = self.dddq_a_ref.copy()     # read at the step only: no direct feedthrough

    def _predicted(self, est: Estimate, T: float) -> Estimate:
        x, P = self.ekf.predicted(0.5 * (est.u + self._u), T, est.x, est.P)
        return Estimate(x, P, est.innovation_norm, self._u)

    def _fused(self, prior: Estimate) -> Estimate:
        y = self.ekf.measurement_vector(self.q_m_meas, (self.acc_s[self._ix], self.acc_s[self._iz]))
        return Estimate(*self.ekf.filtered(y, prior.x, prior.P), prior.u)

    def _show(self, est: Estimate) -> None:
        x, P = est.x, est.P
        self._outputs[self._states] = x[0:6]
        self.p_tool_hat[:] = self.ekf.tool_position(x)
        self.trace_P_q = float(P[0, 0] + P[1, 1])
        self.innovation_norm = est.innovation_norm
        P.take(_TRIL, out=self.P_x)

"""FMU adapter of the particle filter (Axelsson, Karlsson, Norrlöf 2012, Algorithm 1, eqs. 6, 28, 30).

The math is in :mod:`fmus.estimators.particle_filter_model`; the model (state, ``Q``, ``R``,
``h``) is the EKF's. After each resampling the particles are moved by a moment-preserving
Gaussian kernel (regularised particle filter, parameter ``bandwidth``; 0 = plain Algorithm 1),
without which the cloud's angle and velocity spread collapses under the rank-2 (jerk) process
noise and the filter drifts (see the model's docstring). The filter runs once per
communication step, whose length is the sample period ``T`` of eqs. 13-14 (the paper: 100 Hz).

Timing (as the EkfAccelerometer FMU): the outputs at time ``t`` are the estimate of the state at
``t``. Each measurement (``q_m_meas`` and ``acc_s``) is fused at the time it was taken, the
optional input ``t_meas`` (the sensors' output), and predicted on to ``t``
(:mod:`fmus.common.filter_adapter`); the prediction over an interval uses the mean of the jerk
reference at its ends, not the end value alone, which would lead the model by half the
interval. Direct feedthrough from ``q_m_meas``, ``acc_s`` and ``t_meas``. Recomputing the update
for changed inputs redraws the same random numbers (the generator's state is part of the
estimate and advances on commit), so a run is reproducible for a given ``seed`` whatever the
master's get/set pattern. The period ``T`` is the host's step rounded to 12 significant digits
(the base class's nominal step): hosts pass steps that differ in the last bits (fmpy's
``simulate_fmu``: ``(n + 1) h - n h``), which changed ``F`` and ``Q`` and so the estimate.
"""
from __future__ import annotations

import copy
from typing import NamedTuple

import numpy as np
from pythonfmu.enums import Fmi2Status

from fmus.common.filter_adapter import FilterAdapter
from fmus.common.frames import G
from fmus.estimators import particle_filter_model as pm


class Estimate(NamedTuple):
    """The filter (a copy: its particles, weights and generator state), its estimate, its last
    update, and the jerk reference at its time."""

    pf: pm.ParticleFilterModel
    x: np.ndarray                  #: the estimate: the update's mean (eq. 6), or its prediction
    last: pm.FilterStep | None
    u: np.ndarray


class ParticleFilter(FilterAdapter):
    """Arm angles, velocities and accelerations from motor angles and a tool accelerometer
    (particle filter, the EKF's model).

    Degeneracy (no particle with a finite weight, e.g. after an absurd measurement) re-initialises
    the particle cloud around the last good estimate with the initial covariance, logs a warning
    naming the cause and counts it in ``n_reinit``; the outputs never become NaN. Only if the
    last good estimate cannot be propagated to a finite value the step ends with an FMI error
    naming the cause (and every later step too); the outputs then hold the last good estimate.
    """

    parameters_class = pm.ParticleFilterParameters
    description = ("Particle filter of arm angles from motor angles and a tool accelerometer "
                   "(Axelsson et al. 2012, Algorithm 1)")

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.input("q_m_meas", 2, unit="rad", description="measured motor angles, motor side")
        self.input("acc_s", 3, unit="m/s2", description="accelerometer specific force, sensor frame",
                   start=(0.0, 0.0, G))
        self.input("dddq_a_ref", 2, unit="rad/s3", description="arm jerk reference (the model's input u)")
        self.declare_t_meas()
        deps = ("q_m_meas", "acc_s", "t_meas")
        self.output("q_a_hat", 2, unit="rad", depends_on=deps, description="estimated arm angles (eq. 6)")
        self.output("dq_a_hat", 2, unit="rad/s", depends_on=deps, description="estimated arm angular velocities")
        self.output("ddq_a_hat", 2, unit="rad/s2", depends_on=deps,
                    description="estimated arm angular accelerations")
        self.output("p_tool_hat", 2, unit="m", depends_on=deps,
                    description="tool position from the estimated arm angles (eq. 29), world x and z")
        self.output("trace_P_q", unit="rad2", depends_on=deps,
                    description="trace of the weighted particle covariance of the arm angles")
        self.output("ess", unit="1", depends_on=deps,
                    description="effective sample size 1/sum(w^2) of the last update, before resampling")
        self.output("n_reinit", unit="1", depends_on=deps,
                    description="number of re-initialisations of the particle cloud after degeneracy")

    def setup(self, params: pm.ParticleFilterParameters) -> None:
        self._ix, self._iz = params.index_x - 1, params.index_z - 1
        self._u = self.dddq_a_ref.copy()           # the jerk input at the last step
        pf = pm.ParticleFilterModel(params)
        self.start_fusion(Estimate(pf, pf.x, None, self._u))

    def _before_step(self) -> None:
        self._u = self.dddq_a_ref.copy()     # read at the step only: no direct feedthrough

    def _predicted(self, est: Estimate, T: float) -> Estimate:
        pf = copy.copy(est.pf)              # shallow: predict and commit replace, never change
        x = pf.predict(0.5 * (est.u + self._u), T)
        return Estimate(pf, x, est.last, self._u)

    def _fused(self, prior: Estimate) -> Estimate:
        y = prior.pf.measurement_vector(self.q_m_meas, (self.acc_s[self._ix], self.acc_s[self._iz]))
        s = prior.pf.filtered(y)
        pf = copy.copy(prior.pf)
        pf.commit(s)
        return Estimate(pf, pf.x, s, prior.u)

    def _committed(self, est: Estimate, t: float) -> None:
        if est.last is not None and est.last.reinit:
            self.log(f"{self.instance_name}: particle cloud re-initialised around the last good estimate "
                     f"with the initial covariance at t = {t:.6g} s: {est.last.reinit} "
                     f"(n_reinit = {est.pf.n_reinit})", Fmi2Status.warning)

    def _show(self, est: Estimate) -> None:
        pf, x = est.pf, est.x
        self.q_a_hat[:] = x[0:2]
        self.dq_a_hat[:] = x[2:4]
        self.ddq_a_hat[:] = x[4:6]
        self.p_tool_hat[:] = pf.tool_position(x)
        self.trace_P_q = float(pf.P[0, 0] + pf.P[1, 1])
        self.ess = pf.ess
        self.n_reinit = float(pf.n_reinit)

"""FMU adapter of the particle filter (Axelsson, Karlsson, Norrlöf 2012, Algorithm 1, eqs. 6, 28, 30).

The math is in :mod:`fmus.estimators.particle_filter_model`; the model (state, ``Q``, ``R``,
``h``) is the EKF's. After each resampling the particles are moved by a moment-preserving
Gaussian kernel (regularised particle filter, parameter ``bandwidth``; 0 = plain Algorithm 1),
without which the cloud's angle and velocity spread collapses under the rank-2 (jerk) process
noise and the filter drifts (see the model's docstring). The filter runs once per
communication step, whose length is the sample period ``T`` of eqs. 13-14 (the paper: 100 Hz).

Timing (as the EkfAccelerometer FMU): the outputs at time ``t`` are the filtered estimate from
the measurements set at ``t`` (direct feedthrough from ``q_m_meas`` and ``acc_s``).
``do_step(t, T)`` commits the last such update, predicts to ``t + T`` with the mean of the jerk
reference inputs at ``t`` and ``t + T``
and fuses the measurement inputs as they are now, as the measurement at ``t + T``. Recomputing
the update for changed inputs redraws the same random numbers (the RNG advances on commit), so
a run is reproducible for a given ``seed`` whatever the master's get/set pattern. The period
``T`` is the host's step rounded to 12 significant digits (the base class's nominal step): hosts
pass steps that differ in the last bits (fmpy's ``simulate_fmu``: ``(n + 1) h - n h``), which
changed ``F`` and ``Q`` and so the estimate from the first such step on.
"""
from __future__ import annotations

import numpy as np
from pythonfmu.enums import Fmi2Status

from fmus.common.fmi import FlexFusionSlave
from fmus.common.frames import G
from fmus.common.kalman import FilterDivergence
from fmus.estimators import particle_filter_model as pm


class ParticleFilter(FlexFusionSlave):
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
        deps = ("q_m_meas", "acc_s")
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
        self.pf = pm.ParticleFilterModel(params)
        self._ix, self._iz = params.index_x - 1, params.index_z - 1
        self._pending: pm.FilterStep | None = None
        self._diverged = ""
        self._u_start = self.dddq_a_ref.copy()     # the jerk input at the last step
        self.update_outputs()

    def _y(self) -> np.ndarray:
        return self.pf.measurement_vector(self.q_m_meas, (self.acc_s[self._ix], self.acc_s[self._iz]))

    def update_outputs(self) -> None:
        if self._diverged:
            return                                      # hold the last good estimate
        try:
            s = self.pf.filtered(self._y())
        except FilterDivergence as exc:
            self._diverged = f"{exc} (measurements at t = {self._time:.6g} s)"
            self._pending = None
            return
        self._pending = s
        self.q_a_hat[:] = s.x[0:2]
        self.dq_a_hat[:] = s.x[2:4]
        self.ddq_a_hat[:] = s.x[4:6]
        self.p_tool_hat[:] = self.pf.tool_position(s.x)
        self.trace_P_q = float(s.P[0, 0] + s.P[1, 1])
        self.ess = s.ess
        self.n_reinit = float(self.pf.n_reinit + bool(s.reinit))

    def step(self, t: float, dt: float) -> None:
        # Commit the estimate at t as last computed (from the measurements present then), not
        # from inputs set since: a Gauss-Seidel master sets the measurements of t + dt before
        # this doStep, and they are fused below, after the prediction to t + dt.
        if self._pending is None:
            self.update_outputs()
        if self._diverged:
            raise FilterDivergence(f"{self._diverged}; the outputs hold the last good estimate")
        s, self._pending = self._pending, None
        self.pf.commit(s)
        if s.reinit:
            self.log(f"{self.instance_name}: particle cloud re-initialised around the last good estimate "
                     f"with the initial covariance at t = {t:.6g} s: {s.reinit} "
                     f"(n_reinit = {self.pf.n_reinit})", Fmi2Status.warning)
        # the jerk over [t, t + dt]: the mean of its values at t and t + dt (the input now, under
        # our Gauss-Seidel master), not the end value alone, which would lead the model by dt / 2
        u_end = self.dddq_a_ref.copy()
        u = 0.5 * (self._u_start + u_end)
        self._u_start = u_end
        try:
            self.pf.predict(u, dt)
        except FilterDivergence as exc:
            self._diverged = f"{exc} (at t = {t:.6g} s)"
            raise
        self.update_outputs()      # the inputs as the measurement at t + dt (re-fused if they change)

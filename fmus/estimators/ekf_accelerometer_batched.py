"""The EKF of Axelsson, Karlsson and Norrlöf (2012) for many runs at once: states ``(runs, n)``,
covariances ``(runs, n, n)``, for the batched study engine (:mod:`orchestration.batched`).

The filter is :mod:`fmus.estimators.ekf_accelerometer_model` (eqs. 3, 12-19, 26) run per run:
:class:`BatchedEkfModel` loops over the runs with the single filter's own compiled kernels and
constants, so each run's numbers are the single filter's, bit for bit. The measurement model
over runs (for the Cramér-Rao bound) is
:class:`~fmus.estimators.axelsson2012_batched.BatchedMeasurement`, the compiled one the particle
filter uses over particles. :class:`BatchedEkfAccelerometer` repeats the FMU adapter
(``ekf_accelerometer_fmu.py``) and its base
:class:`~fmus.estimators.filter_adapter.FilterAdapter`: the same commit / predict /
update order and the same sample-time rule.
"""
from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple, Sequence

import numpy as np

from fmus.common.filter_adapter import FusionSchedule
from fmus.common.sample_time import UNSTAMPED, measurement_time
from fmus.common.jit import kernel
from fmus.common.kalman import OK, FilterDivergence, linear_time_update_kernel, raise_for
from fmus.estimators import axelsson2012_model as am
from fmus.estimators import ekf_accelerometer_model as em
from fmus.estimators.axelsson2012_batched import BatchedMeasurement

_TRIL = np.tril_indices(6)


class Estimate(NamedTuple):
    """The adapter's estimate (the FMU packs the same in one array:
    :func:`~fmus.estimators.ekf_accelerometer_model.packed_estimate`) for every run."""

    x: np.ndarray                # (runs, n)
    P: np.ndarray                # (runs, n, n)
    innovation_norm: np.ndarray  # (runs,)
    u: np.ndarray                # (runs, 2)


@kernel(aot="Tuple((float64[:, :], float64[:, :, :], float64[:], int64[:]))(float64[:, :], "
            "float64[:, :, :], float64[:, :], float64[:, :], float64[:], boolean, boolean)")
def _filtered_runs(x: np.ndarray, P: np.ndarray, y: np.ndarray, R: np.ndarray, k: np.ndarray,
                   use_accelerometer: bool, use_bias: bool) -> tuple:
    """:func:`~fmus.estimators.ekf_accelerometer_model.filtered_kernel` for each run."""
    xf, Pf = np.empty_like(x), np.empty_like(P)
    nis, status = np.empty(x.shape[0]), np.empty(x.shape[0], np.int64)
    for r in range(x.shape[0]):
        xf[r], Pf[r], nis[r], status[r] = em.filtered_kernel(x[r], P[r], y[r], R, k, use_accelerometer,
                                                             use_bias)
    return xf, Pf, nis, status


@kernel(aot="Tuple((float64[:, :], float64[:, :, :], int64[:]))(float64[:, :], float64[:, :, :], "
            "float64[:, :], float64[:, :], float64[:, :], float64[:, :, :])")
def _predicted_runs(x: np.ndarray, P: np.ndarray, F: np.ndarray, Gu: np.ndarray, u: np.ndarray,
                    GQG: np.ndarray) -> tuple:
    """:func:`fmus.common.kalman.linear_time_update_kernel` for each run (``GQG`` per run)."""
    xp, Pp, status = np.empty_like(x), np.empty_like(P), np.empty(x.shape[0], np.int64)
    for r in range(x.shape[0]):
        xp[r], Pp[r], status[r] = linear_time_update_kernel(x[r], P[r], F, Gu, u[r], GQG[r], True)
    return xp, Pp, status


def _raise_for_runs(status: np.ndarray, where: str, P: np.ndarray) -> None:
    """:func:`fmus.common.kalman.raise_for` of the first diverged run, naming every one (0-based)."""
    bad = np.flatnonzero(status != OK)
    if bad.size:
        try:
            raise_for(int(status[bad[0]]), where, P[bad[0]])
        except FilterDivergence as e:
            raise FilterDivergence(f"{e} (runs {bad.tolist()})") from None


class BatchedEkfModel:
    """:class:`~fmus.estimators.ekf_accelerometer_model.EkfAccelerometerModel`'s ``filtered``
    and ``predicted`` (eq. 3) for many runs of one parameter set, or of parameter sets that
    differ only in the jerk noise ``q_jerk`` (``p`` one per run): each run's ``G_w Q G_w^T``
    is its own single filter's. Each run goes through the single filter's compiled kernels, so
    its numbers are the single filter's, bit for bit."""

    def __init__(self, p: am.EkfAccelerometerParameters | Sequence[am.EkfAccelerometerParameters]) -> None:
        per_run = [p] if isinstance(p, am.EkfAccelerometerParameters) else list(p)
        first = per_run[0]
        if any(dataclasses.replace(q, q_jerk=first.q_jerk) != first for q in per_run):
            raise ValueError("the runs of one batched EKF may differ in q_jerk only")
        self.singles = {q.q_jerk: em.EkfAccelerometerModel(q) for q in per_run}
        self.single = self.singles[first.q_jerk]
        self._q_jerk = [q.q_jerk for q in per_run]
        self.layout = self.single.layout
        self._T: float | None = None

    def _matrices(self, T: float, runs: int) -> None:
        if self._T != T or self.GQG.shape[0] != runs:
            self.F, self.Gu, GQG = self.single.transition(T)
            if len(self.singles) == 1:
                self.GQG = np.repeat(GQG[None], runs, axis=0)
            else:
                self.GQG = np.stack([self.singles[q].transition(T)[2] for q in self._q_jerk])
            self._T = T

    def filtered(self, y: np.ndarray, x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Eq. 3b, as ``EkfAccelerometerModel.filtered`` for each run (the rows of ``y``,
        ``x``, ``P``): ``(x+, P+, normalised innovation norm)``."""
        s = self.single
        xf, Pf, nis, status = _filtered_runs(np.ascontiguousarray(x, float), np.ascontiguousarray(P, float),
                                             np.ascontiguousarray(y, float), s.R, s.meas.constants,
                                             *s.meas.switches)
        _raise_for_runs(status, "EKF diverged in the measurement update", Pf)
        return xf, Pf, np.sqrt(nis)

    def predicted(self, u: np.ndarray, T: float, x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Eqs. 3a, 13, as ``EkfAccelerometerModel.predicted`` for each run."""
        runs = x.shape[0]
        self._matrices(float(T), runs)
        u = np.ascontiguousarray(np.broadcast_to(u, (runs, 2)), float)
        xp, Pp, status = _predicted_runs(np.ascontiguousarray(x, float), np.ascontiguousarray(P, float),
                                         self.F, self.Gu, u, self.GQG)
        _raise_for_runs(status, "EKF diverged in the time update", Pp)
        return xp, Pp


def tool_position(q: np.ndarray, p) -> np.ndarray:
    """``kinematics.tool_position`` (eq. 29) for ``(runs, 2)`` arm angles."""
    q1, phi = q[:, 0], q[:, 0] + q[:, 1]
    s1, c1, sp, cp = np.sin(q1), np.cos(q1), np.sin(phi), np.cos(phi)
    ox, oz = 0.0, 0.0
    r2x = p.l2 * cp + cp * ox + sp * oz
    r2z = -p.l2 * sp - sp * ox + cp * oz
    return np.stack([p.l1 * s1 + r2x, p.l1 * c1 + r2z], axis=1)


class BatchedEkfAccelerometer(FusionSchedule):
    """The EkfAccelerometer FMU (``ekf_accelerometer_fmu.py`` on ``fmus/common/filter_adapter.py``)
    for many runs of one parameter set (or sets differing in ``q_jerk``, one per run:
    :class:`BatchedEkfModel`): the measurement inputs are ``(runs, ...)`` arrays, the
    times (``t``, ``t_meas``) are shared. Call :meth:`initial` where the FMU leaves
    Initialization Mode, :meth:`refresh` where an input changed without a step (the FMU's
    output update) and :meth:`step` per communication step; :meth:`outputs` are then the
    FMU's outputs. The fusion schedule (pending update, commit, prediction to the stamp) is the
    FMU's own code, :class:`~fmus.common.filter_adapter.FusionSchedule`. A diverged run raises
    :class:`~.ekf_accelerometer_model.FilterDivergence` naming it (the FMU ends its step with an
    error there)."""

    def __init__(self, p: am.EkfAccelerometerParameters | Sequence[am.EkfAccelerometerParameters],
                 step: float) -> None:
        self.ekf = BatchedEkfModel(p)
        p = self.ekf.single.p
        self._ix, self._iz = p.index_x - 1, p.index_z - 1
        self._step = step

    # -- inputs: set before each call
    q_m_meas: np.ndarray
    acc_s: np.ndarray
    dddq_a_ref: np.ndarray
    t_meas: float = UNSTAMPED

    # -- the adapter (ekf_accelerometer_fmu.EkfAccelerometer)
    def initial(self, t0: float, runs: int) -> None:
        s = self.ekf.single
        self._u = np.broadcast_to(self.dddq_a_ref, (runs, 2)).copy()
        n = self.ekf.layout.n
        self._est = Estimate(np.broadcast_to(s.x, (runs, n)).copy(), np.broadcast_to(s.P, (runs, n, n)).copy(),
                             np.zeros(runs), self._u)
        self._t_state, self._t_fused, self._pending = t0, -math.inf, None
        self.refresh(t0)

    def _predicted(self, est: Estimate, T: float) -> Estimate:
        x, P = self.ekf.predicted(0.5 * (est.u + self._u), T, est.x, est.P)
        return Estimate(x, P, est.innovation_norm, self._u)

    def _fused(self, prior: Estimate) -> Estimate:
        q = np.broadcast_to(self.q_m_meas, (prior.x.shape[0], 2))
        if self.ekf.layout.use_accelerometer:
            acc = np.broadcast_to(self.acc_s, (prior.x.shape[0], 3))
            y = np.concatenate([q, acc[:, [self._ix, self._iz]]], axis=1)
        else:
            y = np.array(q, dtype=float)
        return Estimate(*self.ekf.filtered(y, prior.x, prior.P), prior.u)

    def _show(self, est: Estimate) -> None:
        self.shown = est

    def outputs(self, names: Sequence[str]) -> dict[str, np.ndarray]:
        """The FMU's outputs ``names`` (whole variables), ``(runs, size)`` each."""
        x, P = self.shown.x, self.shown.P
        make = {"q_a_hat": lambda: x[:, 0:2], "dq_a_hat": lambda: x[:, 2:4], "ddq_a_hat": lambda: x[:, 4:6],
                "p_tool_hat": lambda: tool_position(x[:, 0:2], self.ekf.single.meas.p),
                "trace_P_q": lambda: (P[:, 0, 0] + P[:, 1, 1])[:, None],
                "innovation_norm": lambda: self.shown.innovation_norm[:, None],
                "P_x": lambda: P[:, _TRIL[0], _TRIL[1]]}
        return {n: make[n]() for n in names}

    def refresh(self, now: float) -> None:
        """The FMU's ``update_outputs`` at time ``now`` (an input was set)."""
        self._fuse_and_show(measurement_time(self.t_meas, now), now)

    def step(self, t: float, dt: float) -> None:
        """The FMU's ``step(t, dt)``: commit the pending update, read the jerk input, fuse."""
        if self._pending is None:
            self.refresh(t)
        if self._pending is not None:
            self._commit()
        self._u = np.array(np.broadcast_to(self.dddq_a_ref, self._est.u.shape), dtype=float)
        self.refresh(t + dt)


__all__ = ["BatchedMeasurement", "BatchedEkfModel", "BatchedEkfAccelerometer", "Estimate", "tool_position"]

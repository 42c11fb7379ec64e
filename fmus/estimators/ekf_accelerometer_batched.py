"""The EKF of Axelsson, Karlsson and Norrlöf (2012) for many runs at once: states ``(runs, n)``,
covariances ``(runs, n, n)``, for the batched study engine (:mod:`orchestration.batched`).

The model is :mod:`fmus.estimators.ekf_accelerometer_model` (eqs. 3, 12-19, 26), whose
constants (``F``, ``G_u``, ``G_w Q G_w^T``, ``R``) are used as they are; this module only
repeats its per-sample arithmetic with a leading run axis, so that each run's numbers are the
single filter's (measured: bit for bit on the 2012 scenario; numpy's batched matrix products
and solves call the same LAPACK/BLAS kernels per matrix). The measurement model over runs is
:class:`~fmus.estimators.axelsson2012_batched.BatchedMeasurement`, the compiled one the
particle filter uses over particles (each row the scalar model's numbers, bit for bit).
:class:`BatchedEkfAccelerometer` repeats the FMU adapter (``ekf_accelerometer_fmu.py``) and its
base :class:`~fmus.estimators.filter_adapter.FilterAdapter`: the same commit / predict /
update order and the same sample-time rule.
"""
from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple, Sequence

import numpy as np

from fmus.common.sample_time import TIME_TOL, UNSTAMPED, intervals, measurement_time
from fmus.common.kalman import FilterDivergence
from fmus.estimators import axelsson2012_model as am
from fmus.estimators import ekf_accelerometer_model as em
from fmus.estimators.axelsson2012_batched import BatchedMeasurement

_TRIL = np.tril_indices(6)


def _T(a: np.ndarray) -> np.ndarray:
    """The transpose of each matrix of a stack."""
    return np.swapaxes(a, -1, -2)


class Estimate(NamedTuple):
    """The adapter's estimate (``ekf_accelerometer_fmu.Estimate``) for every run."""

    x: np.ndarray                # (runs, n)
    P: np.ndarray                # (runs, n, n)
    innovation_norm: np.ndarray  # (runs,)
    u: np.ndarray                # (runs, 2)


class BatchedEkfModel:
    """:class:`~fmus.estimators.ekf_accelerometer_model.EkfAccelerometerModel`'s ``filtered``
    and ``predicted`` (eq. 3) for many runs of one parameter set, or of parameter sets that
    differ only in the jerk noise ``q_jerk`` (``p`` one per run): each run's ``G_w Q G_w^T``
    is its own single filter's."""

    def __init__(self, p: am.EkfAccelerometerParameters | Sequence[am.EkfAccelerometerParameters]) -> None:
        per_run = [p] if isinstance(p, am.EkfAccelerometerParameters) else list(p)
        first = per_run[0]
        if any(dataclasses.replace(q, q_jerk=first.q_jerk) != first for q in per_run):
            raise ValueError("the runs of one batched EKF may differ in q_jerk only")
        self.singles = {q.q_jerk: em.EkfAccelerometerModel(q) for q in per_run}
        self.single = self.singles[first.q_jerk]
        self._q_jerk = [q.q_jerk for q in per_run] if len(self.singles) > 1 else None
        self.layout = self.single.layout
        self.meas = BatchedMeasurement(self.single.meas)
        self._T: float | None = None

    def _matrices(self, T: float) -> None:
        if self._T != T:
            for s in self.singles.values():
                s._matrices(T)
            self.F, self.Gu = self.single.F, self.single.Gu
            self.GQG = (self.single.GQG if self._q_jerk is None
                        else np.stack([self.singles[q].GQG for q in self._q_jerk]))
            self._T = T

    def filtered(self, y: np.ndarray, x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Eq. 3b (Joseph form), as ``EkfAccelerometerModel.filtered``."""
        R, n = self.single.R, self.layout.n
        with np.errstate(all="ignore"):
            hx, H = self.meas.h_and_jacobian(x)
            nu = y - hx
            S = H @ P @ _T(H) + R
            Sc = _cholesky(S, "the measurement update: the innovation covariance is not positive definite")
            PHt = P @ _T(H)
            # Sc^-1 (H P | nu) in one call: the gain's columns come out as in the single filter,
            # the normalised innovation z to round-off
            W = np.linalg.solve(Sc, np.concatenate([_T(PHt), nu[:, :, None]], axis=2))
            K = _T(np.linalg.solve(_T(Sc), W[:, :, :n]))
            z = W[:, :, n]
            xf = x + (K @ nu[:, :, None])[:, :, 0]
            IKH = np.eye(n) - K @ H
            Pf = IKH @ P @ _T(IKH) + K @ R @ _T(K)
            Pf = 0.5 * (Pf + _T(Pf))
        _check(xf, Pf, "measurement update")
        return xf, Pf, np.sqrt(np.einsum("ri,ri->r", z, z))

    def predicted(self, u: np.ndarray, T: float, x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Eqs. 3a, 13, as ``EkfAccelerometerModel.predicted``."""
        self._matrices(float(T))
        with np.errstate(all="ignore"):
            x = (self.F @ x[:, :, None])[:, :, 0] + (self.Gu @ np.asarray(u, float)[:, :, None])[:, :, 0]
            P = self.F @ P @ self.F.T + self.GQG
            P = 0.5 * (P + _T(P))
        _check(x, P, "time update")
        return x, P


def _cholesky(A: np.ndarray, what: str) -> np.ndarray:
    try:
        return np.linalg.cholesky(A)
    except np.linalg.LinAlgError:
        raise FilterDivergence(f"EKF diverged in {what} (runs {_bad_runs(A)})") from None


def _bad_runs(A: np.ndarray) -> list[int]:
    bad = []
    for r, a in enumerate(A):
        try:
            np.linalg.cholesky(a)
        except np.linalg.LinAlgError:
            bad.append(r)
    return bad


def _check(x: np.ndarray, P: np.ndarray, where: str) -> None:
    """``ekf_accelerometer_model._check`` for every run; the error names the runs (0-based)."""
    finite = np.isfinite(x).all(axis=1) & np.isfinite(P).all(axis=(1, 2))
    if not finite.all():
        raise FilterDivergence(f"EKF diverged in the {where}: non-finite state or covariance "
                                  f"(runs {np.flatnonzero(~finite).tolist()})")
    _cholesky(P, f"the {where}: the covariance is not positive definite")


def tool_position(q: np.ndarray, p) -> np.ndarray:
    """``kinematics.tool_position`` (eq. 29) for ``(runs, 2)`` arm angles."""
    q1, phi = q[:, 0], q[:, 0] + q[:, 1]
    s1, c1, sp, cp = np.sin(q1), np.cos(q1), np.sin(phi), np.cos(phi)
    ox, oz = 0.0, 0.0
    r2x = p.l2 * cp + cp * ox + sp * oz
    r2z = -p.l2 * sp - sp * ox + cp * oz
    return np.stack([p.l1 * s1 + r2x, p.l1 * c1 + r2z], axis=1)


class BatchedEkfAccelerometer:
    """The EkfAccelerometer FMU (``ekf_accelerometer_fmu.py`` on ``fmus/common/filter_adapter.py``)
    for many runs of one parameter set (or sets differing in ``q_jerk``, one per run:
    :class:`BatchedEkfModel`): the measurement inputs are ``(runs, ...)`` arrays, the
    times (``t``, ``t_meas``) are shared. Call :meth:`initial` where the FMU leaves
    Initialization Mode, :meth:`refresh` where an input changed without a step (the FMU's
    output update) and :meth:`step` per communication step; :meth:`outputs` are then the
    FMU's outputs. A diverged run raises :class:`~.ekf_accelerometer_model.FilterDivergence`
    naming it (the FMU ends its step with an error there)."""

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
        self._refresh(t0)

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

    # -- the base (filter_adapter.FilterAdapter), without the FMI parts
    def _predicted_to(self, est: Estimate, t0: float, t1: float) -> Estimate:
        if t1 <= t0 + TIME_TOL:
            return est
        n, T = intervals(t0, t1, self._step)
        for _ in range(n):
            est = self._predicted(est, T)
        return est

    def _commit(self) -> None:
        (self._t_state, self._est), self._pending = self._pending, None
        self._t_fused = self._t_state

    def _refresh(self, now: float) -> None:
        t_m = measurement_time(self.t_meas, now)
        if t_m <= now + TIME_TOL:
            if self._pending is not None and t_m > self._pending[0] + TIME_TOL:
                self._commit()
            if t_m > self._t_fused + TIME_TOL:
                prior = self._predicted_to(self._est, self._t_state, t_m)
                self._pending = (t_m, self._fused(prior))
        t, est = self._pending if self._pending is not None else (self._t_state, self._est)
        self._show(self._predicted_to(est, t, now))

    def refresh(self, now: float) -> None:
        """The FMU's ``update_outputs`` at time ``now`` (an input was set)."""
        self._refresh(now)

    def step(self, t: float, dt: float) -> None:
        """The FMU's ``step(t, dt)``: commit the pending update, read the jerk input, fuse."""
        if self._pending is None:
            self._refresh(t)
        if self._pending is not None:
            self._commit()
        self._u = np.array(np.broadcast_to(self.dddq_a_ref, self._est.u.shape), dtype=float)
        self._refresh(t + dt)


__all__ = ["BatchedMeasurement", "BatchedEkfModel", "BatchedEkfAccelerometer", "Estimate", "tool_position"]

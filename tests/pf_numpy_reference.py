"""The particle filter's sampling and weighting as numpy code (main before the compiled kernels,
commit f04d4a7): the reference the kernels of ``particle_filter_model.propose_and_weigh`` and
``axelsson2012_batched.measure_many`` are tested against. Kept here verbatim (only the class
and function names shortened), not used by the package."""
from __future__ import annotations

import numpy as np

from fmus.common import dynamics


class NumpyMeasurement:
    """``h(x)`` of eq. 15 and its Jacobian, vectorised over particles with numpy (the former
    ``BatchMeasurementModel``); ``meas`` is the scalar model."""

    def __init__(self, meas) -> None:
        self.meas = meas
        self.p = meas.p
        self.layout = meas.layout
        self.a, self.c, self.e = meas.a, meas.c, meas.e
        self.g1, self.g2, self.g, self.l1 = meas.g1, meas.g2, meas.g, meas.l1
        self.v, self.Sv, self.r = meas.v, meas.Sv, meas.r
        p = self.p
        self.k_hi = np.asarray(p.k_hi, float)
        self.k_soft = self.k_hi - np.asarray(p.k_lo, float)
        self.delta = np.asarray(p.delta, float)

    def arm_torque(self, X):
        q1, q2, dq1, dq2, a1, a2 = X[:, 0], X[:, 1], X[:, 2], X[:, 3], X[:, 4], X[:, 5]
        b = -self.e * np.sin(q2)
        bd = -self.e * np.cos(q2)
        gc = self.g2 * np.cos(q1 + q2)
        tau = np.empty((X.shape[0], 2))
        tau[:, 0] = (self.a + 2 * b) * a1 + (self.c + b) * a2 + bd * (2 * dq1 * dq2 + dq2 * dq2) \
            - self.g1 * np.sin(q1) - gc
        tau[:, 1] = (self.c + b) * a1 + self.c * a2 - bd * dq1 * dq1 - gc
        return tau

    def arm_torque_jacobian(self, X):
        q1, q2, dq1, dq2, a1, a2 = X[:, 0], X[:, 1], X[:, 2], X[:, 3], X[:, 4], X[:, 5]
        s2, c2 = np.sin(q2), np.cos(q2)
        gs = self.g2 * np.sin(q1 + q2)
        b, bd, bdd = -self.e * s2, -self.e * c2, self.e * s2
        J = np.zeros((X.shape[0], 2, 6))
        J[:, 0, 0] = -self.g1 * np.cos(q1) + gs
        J[:, 1, 0] = gs
        J[:, 0, 1] = 2 * bd * a1 + bd * a2 + bdd * (2 * dq1 * dq2 + dq2 * dq2) + gs
        J[:, 1, 1] = bd * a1 - bdd * dq1 * dq1 + gs
        J[:, 0, 2] = 2 * bd * dq2
        J[:, 0, 3] = 2 * bd * (dq1 + dq2)
        J[:, 1, 2] = -2 * bd * dq1
        J[:, 0, 4], J[:, 0, 5] = self.a + 2 * b, self.c + b
        J[:, 1, 4], J[:, 1, 5] = self.c + b, self.c
        return J

    def specific_force(self, X):
        q1, q2, dq1 = X[:, 0], X[:, 1], X[:, 2]
        dphi, a1, aphi = dq1 + X[:, 3], X[:, 4], X[:, 4] + X[:, 5]
        c2, s2 = np.cos(q2), np.sin(q2)
        phi = q1 + q2
        u2 = -dq1 * dq1
        d2 = dphi * dphi
        f = np.empty((X.shape[0], 2))
        f[:, 0] = self.l1 * (c2 * a1 - s2 * u2) + self.Sv[0] * aphi - self.v[0] * d2 - self.g * np.sin(phi)
        f[:, 1] = self.l1 * (s2 * a1 + c2 * u2) + self.Sv[1] * aphi - self.v[1] * d2 + self.g * np.cos(phi)
        return f

    def specific_force_jacobian(self, X):
        q1, q2, dq1 = X[:, 0], X[:, 1], X[:, 2]
        dphi, a1 = dq1 + X[:, 3], X[:, 4]
        c2, s2 = np.cos(q2), np.sin(q2)
        phi = q1 + q2
        cp, sp = np.cos(phi), np.sin(phi)
        u2 = -dq1 * dq1
        l1, v, Sv, g = self.l1, self.v, self.Sv, self.g
        J = np.zeros((X.shape[0], 2, 6))
        J[:, 0, 0] = -g * cp
        J[:, 1, 0] = -g * sp
        J[:, 0, 1] = -g * cp + l1 * (-s2 * a1 - c2 * u2)
        J[:, 1, 1] = -g * sp + l1 * (c2 * a1 - s2 * u2)
        J[:, 0, 2] = 2 * l1 * s2 * dq1 - 2 * v[0] * dphi
        J[:, 1, 2] = -2 * l1 * c2 * dq1 - 2 * v[1] * dphi
        J[:, 0, 3] = -2 * v[0] * dphi
        J[:, 1, 3] = -2 * v[1] * dphi
        J[:, 0, 4] = l1 * c2 + Sv[0]
        J[:, 1, 4] = l1 * s2 + Sv[1]
        J[:, 0, 5] = Sv[0]
        J[:, 1, 5] = Sv[1]
        return J

    def deflection(self, X, D0=None):
        tau = self.arm_torque(X)
        k_hi, k_soft, delta = self.k_hi, self.k_soft, self.delta
        if D0 is None:
            D = (tau + np.sign(tau) * k_soft * delta * np.tanh(np.abs(tau) / (k_hi * delta))) / k_hi
        else:
            D = np.array(D0, float)
        tol = 1e-12 * np.maximum(1.0, np.abs(tau))
        for _ in range(50):
            t = np.tanh(D / delta)
            f = k_hi * D - k_soft * delta * t - tau
            if np.all(np.abs(f) <= tol):
                break
            D = D - f / (k_hi - k_soft * (1.0 - t * t))
        return D

    def h(self, X, D=None):
        L = self.layout
        Y = np.empty((X.shape[0], L.m))
        Y[:, 0:2] = self.r * (X[:, 0:2] + (self.deflection(X) if D is None else D))
        if L.bias_m is not None:
            Y[:, 0:2] += X[:, L.bias_m]
        if L.use_accelerometer:
            Y[:, 2:4] = self.specific_force(X)
            if L.bias_acc is not None:
                Y[:, 2:4] += X[:, L.bias_acc]
        return Y

    def jacobian(self, X, D=None):
        L = self.layout
        H = np.zeros((X.shape[0], L.m, L.n))
        k = dynamics.spring_stiffness(self.deflection(X) if D is None else D, self.p)
        H[:, 0:2, 0:6] = (self.r / k)[:, :, None] * self.arm_torque_jacobian(X)
        H[:, 0, 0] += self.r[0]
        H[:, 1, 1] += self.r[1]
        if L.bias_m is not None:
            H[:, 0, L.bias_m.start] += 1.0
            H[:, 1, L.bias_m.start + 1] += 1.0
        if L.use_accelerometer:
            H[:, 2:4, 0:6] = self.specific_force_jacobian(X)
            if L.bias_acc is not None:
                H[:, 2, L.bias_acc.start] += 1.0
                H[:, 3, L.bias_acc.start + 1] += 1.0
        return H


def finite_rows(X):
    with np.errstate(invalid="ignore"):
        return np.isfinite(X @ np.ones(X.shape[1]))


def chol_solve(A, b, Z):
    if A.shape[1] == 2:
        c11 = np.sqrt(A[:, 0, 0])
        c21 = A[:, 1, 0] / c11
        c22 = np.sqrt(A[:, 1, 1] - c21 * c21)
        z1 = b[:, 0] / c11
        z2 = (b[:, 1] - c21 * z1) / c22
        x2 = z2 / c22
        x1 = (z1 - c21 * x2) / c11
        v2 = Z[:, 1] / c22
        v1 = (Z[:, 0] - c21 * v2) / c11
        return (np.column_stack([x1, x2]), np.column_stack([v1, v2]),
                np.log(c11) + np.log(c22))
    C = np.linalg.cholesky(A)
    Ct = np.swapaxes(C, 1, 2)
    z = np.linalg.solve(C, b[:, :, None])
    x = np.linalg.solve(Ct, z)[:, :, 0]
    v = np.linalg.solve(Ct, Z[:, :, None])[:, :, 0]
    return x, v, np.log(np.diagonal(C, axis1=1, axis2=2)).sum(axis=1)


def propose_and_weigh(batch: NumpyMeasurement, proposal, r_inv, M, L, logw_prev, y, Z):
    """The former ``ParticleFilterModel._sample_and_weight`` up to the unnormalised log-weights,
    with the standard normals ``Z`` given: ``(X, logw)``, ``-inf`` and a zero row where not finite."""
    n_p, k = M.shape[0], L.shape[1]
    D0 = None
    with np.errstate(all="ignore"):
        if proposal == "ekf":
            D0 = batch.deflection(M)
            m = batch.layout.m
            He = (batch.jacobian(M, D0).reshape(n_p * m, -1) @ L).reshape(n_p, m, k)
            HtRi = np.swapaxes(He, 1, 2) * r_inv
            A = HtRi @ He
            A[:, range(k), range(k)] += 1.0
            b = (HtRi @ (y - batch.h(M, D0))[:, :, None])[:, :, 0]
            bad = ~(finite_rows(A.reshape(n_p, k * k)) & finite_rows(b))
            if bad.any():
                A[bad], b[bad] = np.eye(k), 0.0
            mu, v, logdet_half = chol_solve(A, b, Z)
            E = mu + v
            dlog = 0.5 * (np.einsum("ij,ij->i", Z, Z) - np.einsum("ij,ij->i", E, E)) - logdet_half
        else:
            E, dlog = Z, 0.0
        X = M + E @ L.T
        nu = y - batch.h(X, batch.deflection(X, D0))
        logw = logw_prev - 0.5 * (nu * nu) @ r_inv + dlog
        ok = np.isfinite(logw) & finite_rows(X)
    return np.where(ok[:, None], X, 0.0), np.where(ok, logw, -np.inf)


def systematic_resample(w, u):
    """The former ``systematic_resample`` (cumulative sum and a sorted search)."""
    n = w.shape[0]
    c = np.cumsum(w)
    c /= c[-1]
    idx = np.searchsorted(c, (u + np.arange(n)) / n, side="right")
    return np.minimum(idx, n - 1)


def weighted_mean_cov(X, w):
    """The former ``weighted_mean_cov`` (matrix products)."""
    x = w @ X
    d = X - x
    return x, (d * w[:, None]).T @ d


def kernel_move(X, x, P, h, Z, sum_w2=0.0):
    """The former ``kernel_move`` of resampled particles ``X``."""
    lam, V = np.linalg.eigh(0.5 * (P + P.T))
    S = V * np.sqrt(np.clip(lam, 0.0, None))
    a = np.sqrt(1.0 - h * h)
    c = np.sqrt(1.0 / (1.0 - sum_w2) - a * a) if sum_w2 < 1.0 else h
    return a * X + (1.0 - a) * x + c * (Z @ S.T)

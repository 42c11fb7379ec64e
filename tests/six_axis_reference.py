"""The six-axis plant's right side in numpy: the readable form the compiled kernel
(``fmus/robot_plant/six_axis_kernels.pyx``) was written from, kept as the tests' oracle
(tests/test_six_axis_kernel.py holds the kernel to it, and tests/test_six_axis_model.py holds
it to Pinocchio). Not in the product: the product computes each thing once, in the kernel.

Featherstone's algorithms (2008) in world coordinates over any tree of revolute joints
(:class:`fmus.robot_plant.six_axis_model.Tree`): RNEA (section 5.3) and CRBA (section 6.2),
their recursions written as sums along the tree's paths with the ancestor matrix (``v = A (S
dq)`` forward, ``f = A^T f^B`` backward); forward dynamics by a dense solve of ``M``.
"""
from __future__ import annotations

import math

import numpy as np

from fmus.robot_plant.six_axis_model import SixAxisPlant, Tree

_P1, _P2 = [1, 2, 0], [2, 0, 1]


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross products of (n, 3) arrays ``a x b`` (cheaper than np.cross for small n)."""
    return a[:, _P1] * b[:, _P2] - a[:, _P2] * b[:, _P1]


def _skew(v: np.ndarray) -> np.ndarray:
    """``[v]x`` (n, 3, 3) of the rows of ``v`` (n, 3)."""
    K = np.zeros(v.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    K[..., 1, 0], K[..., 2, 0], K[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return K


def _crm(v: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Spatial motion cross product ``v x m`` of rows (n, 6): ``(w x a, w x b + u x a)`` for
    ``v = (w, u)``, ``m = (a, b)`` (Featherstone 2008, eq. 2.31); one call of :func:`_cross`."""
    n = len(v)
    w, u, a, b = v[:, :3], v[:, 3:], m[:, :3], m[:, 3:]
    c = _cross(np.concatenate([w, w, u]), np.concatenate([a, b, a]))
    return np.concatenate([c[:n], c[n:2 * n] + c[2 * n:]], axis=1)


def _crf(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Spatial force cross product ``v x* f`` of rows (n, 6): ``(w x n + u x f, w x f)`` for
    ``v = (w, u)``, ``f = (n, f)`` (Featherstone 2008, eq. 2.32); one call of :func:`_cross`."""
    n = len(v)
    w, u, nf, fl = v[:, :3], v[:, 3:], f[:, :3], f[:, 3:]
    c = _cross(np.concatenate([w, u, w]), np.concatenate([nf, fl, fl]))
    return np.concatenate([c[:n] + c[n:2 * n], c[2 * n:]], axis=1)


class RigidBodyDynamics:
    """RNEA, CRBA and forward dynamics of a :class:`Tree` ``tree`` in world coordinates (the
    module docstring); methods take the joint angles ``q`` [rad], rates ``dq`` [rad/s] and
    accelerations ``ddq`` [rad/s^2] (n each) or the :meth:`kinematics` ``k`` of ``q``."""

    def __init__(self, tree: Tree) -> None:
        self.tree = tree
        self.n = tree.n
        self.A = tree.ancestors()
        self.AT = self.A.T.copy()
        self.has_parent = tree.parent >= 0
        self.par = np.where(self.has_parent, tree.parent, 0)
        self.a0 = np.array([0.0, 0.0, 0.0, 0.0, 0.0, tree.g])      # gravity: the base accelerates up
        self.tool_path = self.A[tree.tool].copy()
        self._K = _skew(tree.axis)                                # Rodrigues: I + sin K + (1 - cos) K^2
        self._KK = self._K @ self._K
        self._axis = tree.axis[:, :, None]
        self._T = np.zeros((self.n, 4, 4))
        self._T[:, :3, :3] = np.eye(3)
        self._T[:, :3, 3] = tree.origin
        self._T[:, 3, 3] = 1.0
        self._com = tree.com[:, :, None]
        self._m = tree.mass[:, None, None]
        self._mI = tree.mass[:, None, None] * np.eye(3)

    def kinematics(self, q) -> dict:
        """World rotation ``R`` (n, 3, 3) and origin ``o`` (n, 3) of each body, the joint axes ``z``
        (n, 3), the motion subspaces ``S`` (n, 6) at the world origin ``(z, o x z)``, the centres
        of mass ``c`` (n, 3) and the spatial inertias ``I`` (n, 6, 6) at the world origin,
        ``[[I_c + m [c]x [c]x^T, m [c]x], [m [c]x^T, m 1]]`` (Featherstone 2008, eq. 2.63), at ``q``."""
        t = self.tree
        qa = np.asarray(q, float)[:, None, None]
        T = self._T.copy()                       # joint transforms: origin, then the rotation
        T[:, :3, :3] += np.sin(qa) * self._K + (1.0 - np.cos(qa)) * self._KK
        Ts = []
        for i, j in enumerate(t.parent):
            Ts.append(T[i] if j < 0 else Ts[j] @ T[i])
        W = np.array(Ts)
        R, o = W[:, :3, :3], W[:, :3, 3]
        z = (R @ self._axis)[:, :, 0]
        c = o + (R @ self._com)[:, :, 0]
        C = _skew(c)
        mC = self._m * C
        I = np.empty((self.n, 6, 6))
        I[:, :3, :3] = R @ t.inertia @ R.transpose(0, 2, 1) - mC @ C
        I[:, :3, 3:] = mC
        I[:, 3:, :3] = -mC
        I[:, 3:, 3:] = self._mI
        S = np.concatenate([z, _cross(o, z)], axis=1)
        return dict(R=R, o=o, z=z, c=c, S=S, I=I)

    def rnea(self, q, dq, ddq, k: dict | None = None) -> np.ndarray:
        """Inverse dynamics ``tau = M ddq + C dq + G`` [N m] (Featherstone 2008, section 5.3,
        world coordinates; the recursions as path sums through the ancestor matrix)."""
        k = self.kinematics(q) if k is None else k
        S, I = k["S"], k["I"]
        Sdq = S * np.asarray(dq, float)[:, None]
        v = self.A @ Sdq
        vp = v - Sdq                                             # the parent's velocity
        a = self.a0 + self.A @ (S * np.asarray(ddq, float)[:, None] + _crm(vp, Sdq))
        f = (I @ a[:, :, None])[:, :, 0] + _crf(v, (I @ v[:, :, None])[:, :, 0])
        return np.sum(S * (self.AT @ f), axis=1)

    def mass_matrix(self, q, k: dict | None = None) -> np.ndarray:
        """Joint-space inertia matrix ``M`` (n, n) [kg m^2] (CRBA, Featherstone 2008, section 6.2)."""
        k = self.kinematics(q) if k is None else k
        S = k["S"]
        Ic = (self.AT @ k["I"].reshape(self.n, 36)).reshape(self.n, 6, 6)   # composite inertia of each subtree
        F = (Ic @ S[:, :, None])[:, :, 0]
        P = (S @ F.T) * self.AT                                  # P[j, i] = S_j . Ic_i S_i, j ancestor of i
        return P + P.T - np.diag(np.diag(P))

    def external(self, wrench, k: dict) -> np.ndarray:
        """Generalised force [N m] of the ``wrench`` (force (3) [N], moment (3) [N m], world axes)
        on the tool at its centre point: ``S_j . (m + p x f, f)`` for the tool's ancestors."""
        w = np.asarray(wrench, float)
        p = k["o"][self.tree.tool] + k["R"][self.tree.tool] @ self.tree.tcp
        f0 = np.concatenate([w[3:] + np.cross(p, w[:3]), w[:3]])
        return (k["S"] @ f0) * self.tool_path

    def potential_energy(self, q, k: dict | None = None) -> float:
        """Gravitational potential energy [J] of the bodies at ``q``: ``sum m_i g z_ci``."""
        k = self.kinematics(q) if k is None else k
        return float(self.tree.g * self.tree.mass @ k["c"][:, 2])


def derivatives(m: SixAxisPlant, dyn: RigidBodyDynamics, x, current, wrench=None) -> np.ndarray:
    """``x_dot`` of the plant ``m`` (its drive-train arrays) at the state ``x`` with the motor
    ``current`` (6) and the tool ``wrench`` (6 or ``None``), rigid-body terms from ``dyn``."""
    n = m.n
    q, qm, dq, dqm, z = m.split(x)
    k = dyn.kinematics(q)
    D = qm / m.r - q[m.act]
    Dd = dqm / m.r - dq[m.act]
    tau_g = m.k_hi * D - m.k_soft * m.delta * np.tanh(D / m.delta) + m.d * Dd + m.k_h * z
    tau = np.zeros(n)
    tau[m.act] = tau_g
    tau[m.pas] = -m.k_p * q[m.pas] - m.d_p * dq[m.pas]
    if wrench is not None:
        tau += dyn.external(wrench, k)
    rhs = tau - dyn.rnea(q, dq, np.zeros(n), k)
    M = dyn.mass_matrix(q, k)
    ddq = np.zeros(n)
    f = m.free
    ddq[f] = np.linalg.solve(M[np.ix_(f, f)], rhs[f])
    applied = m.kt * np.asarray(current, float) + m.ripple * np.sin(m.periods * qm)
    level = m.f_c + (m.f_s - m.f_c) * np.exp(-(dqm / m.w_s) ** 2) + m.mu_L * np.abs(tau_g) / m.r
    ddqm = (applied - (m.f_v * dqm + level * np.tanh(dqm / m.w_c)) - tau_g / m.r) / m.J_m
    ddqm[m.locked] = 0.0
    if m.hyst:
        dz = Dd - (np.abs(Dd) * z + Dd * np.abs(z)) / (2.0 * m.z0)
    else:
        dz = np.zeros(6)
    return np.concatenate([dq, dqm, ddq, ddqm, dz])


def step(m: SixAxisPlant, dyn: RigidBodyDynamics, x, i0, tau_m, wrench, dt: float, substeps: int) -> tuple:
    """``(x, current)`` after ``dt`` [s] from ``x`` and the current ``i0`` with ``tau_m`` and
    the tool ``wrench`` held: ``substeps`` RK4 steps, the current exact at each stage."""
    h = dt / substeps
    for k in range(substeps):
        t0 = k * h
        c0 = m.current_at(i0, tau_m, t0)
        cm = m.current_at(i0, tau_m, t0 + 0.5 * h)
        c1 = m.current_at(i0, tau_m, t0 + h)
        k1 = derivatives(m, dyn, x, c0, wrench)
        k2 = derivatives(m, dyn, x + 0.5 * h * k1, cm, wrench)
        k3 = derivatives(m, dyn, x + 0.5 * h * k2, cm, wrench)
        k4 = derivatives(m, dyn, x + h * k3, c1, wrench)
        x = x + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return x, m.current_at(i0, tau_m, dt)

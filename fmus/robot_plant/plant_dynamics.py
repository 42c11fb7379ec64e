"""The plant's own dynamics: the flexible-joint robot plus what no estimator's model has.

The estimators use the 8-state flexible-joint model of :mod:`fmus.common.dynamics` (Axelsson
2012, eqs. 10-11) with the nominal :class:`~fmus.common.robot_params.RobotParameters`. The real
robot differs from it by

1. **elasticity beyond the gearbox** (the extended flexible-joint model of Moberg, Wernholt,
   Hanssen and Brogardh, "Modeling and parameter estimation of robot manipulators using extended
   flexible joint models", ASME J. Dyn. Sys. Meas. Control 136, 2014: non-actuated elastic joints
   that stand for link and bearing bending). Each link is split, at ``bend_location`` of its
   length, by a non-actuated rotational joint with a linear spring-damper: the arm becomes a
   planar chain of four bodies (inner upper arm, outer upper arm, inner forearm, outer forearm).
   With the motors locked, the wrist end of the forearm (wrist, tool, payload) vibrates on its
   bending joint at 34-36 Hz over the workspace, above the gearbox modes (8-19 Hz, almost
   unchanged): a mode that moves the tool with 92-100 % of its strain energy in the bending
   joints, not in the gearbox springs. The upper-arm bending, much stiffer than its gearbox,
   adds a local mode of the light inner upper arm between its two springs (about 220 Hz, 15 %
   damped). Gravity bends the links by about 0.2 mm at the tool;
2. **motor torque errors**: torque-constant error and cogging / commutation ripple, periodic in
   the motor angle: ``tau_applied = (1 + e_kt) tau_m + A sin(n q_m)`` (``tau_m``: the commanded
   torque, the plant's input, which the estimators receive);
3. **static kinematic errors**: true link lengths ``l + dl``, arm-side joint zero offsets
   ``q_offset`` (the link's real direction is ``q_a + q_offset`` where ``q_a`` is the encoder's
   arm angle) and an accelerometer mount error ``sensor_offset_error``;
4. optionally (off by default), the force paper's **compliant tool** (:class:`CompliantTool`).

``ideal = true`` bypasses all of it: :class:`IdealPlant` is today's 8-state plant.

Coordinates. Body ``k`` of the chain is entered through joint ``k`` (relative angle ``theta_k``)
and points along ``u(psi_k) = (sin psi_k, cos psi_k)`` (world x, z) with the absolute angle
``psi_k = psi_{k-1} + theta_k + o_k``; the constant offsets ``o_k`` are the zero offsets and, at
the elbow, ``pi/2`` (the forearm of :mod:`fmus.common.kinematics` points along
``(cos phi, -sin phi) = u(phi + pi/2)``). The joint angles are ``(q1, b1, q2, b2)`` with bending
(``(q1, q2)`` with rigid links); the state is ``(theta, q_m, dtheta, dq_m)``. ``q_a`` is the gearbox
output angle (``q_m / r - D``), as in the 8-state model.

Equations (Lagrange, absolute angles, planar serial chain). With body length ``L_k`` (joint to
next joint; the last one to the tool point), mass ``m_k``, centre of mass ``c_k`` along the body,
inertia ``I_k`` about it, ``m_{>k}`` the mass beyond body ``k`` and ``g_k = m_k c_k + m_{>k} L_k``:

.. math::

    \\sum_k M_{jk} \\ddot\\psi_k + \\sum_k h_{jk} \\sin(\\psi_j - \\psi_k) \\dot\\psi_k^2 = Q_j,
    \\quad M_{jk} = h_{jk} \\cos(\\psi_j - \\psi_k),\\ h_{jk} = L_{\\min(j,k)} g_{\\max(j,k)}\\ (j \\ne k),
    \\ M_{kk} = I_k + m_k c_k^2 + m_{>k} L_k^2

with the generalised forces ``Q_j = g g_j sin psi_j + L_j (f_x cos psi_j - f_z sin psi_j)
+ tau_j - tau_{j+1}`` (gravity, tool force by virtual work, joint torques ``tau_j`` of joint ``j``
on body ``j``): the gearbox torque ``tau_s(D) + d D_dot`` of eq. 11, or ``-(k_b b + d_b b_dot)``
at a bending joint. The motors follow eq. 10 with the applied torque of item 2.

The hot path: the four-body chain's equations written out (an LDL^T solve of the 4x4 system)
and compiled (robot_plant/plant_kernels.pyx, Cython); plain-float Python loops over the bodies
for a chain of rigid links (``link_bending = false``), which the tests also hold the compiled
chain to.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from fmus.common import cython_kernels, dynamics, kinematics
from fmus.common.parameters import ParameterError

HALF_PI = 0.5 * math.pi


def true_link(p, i: int) -> tuple[float, float, float, float]:
    """``(L, m, c, I)`` of the rigid link ``i`` (0 or 1) of the real robot described by the plant
    parameters ``p``: true length ``l + dl``."""
    if i == 0:
        return float(p.l1 + p.dl[0]), float(p.m1), float(p.c1), float(p.I1)
    return float(p.l2 + p.dl[1]), float(p.m2), float(p.c2), float(p.I2)


def split_link(p, i: int) -> tuple[tuple, tuple]:
    """Bodies ``(L, m, c, I)`` of link ``i`` (0 or 1) of the plant parameters ``p``, split at
    ``s l`` (``s = bend_location``, ``l`` the true length): the inner part a uniform rod with the
    mass share ``mu = bend_mass_fraction``; the outer part carries the rest, with the link's
    total centre of mass and inertia (so that the rigid chain is the link).

    Raises
    ------
    ParameterError
        If the outer part would need a negative inertia.
    """
    l, m, c, I = true_link(p, i)
    s, mu = float(p.bend_location[i]), float(p.bend_mass_fraction[i])
    Li, mi = s * l, mu * m
    ci, Ii = 0.5 * Li, mi * Li * Li / 12.0
    mo = m - mi
    co_abs = (m * c - mi * ci) / mo                 # from the link's proximal joint
    Io = I + m * c * c - (Ii + mi * ci * ci) - mo * co_abs * co_abs
    if Io < 0.0:
        raise ParameterError(
            f"parameter 'bend_mass_fraction[{i + 1}]' = {mu} with 'bend_location[{i + 1}]' = {s}: the outer "
            f"part of link {i + 1} would need a negative inertia ({Io:.3g} kg.m2); put more mass inside")
    return (Li, mi, ci, Ii), ((1.0 - s) * l, mo, co_abs - Li, Io)


# ---- the four-body chain, compiled (the default plant's hot path) -----------------------------
# robot_plant/plant_kernels.pyx: the chain's equations written out (an LDL^T solve of the 4x4
# system) on its constants ``P`` (:meth:`PlantChain._pack`; the fields of its struct ``Chain4``,
# in the array's order); the tests hold them to PlantChain's loops over the bodies.
_kernels = cython_kernels.load("robot_plant.plant_kernels")
chain4_step = _kernels.chain4_step
chain4_outputs = _kernels.chain4_outputs
chain4_advance = _kernels.chain4_advance


class PlantChain:
    """The plant's parameters as plain floats and the chain's equations of motion.

    Parameters
    ----------
    p
        :class:`fmus.robot_plant.plant_model.PlantParameters` (``ideal`` must be false).

    Notes
    -----
    Methods take the state ``s`` (a tuple), the motor torque commands ``tau1, tau2`` (N m,
    motor side) and the external force on the tool ``fx, fz`` (N, world x and z).
    """

    def __init__(self, p) -> None:
        self.p = p
        self.robot = p.robot()
        self.k = dynamics.ArmConstants(self.robot)    # gearbox spring, motor and friction constants
        g = float(p.g)
        bodies, kinds, offsets = [], [], []         # kinds: ("gear", axis) or ("bend", k_b, d_b)
        for i in range(2):
            offsets.append(float(p.q_offset[i]) + (HALF_PI if i == 1 else 0.0))
            kinds.append(("gear", i))
            if p.link_bending:
                bodies += split_link(p, i)
                kinds.append(("bend", float(p.bend_stiffness[i]), float(p.bend_damping[i])))
                offsets.append(0.0)
            else:
                bodies.append(true_link(p, i))
        self.n = n = len(bodies)
        self.L = [b[0] for b in bodies]
        beyond = [sum(b[1] for b in bodies[k + 1:]) for k in range(n)]
        gk = [b[1] * b[2] + beyond[k] * b[0] for k, b in enumerate(bodies)]
        self.grav = [g * v for v in gk]
        self.h = [[self.L[min(j, k)] * gk[max(j, k)] for k in range(n)] for j in range(n)]
        self.m_diag = [b[3] + b[1] * b[2] ** 2 + beyond[k] * b[0] ** 2 for k, b in enumerate(bodies)]
        self.kinds = kinds
        self.offsets = offsets
        self.offset_sum = sum(offsets)
        self.gear_index = [k for k, kind in enumerate(kinds) if kind[0] == "gear"]
        self.bend_index = [k for k, kind in enumerate(kinds) if kind[0] == "bend"]
        self.kt = tuple(1.0 + float(e) for e in p.torque_constant_error)
        self.ripple = tuple(map(float, p.ripple_amplitude))
        self.periods = tuple(map(float, p.ripple_periods))
        self.sensor = tuple(float(a) + float(b) for a, b in zip(p.sensor_offset, p.sensor_offset_error))
        #: the four-body chain's constants for the compiled kernels (None: a chain of rigid links)
        self.P = self._pack() if n == 4 else None

    def _pack(self) -> np.ndarray:
        """The constants of the four-body chain in the kernels' order (the struct ``Chain4`` of
        robot_plant/plant_kernels.pyx): offsets o_1, o_3 | gear ratios r | k_hi | k_hi - k_lo |
        delta | gearbox damping d | f_v | f_c | w_c | J_m | bending k_b, d_b of link 1, then of
        link 2 | h12 h13 h14 h23 h24 h34 | g g_k (4) | L_k (4) | M_kk (4) | 1 + torque-constant
        error (2) | ripple amplitude (2) | ripple periods (2) | sensor offset (x, z) | sum of the
        offsets o_k."""
        k = self.k
        return np.array([self.offsets[0], self.offsets[2], *k.r, *k.k_hi, *k.k_soft, *k.delta, *k.d, *k.f_v,
                         *k.f_c, *k.w_c, *k.jm, *self.kinds[1][1:], *self.kinds[3][1:], *self.h[0][1:],
                         *self.h[1][2:], self.h[2][3], *self.grav, *self.L, *self.m_diag, *self.kt,
                         *self.ripple, *self.periods, *self.sensor, self.offset_sum])

    # ---- the hot path ---------------------------------------------------------------------
    def applied_torque(self, i: int, tau: float, qm: float) -> float:
        """Torque the motor ``i`` applies for the command ``tau`` at motor angle ``qm`` (the same
        expression is written out in :meth:`derivatives`)."""
        return self.kt[i] * tau + self.ripple[i] * math.sin(self.periods[i] * qm)

    def arm(self, s, fx: float, fz: float) -> tuple:
        """Absolute angles' sines, cosines, rates and accelerations of the bodies, and the joint
        torques, at state ``s`` with the tool force ``(fx, fz)`` (any number of bodies; the
        four-body chain's compiled: ``plant_kernels.chain4_arm``)."""
        if self.P is not None:
            return _kernels.chain4_arm(s, fx, fz, self.P)
        n = self.n
        k = self.k
        qm, dqm = s[n:n + 2], s[2 * n + 2:2 * n + 4]
        S, C, W, tj = [], [], [], []
        psi = w = 0.0
        for j, kind in enumerate(self.kinds):
            th, dth = s[j], s[n + 2 + j]
            psi += th + self.offsets[j]
            w += dth
            S.append(math.sin(psi))
            C.append(math.cos(psi))
            W.append(w)
            if kind[0] == "gear":
                i = kind[1]
                r = k.r[i]
                tj.append(k.spring(i, qm[i] / r - th) + k.d[i] * (dqm[i] / r - dth))
            else:
                tj.append(-(kind[1] * th + kind[2] * dth))
        # generalised forces minus the velocity terms; the mass matrix
        b, M = [], []
        h = self.h
        for j in range(n):
            Sj, Cj, hj = S[j], C[j], h[j]
            q = self.grav[j] * Sj + self.L[j] * (fx * Cj - fz * Sj) + tj[j] - (tj[j + 1] if j + 1 < n else 0.0)
            row = []
            for kk in range(n):
                if kk == j:
                    row.append(self.m_diag[j])
                else:
                    row.append(hj[kk] * (Cj * C[kk] + Sj * S[kk]))
                    q -= hj[kk] * (Sj * C[kk] - Cj * S[kk]) * W[kk] * W[kk]
            b.append(q)
            M.append(row)
        return S, C, W, _solve_spd(M, b), tj

    def derivatives(self, s, tau1: float, tau2: float, fx: float, fz: float) -> tuple:
        """``x_dot`` as a tuple of floats (the same call as ``dynamics.ArmConstants.derivatives``)."""
        if self.P is not None:
            return _kernels.chain4_rates(s, tau1, tau2, fx, fz, self.P)
        n, k = self.n, self.k
        _, _, _, A, tj = self.arm(s, fx, fz)
        qm1, qm2, dqm1, dqm2 = s[n], s[n + 1], s[2 * n + 2], s[2 * n + 3]
        j1, j2 = self.gear_index
        (e1, e2), (A1, A2), (n1, n2) = self.kt, self.ripple, self.periods
        ddqm1 = (e1 * tau1 + A1 * math.sin(n1 * qm1) - k.f_v[0] * dqm1 - k.f_c[0] * math.tanh(dqm1 / k.w_c[0])
                 - tj[j1] / k.r[0]) / k.jm[0]
        ddqm2 = (e2 * tau2 + A2 * math.sin(n2 * qm2) - k.f_v[1] * dqm2 - k.f_c[1] * math.tanh(dqm2 / k.w_c[1])
                 - tj[j2] / k.r[1]) / k.jm[1]
        return s[n + 2:] + (A[0],) + tuple(A[j] - A[j - 1] for j in range(1, n)) + (ddqm1, ddqm2)

    def outputs(self, s, fx: float, fz: float) -> tuple:
        """Every plant output at state ``s``, as plain floats: ``q_a, dq_a, ddq_a, q_m, dq_m`` (2
        each), ``p_tool, v_tool, a_tool`` (2 each), ``phi_tool, omega_tool``, ``p_sensor,
        a_sensor`` (2 each), ``tau_s`` (2, the gearbox spring torque without damping); the tool and
        sensor of the real (bent) robot."""
        if self.P is not None:
            return chain4_outputs(s, fx, fz, self.P)
        n = self.n
        S, C, W, A, tj = self.arm(s, fx, fz)
        px = pz = vx = vz = ax = az = 0.0
        for L, Sk, Ck, Wk, Ak in zip(self.L, S, C, W, A):
            px += L * Sk
            pz += L * Ck
            vx += L * Wk * Ck
            vz -= L * Wk * Sk
            ax += L * (Ak * Ck - Wk * Wk * Sk)
            az -= L * (Ak * Sk + Wk * Wk * Ck)
        # sensor: p_tool + R(phi) o with phi = psi_last - pi/2 (cos phi = sin psi, sin phi = -cos psi)
        cphi, sphi, w, a = S[-1], -C[-1], W[-1], A[-1]
        ox, oz = self.sensor
        rx, rz = cphi * ox + sphi * oz, -sphi * ox + cphi * oz
        ex, ez = -sphi * ox + cphi * oz, -cphi * ox - sphi * oz        # d(R o)/d phi
        g1, g2 = self.gear_index
        q = (s[g1], s[g2])
        dq = (s[n + 2 + g1], s[n + 2 + g2])
        ddq = (A[g1] - (A[g1 - 1] if g1 else 0.0), A[g2] - A[g2 - 1])
        phi = sum(s[:n]) + self.offset_sum - HALF_PI
        k, qm1, qm2 = self.k, s[n], s[n + 1]
        return (q + dq + ddq + (qm1, qm2) + tuple(s[2 * n + 2:2 * n + 4])
                + (px, pz, vx, vz, ax, az, phi, w, px + rx, pz + rz,
                   ax + a * ex - w * w * rx, az + a * ez - w * w * rz,
                   k.spring(0, qm1 / k.r[0] - q[0]), k.spring(1, qm2 / k.r[1] - q[1])))

    # ---- analysis (numpy; not on the hot path) ---------------------------------------------
    def energy(self, s) -> float:
        """Kinetic, gravity and spring energy, plus the ripple's potential ``(A/n) cos(n q_m)``
        (the ripple torque ``A sin(n q_m)`` is its negative gradient)."""
        n, k = self.n, self.k
        S, C, W, _, _ = self.arm(s, 0.0, 0.0)
        kin = 0.0
        for j in range(n):
            for kk in range(n):
                m = self.m_diag[j] if j == kk else self.h[j][kk] * (C[j] * C[kk] + S[j] * S[kk])
                kin += 0.5 * m * W[j] * W[kk]
        pot = sum(gj * Cj for gj, Cj in zip(self.grav, C))     # gravity: g sum_k m_k z_k
        for i in range(2):
            qm, dqm = s[n + i], s[2 * n + 2 + i]
            kin += 0.5 * k.jm[i] * dqm * dqm
            D = qm / k.r[i] - s[self.gear_index[i]]
            pot += 0.5 * k.k_hi[i] * D * D - k.k_soft[i] * k.delta[i] ** 2 * math.log(math.cosh(D / k.delta[i]))
            if self.periods[i] > 0.0:
                pot += self.ripple[i] / self.periods[i] * math.cos(self.periods[i] * qm)
        for j in self.bend_index:
            pot += 0.5 * self.kinds[j][1] * s[j] ** 2
        return kin + pot

    def static_equilibrium(self, q_a, fx: float = 0.0, fz: float = 0.0) -> tuple:
        """The state at rest with the gearbox outputs at ``q_a`` under the constant tool force
        ``(fx, fz)``: bending joints and gearbox springs carry gravity and the force (fixed point
        over the bending angles, which are small)."""
        n = self.n
        th = [0.0] * n
        for j, i in zip(self.gear_index, range(2)):
            th[j] = float(q_a[i])
        for _ in range(100):
            psi, G = 0.0, []
            for j in range(n):
                psi += th[j] + self.offsets[j]
                S, C = math.sin(psi), math.cos(psi)
                G.append(self.grav[j] * S + self.L[j] * (fx * C - fz * S))
            # at rest Q_j = 0: the torque of joint j carries the gravity of everything beyond it
            tau = [-sum(G[j:]) for j in range(n)]
            old = list(th)
            for j in self.bend_index:
                th[j] = -tau[j] / self.kinds[j][1]
            if max(abs(a - b) for a, b in zip(th, old)) < 1e-16:
                break
        D = dynamics.spring_deflection([tau[j] for j in self.gear_index], self.robot)
        qm = [self.k.r[i] * (float(q_a[i]) + float(D[i])) for i in range(2)]
        return tuple(th) + tuple(qm) + (0.0,) * (n + 2)

    def mass_matrix(self, s) -> np.ndarray:
        """Inertia matrix of the position coordinates ``(theta, q_m)`` at ``s``: the chain's
        ``T^T M T`` (``T``: joint rates to absolute rates, a lower triangle of ones) and the motors'
        ``J_m``, which have no inertial coupling with the arm."""
        n = self.n
        S, C, _, _, _ = self.arm(s, 0.0, 0.0)
        M = np.array([[self.m_diag[j] if j == k else self.h[j][k] * (C[j] * C[k] + S[j] * S[k])
                       for k in range(n)] for j in range(n)])
        T = np.tril(np.ones((n, n)))
        out = np.zeros((n + 2, n + 2))
        out[:n, :n] = T.T @ M @ T
        out[n:, n:] = np.diag(self.k.jm)
        return out

    def linearised_modes(self, s, free: list[int], shapes: bool = False) -> tuple:
        """Natural frequencies [Hz] and damping ratios of the linearisation at the rest state
        ``s`` with only the position coordinates ``free`` (indices into the state) moving and the
        others clamped (constrained, e.g. motors locked or gearbox outputs held); ascending.

        ``M_ff x_f'' = -K_ff x_f - D_ff x_f'`` with ``M`` of :meth:`mass_matrix` and the generalised
        forces' Jacobians ``[K, D] = -M d(accelerations)/d(positions, rates)`` by central
        differences of :meth:`derivatives` (at rest the accelerations vanish, so ``M d acc`` is the
        Jacobian of the forces). With ``shapes``, also the mode shapes: the columns of a
        ``(len(free), modes)`` array of the free positions (complex; of an undamped mode, real up to
        a factor).
        """
        n2 = self.n + 2
        F = self.mass_matrix(s) @ jacobian(self, s)[n2:]
        f = list(free)
        Mff = self.mass_matrix(s)[np.ix_(f, f)]
        K, D = F[np.ix_(f, f)], F[np.ix_(f, [n2 + i for i in f])]
        m = len(f)
        A = np.block([[np.zeros((m, m)), np.eye(m)], [np.linalg.solve(Mff, K), np.linalg.solve(Mff, D)]])
        lam, vec = np.linalg.eig(A)
        keep = lam.imag >= 0                        # one of each conjugate pair
        lam, vec = lam[keep], vec[:m, keep]
        wn = np.abs(lam)
        order = np.argsort(wn)
        zeta = -lam.real / np.where(wn > 0, wn, 1.0)
        if shapes:
            return wn[order] / (2 * np.pi), zeta[order], vec[:, order]
        return wn[order] / (2 * np.pi), zeta[order]


class CompliantTool:
    """The chain with a compliant tool (the force paper's Optidrive: a spring-damper between the
    robot's flange and the tool): the tool mass ``m_t`` on an isotropic translational spring
    ``k = 1 / tool_compliance`` and damper ``d_t`` at the chain's tool point (the flange).

    State: the chain's, then the tool mass's world position and velocity ``(x_t, z_t, vx_t,
    vz_t)``. With ``u = p_t - p_flange``, the spring-damper force ``F = k u + d_t u_dot`` pulls
    the flange (the chain's tool force) and ``m_t a_t = f_ext - F + m_t g_vec`` moves the tool.
    ``p_tool``, ``v_tool``, ``a_tool`` are the tool mass's motion; the tool angle, the
    accelerometer and ``q_a`` stay on the robot (the tool mount does not rotate).

    ``p`` are the plant parameters (``tool_mass``, ``tool_compliance``, ``tool_damping``); the
    methods take the same arguments as :class:`PlantChain`'s (``s``, ``tau1, tau2``, ``fx, fz``).
    """

    def __init__(self, p) -> None:
        self.chain = chain = PlantChain(p)
        self.n, self.k, self.gear_index = chain.n, chain.k, chain.gear_index
        self.m_t, self.k_t, self.d_t = float(p.tool_mass), 1.0 / float(p.tool_compliance), float(p.tool_damping)
        self.g = float(p.g)
        self.size = 2 * chain.n + 4        # the chain's part of the state

    def _force(self, s, flange: tuple) -> tuple[float, float]:
        """The spring-damper force on the flange (``F``) from the chain outputs ``flange``."""
        xt, zt, vxt, vzt = s[self.size:]
        return (self.k_t * (xt - flange[10]) + self.d_t * (vxt - flange[12]),
                self.k_t * (zt - flange[11]) + self.d_t * (vzt - flange[13]))

    def derivatives(self, s, tau1: float, tau2: float, fx: float, fz: float) -> tuple:
        """``x_dot``: the chain's, pulled by the spring-damper force, then the tool mass's."""
        c = self.chain
        arm = s[:self.size]
        Fx, Fz = self._force(s, c.outputs(arm, 0.0, 0.0))
        _, _, vxt, vzt = s[self.size:]
        return c.derivatives(arm, tau1, tau2, Fx, Fz) + (vxt, vzt, (fx - Fx) / self.m_t,
                                                         (fz - Fz) / self.m_t - self.g)

    def outputs(self, s, fx: float, fz: float) -> tuple:
        """:meth:`PlantChain.outputs` with the tool quantities those of the tool mass."""
        c = self.chain
        arm = s[:self.size]
        Fx, Fz = self._force(s, c.outputs(arm, 0.0, 0.0))
        out = c.outputs(arm, Fx, Fz)
        xt, zt, vxt, vzt = s[self.size:]
        return out[:10] + (xt, zt, vxt, vzt, (fx - Fx) / self.m_t, (fz - Fz) / self.m_t - self.g) + out[16:]

    def energy(self, s) -> float:
        """The chain's energy plus the tool's kinetic and gravity energy and the spring's."""
        flange = self.chain.outputs(s[:self.size], 0.0, 0.0)
        xt, zt, vxt, vzt = s[self.size:]
        ux, uz = xt - flange[10], zt - flange[11]
        return (self.chain.energy(s[:self.size]) + 0.5 * self.m_t * (vxt * vxt + vzt * vzt)
                + self.m_t * self.g * zt + 0.5 * self.k_t * (ux * ux + uz * uz))

    def static_equilibrium(self, q_a) -> tuple:
        """At rest, the tool hanging on its spring ``m_t g / k`` below the flange."""
        w = self.m_t * self.g
        arm = self.chain.static_equilibrium(q_a, 0.0, -w)
        x, z = self.chain.outputs(arm, 0.0, -w)[10:12]
        return arm + (x, z - w / self.k_t, 0.0, 0.0)


def jacobian(chain, s) -> np.ndarray:
    """``d x_dot / d x`` of ``chain.derivatives`` at ``s`` with zero inputs (central differences)."""
    x0 = np.array(s, float)
    A = np.empty((x0.size, x0.size))
    for i in range(x0.size):
        h = 1e-7 * max(1.0, abs(x0[i]))
        e = np.zeros(x0.size)
        e[i] = h
        A[:, i] = (np.array(chain.derivatives(tuple(x0 + e), 0.0, 0.0, 0.0, 0.0))
                   - np.array(chain.derivatives(tuple(x0 - e), 0.0, 0.0, 0.0, 0.0))) / (2 * h)
    return A


def highest_frequency(chain, s) -> float:
    """Highest natural frequency [Hz] of the ``chain`` (:class:`PlantChain` or
    :class:`CompliantTool`), ``max |lambda| / 2 pi`` over the eigenvalues of the linearisation
    at ``s`` (every coordinate free)."""
    return float(np.abs(np.linalg.eigvals(jacobian(chain, s))).max() / (2 * np.pi))


def _solve_spd(M: list, b: list) -> list:
    """``M x = b`` for a small symmetric positive definite ``M`` (Cholesky, plain floats)."""
    n = len(b)
    Lc = [[0.0] * n for _ in range(n)]
    for i in range(n):
        Li = Lc[i]
        for j in range(i + 1):
            Lj = Lc[j]
            acc = M[i][j]
            for t in range(j):
                acc -= Li[t] * Lj[t]
            Li[j] = math.sqrt(acc) if i == j else acc / Lj[j]
    y = [0.0] * n
    for i in range(n):
        acc = b[i]
        for t in range(i):
            acc -= Lc[i][t] * y[t]
        y[i] = acc / Lc[i][i]
    x = [0.0] * n
    for i in reversed(range(n)):
        acc = y[i]
        for t in range(i + 1, n):
            acc -= Lc[t][i] * x[t]
        x[i] = acc / Lc[i][i]
    return x


class _Advancing:
    """:meth:`advance` of a plant model in Python (its ``step``, ``outputs`` and
    ``applied_torques``)."""

    def advance(self, tau_m: np.ndarray, f_ext: np.ndarray, dt: float, out: np.ndarray, at: np.ndarray
                ) -> tuple[float, float]:
        """:meth:`ExtendedRobotModel.advance`."""
        self.step(tau_m, f_ext, dt)
        y = self.outputs(float(f_ext[0]), float(f_ext[1])) + self.applied_torques(float(tau_m[0]), float(tau_m[1]))
        scatter(y, out, at)
        return y[16], y[17]


def scatter(values: Sequence[float], out: np.ndarray, at: np.ndarray) -> None:
    """``out[at[i]] = values[i]`` where ``at[i]`` is not negative (as :func:`chain4_advance`
    writes its outputs)."""
    for i, v in zip(at, values):
        if i >= 0:
            out[i] = v


class IdealPlant(_Advancing, dynamics.FlexibleRobotModel):
    """Today's plant, unchanged: the estimators' 8-state model (``ideal = true``).

    Methods take the motor torque commands ``tau1, tau2`` (N m) and the external force on the
    tool ``fx, fz`` (N, world x and z) as :class:`ExtendedRobotModel`'s do.
    """

    def outputs(self, fx: float, fz: float) -> tuple:
        """The outputs of :meth:`PlantChain.outputs`, from the rigid kinematics of the nominal robot."""
        p, s = self.p, self._s
        q, qm, dq, dqm = s[0:2], s[2:4], s[4:6], s[6:8]
        ddq = self.arm_acceleration(fx, fz)
        tool = kinematics.point_motion(q, dq, ddq, p, "tool")
        sensor = kinematics.point_motion(q, dq, ddq, p, "sensor")
        return (q + dq + ddq + qm + dqm + tool + (q[0] + q[1], dq[0] + dq[1]) + sensor[0:2] + sensor[4:6]
                + self.spring_torques())

    def applied_torques(self, tau1: float, tau2: float) -> tuple[float, float]:
        """The commands themselves (an ideal drive)."""
        return tau1, tau2

    def check_step(self, dt: float) -> None:
        """Nothing to check for any ``dt``: today's plant, whose stiffest mode is far below 1 kHz."""


class ExtendedRobotModel(_Advancing, dynamics.FlexibleRobotModel):
    """The realistic plant: :class:`PlantChain` integrated by the 8-state model's RK4 with
    ``substeps`` per :meth:`step` (inherited: the integrator works on any state tuple), for the
    plant parameters ``p``, starting at rest in the static equilibrium at arm angles ``q_a0``.

    Methods take the motor torque commands ``tau1, tau2`` (N m) and the external force on the
    tool ``fx, fz`` (N, world x and z).
    """

    def __init__(self, p, q_a0, substeps: int = 1) -> None:
        self.p = p
        self._k = chain = CompliantTool(p) if p.tool_compliance > 0.0 else PlantChain(p)
        self._chain = getattr(chain, "chain", chain)
        self._s = chain.static_equilibrium(q_a0)
        self.substeps = int(substeps)
        self.t = 0.0
        #: highest natural frequency [Hz] of the linearisation at the initial state (every
        #: coordinate free): what the integration step must resolve
        self.highest_frequency = highest_frequency(chain, self._s)
        self._checked_dt = None

    def advance(self, tau_m: np.ndarray, f_ext: np.ndarray, dt: float, out: np.ndarray, at: np.ndarray
                ) -> tuple[float, float]:
        """:meth:`step` over ``dt`` [s], then the outputs at the new state (:meth:`outputs`, then
        :meth:`applied_torques` of ``tau_m``) written as :func:`chain4_advance` writes them into
        ``out`` at ``at``; returns the tool angle and rate (the four-body chain: one compiled
        call, the same operations). ``tau_m``, ``f_ext``: float arrays of 2."""
        P = getattr(self._k, "P", None)
        if P is None:
            return super().advance(tau_m, f_ext, dt, out, at)
        self._s, phi, omega = chain4_advance(self._s, tau_m, f_ext, dt, self.substeps, P, out, at)
        self.t += dt
        return phi, omega

    def step(self, tau_m, f_ext, dt: float) -> None:
        """Advance by ``dt`` [s] with the motor torque ``tau_m`` [N m] and the tool force
        ``f_ext`` [N] held (the inherited RK4; the four-body chain's compiled,
        :func:`chain4_step`, the same operations)."""
        P = getattr(self._k, "P", None)          # a compliant tool's chain has its own state
        if P is None:
            return super().step(tau_m, f_ext, dt)
        self._s = chain4_step(self._s, float(tau_m[0]), float(tau_m[1]), float(f_ext[0]), float(f_ext[1]),
                              dt, self.substeps, P)
        self.t += dt

    def arm_acceleration(self, fx: float, fz: float) -> tuple[float, float]:
        """Gearbox output angular accelerations now, with the tool force ``(fx, fz)``."""
        return self._k.outputs(self._s, fx, fz)[4:6]

    def spring_torques(self) -> tuple[float, float]:
        """The gearbox spring torques now (N m, arm side, without damping)."""
        return self.outputs(0.0, 0.0)[22:24]

    def outputs(self, fx: float, fz: float) -> tuple:
        """Every plant output now (:meth:`PlantChain.outputs`)."""
        return self._k.outputs(self._s, fx, fz)

    def applied_torques(self, tau1: float, tau2: float) -> tuple[float, float]:
        """Torques the motors apply now for the commands ``tau1, tau2``."""
        n, s, k = self._k.n, self._s, self._chain
        return k.applied_torque(0, tau1, s[n]), k.applied_torque(1, tau2, s[n + 1])

    def check_step(self, dt: float) -> None:
        """Reject an integration step ``h = dt / substeps`` that cannot resolve the stiffest mode:
        RK4 is stable for ``omega h <= 2 sqrt(2)``, a little below the Nyquist limit ``omega h = pi``.

        Raises
        ------
        ParameterError
            Naming ``substeps`` and the mode's frequency.
        """
        if dt == self._checked_dt:
            return
        h = dt / self.substeps
        if 2 * math.pi * self.highest_frequency * h > 2 * math.sqrt(2):
            raise ParameterError(
                f"parameter 'substeps' = {self.substeps}: the integration step dt/substeps = {h:.3g} s "
                f"does not resolve the plant's stiffest mode at {self.highest_frequency:.1f} Hz (RK4 needs "
                f"2 pi f h <= 2 sqrt(2), below the Nyquist limit {0.5 / h:.1f} Hz); raise 'substeps' to at "
                f"least {math.ceil(2 * math.pi * self.highest_frequency * dt / (2 * math.sqrt(2)))} or lower "
                f"'bend_stiffness' (or raise 'tool_compliance')")
        self._checked_dt = dt


def plant_model(p) -> IdealPlant | ExtendedRobotModel:
    """The plant of the parameters ``p`` (PlantParameters): today's 8-state model if ``p.ideal``."""
    if p.ideal:
        return IdealPlant(p.robot(), p.initial_angles(), substeps=p.substeps)
    return ExtendedRobotModel(p, p.initial_angles(), substeps=p.substeps)

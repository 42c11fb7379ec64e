"""The acceleration-based deterministic observer of De Luca, Schröder and Thümmel (2007), as used
by Henriksson et al. (2009), section III-B, plus a fix for its low-frequency drift.

Model
-----
State per joint ``i`` (the paper's eq. 1 reordered per joint)::

    z_i = (q_a, q_m, dq_a, dq_m)      arm angle, motor angle (motor side), and their rates

With the gearbox deflection ``D = q_m / r - q_a`` (arm side) the motor equation of eq. 2 is
``J_m ddq_m = tau_m - F(dq_m) - (tau_s(D) + d dD) / r``. The arm equation is not used: the arm
acceleration is *measured* through the accelerometer (section III-B). Split as in the paper
into a linear part with the constant stiffness ``K = k_hi`` (the stiffness under load) and a
known nonlinear rest evaluated at the estimate,

.. math::

    \\dot z_i = A_i z_i + B_i \\begin{bmatrix} \\ddot q_a^M \\\\ \\tau_m + n_i(\\hat z) \\end{bmatrix},
    \\qquad y_i = C z_i = q_{m,i},

    A_i = \\begin{bmatrix} 0 & 0 & 1 & 0 \\\\ 0 & 0 & 0 & 1 \\\\ 0 & 0 & 0 & 0 \\\\
          \\frac{K}{r J_m} & -\\frac{K}{r^2 J_m} & \\frac{d}{r J_m} & -\\frac{d/r^2 + f_v}{J_m}
          \\end{bmatrix}, \\quad
    B_i = \\begin{bmatrix} 0 & 0 \\\\ 0 & 0 \\\\ 1 & 0 \\\\ 0 & 1/J_m \\end{bmatrix},

with ``n_i = -f_c tanh(dq_m / w_c) + (k_hi - k_lo) delta tanh(D / delta) / r`` (Coulomb friction
and the softening of the gearbox spring; see :mod:`fmus.common.dynamics`). These are the
paper's ``A_0``, ``G_0`` and ``C_0`` (section III-B), block-diagonal over the joints.

Measured arm acceleration (section III-B)
-----------------------------------------
The accelerometer reads ``f = R(phi)^T (J_s(q) ddq + J_s_dot(q, dq) dq - g_vec)`` (eq. 7, with
``J_s`` the Jacobian of the sensor mount point), so

.. math::

    \\ddot q_a^M = J_s(\\hat q_a)^{-1} \\left( R(\\hat\\phi) f + g_{vec} - \\dot J_s \\dot{\\hat q}_a \\right).

The inverse is a damped least-squares inverse (Nakamura and Hanafusa 1986; Chiaverini 1997):
with the singular values ``s_1 >= s_2`` of ``J_s`` (metres per radian), ``J_s^+ = V diag(s /
(s^2 + mu^2)) U^T`` and ``mu^2 = mu_max^2 (1 - (s_2 / eps)^2)`` when ``s_2 < eps``, else 0: the
exact inverse away from singular poses (arm stretched or folded for the sensor point), and a
bounded acceleration (at most ``|b| / (2 mu_max)``) at them.

Observer and pole placement (section III-B, III-C-2)
----------------------------------------------------
``dz/dt = A z + B [ddq^M; tau + n] + L (q_m^M - C z)``. The error dynamics of the linear part
are ``de/dt = (A - L C) e``; ``L`` is placed with Ackermann's formula so that the characteristic
polynomial of each joint is ``(s^2 + 2 zeta_a w_a s + w_a^2)(s^2 + 2 zeta_b w_b s + w_b^2)``:
eight poles given as four eigenfrequencies and dampings (the paper's parameterisation). The
observer is discretised exactly for inputs linear over the step (first-order hold; matrix
exponential), so the discrete error poles are ``exp(lambda T)`` for any step.

Drift fix (beyond the paper)
----------------------------
The paper left the low-frequency drift of the observer unsolved (section IV-D). With
``drift_crossover = f_c > 0`` the arm angles are fused with the static forward-kinematics
estimate ``q_static = q_m / r - D(G(q))`` (motor angles minus the gravity deflection of the
model: what rigid kinematics with gravity compensation uses) by a first-order complementary
filter,

.. math::

    \\dot{\\tilde q} = \\dot{\\hat q}_a + \\omega_c (q_{static} - \\tilde q), \\quad \\omega_c = 2\\pi f_c,

i.e. ``q~ = s/(s + w_c) q_hat + w_c/(s + w_c) q_static`` (``drift_order = 1``, default): below ``f_c``
the estimate is the static one (no drift, the accuracy of rigid kinematics), above it the
observer's (its 3-30 Hz accuracy). With ``drift_order = 2`` the correction is
proportional-integral, ``dq~/dt = dq_hat + 2 w_c e + w_c^2 int e``, ``e = q_static - q~``:

.. math::

    \\tilde q = \\frac{s^2}{(s + \\omega_c)^2} \\hat q_a
              + \\frac{2\\omega_c s + \\omega_c^2}{(s + \\omega_c)^2} q_{static},

whose high-pass also removes a constant rate error of the observer (a drift ramp) instead of
turning it into an offset. Implemented on the increments of the observer's angles, so the
filter adds no integration error. ``static_gravity_compensation = false`` uses ``q_m / r``
(the paper's rigid kinematics: no stiffness in it, so immune to stiffness errors, but sagging
under gravity).

Measured figures (P1, with and without the fusion, and with a stiffness error):
docs/henriksson2009_ekf_notes.md.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fmus.common import dynamics, kinematics
from fmus.common.kalman import FilterDivergence
from fmus.common.parameters import ParameterError, as_array, param, replace
from fmus.common.robot_params import RobotAtInitialPose, RobotParameters

PAPER = "Henriksson et al. 2009, section III-B (De Luca et al. 2007)"


@dataclass(frozen=True)
class AccelerationObserverParameters(RobotAtInitialPose):
    """The observer's robot model (inherited; values differing from the plant's are model
    errors), its poles, the singularity handling and the drift fix."""

    pole_freq: tuple = param((0.5, 2.0, 0.5, 2.0), "Hz", "eigenfrequencies of the observer's "
                             "error poles: joint 1 pair a, joint 1 pair b, joint 2 pair a, joint 2 "
                             "pair b", low=0.0, low_inclusive=False, high=400.0, search=(0.3, 60.0),
                             source=f"{PAPER}, section III-C-2; hand-tuned for the 3-30 Hz band on P1 (study_tune "
                             "refines them)")
    pole_damping: tuple = param((0.7, 0.7, 0.7, 0.7), "1", "damping ratios of the four pole pairs "
                                "(>= 1: two real poles)", low=0.0, low_inclusive=False, high=20.0,
                                search=(0.2, 3.0),
                                source=f"{PAPER}, section III-C-2")
    singular_threshold: float = param(0.05, "m", "smallest singular value of the sensor Jacobian "
                                      "below which the inverse is damped (damped least squares)",
                                      low=0.0, low_inclusive=False)
    max_damping: float = param(0.05, "m", "damping factor mu_max of the damped least-squares "
                               "inverse at a singular pose", low=0.0, low_inclusive=False)
    stiffness_scale: float = param(1.0, "1", "factor on the model's gearbox stiffness k_lo and k_hi "
                                   "(a model error when not 1; the robustness study uses 0.5)",
                                   low=0.0, low_inclusive=False, source="Henriksson et al. 2009, Table I")
    drift_crossover: float = param(0.0, "Hz", "crossover frequency of the complementary fusion "
                                   "with the static forward-kinematics estimate (0 = off: the "
                                   "paper's observer, which drifts)", low=0.0, high=100.0)
    drift_order: int = param(1, "1", "order of the complementary fusion: 1 (first-order low-pass "
                             "of the static estimate) or 2 (also removes a constant rate error)",
                             low=1, high=2)
    static_gravity_compensation: bool = param(True, "1", "the static estimate subtracts the model's "
                                              "gravity deflection (off: q_m / r, immune to "
                                              "stiffness errors but sagging under gravity)")
    index_x: int = param(1, "1", "index (1-based) of the sensor-frame x component in acc_s", low=1, high=3)
    index_z: int = param(3, "1", "index (1-based) of the sensor-frame z component in acc_s", low=1, high=3)

    def check(self) -> None:
        """The robot's rules, and ``index_x`` differs from ``index_z``; raises
        :class:`ParameterError`."""
        super().check()
        if self.index_x == self.index_z:
            raise ParameterError(f"parameters 'index_x' and 'index_z' must differ (both {self.index_x})")


def model_robot(p: AccelerationObserverParameters) -> RobotParameters:
    """The observer's robot model: the robot parameters of ``p`` with the stiffness ``k_lo``,
    ``k_hi`` scaled by its ``stiffness_scale``."""
    r = p.robot()
    if p.stiffness_scale == 1.0:
        return r
    s = float(p.stiffness_scale)
    return replace(r, k_hi=tuple(s * k for k in r.k_hi), k_lo=tuple(s * k for k in r.k_lo))


# ---- the linear part -----------------------------------------------------------------------
def joint_matrices(p: RobotParameters, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(A_i, B_i, C)`` of joint ``i`` (0-based) of the robot model ``p``: the linear part with
    ``K = k_hi`` (section III-B's ``A_0``, ``G_0``, ``C_0``).

    Inputs ``(ddq_a, tau)``: the measured arm acceleration and the motor torque (motor side)
    plus the nonlinear rest :func:`nonlinear_torque`.
    """
    r, jm = float(p.gear_ratio[i]), float(p.J_m[i])
    k, d, fv = float(p.k_hi[i]), float(p.d[i]), float(p.f_v[i])
    A = np.zeros((4, 4))
    A[0, 2] = A[1, 3] = 1.0
    A[3] = [k / (r * jm), -k / (r * r * jm), d / (r * jm), -(d / (r * r) + fv) / jm]
    B = np.zeros((4, 2))
    B[2, 0] = 1.0
    B[3, 1] = 1.0 / jm
    C = np.array([[0.0, 1.0, 0.0, 0.0]])
    return A, B, C


def characteristic_polynomial(freqs, dampings) -> np.ndarray:
    """Coefficients (highest power first) of ``prod_j (s^2 + 2 zeta_j w_j s + w_j^2)``,
    ``w_j = 2 pi f_j``, for the eigenfrequencies ``freqs`` = ``f_j`` [Hz] and the damping ratios
    ``dampings`` = ``zeta_j`` of the pole pairs."""
    c = np.array([1.0])
    for f, z in zip(freqs, dampings):
        w = 2 * math.pi * float(f)
        c = np.convolve(c, [1.0, 2 * float(z) * w, w * w])
    return c


def poles(freqs, dampings) -> np.ndarray:
    """The poles [rad/s] ``-zeta w +- w sqrt(zeta^2 - 1)`` of the pairs (complex for
    ``zeta < 1``), ``w = 2 pi f`` for the eigenfrequencies ``freqs`` = ``f`` [Hz] and the damping
    ratios ``dampings`` = ``zeta``."""
    out = []
    for f, z in zip(freqs, dampings):
        w = 2 * math.pi * float(f)
        root = np.sqrt(complex(float(z) ** 2 - 1.0))
        out += [w * (-float(z) + root), w * (-float(z) - root)]
    return np.array(out)


def ackermann_gain(A: np.ndarray, C: np.ndarray, coeffs: np.ndarray, scale=None) -> np.ndarray:
    """Observer gain ``L`` with ``det(sI - (A - L C)) = coeffs`` (Ackermann's formula for a
    single output: ``L = phi(A) O^-1 e_n``, ``O`` the observability matrix).

    Evaluated in the coordinates ``z' = S^-1 z``, ``S = diag(scale)`` (for the joint model
    ``(1, r, 1, r)``: motor angles on the arm scale) with time scaled by the geometric mean of
    the pole magnitudes, which keeps ``O`` well conditioned although ``K / (r J_m)`` is ~1e5.

    Raises
    ------
    ParameterError
        If the pair ``(A, C)`` is not observable (zero stiffness).
    """
    n = A.shape[0]
    s = np.ones(n) if scale is None else np.asarray(scale, float)
    S = np.diag(s)
    Si = np.diag(1.0 / s)
    As = Si @ A @ S
    Cs = C @ S
    # time scaling: A'' = As / w0, coefficients c_k / w0^k
    w0 = max(abs(coeffs[-1]) ** (1.0 / n), 1e-12)
    Aw = As / w0
    cw = np.array([c / w0 ** k for k, c in enumerate(coeffs)])
    O = np.vstack([Cs @ np.linalg.matrix_power(Aw, k) for k in range(n)])
    if np.linalg.cond(O) > 1e12:
        raise ParameterError("the observer's model is not observable from the motor angles "
                             "(check the stiffness k_hi)")
    phi = np.zeros_like(Aw)
    for c in cw:
        phi = phi @ Aw + c * np.eye(n)
    en = np.zeros((n, 1))
    en[-1, 0] = 1.0
    Lw = phi @ np.linalg.solve(O, en)
    # back to physical time and coordinates: A - L C = S (w0 (Aw - Lw Cs)) S^-1
    return (S @ (w0 * Lw)).reshape(n, 1)


def observer_gains(p: AccelerationObserverParameters) -> list[np.ndarray]:
    """``L_i`` (4 x 1) per joint from the pole parameters of ``p`` (``pole_freq``,
    ``pole_damping``), on its model robot (:func:`model_robot`)."""
    f, z = as_array(p.pole_freq), as_array(p.pole_damping)
    gains = []
    robot = model_robot(p)
    for i in range(2):
        A, _, C = joint_matrices(robot, i)
        r = float(p.gear_ratio[i])
        coeffs = characteristic_polynomial(f[2 * i:2 * i + 2], z[2 * i:2 * i + 2])
        gains.append(ackermann_gain(A, C, coeffs, scale=(1.0, r, 1.0, r)))
    return gains


def closed_loop_matrix(p: AccelerationObserverParameters) -> np.ndarray:
    """``A - L C`` of both joints (8 x 8, states per joint ``(q_a, q_m, dq_a, dq_m)``): the error
    dynamics of the linear part, whose eigenvalues are :func:`poles` of the parameters ``p``."""
    M = np.zeros((8, 8))
    robot = model_robot(p)
    for i, L in enumerate(observer_gains(p)):
        A, _, C = joint_matrices(robot, i)
        M[4 * i:4 * i + 4, 4 * i:4 * i + 4] = A - L @ C
    return M


def discretise(p: AccelerationObserverParameters, T: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact first-order-hold discretisation of the observer with the parameters ``p`` over the
    step ``T`` [s].

    With the inputs ``u = (ddq^M, tau, q_m^M)`` of both joints, ordered ``(ddq_1, tau_1, qm_1,
    ddq_2, tau_2, qm_2)`` and linear between the samples ``u_k`` and ``u_{k+1}``:
    ``z_{k+1} = Phi z_k + Gamma0 u_k + Gamma1 (u_{k+1} - u_k)``.

    Returns
    -------
    Phi, Gamma0, Gamma1
        8 x 8, 8 x 6, 8 x 6. ``Phi = exp((A - L C) T)``.
    """
    from scipy.linalg import expm       # here: scipy.linalg takes 0.15 s to import
    Phi = np.zeros((8, 8))
    G0 = np.zeros((8, 6))
    G1 = np.zeros((8, 6))
    robot = model_robot(p)
    for i, L in enumerate(observer_gains(p)):
        A, B, C = joint_matrices(robot, i)
        M = np.zeros((10, 10))
        M[:4, :4] = A - L @ C
        M[:4, 4:6] = B
        M[:4, 6:7] = L
        M[4:7, 7:10] = np.eye(3) / T          # the ramp (u_{k+1} - u_k) t / T
        E = expm(M * T)
        j = slice(4 * i, 4 * i + 4)
        Phi[j, j] = E[:4, :4]
        G0[j, 3 * i:3 * i + 3] = E[:4, 4:7]
        G1[j, 3 * i:3 * i + 3] = E[:4, 7:10]
    return Phi, G0, G1


# ---- the nonlinear parts ---------------------------------------------------------------------
def damped_solve(J, b, eps: float, mu_max: float) -> tuple[np.ndarray, float]:
    """``J^+ b`` for a 2 x 2 ``J`` with the damped least-squares inverse of the module docstring.

    ``J^+ = (J^T J + mu^2 I)^-1 J^T`` (equal to ``V diag(s / (s^2 + mu^2)) U^T``); the smallest
    singular value from the eigenvalues of ``J^T J``. Written out in floats (this runs every step).
    Returns the solution and the damping ``mu`` used (0 away from singular poses). ``eps`` is
    the singular-value threshold below which the inverse is damped and ``mu_max`` the damping at
    a singular pose (both in the unit of ``J``'s singular values, m/rad for the sensor Jacobian).
    """
    a, bb, c, d = float(J[0][0]), float(J[0][1]), float(J[1][0]), float(J[1][1])
    y1, y2 = float(b[0]), float(b[1])
    # J^T J = [[p, q], [q, r]]
    p_, q_, r_ = a * a + c * c, a * bb + c * d, bb * bb + d * d
    tr, det = p_ + r_, a * d - bb * c
    smin2 = 0.5 * (tr - math.sqrt(max(tr * tr - 4.0 * det * det, 0.0)))
    smin = math.sqrt(max(smin2, 0.0))
    if smin >= eps:
        return np.array([(d * y1 - bb * y2) / det, (a * y2 - c * y1) / det]), 0.0
    mu2 = mu_max * mu_max * (1.0 - (smin / eps) ** 2)
    g1, g2 = a * y1 + c * y2, bb * y1 + d * y2            # J^T b
    p_, r_ = p_ + mu2, r_ + mu2
    dd = p_ * r_ - q_ * q_
    return np.array([(r_ * g1 - q_ * g2) / dd, (p_ * g2 - q_ * g1) / dd]), math.sqrt(mu2)


def measured_arm_acceleration(q, dq, f_xz, p: RobotParameters, eps: float, mu_max: float
                              ) -> tuple[np.ndarray, float]:
    """``ddq_a^M`` [rad/s^2] of section III-B from the accelerometer reading ``f_xz`` [m/s^2]
    (sensor x, z) at the estimated arm angles ``q`` [rad] and rates ``dq`` [rad/s] of the robot
    model ``p``; returns it and the damping used (:func:`damped_solve` with ``eps`` and
    ``mu_max``)."""
    phi = float(q[0]) + float(q[1])
    c, s = math.cos(phi), math.sin(phi)
    fx, fz = float(f_xz[0]), float(f_xz[1])
    # world acceleration of the mount: R(phi) f + g_vec
    ax = c * fx + s * fz
    az = -s * fx + c * fz - p.g
    _, _, _, _, cx, cz = kinematics.point_motion(q, dq, (0.0, 0.0), p, "sensor")   # J_dot dq
    J = kinematics.jacobian(q, p, "sensor")
    return damped_solve(J, np.array([ax - cx, az - cz]), eps, mu_max)


def nonlinear_torque(z: np.ndarray, p: RobotParameters) -> np.ndarray:
    """The motor-side torques ``n_i`` [N.m] outside the linear part at the observer state ``z``
    (8, per joint ``(q_a, q_m, dq_a, dq_m)``) of the robot model ``p``: Coulomb friction and the
    softening of the spring (``tau_s(D) = k_hi D - (k_hi - k_lo) delta tanh(D / delta)``)."""
    out = np.empty(2)
    for i in range(2):
        qa, qm, _, dqm = z[4 * i:4 * i + 4]
        r = float(p.gear_ratio[i])
        D = qm / r - qa
        delta = float(p.delta[i])
        soft = (float(p.k_hi[i]) - float(p.k_lo[i])) * delta * math.tanh(D / delta)
        out[i] = -float(p.f_c[i]) * math.tanh(dqm / float(p.w_c[i])) + soft / r
    return out


# ---- the observer ----------------------------------------------------------------------------
class AccelerationObserverModel:
    """The observer of the module docstring, stepped at a fixed period.

    Parameters
    ----------
    p
        Observer parameters.

    The measurements of a call are the motor angles ``q_m_meas`` [rad, motor side], the
    accelerometer reading ``acc_s`` [m/s^2] (sensor frame; ``index_x`` and ``index_z`` pick its
    x and z) and the motor torques ``tau_m`` [N.m, motor side].

    Notes
    -----
    :meth:`step` advances the state from ``t`` to ``t + T`` with the measurements of ``t + T``
    (interpolated linearly from those of the previous call: first-order hold). :attr:`q_a` is
    the arm-angle estimate (fused with the static estimate when ``drift_crossover > 0``).
    """

    def __init__(self, p: AccelerationObserverParameters) -> None:
        self.p = p
        self.robot = model_robot(p)
        x0 = dynamics.static_equilibrium(p.initial_angles(), self.robot)
        self.z = np.array([x0[0], x0[2], x0[4], x0[6], x0[1], x0[3], x0[5], x0[7]], float)
        self.r = as_array(p.gear_ratio)
        self.q_fused = x0[0:2].copy()
        self._integral = np.zeros(2)
        self._k = dynamics.arm_constants(self.robot)
        self._D = list(dynamics.spring_deflection(dynamics.gravity_torque(x0[0:2], self.robot),
                                                  self.robot))    # warm start of the deflection
        self._T: float | None = None
        self._u_prev: np.ndarray | None = None
        self.mu = 0.0
        self.ddq_meas = np.zeros(2)
        self.omega_c = 2 * math.pi * float(p.drift_crossover)
        self._ix, self._iz = p.index_x - 1, p.index_z - 1
        observer_gains(p)                    # fail early (not observable)

    def _matrices(self, T: float) -> None:
        if self._T != T:
            self.Phi, self.G0, self.G1 = discretise(self.p, T)
            w = self.omega_c
            if self.p.drift_order == 1:
                self.alpha, self.beta = 1.0 - math.exp(-w * T), 0.0
            else:    # s^2 + 2 w s + w^2 (critically damped): proportional and integral gains
                self.alpha, self.beta = 2.0 * w * T, (w * T) ** 2
            self._T = T

    @property
    def q_a_obs(self) -> np.ndarray:
        """The observer's own arm-angle estimate (without the drift fix)."""
        return self.z[[0, 4]]

    @property
    def q_a(self) -> np.ndarray:
        """Arm-angle estimate (fused with the static estimate when the drift fix is on)."""
        return self.q_fused.copy() if self.omega_c > 0 else self.q_a_obs

    @property
    def dq_a(self) -> np.ndarray:
        """Arm angular velocity estimate."""
        return self.z[[2, 6]]

    @property
    def q_m(self) -> np.ndarray:
        """Motor angle estimate (motor side)."""
        return self.z[[1, 5]]

    def static_angles(self, q_m_meas) -> np.ndarray:
        """``q_m / r - D(G(q))`` for the measured motor angles ``q_m_meas``, with ``G`` at the
        current fused estimate (Newton steps on the spring from the last deflection, in floats);
        ``q_m / r`` without ``static_gravity_compensation``."""
        qs = [float(q_m_meas[0]) / self.r[0], float(q_m_meas[1]) / self.r[1]]
        if not self.p.static_gravity_compensation:
            return np.array(qs)
        k = self._k
        q1, q2 = float(self.q_fused[0]), float(self.q_fused[1])
        cp = math.cos(q1 + q2)
        G = (-k.g1 * math.sin(q1) - k.g2 * cp, -k.g2 * cp)          # dynamics.gravity_torque
        self._D = list(self._D)          # a new list: a copy of the observer shares the old one
        for i in range(2):
            D = self._D[i]
            for _ in range(20):
                th = math.tanh(D / k.delta[i])
                f = k.k_hi[i] * D - k.k_soft[i] * k.delta[i] * th - G[i]
                D -= f / (k.k_hi[i] - k.k_soft[i] * (1.0 - th * th))
                if abs(f) <= 1e-9 * max(1.0, abs(G[i])):
                    break
            self._D[i] = D
            qs[i] -= D
        return np.array(qs)

    def inputs(self, q_m_meas, acc_s, tau_m, z: np.ndarray) -> np.ndarray:
        """The observer's input vector ``(ddq_1, tau_1, qm_1, ddq_2, tau_2, qm_2)`` for the
        measurements, with the arm acceleration and the nonlinear torques at the state ``z``."""
        acc = (float(acc_s[self._ix]), float(acc_s[self._iz]))
        ddq, self.mu = measured_arm_acceleration(z[[0, 4]], z[[2, 6]], acc, self.robot,
                                                 self.p.singular_threshold, self.p.max_damping)
        self.ddq_meas = ddq
        n = nonlinear_torque(z, self.robot)
        return np.array([ddq[0], float(tau_m[0]) + n[0], float(q_m_meas[0]),
                         ddq[1], float(tau_m[1]) + n[1], float(q_m_meas[1])])

    def predict(self, T: float) -> None:
        """The estimate ``T`` ahead without new measurements: the observer's model with its last
        inputs held (the output of an observer whose newest measurement is older than now)."""
        if self._u_prev is None:
            return                            # no measurement yet: the start estimate holds
        self._matrices(float(T))
        z_new = self.Phi @ self.z + self.G0 @ self._u_prev
        self.q_fused = self.q_fused + (z_new[[0, 4]] - self.z[[0, 4]])
        self.z = z_new

    def step(self, q_m_meas, acc_s, tau_m, T: float) -> None:
        """Advance from ``t`` to ``t + T``; the measurements are those of ``t + T``.

        The inputs are interpolated linearly between the previous call's measurements (those
        of ``t``; at the first call the same as now) and these (first-order hold). The arm
        acceleration of ``t + T`` is computed at the estimate of ``t`` advanced by ``T``
        with its rates.

        Raises
        ------
        FilterDivergence
            If the state becomes non-finite (e.g. non-finite inputs).
        """
        self._matrices(float(T))
        z = self.z
        z_ahead = z.copy()
        z_ahead[[0, 1, 4, 5]] += T * z[[2, 3, 6, 7]]
        with np.errstate(all="ignore"):
            u = self.inputs(q_m_meas, acc_s, tau_m, z_ahead)
            u_prev = u if self._u_prev is None else self._u_prev
            z_new = self.Phi @ z + self.G0 @ u_prev + self.G1 @ (u - u_prev)
        if not np.all(np.isfinite(z_new)):
            raise FilterDivergence("the acceleration observer diverged: non-finite state "
                                     "(non-finite inputs, or an estimate far from the truth)")
        q_old = z[[0, 4]]
        self.z = z_new
        self._u_prev = u
        if self.omega_c > 0:
            pred = self.q_fused + (z_new[[0, 4]] - q_old)
            e = self.static_angles(q_m_meas) - pred
            self._integral = self._integral + e
            self.q_fused = pred + self.alpha * e + self.beta * self._integral

    def tool_position(self) -> np.ndarray:
        """Tool position (world x, z) from the arm-angle estimate."""
        return kinematics.tool_position(self.q_a, self.robot)


__all__ = ["AccelerationObserverParameters", "AccelerationObserverModel",
           "joint_matrices", "characteristic_polynomial", "poles", "ackermann_gain",
           "model_robot", "observer_gains", "closed_loop_matrix", "discretise", "damped_solve",
           "measured_arm_acceleration", "nonlinear_torque"]

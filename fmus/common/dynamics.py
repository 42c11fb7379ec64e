"""Flexible-joint dynamics of the two-axis arm (Axelsson et al. 2012, eqs. 10-11; Henriksson et
al. 2009, eq. 2).

State ``x = (q_a[2], q_m[2], dq_a[2], dq_m[2])`` (arm angles, motor angles motor side, and their
rates). With the gearbox deflection ``D = q_m / r - q_a`` (arm side),

.. math::

    M(q_a)\\ddot q_a + C(q_a, \\dot q_a)\\dot q_a + G(q_a) &= \\tau_s(D) + d\\,\\dot D + J^T f_{ext}
    \\qquad\\text{(eq. 11)}\\\\
    J_m \\ddot q_m + F(\\dot q_m) + (\\tau_s(D) + d\\,\\dot D) / r &= \\tau_m
    \\qquad\\text{(eq. 10)}

with the nonlinear gearbox spring ``tau_s(D) = k_hi D - (k_hi - k_lo) delta tanh(D / delta)``
(stiffness ``k_lo`` at zero torque rising to ``k_hi``; Moberg & Öhr's benchmark), motor friction
``F(w) = f_v w + f_c tanh(w / w_c)``, and the rigid two-link inertia matrix, Coriolis and gravity
terms of the planar arm (see :mod:`fmus.common.kinematics` for the geometry).

The hot path (:class:`FlexibleRobotModel`) is scalar Python: for 2x2 systems it is several
times faster than numpy.
"""
from __future__ import annotations

import math

import numpy as np

from fmus.common import cython_kernels
from fmus.common.parameters import as_array
from fmus.common.robot_params import RobotParameters


# compiled (common/dynamics_kernels.pyx): the gearbox spring (common/gearbox.pxd, the one
# definition), the rates of eqs. 10-11 and their RK4 step, on :attr:`ArmConstants.packed` (the
# fields of its struct ``Arm``, in the array's order); the tests hold them to their Python forms.
_kernels = cython_kernels.load("common.dynamics_kernels")
#: ``spring_scalar(k_hi, k_soft, delta, D)``: the gearbox spring torque
#: ``tau_s(D) = k_hi D - (k_hi - k_lo) delta tanh(D / delta)`` [N.m] of one joint on floats
#: (``k_soft = k_hi - k_lo``, deflection ``D`` [rad])
spring_scalar = _kernels.spring_scalar
#: ``flex_rates(s, tau1, tau2, fx, fz, K)``: ``x_dot`` (8-tuple) of eqs. 10-11 at the state ``s``
#: (8-tuple), motor torques [N.m], tool force [N], constants ``K`` (:attr:`ArmConstants.packed`)
flex_rates = _kernels.flex_rates
#: ``flex_step(s, tau1, tau2, fx, fz, dt, substeps, K)``: ``substeps`` RK4 steps over ``dt`` [s]
#: of :func:`flex_rates`, the inputs held: the new state (8-tuple)
flex_step = _kernels.flex_step


#: ``spring_inverse(k_hi, k_soft, delta, tau, D, guess)``: the deflection ``D`` [rad] of one
#: gearbox spring carrying the torque ``tau`` [N.m] (Newton's method on ``tau_s(D) = tau``, from
#: ``D`` when ``guess``; :func:`spring_deflection` for one joint; common/gearbox.pxd)
spring_inverse = _kernels.spring_inverse
#: ``gravity_torques(g1, g2, q1, q2)``: the gravity torques of eq. 11 [N.m] on floats
#: (:func:`gravity_torque`; the constants ``g1``, ``g2`` of :class:`ArmConstants`; common/planar_arm.pxd)
gravity_torques = _kernels.gravity_torques


class ArmConstants:
    """The parameters as plain floats, and the inertia and gravity constants of the planar arm
    (eq. 11), the one place they are formed (plant, filters, identification and CRLB read them
    here; :func:`arm_constants` caches them per parameter set).

    ``M11 = a + 2 b(q2)``, ``M12 = c + b(q2)``, ``M22 = c`` with ``b = -e sin q2``,
    ``e = m2 l1 c2``; gravity ``G = (-g1 sin q1 - g2 cos(q1 + q2), -g2 cos(q1 + q2))``.

    Built from ``p``, the robot parameters. The methods take a joint index ``i`` (0: axis 2,
    1: axis 3) and arm-side quantities: deflection ``D`` [rad], torque ``tau`` [N.m].
    """

    def __init__(self, p: RobotParameters) -> None:
        self.p = p
        self.l1, self.l2, self.g = float(p.l1), float(p.l2), float(p.g)
        self.a = p.I1 + p.m1 * p.c1 ** 2 + p.I2 + p.m2 * (p.l1 ** 2 + p.c2 ** 2)
        self.c = p.I2 + p.m2 * p.c2 ** 2
        self.e = p.m2 * p.l1 * p.c2
        self.g1 = p.g * (p.m1 * p.c1 + p.m2 * p.l1)
        self.g2 = p.g * p.m2 * p.c2
        self.r = tuple(map(float, p.gear_ratio))
        self.jm = tuple(map(float, p.J_m))
        self.k_hi = tuple(map(float, p.k_hi))
        self.k_soft = tuple(float(h - lo) for h, lo in zip(p.k_hi, p.k_lo))
        self.delta = tuple(map(float, p.delta))
        self.d = tuple(map(float, p.d))
        self.f_v = tuple(map(float, p.f_v))
        self.f_c = tuple(map(float, p.f_c))
        self.w_c = tuple(map(float, p.w_c))
        #: gravity and spring constants of the compiled static inversion (the rigid baseline):
        #: g1, g2, k_hi (2), k_soft (2), delta (2)
        self.static = np.array([self.g1, self.g2, *self.k_hi, *self.k_soft, *self.delta])
        #: every constant of :func:`flex_rates`, in its order: a, c, e, g1, g2, l1, l2, gear ratios,
        #: k_hi, k_soft, delta, d, f_v, f_c, w_c, J_m (2 each)
        self.packed = np.array([self.a, self.c, self.e, self.g1, self.g2, self.l1, self.l2, *self.r, *self.k_hi,
                                *self.k_soft, *self.delta, *self.d, *self.f_v, *self.f_c, *self.w_c, *self.jm],
                               dtype=float)

    def spring(self, i: int, D: float) -> float:
        """Gearbox spring torque ``tau_s(D)`` [N.m] of joint ``i`` at the deflection ``D`` [rad]
        (:func:`spring_torque` on a float)."""
        return spring_scalar(self.k_hi[i], self.k_soft[i], self.delta[i], D)

    def deflection(self, i: int, tau: float, D0: float | None = None) -> float:
        """:func:`spring_deflection` of joint ``i`` on a float: the deflection [rad] carrying the
        spring torque ``tau`` [N.m], from the guess ``D0`` [rad] if given (:func:`spring_inverse`)."""
        return spring_inverse(self.k_hi[i], self.k_soft[i], self.delta[i], float(tau),
                              0.0 if D0 is None else float(D0), D0 is not None)

    def gravity(self, q1: float, q2: float) -> tuple[float, float]:
        """:func:`gravity_torque` [N.m] on floats: the arm angles ``q1``, ``q2`` [rad]
        (:func:`gravity_torques`)."""
        return gravity_torques(self.g1, self.g2, float(q1), float(q2))

    def derivatives(self, s, tau1: float, tau2: float, fx: float, fz: float) -> tuple:
        """``x_dot`` as a tuple of 8 floats (eqs. 10-11) at the state ``s`` (8 floats, the
        module's ``x``), with the motor torques ``tau1``, ``tau2`` [N.m, motor side] and the
        external tool force ``fx``, ``fz`` [N, world x, z] (:func:`flex_rates`, compiled)."""
        return flex_rates(tuple(s), tau1, tau2, fx, fz, self.packed)   # a tuple: the kernel's type


_CACHE: dict[int, ArmConstants] = {}
_CACHE_SIZE = 128      # a tuning study makes thousands of parameter sets: keep the cache bounded


def arm_constants(p: RobotParameters) -> ArmConstants:
    """Constants of ``p``, cached by identity (parameter sets are frozen; an entry keeps its ``p``
    alive, so an id is not reused while cached)."""
    k = _CACHE.get(id(p))
    if k is None:
        if len(_CACHE) >= _CACHE_SIZE:
            _CACHE.clear()
        k = _CACHE[id(p)] = ArmConstants(p)
    return k


# ---- the terms of eq. 11; vectorised over leading axes: q[..., 2] ---------------------------
def _arr(v) -> np.ndarray:
    return np.asarray(v, dtype=float)


def mass_matrix(q, p: RobotParameters) -> np.ndarray:
    """Arm inertia matrix ``M(q_a)`` [kg.m^2] of eq. 11 (shape (..., 2, 2)) at the arm angles
    ``q`` [rad] (shape (..., 2)) of the robot ``p``."""
    k = arm_constants(p)
    b = -k.e * np.sin(_arr(q)[..., 1])
    m12 = k.c + b
    return np.stack([np.stack([k.a + 2 * b, m12], -1), np.stack([m12, np.full_like(b, k.c)], -1)], -2)


def coriolis(q, dq, p: RobotParameters) -> np.ndarray:
    """Coriolis and centrifugal torques ``C(q_a, dq_a) dq_a`` [N.m] of eq. 11 (Christoffel symbols
    of M) at the arm angles ``q`` [rad] and rates ``dq`` [rad/s] of the robot ``p``."""
    k = arm_constants(p)
    bd = -k.e * np.cos(_arr(q)[..., 1])
    dq = _arr(dq)
    dq1, dq2 = dq[..., 0], dq[..., 1]
    return np.stack([bd * (2 * dq1 * dq2 + dq2 * dq2), -bd * dq1 * dq1], -1)


def gravity_torque(q, p: RobotParameters) -> np.ndarray:
    """Gravity torques ``G(q_a) = dV/dq_a`` [N.m] of eq. 11 (``V``: potential energy of the links)
    at the arm angles ``q`` [rad] of the robot ``p``."""
    k = arm_constants(p)
    q = _arr(q)
    cp = np.cos(q[..., 0] + q[..., 1])
    return np.stack([-k.g1 * np.sin(q[..., 0]) - k.g2 * cp, -k.g2 * cp], -1)


def inverse_dynamics_rigid(q, dq, ddq, p: RobotParameters) -> np.ndarray:
    """Arm-side torque ``M ddq + C dq + G`` [N.m] the gearboxes must deliver (eq. 11, left side)
    at the arm angles ``q`` [rad], rates ``dq`` [rad/s] and accelerations ``ddq`` [rad/s^2] of
    the robot ``p``."""
    return (np.einsum("...ij,...j->...i", mass_matrix(q, p), _arr(ddq)) + coriolis(q, dq, p)
            + gravity_torque(q, p))


def spring_torque(q_a, q_m, p: RobotParameters) -> np.ndarray:
    """Gearbox spring torque ``tau_s(D)`` [N.m], ``D = q_m / r - q_a`` (arm side, without
    damping), of the arm angles ``q_a`` [rad] and motor angles ``q_m`` [rad, motor side] of the
    robot ``p`` (its gear ratios and springs)."""
    k = arm_constants(p)
    D = _arr(q_m) / np.array(k.r) - _arr(q_a)
    delta = np.array(k.delta)
    return np.array(k.k_hi) * D - np.array(k.k_soft) * delta * np.tanh(D / delta)


def spring_stiffness(D, p: RobotParameters) -> np.ndarray:
    """``d tau_s / dD`` [N.m/rad] at the deflection ``D`` [rad] of the springs of ``p``: ``k_lo``
    at zero, ``k_hi`` for ``|D| >> delta``."""
    k = arm_constants(p)
    return np.array(k.k_hi) - np.array(k.k_soft) / np.cosh(_arr(D) / np.array(k.delta)) ** 2


def spring_deflection(tau, p: RobotParameters, D0=None) -> np.ndarray:
    """The deflection ``D`` [rad] with ``tau_s(D) = tau`` (``tau`` [N.m] arm side, springs of
    ``p``; Newton's method, ``tau_s`` is monotonic), from ``D0`` [rad] if given (a nearby
    solution: one or two steps)."""
    k = arm_constants(p)
    tau = _arr(tau)
    k_hi, k_soft, delta = np.array(k.k_hi), np.array(k.k_soft), np.array(k.delta)
    if D0 is not None:
        D = _arr(D0)
    else:
        # start on the high-stiffness asymptote, shifted by the soft zone: a few Newton steps
        D = (tau + np.sign(tau) * k_soft * delta * np.tanh(np.abs(tau) / (k_hi * delta))) / k_hi
    # f = k_hi D - k_soft delta tanh(D / delta) - tau,  D -= f / (k_hi - k_soft / cosh(D / delta)^2),
    # in place (a setup solves it on tables of 20 000 rows: no temporaries, each term once)
    D = np.broadcast_to(D, np.broadcast_shapes(D.shape, tau.shape, k_hi.shape)).astype(float)  # a copy
    tol = 1e-12 * np.maximum(1.0, np.abs(tau))
    soft = k_soft * delta
    x, f, g = np.empty_like(D), np.empty_like(D), np.empty_like(D)
    for _ in range(50):
        np.divide(D, delta, out=x)
        np.multiply(soft, np.tanh(x, out=g), out=g)
        np.subtract(np.multiply(k_hi, D, out=f), g, out=f)
        f -= tau
        np.square(np.cosh(x, out=x), out=x)
        np.subtract(k_hi, np.divide(k_soft, x, out=x), out=x)
        D -= np.divide(f, x, out=x)
        if np.all(np.abs(f, out=g) <= tol):
            break
    return D


def motor_friction(dq_m, p: RobotParameters) -> np.ndarray:
    """Motor friction ``f_v w + f_c tanh(w / w_c)`` [N.m] (motor side; smooth Coulomb friction)
    at the motor rates ``w`` = ``dq_m`` [rad/s], with the friction parameters of ``p``."""
    k = arm_constants(p)
    w = _arr(dq_m)
    return np.array(k.f_v) * w + np.array(k.f_c) * np.tanh(w / np.array(k.w_c))


def derivatives(x, tau_m, f_ext, p: RobotParameters) -> np.ndarray:
    """``x_dot`` of the flexible-joint model (eqs. 10-11) of the robot ``p`` at state ``x``, motor
    torque ``tau_m`` [N.m] (motor side) and external tool force ``f_ext`` [N] (world x, z)."""
    return np.array(arm_constants(p).derivatives(tuple(map(float, x)), float(tau_m[0]), float(tau_m[1]),
                                              float(f_ext[0]), float(f_ext[1])))


def arm_acceleration(x, f_ext, p: RobotParameters) -> np.ndarray:
    """Arm angular acceleration [rad/s^2] of the robot ``p`` at state ``x`` with the external
    tool force ``f_ext`` [N] (world x, z) (independent of the motor torque, eq. 11)."""
    return derivatives(x, (0.0, 0.0), f_ext, p)[4:6]


def energy(x, p: RobotParameters) -> float:
    """Total mechanical energy [J] of the robot ``p`` at state ``x``: kinetic (arm and motors),
    gravity and spring potential."""
    k = arm_constants(p)
    q, qm, dq, dqm = x[0:2], x[2:4], np.asarray(x[4:6], float), x[6:8]
    kinetic = 0.5 * dq @ mass_matrix(q, p) @ dq + 0.5 * sum(k.jm[i] * dqm[i] ** 2 for i in range(2))
    q1, phi = float(q[0]), float(q[0]) + float(q[1])
    gravity = k.g1 * math.cos(q1) - k.g2 * math.sin(phi)
    spring = 0.0
    for i in range(2):
        D = float(qm[i]) / k.r[i] - float(q[i])
        spring += 0.5 * k.k_hi[i] * D * D - k.k_soft[i] * k.delta[i] ** 2 * math.log(math.cosh(D / k.delta[i]))
    return float(kinetic + gravity + spring)


def static_equilibrium(q_a, p: RobotParameters) -> np.ndarray:
    """The state at rest with the arm at ``q_a`` [rad]: motors where the springs of the robot
    ``p`` carry gravity.

    Returns ``x`` with ``q_m = r (q_a + D)``, ``tau_s(D) = G(q_a)``; the motor torque that holds
    it is ``G(q_a) / r``.
    """
    q_a = np.asarray(q_a, float)
    D = spring_deflection(gravity_torque(q_a, p), p)
    return np.concatenate([q_a, as_array(p.gear_ratio) * (q_a + D), np.zeros(4)])


def locked_motor_frequencies(q_a, p: RobotParameters) -> np.ndarray:
    """Natural frequencies [Hz] of the arm of the robot ``p`` with the motors locked, linearised
    at rest at the arm angles ``q_a`` [rad].

    ``M ddq = -(K + dG/dq) dq`` with ``K = diag(d tau_s / dD)`` at the gravity deflection.
    """
    q_a = np.asarray(q_a, float)
    K = np.diag(spring_stiffness(spring_deflection(gravity_torque(q_a, p), p), p))
    h = 1e-6
    dG = np.column_stack([(gravity_torque(q_a + h * e, p) - gravity_torque(q_a - h * e, p)) / (2 * h)
                          for e in np.eye(2)])
    w2 = np.linalg.eigvals(np.linalg.solve(mass_matrix(q_a, p), K + dG))
    return np.sort(np.sqrt(w2.real)) / (2 * np.pi)


class FlexibleRobotModel:
    """The plant: state, and a fixed-step RK4 integrator with ``substeps`` per call of :meth:`step`.

    Parameters
    ----------
    p
        Robot parameters.
    q_a0
        Initial arm angles; the robot starts at rest in static equilibrium there.
    substeps
        RK4 steps per :meth:`step` (the stiffest mode is about 20 Hz: 1 ms steps are accurate
        to well under 1 um, see the convergence test).
    """

    def __init__(self, p: RobotParameters, q_a0, substeps: int = 1) -> None:
        self.p = p
        self._k = ArmConstants(p)
        self._s = tuple(float(v) for v in static_equilibrium(q_a0, p))
        self.substeps = int(substeps)
        self.t = 0.0

    @property
    def x(self) -> np.ndarray:
        """The state ``(q_a, q_m, dq_a, dq_m)``."""
        return np.array(self._s)

    @x.setter
    def x(self, value) -> None:
        """Set the state to ``value`` (8 numbers, as :attr:`x`)."""
        self._s = tuple(float(v) for v in value)

    @property
    def state(self) -> tuple:
        """The state as a tuple of floats (no copy: the hot path's view of :attr:`x`)."""
        return self._s

    def arm_acceleration(self, fx: float, fz: float) -> tuple[float, float]:
        """Arm angular acceleration now, with the tool force ``(fx, fz)`` (eq. 11)."""
        d = self._k.derivatives(self._s, 0.0, 0.0, fx, fz)
        return d[4], d[5]

    def spring_torques(self) -> tuple[float, float]:
        """Gearbox spring torques (arm side, without damping) now."""
        k, s = self._k, self._s
        return k.spring(0, s[2] / k.r[0] - s[0]), k.spring(1, s[3] / k.r[1] - s[1])

    def step(self, tau_m, f_ext, dt: float) -> None:
        """Advance by ``dt`` [s] with the inputs held constant (zero-order hold): the motor
        torque ``tau_m`` [N.m, motor side] and the external tool force ``f_ext`` [N, world x, z]."""
        t1, t2, fx, fz = float(tau_m[0]), float(tau_m[1]), float(f_ext[0]), float(f_ext[1])
        if type(self._k) is ArmConstants:        # the 8-state model: compiled, the same operations
            self._s = flex_step(self._s, t1, t2, fx, fz, float(dt), self.substeps, self._k.packed)
            self.t += dt
            return
        f = self._k.derivatives                  # any other model's derivatives (a plant's chain)
        h = dt / self.substeps
        hh, h6 = 0.5 * h, h / 6.0       # the same products as 0.5 * h * b, h / 6.0 * (...)
        s = self._s
        for _ in range(self.substeps):     # tuples of list comprehensions: faster than generators
            k1 = f(s, t1, t2, fx, fz)
            k2 = f(tuple([a + hh * b for a, b in zip(s, k1)]), t1, t2, fx, fz)
            k3 = f(tuple([a + hh * b for a, b in zip(s, k2)]), t1, t2, fx, fz)
            k4 = f(tuple([a + h * b for a, b in zip(s, k3)]), t1, t2, fx, fz)
            s = tuple([a + h6 * (b1 + 2 * b2 + 2 * b3 + b4) for a, b1, b2, b3, b4 in zip(s, k1, k2, k3, k4)])
        self._s = s
        self.t += dt

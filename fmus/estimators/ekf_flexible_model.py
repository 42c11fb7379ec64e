"""The three extended Kalman filters of Henriksson, Norrlöf, Moberg, Wernholt and Schön (2009):
*EKF Complete*, *EKF Motor* and *EKF Integrated* (section III-A).

Estimation model (section II, eq. 2)
------------------------------------
State (eq. 1) ``x = (q_a[2], q_m[2], dq_a[2], dq_m[2])`` (arm angles, motor angles motor side,
rates), input ``u = tau_m`` (motor torque, motor side). The continuous-time model is the plant's
own flexible-joint model, :mod:`fmus.common.dynamics` (eq. 2 with the nonlinear gearbox spring,
gearbox damping and motor friction), evaluated with the filter's parameters (which may differ
from the plant's: a model error) and without the external tool force (unknown to the filter).
It is discretised with Euler's forward difference (section III-A)::

    x_{k+1} = F(x_k, u_k) = x_k + T f(x_k, u_k),    A_k = I + T df/dx    (eqs. 3a, 5)

with the analytic Jacobian :meth:`FlexibleModel.jacobian` (checked against finite differences in
the tests). Euler's method needs ``T`` well below the model's fastest time constants: at the
paper's 2 kHz it is stable for the robot's 8-15 Hz gearbox modes; at 100 Hz it is not.

Measurements (eqs. 3b, 6-8), variants :data:`VARIANTS`
------------------------------------------------------
* ``"complete"`` (eqs. 6-7): motor angles and the accelerometer through the dynamics,
  ``h = (q_m, rho_s(x))``, where ``rho_s`` is the specific force at the sensor mount in the
  tool frame (x, z), with the arm acceleration ``ddq_a`` replaced by its model equation (eq. 2,
  independent of ``u``)::

      rho_s = R(phi)^T (J_s ddq_a + J_s_dot dq_a - g_vec)
            = l1 R(-q2) (ddq1, -dq1^2) + S v dphi_dot - v dphi^2 + g (-sin phi, cos phi)

  (``phi = q1 + q2``, mount vector ``v = (l2 + o_x, o_z)`` in the tool frame, ``S v = (v_z,
  -v_x)``; the closed form of :func:`fmus.common.kinematics.specific_force`).
* ``"motor"``: motor angles only, ``h = q_m``.
* ``"integrated"`` (eq. 8): motor angles and the velocity of the sensor mount in the world frame,
  ``h = (q_m, J_s(q_a) dq_a)``; its measurement is the accelerometer reading rotated to the world
  frame with the estimated tool angle (the predicted ``phi`` at the sample), gravity removed and
  integrated from rest at ``t = 0`` (trapezoidal rule)::

      v_k = v_{k-1} + T / 2 (a_{k-1} + a_k),   a_k = R(phi_hat_k) rho_s_k + g_vec

The accelerometer input is the 3-axis reading ``acc_s`` in the sensor frame
(``R_s = Ry(phi) R_mount``, see :mod:`fmus.robot_plant.sensor_model`); the filter turns it into
the tool frame with its ``mount_rpy`` parameter and uses the x and z components.

Noise (section III-C)
---------------------
The paper's parameterisation: the process noise (its ``R~_lambda``) is block diagonal with the
scalings ``lambda1 .. lambda4`` on the ``q_a``, ``q_m``, ``dq_a``, ``dq_m`` blocks of an initial
guess, and the measurement noise (``W~_lambda``) has ``lambda5`` on the motor-angle block and 1
on the second (accelerometer or velocity) block. Our initial guesses are physical: process noise
intensities ``w_*`` (per sqrt(s), so that ``Q = T diag(...)`` does not depend on the sample
rate) and sensor standard deviations ``r_*``::

    Q = T diag(l1 w_q_a^2 I, l2 w_q_m^2 I, l3 w_dq_a^2 I, l4 w_dq_m^2 I)
    R = diag(l5 r_motor^2 I, r_acc^2 I)       (complete; r_vel for integrated; motor: l5 r_motor^2 I)

The defaults are the physical guesses with every ``lambda = 1``, checked by hand on our plant
(see :data:`DEFAULT_LAMBDAS`); the automatic tuning study sets ``lambda1 .. lambda5``.

The filter (eqs. 4-5) uses the Joseph form of eq. 4b. Divergence (a non-finite state or a
covariance that is not positive definite) raises :class:`FilterDivergence`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg.lapack import dpotrf, dpotrs

from fmus.common import dynamics, kinematics
from fmus.common.parameters import ParameterError, param, replace
from fmus.common.robot_params import RobotAtInitialPose, RobotParameters
from fmus.robot_plant.sensor_model import rot_rpy

PAPER = "Henriksson et al. 2009"
VARIANTS = ("complete", "motor", "integrated")

#: Default scalings ``lambda1 .. lambda5`` per variant (section III-C's free variables; 1 = the
#: physical initial guesses ``w_*``, ``r_*``). Checked by hand on P1 at 2 kHz with three hammer
#: strikes and sensor noise (tests/ekf_flexible_truth.py): a coordinate search on the exact
#: model lowered the 3-30 Hz mean error of EKF Motor and EKF Integrated (0.0028 -> 0.0025 mm,
#: 0.0099 -> 0.0023 mm) but made EKF Integrated lose its robustness to a 50 % stiffness error
#: (0.08 -> 0.23 mm); a grid over lambda1, lambda3, lambda5 in {0.01, 1, 100} found no setting
#: better on both (EKF Complete barely depends on them). Hence 1 until the tuning study.
DEFAULT_LAMBDAS = {
    "complete": (1.0, 1.0, 1.0, 1.0, 1.0),
    "motor": (1.0, 1.0, 1.0, 1.0, 1.0),
    "integrated": (1.0, 1.0, 1.0, 1.0, 1.0),
}


class FilterDivergence(FloatingPointError):
    """The filter's state or covariance became non-finite or lost positive definiteness."""


# ---- parameters ------------------------------------------------------------------------------
def _lambda(i: int, default: float):
    blocks = {1: "arm-angle (q_a)", 2: "motor-angle (q_m)", 3: "arm-velocity (dq_a)",
              4: "motor-velocity (dq_m)", 5: "motor-angle measurement"}
    what = "process noise" if i <= 4 else "measurement noise"
    return param(default, "1", f"scaling lambda{i} of the {blocks[i]} {what} block (section III-C)",
                 low=0.0, low_inclusive=False,
                 source=f"{PAPER}, section III-C; default 1 (see DEFAULT_LAMBDAS)")


@dataclass(frozen=True)
class EkfMotorParameters(RobotAtInitialPose):
    """Parameters of EKF Motor (and the common part of the other two): the filter's robot model
    (inherited; values differing from the plant's are a model error), its noise model and
    initial covariance."""

    stiffness_scale: float = param(1.0, "1", "factor on the model's gearbox stiffness k_lo and k_hi "
                                   "(0.5: the paper's 50 % stiffness error, Table I)", low=0.0,
                                   low_inclusive=False, source=f"{PAPER}, section IV-C")
    lambda1: float = _lambda(1, DEFAULT_LAMBDAS["motor"][0])
    lambda2: float = _lambda(2, DEFAULT_LAMBDAS["motor"][1])
    lambda3: float = _lambda(3, DEFAULT_LAMBDAS["motor"][2])
    lambda4: float = _lambda(4, DEFAULT_LAMBDAS["motor"][3])
    lambda5: float = _lambda(5, DEFAULT_LAMBDAS["motor"][4])
    w_q_a: float = param(1e-4, "rad/s0.5", "process noise intensity of the arm angles (initial guess)",
                         low=0.0, low_inclusive=False,
                         source="physical guess: the angles follow their velocities (Euler error only)")
    w_q_m: float = param(1e-4, "rad/s0.5", "process noise intensity of the motor angles, motor side "
                         "(initial guess)", low=0.0, low_inclusive=False,
                         source="physical guess, as w_q_a (motor side)")
    w_dq_a: float = param(1.0, "rad/s/s0.5", "process noise intensity of the arm velocities: unknown "
                          "forces and model errors (initial guess)", low=0.0, low_inclusive=False,
                          source="physical guess: arm accelerations off the model by about 1 rad/s2")
    w_dq_m: float = param(10.0, "rad/s/s0.5", "process noise intensity of the motor velocities, motor "
                          "side: torque and friction errors (initial guess)", low=0.0,
                          low_inclusive=False,
                          source="physical guess: torque errors about 0.05 N m on J_m = 5e-3 kg m2")
    r_motor: float = param(1e-4, "rad", "measurement noise std of the motor angles, motor side",
                           low=0.0, low_inclusive=False,
                           source="16-bit encoder quantisation (1e-4 rad) plus noise, Encoder FMU")
    p0_q_a: float = param(1e-3, "rad", "initial std of the arm angles", low=0.0, low_inclusive=False)
    p0_q_m: float = param(1e-3, "rad", "initial std of the motor angles, motor side", low=0.0,
                          low_inclusive=False)
    p0_dq_a: float = param(1e-3, "rad/s", "initial std of the arm velocities", low=0.0, low_inclusive=False)
    p0_dq_m: float = param(1e-2, "rad/s", "initial std of the motor velocities", low=0.0,
                           low_inclusive=False)
    init_from_motors: bool = param(True, "1", "start from rest in static equilibrium at the first "
                                   "measured motor angles (off: at q_a0 / p_tool0, which must then "
                                   "match the robot's start)")

    def model_robot(self) -> RobotParameters:
        """The filter's robot model: the robot parameters with ``stiffness_scale`` applied."""
        r = self.robot()
        if self.stiffness_scale == 1.0:
            return r
        s = self.stiffness_scale
        return replace(r, k_lo=tuple(s * k for k in r.k_lo), k_hi=tuple(s * k for k in r.k_hi))


@dataclass(frozen=True)
class EkfCompleteParameters(EkfMotorParameters):
    """Parameters of EKF Complete: EKF Motor's plus the accelerometer's."""

    lambda1: float = _lambda(1, DEFAULT_LAMBDAS["complete"][0])
    lambda2: float = _lambda(2, DEFAULT_LAMBDAS["complete"][1])
    lambda3: float = _lambda(3, DEFAULT_LAMBDAS["complete"][2])
    lambda4: float = _lambda(4, DEFAULT_LAMBDAS["complete"][3])
    lambda5: float = _lambda(5, DEFAULT_LAMBDAS["complete"][4])
    r_acc: float = param(0.05, "m/s2", "measurement noise std of the accelerometer (x and z)", low=0.0,
                         low_inclusive=False, source="Imu FMU noise 0.02 m/s2, plus model error")
    mount_rpy: tuple = param((0.0, 0.0, 0.0), "rad", "mounting roll, pitch, yaw of the accelerometer "
                             "on the tool (as the Imu FMU's)", low=-math.pi, high=math.pi)


@dataclass(frozen=True)
class EkfIntegratedParameters(EkfMotorParameters):
    """Parameters of EKF Integrated: EKF Motor's plus the integrated accelerometer's."""

    lambda1: float = _lambda(1, DEFAULT_LAMBDAS["integrated"][0])
    lambda2: float = _lambda(2, DEFAULT_LAMBDAS["integrated"][1])
    lambda3: float = _lambda(3, DEFAULT_LAMBDAS["integrated"][2])
    lambda4: float = _lambda(4, DEFAULT_LAMBDAS["integrated"][3])
    lambda5: float = _lambda(5, DEFAULT_LAMBDAS["integrated"][4])
    r_vel: float = param(2e-3, "m/s", "measurement noise std of the integrated sensor velocity "
                         "(x and z)", low=0.0, low_inclusive=False,
                         source="physical guess: 0.02 m/s2 noise and small angle errors, "
                         "integrated over seconds")
    mount_rpy: tuple = param((0.0, 0.0, 0.0), "rad", "mounting roll, pitch, yaw of the accelerometer "
                             "on the tool (as the Imu FMU's)", low=-math.pi, high=math.pi)


PARAMETERS = {"complete": EkfCompleteParameters, "motor": EkfMotorParameters,
              "integrated": EkfIntegratedParameters}


# ---- eq. 2 and its Jacobian ------------------------------------------------------------------
class FlexibleModel:
    """``f(x, u)`` of eq. 2 (the plant's :mod:`fmus.common.dynamics` with no tool force), its
    analytic Jacobian, and the measurement functions of eqs. 6-8 with their Jacobians.

    Parameters
    ----------
    p
        The filter's robot model.
    """

    def __init__(self, p: RobotParameters) -> None:
        self.p = p
        self.k = k = dynamics._Constants(p)      # the plant's own constants and f(x, u)
        self.l1, self.l2, self.g = k.l1, k.l2, k.g
        self.vx = float(p.l2 + p.sensor_offset[0])   # sensor mount, tool frame
        self.vz = float(p.sensor_offset[1])
        self.ox, self.oz = float(p.sensor_offset[0]), float(p.sensor_offset[1])

    # -- eq. 2
    def f(self, x, u) -> tuple:
        """``x_dot = f(x, u)`` (eq. 2) as a tuple of 8 floats."""
        return self.k.derivatives(x, u[0], u[1], 0.0, 0.0)

    def jacobian(self, x, u=None, xdot=None) -> np.ndarray:
        """``df/dx`` (8 x 8), analytic (``u`` enters linearly and does not appear).

        ``xdot`` (``f(x, u)``) may be passed to save its evaluation.
        """
        k = self.k
        q1, q2, qm1, qm2, dq1, dq2, dqm1, dqm2 = x
        if xdot is None:
            xdot = self.f(x, (0.0, 0.0) if u is None else u)
        a1, a2 = xdot[4], xdot[5]
        s1, c1 = math.sin(q1), math.cos(q1)
        sp = math.sin(q1 + q2)
        s2, c2 = math.sin(q2), math.cos(q2)
        e = k.e
        b = -e * s2
        bd = -e * c2                      # db/dq2
        bdd = e * s2                      # d bd / dq2
        m11, m12, m22 = k.a + 2 * b, k.c + b, k.c
        det = m11 * m22 - m12 * m12
        i11, i12, i22 = m22 / det, -m12 / det, m11 / det
        r1, r2 = k.r
        D1, D2 = qm1 / r1 - q1, qm2 / r2 - q2
        k1 = k.k_hi[0] - k.k_soft[0] * (1.0 - math.tanh(D1 / k.delta[0]) ** 2)
        k2 = k.k_hi[1] - k.k_soft[1] * (1.0 - math.tanh(D2 / k.delta[1]) ** 2)
        d1, d2 = k.d
        g1, g2 = k.g1, k.g2
        # d rhs / dx (rows: rhs1, rhs2), rhs = tau_spring + damping - Coriolis + gravity terms
        R1 = [-k1 + g1 * c1 - g2 * sp,
              -bdd * (2 * dq1 * dq2 + dq2 * dq2) - g2 * sp,
              k1 / r1, 0.0,
              -d1 - 2 * bd * dq2, -bd * (2 * dq1 + 2 * dq2),
              d1 / r1, 0.0]
        R2 = [-g2 * sp,
              -k2 + bdd * dq1 * dq1 - g2 * sp,
              0.0, k2 / r2,
              2 * bd * dq1, -d2,
              0.0, d2 / r2]
        # dM/dq2 ddq = (2 bd a1 + bd a2, bd a1): subtract from d rhs / dq2
        R1[1] -= 2 * bd * a1 + bd * a2
        R2[1] -= bd * a1
        A = np.zeros((8, 8))
        A[0, 4] = A[1, 5] = A[2, 6] = A[3, 7] = 1.0
        A[4] = [i11 * u1 + i12 * u2 for u1, u2 in zip(R1, R2)]
        A[5] = [i12 * u1 + i22 * u2 for u1, u2 in zip(R1, R2)]
        jm1, jm2 = k.jm
        # motors: jm ddqm = tau - friction - (spring + damping) / r
        A[6, 0] = k1 / r1 / jm1
        A[6, 2] = -k1 / (r1 * r1) / jm1
        A[6, 4] = d1 / r1 / jm1
        A[6, 6] = (-k.f_v[0] - k.f_c[0] / k.w_c[0] * (1.0 - math.tanh(dqm1 / k.w_c[0]) ** 2)
                   - d1 / (r1 * r1)) / jm1
        A[7, 1] = k2 / r2 / jm2
        A[7, 3] = -k2 / (r2 * r2) / jm2
        A[7, 5] = d2 / r2 / jm2
        A[7, 7] = (-k.f_v[1] - k.f_c[1] / k.w_c[1] * (1.0 - math.tanh(dqm2 / k.w_c[1]) ** 2)
                   - d2 / (r2 * r2)) / jm2
        return A

    # -- eq. 7: the accelerometer through the dynamics
    def specific_force(self, x, xdot) -> tuple[float, float]:
        """Specific force at the sensor mount, tool frame (x, z) (eq. 7), with the arm
        acceleration ``xdot[4:6]`` of eq. 2."""
        q1, q2 = x[0], x[1]
        dq1, dphi = x[4], x[4] + x[5]
        a1, aphi = xdot[4], xdot[4] + xdot[5]
        s2, c2 = math.sin(q2), math.cos(q2)
        phi = q1 + q2
        l1, vx, vz, g = self.l1, self.vx, self.vz, self.g
        w = dq1 * dq1
        dp2 = dphi * dphi
        fx = l1 * (c2 * a1 + s2 * w) + vz * aphi - vx * dp2 - g * math.sin(phi)
        fz = l1 * (s2 * a1 - c2 * w) - vx * aphi - vz * dp2 + g * math.cos(phi)
        return fx, fz

    def specific_force_jacobian(self, x, xdot, A: np.ndarray) -> np.ndarray:
        """``d rho_s / dx`` (2 x 8) of :meth:`specific_force` with ``ddq_a(x)``: the direct
        terms plus ``d rho_s / d ddq_a`` times the rows ``A[4:6]`` of :meth:`jacobian`."""
        q1, q2 = x[0], x[1]
        dq1, dphi = x[4], x[4] + x[5]
        a1 = xdot[4]
        s2, c2 = math.sin(q2), math.cos(q2)
        phi = q1 + q2
        sp, cp = math.sin(phi), math.cos(phi)
        l1, vx, vz, g = self.l1, self.vx, self.vz, self.g
        w = dq1 * dq1
        # d rho / d ddq_a
        Fa = np.array([[l1 * c2 + vz, vz], [l1 * s2 - vx, -vx]])
        H = Fa @ A[4:6]
        H[0, 0] += -g * cp
        H[1, 0] += -g * sp
        H[0, 1] += -g * cp + l1 * (-s2 * a1 + c2 * w)
        H[1, 1] += -g * sp + l1 * (c2 * a1 + s2 * w)
        H[0, 4] += 2 * l1 * s2 * dq1 - 2 * vx * dphi
        H[1, 4] += -2 * l1 * c2 * dq1 - 2 * vz * dphi
        H[0, 5] += -2 * vx * dphi
        H[1, 5] += -2 * vz * dphi
        return H

    # -- eq. 8: the sensor velocity
    def _levers(self, q1: float, q2: float) -> tuple[float, float, float, float]:
        """Lever arms ``r1 = p_s`` and ``r2 = p_s - p_elbow`` (world x, z) of the sensor mount."""
        phi = q1 + q2
        sp, cp = math.sin(phi), math.cos(phi)
        r2x = self.l2 * cp + cp * self.ox + sp * self.oz
        r2z = -self.l2 * sp - sp * self.ox + cp * self.oz
        return self.l1 * math.sin(q1) + r2x, self.l1 * math.cos(q1) + r2z, r2x, r2z

    def sensor_velocity(self, x) -> tuple[float, float]:
        """World velocity ``J_s(q_a) dq_a`` of the sensor mount (eq. 8)."""
        rx, rz, r2x, r2z = self._levers(x[0], x[1])
        dq1, dq2 = x[4], x[5]
        return rz * dq1 + r2z * dq2, -rx * dq1 - r2x * dq2

    def sensor_velocity_jacobian(self, x) -> np.ndarray:
        """``d (J_s dq_a) / dx`` (2 x 8), analytic."""
        rx, rz, r2x, r2z = self._levers(x[0], x[1])
        dq1, dq2 = x[4], x[5]
        dphi = dq1 + dq2
        H = np.zeros((2, 8))
        H[0, 0] = -rx * dq1 - r2x * dq2
        H[1, 0] = -rz * dq1 - r2z * dq2
        H[0, 1] = -r2x * dphi
        H[1, 1] = -r2z * dphi
        H[0, 4], H[0, 5] = rz, r2z
        H[1, 4], H[1, 5] = -rx, -r2x
        return H


# ---- the filter (eqs. 3-5) -------------------------------------------------------------------
def _not_pd(P: np.ndarray, where: str) -> FilterDivergence:
    with np.errstate(all="ignore"):
        ev = np.linalg.eigvalsh(P).min() if np.all(np.isfinite(P)) else float("nan")
    return FilterDivergence(f"EKF diverged in the {where}: the covariance is not positive definite "
                            f"(smallest eigenvalue {ev:.3g})")


def _check(x: np.ndarray, P: np.ndarray, where: str, definite: bool = True) -> None:
    """Raise :class:`FilterDivergence` unless ``x`` is finite and ``P`` finite (and, with
    ``definite``, positive definite: a Cholesky factorisation)."""
    if not (math.isfinite(float(x.sum())) and math.isfinite(float(P.sum()))):
        raise FilterDivergence(f"EKF diverged in the {where}: non-finite state or covariance")
    if definite and dpotrf(P, lower=1, clean=0)[1] != 0:
        raise _not_pd(P, where)


@dataclass
class Filtered:
    """A measurement update not yet committed (see :meth:`EkfFlexibleModel.filtered`)."""

    x: np.ndarray
    P: np.ndarray
    innovation_norm: float
    u: tuple                       # the input at the sample (used by the next prediction)
    v_int: tuple = (0.0, 0.0)      # integrated velocity measurement (EKF Integrated)
    a_world: tuple = (0.0, 0.0)    # world acceleration of the sample (trapezoidal rule)


class EkfFlexibleModel:
    """One of the three EKFs of section III-A on the flexible model of eq. 2.

    Parameters
    ----------
    p
        Filter parameters (an :data:`PARAMETERS` class matching ``variant``).
    variant
        ``"complete"``, ``"motor"`` or ``"integrated"``.

    Notes
    -----
    Per sample ``k``: :meth:`update` with the motor angles, the accelerometer reading and the
    motor torque at ``t_k`` gives ``x_{k|k}`` (eq. 4); :meth:`predict` gives ``x_{k+1|k}`` with the
    torque of that sample (eq. 5). :meth:`filtered` computes an update without committing it
    (for an FMU's outputs), :meth:`commit` commits it. With ``init_from_motors`` the first
    update starts from :meth:`initial_state` at the measured motor angles instead of the state
    at ``q_a0`` / ``p_tool0``.
    """

    def __init__(self, p: EkfMotorParameters, variant: str) -> None:
        if variant not in VARIANTS:
            raise ValueError(f"unknown EKF variant {variant!r}; expected one of {VARIANTS}")
        if not isinstance(p, PARAMETERS[variant]):
            raise TypeError(f"EKF {variant!r} needs {PARAMETERS[variant].__name__}, got {type(p).__name__}")
        self.p = p
        self.variant = variant
        self.robot = p.model_robot()
        self.model = FlexibleModel(self.robot)
        self.n = 8
        self.m = 2 if variant == "motor" else 4
        self._wq = np.array([p.lambda1 * p.w_q_a ** 2] * 2 + [p.lambda2 * p.w_q_m ** 2] * 2
                            + [p.lambda3 * p.w_dq_a ** 2] * 2 + [p.lambda4 * p.w_dq_m ** 2] * 2)
        r2 = [p.lambda5 * p.r_motor ** 2] * 2
        if variant == "complete":
            r2 += [p.r_acc ** 2] * 2
        elif variant == "integrated":
            r2 += [p.r_vel ** 2] * 2
        self.R = np.diag(r2)
        self._rdiag = np.array(r2)
        self._mount = rot_rpy(p.mount_rpy)[[0, 2]] if variant != "motor" else None   # sensor -> tool x, z
        self.x = dynamics.static_equilibrium(p.initial_angles(), self.robot)
        self.P = np.diag(np.square([p.p0_q_a] * 2 + [p.p0_q_m] * 2 + [p.p0_dq_a] * 2 + [p.p0_dq_m] * 2))
        self.u = (0.0, 0.0)
        self.innovation_norm = 0.0
        self.v_int = (0.0, 0.0)            # integrated velocity (EKF Integrated)
        self.a_world: tuple | None = None  # last world acceleration (None: before the first sample)
        self._T = 0.0                      # the last prediction's step (the integration step)
        self._started = False              # False until the first update is committed
        self._I = np.eye(8)

    # -- process and measurement noise
    def process_noise(self, T: float) -> np.ndarray:
        """``Q`` for the sample period ``T`` (section III-C, module docstring)."""
        return np.diag(T * self._wq)

    def tool_frame(self, acc_s) -> tuple[float, float]:
        """The accelerometer reading (sensor frame, 3 axes) in the tool frame, x and z."""
        f = self._mount @ np.asarray(acc_s, float)
        return float(f[0]), float(f[1])

    # -- eq. 3b: the measurement function of the variant
    def h(self, x, u=(0.0, 0.0)) -> np.ndarray:
        """``h(x, u)`` (eqs. 6-8) of the variant."""
        x = tuple(map(float, x))
        y = [x[2], x[3]]
        if self.variant == "complete":
            y += self.model.specific_force(x, self.model.f(x, u))
        elif self.variant == "integrated":
            y += self.model.sensor_velocity(x)
        return np.array(y)

    def h_jacobian(self, x, u=(0.0, 0.0)) -> np.ndarray:
        """``H = dh/dx`` (eq. 5 notation), analytic."""
        x = tuple(map(float, x))
        H = np.zeros((self.m, 8))
        H[0, 2] = H[1, 3] = 1.0
        if self.variant == "complete":
            xdot = self.model.f(x, u)
            H[2:4] = self.model.specific_force_jacobian(x, xdot, self.model.jacobian(x, xdot=xdot))
        elif self.variant == "integrated":
            H[2:4] = self.model.sensor_velocity_jacobian(x)
        return H

    def transition(self, x, u, T: float) -> np.ndarray:
        """``F(x, u) = x + T f(x, u)`` (Euler forward, eq. 3a)."""
        return np.asarray(x, float) + T * np.array(self.model.f(tuple(map(float, x)), u))

    def transition_jacobian(self, x, u, T: float) -> np.ndarray:
        """``A = dF/dx = I + T df/dx`` (eq. 5)."""
        return self._I + T * self.model.jacobian(tuple(map(float, x)), u)

    # -- eq. 4
    def filtered(self, q_m, acc_s=None, u=(0.0, 0.0)) -> Filtered:
        """The measurement update (eq. 4) for the sample ``(q_m, acc_s)`` with the input ``u``,
        not committed.

        Raises
        ------
        FilterDivergence
            If the result is non-finite or its covariance not positive definite.
        """
        with np.errstate(all="ignore"):      # non-finite results are caught by the checks
            return self._filtered(q_m, acc_s, (float(u[0]), float(u[1])))

    def initial_state(self, q_m) -> np.ndarray:
        """The state at rest in static equilibrium (the filter's model) with motor angles ``q_m``:
        ``q_a = q_m / r - D(q_a)``, ``tau_s(D) = G(q_a)``, solved by fixed-point iteration (the
        gravity deflection is small: it contracts by about ``|dG/dq| / k`` per iteration)."""
        r = np.asarray(self.robot.gear_ratio, float)
        q_m = np.asarray(q_m, float)
        q = q_m / r
        for _ in range(20):
            D = dynamics.spring_deflection(dynamics.gravity_torque(q, self.robot), self.robot)
            q_new = q_m / r - D
            done = np.abs(q_new - q).max() <= 1e-13
            q = q_new
            if done:
                break
        x = dynamics.static_equilibrium(q, self.robot)
        x[2:4] = q_m
        return x

    def _filtered(self, q_m, acc_s, u: tuple) -> Filtered:
        x0 = self.x
        if not self._started and self.p.init_from_motors:
            x0 = self.initial_state(q_m)
        xs = tuple(x0.tolist())
        m = self.model
        H = np.zeros((self.m, 8))
        H[0, 2] = H[1, 3] = 1.0
        y = [float(q_m[0]), float(q_m[1])]
        hx = [xs[2], xs[3]]
        v_int, a_w = self.v_int, self.a_world
        if self.variant == "complete":
            y += self.tool_frame(acc_s)
            xdot = m.f(xs, u)
            hx += m.specific_force(xs, xdot)
            H[2:4] = m.specific_force_jacobian(xs, xdot, m.jacobian(xs, xdot=xdot))
        elif self.variant == "integrated":
            fx, fz = self.tool_frame(acc_s)
            phi = xs[0] + xs[1]
            c, s = math.cos(phi), math.sin(phi)
            a_w = (c * fx + s * fz, -s * fx + c * fz - self.model.g)      # R(phi) rho + g_vec
            if self.a_world is not None:
                h2 = 0.5 * self._T
                a0 = self.a_world
                v_int = (v_int[0] + h2 * (a0[0] + a_w[0]), v_int[1] + h2 * (a0[1] + a_w[1]))
            y += v_int
            hx += m.sensor_velocity(xs)
            H[2:4] = m.sensor_velocity_jacobian(xs)
        nu = np.array(y) - np.array(hx)
        P = self.P
        PHt = P @ H.T
        S = H @ PHt + self.R
        Sc, info = dpotrf(S, lower=1, clean=0)
        if info != 0:
            raise FilterDivergence("EKF diverged in the measurement update: the innovation covariance "
                                   "is not positive definite")
        KT = dpotrs(Sc, PHt.T, lower=1)[0]            # S^-1 H P = K^T (eq. 5c)
        K = KT.T
        xf = x0 + K @ nu
        IKH = self._I - K @ H
        Pf = IKH @ P @ IKH.T + (K * self._rdiag) @ KT   # Joseph form of eq. 4b (R diagonal)
        Pf = 0.5 * (Pf + Pf.T)
        _check(xf, Pf, "measurement update")
        nnu = math.sqrt(abs(float(nu @ dpotrs(Sc, nu, lower=1)[0])))
        if not math.isfinite(nnu):
            raise FilterDivergence("EKF diverged in the measurement update: the innovation is not finite")
        return Filtered(xf, Pf, nnu, u, v_int, a_w)

    def commit(self, r: Filtered) -> np.ndarray:
        """Make a :meth:`filtered` result the current estimate ``x_{k|k}``."""
        self.x, self.P, self.innovation_norm, self.u = r.x, r.P, r.innovation_norm, r.u
        self._started = True
        self.v_int, self.a_world = r.v_int, r.a_world
        return self.x

    def update(self, q_m, acc_s=None, u=(0.0, 0.0)) -> np.ndarray:
        """Measurement update (eq. 4) with the sample at ``t_k``; returns ``x_{k|k}``."""
        return self.commit(self.filtered(q_m, acc_s, u))

    # -- eq. 5
    def predict(self, T: float, u=None) -> np.ndarray:
        """Time update over ``T`` (eqs. 5a-b), with the input of the last update unless ``u``."""
        u = self.u if u is None else (float(u[0]), float(u[1]))
        T = float(T)
        with np.errstate(all="ignore"):
            xs = tuple(self.x.tolist())
            xdot = self.model.f(xs, u)
            A = self._I + T * self.model.jacobian(xs, xdot=xdot)
            x = self.x + T * np.array(xdot)
            P = A @ self.P @ A.T
            P[np.diag_indices(8)] += T * self._wq
            P = 0.5 * (P + P.T)
        # A P A^T + Q is positive definite if P is: finiteness suffices here (the measurement
        # update checks definiteness)
        _check(x, P, "time update", definite=False)
        self.x, self.P, self._T = x, P, T
        self._started = True
        return x

    # -- outputs
    def tool_position(self, x=None) -> np.ndarray:
        """Tool position (world x, z) from the estimated arm angles (rigid forward kinematics)."""
        return kinematics.tool_position((self.x if x is None else x)[0:2], self.robot)

    def tool_position_variance(self, x=None, P=None) -> float:
        """Trace of the tool position covariance ``J P_qa J^T`` (m^2)."""
        x = self.x if x is None else x
        P = self.P if P is None else P
        J = kinematics.jacobian(x[0:2], self.robot)
        return float(np.einsum("ij,jk,ik->", J, P[0:2, 0:2], J))


def make_filter(variant: str, **params) -> EkfFlexibleModel:
    """An :class:`EkfFlexibleModel` of ``variant`` with validated parameters ``params``.

    Raises
    ------
    ParameterError
        Naming an invalid parameter.
    """
    from fmus.common.parameters import validate
    if variant not in VARIANTS:
        raise ParameterError(f"unknown EKF variant {variant!r}; expected one of {VARIANTS}")
    return EkfFlexibleModel(validate(PARAMETERS[variant](**params)), variant)


__all__ = ["EkfCompleteParameters", "EkfFlexibleModel", "EkfIntegratedParameters", "EkfMotorParameters",
           "FilterDivergence", "Filtered", "FlexibleModel", "PARAMETERS", "VARIANTS", "DEFAULT_LAMBDAS",
           "make_filter"]

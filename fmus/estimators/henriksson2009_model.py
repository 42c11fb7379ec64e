"""The estimation model of Henriksson, Norrlöf, Moberg, Wernholt and Schön (2009), shared by
their three EKFs (:mod:`fmus.estimators.ekf_flexible_model`): the flexible-joint model of
eq. 2 with its analytic Jacobian, and the measurement functions of eqs. 6-8 with theirs.

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

Measurements (eqs. 3b, 6-8), variants :data:`fmus.estimators.ekf_flexible_model.VARIANTS`
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
"""
from __future__ import annotations

import math

import numpy as np

from fmus.common import dynamics
from fmus.common.robot_params import RobotParameters


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
        self.k = k = dynamics.arm_constants(p)      # the plant's own constants and f(x, u)
        self.l1, self.l2, self.g = k.l1, k.l2, k.g
        self.vx = float(p.l2 + p.sensor_offset[0])   # sensor mount, tool frame
        self.vz = float(p.sensor_offset[1])
        self.ox, self.oz = float(p.sensor_offset[0]), float(p.sensor_offset[1])

    # -- eq. 2
    def f(self, x, u) -> tuple:
        """``x_dot = f(x, u)`` (eq. 2) as a tuple of 8 floats."""
        return self.k.derivatives(x, u[0], u[1], 0.0, 0.0)

    def f_scaled(self, x, u, sigma: float) -> tuple:
        """``f(x, u)`` with the gearbox spring torque ``tau_s(D)`` (not the damping) scaled by
        ``sigma`` (the stiffness-factor state of the ``tilt_stiffness`` drift correction):
        ``f + (sigma - 1) df/dsigma``, since ``f`` is linear in the spring torque."""
        xdot = self.k.derivatives(x, u[0], u[1], 0.0, 0.0)
        if sigma == 1.0:
            return xdot
        col = self.stiffness_column(x)
        s1 = sigma - 1.0
        return tuple(a + s1 * c for a, c in zip(xdot, col))

    def stiffness_column(self, x) -> tuple:
        """``df/dsigma`` (8 floats) of :meth:`f_scaled`: the spring torques ``tau_s(D)`` through
        ``M^-1`` on the arm and ``-1 / (r J_m)`` on the motors."""
        k = self.k
        q2 = x[1]
        b = -k.e * math.sin(q2)
        m11, m12, m22 = k.a + 2 * b, k.c + b, k.c
        det = m11 * m22 - m12 * m12
        r1, r2 = k.r
        t1 = k.spring(0, x[2] / r1 - x[0])
        t2 = k.spring(1, x[3] / r2 - x[1])
        return (0.0, 0.0, 0.0, 0.0, (m22 * t1 - m12 * t2) / det, (m11 * t2 - m12 * t1) / det,
                -t1 / (r1 * k.jm[0]), -t2 / (r2 * k.jm[1]))

    def jacobian(self, x, u=None, xdot=None, sigma: float = 1.0) -> np.ndarray:
        """``df/dx`` (8 x 8), analytic (``u`` enters linearly and does not appear).

        ``xdot`` (``f(x, u)``, or :meth:`f_scaled` with ``sigma``) may be passed to save its
        evaluation; ``sigma`` scales the spring torque as in :meth:`f_scaled`.
        """
        k = self.k
        q1, q2, qm1, qm2, dq1, dq2, dqm1, dqm2 = x
        if xdot is None:
            xdot = self.f_scaled(x, (0.0, 0.0) if u is None else u, sigma)
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
        k1 = sigma * (k.k_hi[0] - k.k_soft[0] * (1.0 - math.tanh(D1 / k.delta[0]) ** 2))
        k2 = sigma * (k.k_hi[1] - k.k_soft[1] * (1.0 - math.tanh(D2 / k.delta[1]) ** 2))
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
        """``d rho_s / dx`` (2 x 8) of :meth:`specific_force` with ``ddq_a(x)``, at the state
        ``x`` and its derivative ``xdot`` (eq. 2, whose ``xdot[4:6]`` is the arm acceleration):
        the direct terms plus ``d rho_s / d ddq_a`` times the rows ``A[4:6]`` of :meth:`jacobian`."""
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


__all__ = ["FlexibleModel"]

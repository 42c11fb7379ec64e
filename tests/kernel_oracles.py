"""The compiled kernels' readable forms: the oracles the tests hold them to, bit for bit.

Plain Python on floats, each the operations of its kernel in the same order (they were the numba
kernels' sources until the kernels moved to Cython): ``math.sin``/``cos``/``tanh`` call the C
library the compiled kernels call, Python rounds each operation as C does without contraction
into fused multiply-adds (fmus/common/cython_kernels.py), so equal inputs give equal bits.

* the 8-state flexible-joint model: :func:`spring_scalar`, :func:`flex_rates`,
  :func:`flex_step` (common/dynamics_kernels.pyx);
* the sensors (robot_plant/sensor_kernels.pyx): :func:`channels_kernel`, :func:`channels_step`
  on SensorChannels' work array (its layout's names below), :func:`imu_reading_into`;
* the laser tracker (robot_plant/tracker_kernels.pyx): :func:`tracker_update`;
* the gearbox spring's inverse and the gravity torques (common/gearbox.pxd, planar_arm.pxd,
  through common/dynamics_kernels.pyx): :func:`spring_inverse`, :func:`gravity_torques`;
* the rigid-kinematics baseline (estimators/rigid_kinematics_kernels.pyx): :func:`compensated`,
  :func:`estimate`; its tool point is the numba kernel's own Python function
  (``fmus.common.kinematics.tool_point``, still numba: the controller and the 2012 EKF call it),
  so that the two definitions are held equal.
* the plant's four-body chain: :func:`chain4_arm`, :func:`chain4_rates`, :func:`chain4_step`,
  :func:`chain4_outputs`, :func:`chain4_advance` (robot_plant/plant_kernels.pyx), on the
  constants ``P`` of ``PlantChain._pack`` (its offsets named in the kernel's struct ``Chain4``).
"""
from __future__ import annotations

import math

import numpy as np

from fmus.common import kinematics
from fmus.common.sample_time import TIME_TOL

HALF_PI = 0.5 * math.pi
tool_point = getattr(kinematics.tool_point, "py_func", kinematics.tool_point)


def spring_scalar(k_hi: float, k_soft: float, delta: float, D: float) -> float:
    """Gearbox spring torque ``tau_s(D) = k_hi D - (k_hi - k_lo) delta tanh(D / delta)`` [N.m] of
    one joint on floats (``k_soft = k_hi - k_lo``), the deflection ``D`` [rad]: the one
    definition of kernels (the plant's chain) and of :meth:`ArmConstants.spring`."""
    return k_hi * D - k_soft * delta * math.tanh(D / delta)


def flex_rates(s, tau1: float, tau2: float, fx: float, fz: float, K: np.ndarray) -> tuple:
    """``x_dot`` of the flexible-joint model (eqs. 10-11) as a tuple of 8 floats at the state
    ``s`` (8 floats: ``q_a``, ``q_m``, ``dq_a``, ``dq_m``), with the motor torques ``tau1``,
    ``tau2`` [N.m, motor side], the external tool force ``fx``, ``fz`` [N, world x, z] and the
    constants ``K`` (:attr:`ArmConstants.packed`)."""
    q1, q2, qm1, qm2, dq1, dq2, dqm1, dqm2 = s[0], s[1], s[2], s[3], s[4], s[5], s[6], s[7]
    s1, c1 = math.sin(q1), math.cos(q1)
    phi = q1 + q2
    sp, cp = math.sin(phi), math.cos(phi)
    s2, c2 = math.sin(q2), math.cos(q2)
    b = -K[2] * s2
    bd = -K[2] * c2                           # db/dq2
    m11, m12, m22 = K[0] + 2.0 * b, K[1] + b, K[1]
    r1, r2 = K[7], K[8]
    D1, D2 = qm1 / r1 - q1, qm2 / r2 - q2
    t1 = spring_scalar(K[9], K[11], K[13], D1) + K[15] * (dqm1 / r1 - dq1)
    t2 = spring_scalar(K[10], K[12], K[14], D2) + K[16] * (dqm2 / r2 - dq2)
    l1, l2, g1, g2 = K[5], K[6], K[3], K[4]
    # J_tool^T f_ext
    e1 = fx * (l1 * c1 - l2 * sp) - fz * (l1 * s1 + l2 * cp)
    e2 = -l2 * (fx * sp + fz * cp)
    rhs1 = t1 + e1 - bd * (2.0 * dq1 * dq2 + dq2 * dq2) + g1 * s1 + g2 * cp
    rhs2 = t2 + e2 + bd * dq1 * dq1 + g2 * cp
    det = m11 * m22 - m12 * m12
    ddq1 = (m22 * rhs1 - m12 * rhs2) / det
    ddq2 = (m11 * rhs2 - m12 * rhs1) / det
    ddqm1 = (tau1 - K[17] * dqm1 - K[19] * math.tanh(dqm1 / K[21]) - t1 / r1) / K[23]
    ddqm2 = (tau2 - K[18] * dqm2 - K[20] * math.tanh(dqm2 / K[22]) - t2 / r2) / K[24]
    return dq1, dq2, dqm1, dqm2, ddq1, ddq2, ddqm1, ddqm2


def rk4_stage(x: np.ndarray, a: float, k: tuple, y: np.ndarray) -> None:
    """``y = x + a k``: the state of an RK4 stage (``k`` the rates of the one before, a tuple)."""
    for i in range(x.size):
        y[i] = x[i] + a * k[i]


def rk4_update(x: np.ndarray, h6: float, k1: tuple, k2: tuple, k3: tuple, k4: tuple) -> None:
    """``x += h6 (k1 + 2 k2 + 2 k3 + k4)`` in place: the end of an RK4 step (``h6 = h / 6``)."""
    for i in range(x.size):
        x[i] = x[i] + h6 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])


def flex_step(s: tuple, tau1: float, tau2: float, fx: float, fz: float, dt: float, substeps: int,
              K: np.ndarray) -> tuple:
    """``substeps`` RK4 steps over ``dt`` [s] of :func:`flex_rates` from the state ``s`` (8-tuple)
    with the inputs ``tau1``, ``tau2`` [N.m], ``fx``, ``fz`` [N] held and the constants ``K``:
    the new state (8-tuple), :meth:`FlexibleRobotModel.step`'s operations in the same order."""
    h = dt / substeps
    hh, h6 = 0.5 * h, h / 6.0
    x, y = np.empty(8), np.empty(8)
    for i in range(8):
        x[i] = s[i]
    for _ in range(substeps):
        k1 = flex_rates(x, tau1, tau2, fx, fz, K)
        rk4_stage(x, hh, k1, y)
        k2 = flex_rates(y, tau1, tau2, fx, fz, K)
        rk4_stage(x, hh, k2, y)
        k3 = flex_rates(y, tau1, tau2, fx, fz, K)
        rk4_stage(x, h, k3, y)
        k4 = flex_rates(y, tau1, tau2, fx, fz, K)
        rk4_update(x, h6, k1, k2, k3, k4)
    return x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7]


def spring4(P, i, D):
    """The gearbox spring ``tau_s(D)`` of joint ``i`` (:func:`fmus.common.spring_scalar`)."""
    return spring_scalar(P[4 + i], P[6 + i], P[8 + i], D)


def applied4(P, i, tau, qm):
    """The torque motor ``i`` applies for the command ``tau`` at the motor angle ``qm``
    (:meth:`PlantChain.applied_torque`)."""
    return P[42 + i] * tau + P[44 + i] * math.sin(P[46 + i] * qm)


def chain4_arm(s, fx, fz, P):
    """:meth:`PlantChain.arm` of the four-body chain, written out (LDL^T solve of the 4x4
    system): the absolute angles' sines, cosines, rates and accelerations, and the joint
    torques, at the state ``s`` (tuple or array) with the tool force ``(fx, fz)``."""
    q1, b1, q2, b2, qm1, qm2, dq1, db1, dq2, db2, dqm1, dqm2 = (s[0], s[1], s[2], s[3], s[4], s[5], s[6],
                                                                s[7], s[8], s[9], s[10], s[11])
    p1 = q1 + P[0]
    p2 = p1 + b1
    p3 = p2 + q2 + P[1]
    p4 = p3 + b2
    s1, c1, s2, c2 = math.sin(p1), math.cos(p1), math.sin(p2), math.cos(p2)
    s3, c3, s4, c4 = math.sin(p3), math.cos(p3), math.sin(p4), math.cos(p4)
    w1 = dq1
    w2 = w1 + db1
    w3 = w2 + dq2
    w4 = w3 + db2
    r1, r2 = P[2], P[3]
    t1 = spring4(P, 0, qm1 / r1 - q1) + P[10] * (dqm1 / r1 - dq1)
    t3 = spring4(P, 1, qm2 / r2 - q2) + P[11] * (dqm2 / r2 - dq2)
    t2 = -(P[20] * b1 + P[21] * db1)
    t4 = -(P[22] * b2 + P[23] * db2)
    h12, h13, h14, h23, h24, h34 = P[24], P[25], P[26], P[27], P[28], P[29]
    # M_jk = h_jk cos(psi_j - psi_k); velocity terms h_jk sin(psi_j - psi_k) w_k^2
    c12, s12 = c1 * c2 + s1 * s2, s1 * c2 - c1 * s2
    c13, s13 = c1 * c3 + s1 * s3, s1 * c3 - c1 * s3
    c14, s14 = c1 * c4 + s1 * s4, s1 * c4 - c1 * s4
    c23, s23 = c2 * c3 + s2 * s3, s2 * c3 - c2 * s3
    c24, s24 = c2 * c4 + s2 * s4, s2 * c4 - c2 * s4
    c34, s34 = c3 * c4 + s3 * s4, s3 * c4 - c3 * s4
    ww1, ww2, ww3, ww4 = w1 * w1, w2 * w2, w3 * w3, w4 * w4
    g1, g2, g3, g4, L1, L2, L3, L4 = P[30], P[31], P[32], P[33], P[34], P[35], P[36], P[37]
    y1 = g1 * s1 + L1 * (fx * c1 - fz * s1) + t1 - t2 - (h12 * s12 * ww2 + h13 * s13 * ww3 + h14 * s14 * ww4)
    y2 = g2 * s2 + L2 * (fx * c2 - fz * s2) + t2 - t3 - (-h12 * s12 * ww1 + h23 * s23 * ww3 + h24 * s24 * ww4)
    y3 = g3 * s3 + L3 * (fx * c3 - fz * s3) + t3 - t4 - (-h13 * s13 * ww1 - h23 * s23 * ww2 + h34 * s34 * ww4)
    y4 = g4 * s4 + L4 * (fx * c4 - fz * s4) + t4 + (h14 * s14 * ww1 + h24 * s24 * ww2 + h34 * s34 * ww3)
    m11, m22, m33, m44 = P[38], P[39], P[40], P[41]
    m12, m13, m14, m23, m24, m34 = h12 * c12, h13 * c13, h14 * c14, h23 * c23, h24 * c24, h34 * c34
    # M = L D L^T
    l21, l31, l41 = m12 / m11, m13 / m11, m14 / m11
    d2 = m22 - l21 * m12
    l32, l42 = (m23 - l31 * m12) / d2, (m24 - l41 * m12) / d2
    d3 = m33 - l31 * m13 - l32 * l32 * d2
    l43 = (m34 - l41 * m13 - l42 * l32 * d2) / d3
    d4 = m44 - l41 * m14 - l42 * l42 * d2 - l43 * l43 * d3
    y2 -= l21 * y1
    y3 -= l31 * y1 + l32 * y2
    y4 -= l41 * y1 + l42 * y2 + l43 * y3
    a4 = y4 / d4
    a3 = y3 / d3 - l43 * a4
    a2 = y2 / d2 - l32 * a3 - l42 * a4
    a1 = y1 / m11 - l21 * a2 - l31 * a3 - l41 * a4
    return (s1, s2, s3, s4), (c1, c2, c3, c4), (w1, w2, w3, w4), (a1, a2, a3, a4), (t1, t2, t3, t4)


def chain4_rates(s, tau1, tau2, fx, fz, P):
    """:meth:`PlantChain.derivatives` of the four-body chain: ``x_dot`` as a 12-tuple."""
    _, _, _, A, T = chain4_arm(s, fx, fz, P)
    qm1, qm2, dqm1, dqm2 = s[4], s[5], s[10], s[11]
    ddqm1 = (applied4(P, 0, tau1, qm1) - P[12] * dqm1 - P[14] * math.tanh(dqm1 / P[16]) - T[0] / P[2]) / P[18]
    ddqm2 = (applied4(P, 1, tau2, qm2) - P[13] * dqm2 - P[15] * math.tanh(dqm2 / P[17]) - T[2] / P[3]) / P[19]
    a1, a2, a3, a4 = A
    return (s[6], s[7], s[8], s[9], s[10], s[11], a1, a2 - a1, a3 - a2, a4 - a3, ddqm1, ddqm2)


def chain4_step(s, tau1, tau2, fx, fz, dt, substeps, P):
    """``substeps`` RK4 steps over ``dt`` [s] of the four-body chain from the state ``s``
    (12-tuple), the motor torques ``tau1``, ``tau2`` [N m] and the tool force ``fx``, ``fz`` [N]
    held; ``P`` the chain's constants (:meth:`PlantChain._pack`). Returns the new state
    (12-tuple): the operations of :meth:`fmus.common.dynamics.FlexibleRobotModel.step`, in the
    same order."""
    h = dt / substeps
    hh, h6 = 0.5 * h, h / 6.0
    x, y = np.empty(12), np.empty(12)
    for i in range(12):
        x[i] = s[i]
    for _ in range(substeps):                   # dynamics.flex_step's RK4 on the chain's rates
        k1 = chain4_rates(x, tau1, tau2, fx, fz, P)
        rk4_stage(x, hh, k1, y)
        k2 = chain4_rates(y, tau1, tau2, fx, fz, P)
        rk4_stage(x, hh, k2, y)
        k3 = chain4_rates(y, tau1, tau2, fx, fz, P)
        rk4_stage(x, h, k3, y)
        k4 = chain4_rates(y, tau1, tau2, fx, fz, P)
        rk4_update(x, h6, k1, k2, k3, k4)
    return (x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7], x[8], x[9], x[10], x[11])


def chain4_outputs(s, fx, fz, P):
    """:meth:`PlantChain.outputs` of the four-body chain (24 floats, the same operations) at the
    state ``s`` with the tool force ``fx``, ``fz`` [N]; ``P`` the chain's constants."""
    S, C, W, A, _ = chain4_arm(s, fx, fz, P)
    px = pz = vx = vz = ax = az = 0.0
    for k in range(4):
        L = P[34 + k]
        px += L * S[k]
        pz += L * C[k]
        vx += L * W[k] * C[k]
        vz -= L * W[k] * S[k]
        ax += L * (A[k] * C[k] - W[k] * W[k] * S[k])
        az -= L * (A[k] * S[k] + W[k] * W[k] * C[k])
    # sensor: p_tool + R(phi) o with phi = psi_last - pi/2 (cos phi = sin psi, sin phi = -cos psi)
    cphi, sphi, w, a = S[3], -C[3], W[3], A[3]
    ox, oz = P[48], P[49]
    rx, rz = cphi * ox + sphi * oz, -sphi * ox + cphi * oz
    ex, ez = -sphi * ox + cphi * oz, -cphi * ox - sphi * oz        # d(R o)/d phi
    phi = 0.0 + s[0] + s[1] + s[2] + s[3] + P[50] - HALF_PI         # sum(s[:4]) as Python adds
    qm1, qm2 = s[4], s[5]
    return (s[0], s[2], s[6], s[8], A[0] - 0.0, A[2] - A[1], qm1, qm2, s[10], s[11],
            px, pz, vx, vz, ax, az, phi, w, px + rx, pz + rz,
            ax + a * ex - w * w * rx, az + a * ez - w * w * rz,
            spring4(P, 0, qm1 / P[2] - s[0]), spring4(P, 1, qm2 / P[3] - s[2]))


def chain4_advance(s, tau, f, dt, substeps, P, out, at):
    """A plant step in one call: :func:`chain4_step` over ``dt`` [s] (``substeps`` RK4 steps)
    from the state ``s`` with the motor torques ``tau`` [N m] and the tool force ``f`` [N]
    (arrays of 2) held and the chain's constants ``P`` (:meth:`PlantChain._pack`), then the
    outputs at the new state (the 24 of :func:`chain4_outputs`, then the 2 applied torques of
    ``tau``, :meth:`ExtendedRobotModel.applied_torques`): value ``i`` of these 26 into
    ``out[at[i]]`` unless ``at[i]`` is negative. Returns the new state, the tool angle and its
    rate (outputs 16 and 17)."""
    tau1, tau2, fx, fz = tau[0], tau[1], f[0], f[1]
    s = chain4_step(s, tau1, tau2, fx, fz, dt, substeps, P)
    y = chain4_outputs(s, fx, fz, P)
    for i in range(24):
        if at[i] >= 0:
            out[at[i]] = y[i]
    if at[24] >= 0:
        out[at[24]] = applied4(P, 0, tau1, s[4])
    if at[25] >= 0:
        out[at[25]] = applied4(P, 1, tau2, s[5])
    return s, y[16], y[17]


# ---- the sensors -----------------------------------------------------------------------------
_COUNT, _PERIOD, _ROW, _STARTED, _ORDER, _N = range(6)
_COEF = 6
_TABLE = _COEF + 5
_GAIN, _BIAS, _RW, _NOISE, _RES, _LIM = range(6)


def channels_kernel(x, work, out, rows, row, order, reset, sample, noisy):
    """One step of :class:`SensorChannels` (its steps 1 and 3-7) on its ``work`` array, the
    numbers of the former elementwise numpy code operation by operation (no fastmath: same
    rounding).

    ``out`` holds ``runs * n`` values (one sensor: ``runs = 1``), element ``k`` of channel
    ``k % n``; the input ``x`` holds ``runs * n`` or ``n`` values (one input for every run).
    ``order`` 0: no filter; ``reset``: start the filter in steady state at ``x``; ``sample``:
    form the reading into ``out`` and the saturation flags; ``noisy``: with the bias-walk step
    ``rows[row, k]`` and the white noise ``rows[row, runs * n + k]`` (standard normal numbers)
    scaled by the table's rows.
    """
    n, size = int(work[_N]), out.size
    z0 = _TABLE + 6 * n
    z1, walk, saturated = z0 + size, z0 + 2 * size, z0 + 3 * size
    b0, b1, b2, a1, a2 = work[_COEF], work[_COEF + 1], work[_COEF + 2], work[_COEF + 3], work[_COEF + 4]
    for k in range(size):
        j = _TABLE + k % n
        y = x[k % x.size]
        if order > 0:
            u = y
            if reset:                            # steady state for a constant input
                if order == 2:
                    work[z1 + k] = (b2 - a2) * u
                work[z0 + k] = (1.0 - b0) * u
            y = b0 * u + work[z0 + k]            # direct form II transposed
            if order == 1:
                work[z0 + k] = b1 * u - a1 * y
            else:
                work[z0 + k] = b1 * u - a1 * y + work[z1 + k]
                work[z1 + k] = b2 * u - a2 * y
        if sample:
            if noisy:
                work[walk + k] = work[walk + k] + work[j + _RW * n] * rows[row, k]
                y = (work[j + _GAIN * n] * y + work[j + _BIAS * n] + work[walk + k]
                     + work[j + _NOISE * n] * rows[row, size + k])
            else:
                y = work[j + _GAIN * n] * y + work[j + _BIAS * n] + work[walk + k]
            res = work[j + _RES * n]
            if res > 0.0:
                y = np.rint(y / res) * res       # numpy's round half to even
            lim = work[j + _LIM * n]
            work[saturated + k] = 1.0 if abs(y) >= lim else 0.0
            if y > lim:
                y = lim
            elif y < -lim:
                y = -lim
            out[k] = y


_HELD, _SAMPLED, _USED_UP = 0, 1, 2       # what _channels_step returns


def channels_step(x, work, out, rows):
    """:meth:`SensorChannels.step` after its checks, in one call: the low-pass (started in
    steady state at its first step), and at a sample (no step since the last) a reading into
    ``out`` with the next row of the drawn standard normal numbers ``rows``
    (:func:`channels_kernel`); then the counters move on. Returns ``_HELD``, ``_SAMPLED`` or
    ``_USED_UP`` (sampled with the last row)."""
    sample = work[_COUNT] == 0.0
    order = int(work[_ORDER])
    reset = order > 0 and work[_STARTED] == 0.0
    if order > 0:
        work[_STARTED] = 1.0
    row = int(work[_ROW])
    if sample:
        work[_ROW] = row + 1
    channels_kernel(x, work, out, rows, row, order, reset, sample, sample)
    work[_COUNT] = (work[_COUNT] + 1.0) % work[_PERIOD]
    if not sample:
        return _HELD
    return _USED_UP if row + 1 == rows.shape[0] else _SAMPLED


def imu_reading_into(a_world_xz, phi, omega, mount, g, acc, gyro):
    """:func:`imu_reading` of ``a_world_xz``, ``phi``, ``omega`` and ``g`` into the arrays
    ``acc`` and ``gyro`` (3 each), with the mount matrix ``mount`` of :func:`mount_matrix`:
    the same operations."""
    m00, m01, m02, m10, m11, m12, m20, m21, m22 = (mount[0], mount[1], mount[2], mount[3], mount[4], mount[5],
                                                   mount[6], mount[7], mount[8])
    c, s = math.cos(phi), math.sin(phi)
    ax, vz = a_world_xz[0], a_world_xz[1] + g          # a - g_vec, y = 0
    # rows 0 and 2 of R_s (row 1 is R_mount's): acc = R_s^T (ax, 0, vz), gyro = R_s^T (0, omega, 0)
    r00, r01, r02 = c * m00 + s * m20, c * m01 + s * m21, c * m02 + s * m22
    r20, r21, r22 = c * m20 - s * m00, c * m21 - s * m01, c * m22 - s * m02
    acc[0], acc[1], acc[2] = r00 * ax + r20 * vz, r01 * ax + r21 * vz, r02 * ax + r22 * vz
    gyro[0], gyro[1], gyro[2] = m10 * omega, m11 * omega, m12 * omega


# ---- the tracker (its layout's names prefixed: the sensors' are above) -----------------------
# TrackerModel's state (a float array the kernel keeps): history entries, index of the next
# sample instant, the held sample's stamp, the next row of the drawn random numbers
_TRACKER_ENTRIES, _TRACKER_NEXT, _TRACKER_T_MEAS, _TRACKER_ROW = range(4)
_TRACKER_DONE, _TRACKER_FULL, _TRACKER_DRAWN = 0, 1, 2           # what tracker_update returns


def _position(hist, m, t, c):
    """Coordinate ``c`` (a column, 1 and up) of the true position at ``t`` by linear
    interpolation in the ``m`` entries ``(t, x, z)`` (or ``(t, x, y, z)``) of ``hist`` (held
    before the first and after the last)."""
    if t <= hist[0, 0]:
        return hist[0, c]
    for i in range(m - 1):
        ta, xa, tb, xb = hist[i, 0], hist[i, c], hist[i + 1, 0], hist[i + 1, c]
        if t <= tb:
            w = (t - ta) / (tb - ta) if tb > ta else 1.0
            return xa + w * (xb - xa)
    return hist[m - 1, c]


def tracker_update(t, p, append, hist, state, consts, rows, p_meas):
    """:meth:`TrackerModel.update` on arrays: append ``(t, p)`` (2 or 3 coordinates) to the
    history ``hist`` (with ``append``), take every sample due by ``t`` into ``p_meas``
    (``consts``: first instant, period, skew, noise; ``state``: the layout above), drop the
    history no later sample needs. Returns ``_TRACKER_FULL`` (nothing done: the history needs
    room), ``_TRACKER_DRAWN`` (the random numbers ``rows`` are used up: call again with new
    ones, without ``append``) or ``_TRACKER_DONE``."""
    m = int(state[_TRACKER_ENTRIES])
    if append:
        if m == hist.shape[0]:
            return _TRACKER_FULL
        hist[m, 0] = t
        for c in range(p.shape[0]):
            hist[m, 1 + c] = p[c]
        m += 1
        state[_TRACKER_ENTRIES] = m
    t0, period, skew, noise = consts[0], consts[1], consts[2], consts[3]
    while True:
        t_k = t0 + state[_TRACKER_NEXT] * period
        if t_k > t + 1e-9 * period:
            break
        row = int(state[_TRACKER_ROW])
        if row == rows.shape[0]:
            return _TRACKER_DRAWN
        for c in range(p_meas.shape[0]):                  # drawn even when noise = 0
            p_meas[c] = _position(hist, m, t_k - skew, c + 1) + noise * rows[row, c]
        state[_TRACKER_ROW] = row + 1
        state[_TRACKER_T_MEAS] = t_k
        state[_TRACKER_NEXT] += 1.0
    # keep what the next sample can need: back to one entry at or before (next t_k - skew)
    oldest = t0 + state[_TRACKER_NEXT] * period - skew
    d = 0
    while m - d > 1 and hist[d + 1, 0] <= oldest:
        d += 1
    if d:
        for i in range(m - d):
            for c in range(hist.shape[1]):
                hist[i, c] = hist[i + d, c]
        state[_TRACKER_ENTRIES] = m - d
    return _TRACKER_DONE


# ---- the rigid-kinematics baseline ----------------------------------------------------------
def spring_inverse(k_hi: float, k_soft: float, delta: float, tau: float, D: float, guess: bool) -> float:
    """The deflection ``D`` [rad] of one gearbox spring (``k_hi``, ``k_soft = k_hi - k_lo``
    [N.m/rad], ``delta`` [rad]) carrying the torque ``tau`` [N.m]: Newton's method on
    ``tau_s(D) = tau`` (:func:`spring_deflection` for one joint, each joint stopping on its own),
    from ``D`` when ``guess``, else from the high-stiffness asymptote shifted by the soft zone."""
    if not guess:
        D = (tau + math.copysign(k_soft * delta * math.tanh(abs(tau) / (k_hi * delta)), tau)) / k_hi
    tol = 1e-12 * max(1.0, abs(tau))
    for _ in range(50):
        th = math.tanh(D / delta)
        f = k_hi * D - k_soft * delta * th - tau
        D -= f / (k_hi - k_soft * (1.0 - th * th))    # sech^2, no overflow
        if abs(f) <= tol:
            break
    return D


def gravity_torques(g1: float, g2: float, q1: float, q2: float) -> tuple[float, float]:
    """Gravity torques of eq. 11 [N.m] on floats (:func:`gravity_torque`): the constants ``g1``,
    ``g2`` of :class:`ArmConstants` [N.m], the arm angles ``q1``, ``q2`` [rad]."""
    cp = math.cos(q1 + q2)
    return -g1 * math.sin(q1) - g2 * cp, -g2 * cp


def compensated(m1: float, m2: float, K: np.ndarray) -> tuple[float, float]:
    """The fixed point of :func:`arm_angles` from ``q_m / r = (m1, m2)``, with the constants
    ``K`` of :attr:`fmus.common.dynamics.ArmConstants.static`."""
    q1, q2, D1, D2, guess = m1, m2, 0.0, 0.0, False
    for _ in range(8):
        G1, G2 = gravity_torques(K[0], K[1], q1, q2)
        D1 = spring_inverse(K[2], K[4], K[6], G1, D1, guess)
        D2 = spring_inverse(K[3], K[5], K[7], G2, D2, guess)
        guess = True                             # each inversion starts from the last one
        n1, n2 = m1 - D1, m2 - D2
        if abs(n1 - q1) <= 1e-11 and abs(n2 - q2) <= 1e-11:      # error left: about 1e-14 rad
            return n1, n2
        q1, q2 = n1, n2
    return q1, q2


def estimate(q_m, t_m, now, consts, samples, out, first):
    """The RigidKinematics FMU's estimate at ``now`` [s] from the motor angles ``q_m`` [rad]
    stamped ``t_m`` [s]: :func:`arm_angles` (``consts`` of :func:`constants`), extrapolated to
    ``now`` at the velocity of the last two distinct samples when the sample is older (the
    latency compensation of a robot controller; ``samples``: their count, then (time, q_a) of
    the one before and of the last, updated), then the tool position
    (:func:`fmus.common.kinematics.tool_point`). Writes ``q_a_hat``, ``p_tool_hat`` into
    ``out[first:first + 4]``; returns the tool angle ``q_a_hat[0] + q_a_hat[1]``."""
    q1, q2 = q_m[0] / consts[0], q_m[1] / consts[1]
    if consts[2] != 0.0:
        q1, q2 = compensated(q1, q2, consts[5:])
    if samples[0] > 0 and t_m <= samples[4] + TIME_TOL:       # the same sample (or set again)
        samples[4], samples[5], samples[6] = t_m, q1, q2
    else:
        samples[1], samples[2], samples[3] = samples[4], samples[5], samples[6]
        samples[4], samples[5], samples[6] = t_m, q1, q2
        samples[0] = min(samples[0] + 1.0, 2.0)
    if now > t_m + TIME_TOL and samples[0] == 2.0:
        t0, a0, b0, t1, a1, b1 = samples[1], samples[2], samples[3], samples[4], samples[5], samples[6]
        f = (now - t1) / (t1 - t0)
        q1, q2 = a1 + (a1 - a0) * f, b1 + (b1 - b0) * f
    x, z = tool_point(q1, q2, consts[3], consts[4])
    out[first], out[first + 1], out[first + 2], out[first + 3] = q1, q2, x, z
    return q1 + q2

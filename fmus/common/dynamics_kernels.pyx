# cython: language_level=3, cdivision=True
"""The flexible-joint model's compiled kernels (:mod:`fmus.common.dynamics`, eqs. 10-11): its
rates and its RK4 step, on the constants of :attr:`fmus.common.dynamics.ArmConstants.packed`
read as the struct :c:type:`Arm` (named fields, in the array's order).

Loaded with ``cython_kernels.load("common.dynamics_kernels")``; the operations of the Python
forms in the tests (tests/test_dynamics_kernels.py), in the same order, compiled without
contraction into fused multiply-adds (fmus/common/cython_kernels.py)."""
from cpython.buffer cimport PyBuffer_Release
from libc.math cimport sin, cos, tanh

from common.arrays cimport acquire
from common.gearbox cimport spring, spring_inverse as _spring_inverse
from common.planar_arm cimport gravity_torques as _gravity_torques


cdef struct Arm:
    # ArmConstants.packed, in its order (25 floats)
    double a, c, e              # inertia: M11 = a + 2 b, M12 = c + b, M22 = c, b = -e sin q2
    double g1, g2               # gravity [N.m]
    double l1, l2               # link lengths [m]
    double r[2]                 # gear ratios
    double k_hi[2]              # gearbox spring: high stiffness [N.m/rad]
    double k_soft[2]            # k_hi - k_lo [N.m/rad]
    double delta[2]             # its soft zone [rad]
    double d[2]                 # gearbox damping [N.m.s/rad]
    double f_v[2]               # motor viscous friction
    double f_c[2]               # motor Coulomb friction
    double w_c[2]               # its tanh speed
    double J_m[2]               # motor inertia [kg.m2]


cdef const Arm* _arm(object K, Py_buffer* view) except NULL:
    """The arm's constants ``K`` (a float array of 25) as its struct; ``view`` to release."""
    acquire(K, view, 1, False, False, sizeof(Arm) // sizeof(double), "K")
    if view.shape[0] * sizeof(double) != sizeof(Arm):
        PyBuffer_Release(view)
        raise ValueError(f"the arm's constants are {sizeof(Arm) // sizeof(double)} floats, not {view.shape[0]}")
    return <const Arm*> view.buf


cdef int _state(tuple s, double* x) except -1:
    """The 8 floats of the state ``s`` into ``x``."""
    cdef int i
    if len(s) != 8:
        raise ValueError(f"the state is 8 floats, not {len(s)}")
    for i in range(8):
        x[i] = s[i]
    return 0


cdef void _rates(const double* s, double tau1, double tau2, double fx, double fz, const Arm* K,
                 double* out) noexcept nogil:
    cdef double q1 = s[0], q2 = s[1], qm1 = s[2], qm2 = s[3], dq1 = s[4], dq2 = s[5], dqm1 = s[6], dqm2 = s[7]
    cdef double s1 = sin(q1), c1 = cos(q1)
    cdef double phi = q1 + q2
    cdef double sp = sin(phi), cp = cos(phi)
    cdef double s2 = sin(q2), c2 = cos(q2)
    cdef double b = -K.e * s2
    cdef double bd = -K.e * c2                          # db/dq2
    cdef double m11 = K.a + 2.0 * b, m12 = K.c + b, m22 = K.c
    cdef double r1 = K.r[0], r2 = K.r[1]
    cdef double D1 = qm1 / r1 - q1, D2 = qm2 / r2 - q2
    cdef double t1 = spring(K.k_hi[0], K.k_soft[0], K.delta[0], D1) + K.d[0] * (dqm1 / r1 - dq1)
    cdef double t2 = spring(K.k_hi[1], K.k_soft[1], K.delta[1], D2) + K.d[1] * (dqm2 / r2 - dq2)
    cdef double l1 = K.l1, l2 = K.l2, g1 = K.g1, g2 = K.g2
    # J_tool^T f_ext
    cdef double e1 = fx * (l1 * c1 - l2 * sp) - fz * (l1 * s1 + l2 * cp)
    cdef double e2 = -l2 * (fx * sp + fz * cp)
    cdef double rhs1 = t1 + e1 - bd * (2.0 * dq1 * dq2 + dq2 * dq2) + g1 * s1 + g2 * cp
    cdef double rhs2 = t2 + e2 + bd * dq1 * dq1 + g2 * cp
    cdef double det = m11 * m22 - m12 * m12
    out[0] = dq1
    out[1] = dq2
    out[2] = dqm1
    out[3] = dqm2
    out[4] = (m22 * rhs1 - m12 * rhs2) / det
    out[5] = (m11 * rhs2 - m12 * rhs1) / det
    out[6] = (tau1 - K.f_v[0] * dqm1 - K.f_c[0] * tanh(dqm1 / K.w_c[0]) - t1 / r1) / K.J_m[0]
    out[7] = (tau2 - K.f_v[1] * dqm2 - K.f_c[1] * tanh(dqm2 / K.w_c[1]) - t2 / r2) / K.J_m[1]


cdef inline tuple _tuple8(const double* x):
    return (x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7])


def spring_scalar(double k_hi, double k_soft, double delta, double D):
    """Gearbox spring torque ``tau_s(D) = k_hi D - (k_hi - k_lo) delta tanh(D / delta)`` [N.m] of
    one joint (``k_hi``, ``k_soft = k_hi - k_lo`` [N.m/rad], ``delta`` [rad]) at the deflection
    ``D`` [rad]: ``common/gearbox.pxd``'s, the one definition."""
    return spring(k_hi, k_soft, delta, D)


def spring_inverse(double k_hi, double k_soft, double delta, double tau, double D, bint guess):
    """The deflection ``D`` [rad] of one gearbox spring (``k_hi``, ``k_soft = k_hi - k_lo``
    [N.m/rad], ``delta`` [rad]) carrying the torque ``tau`` [N.m]: Newton's method on
    ``tau_s(D) = tau``, from ``D`` when ``guess``, else from the high-stiffness asymptote
    shifted by the soft zone (``common/gearbox.pxd``'s, the one definition)."""
    return _spring_inverse(k_hi, k_soft, delta, tau, D, guess)


def gravity_torques(double g1, double g2, double q1, double q2):
    """Gravity torques of eq. 11 [N.m] on floats: the constants ``g1``, ``g2`` of
    :class:`~fmus.common.dynamics.ArmConstants` [N.m], the arm angles ``q1``, ``q2`` [rad]
    (``common/planar_arm.pxd``'s, the one definition)."""
    cdef double G1, G2
    _gravity_torques(g1, g2, q1, q2, &G1, &G2)
    return G1, G2


def flex_rates(tuple s, double tau1, double tau2, double fx, double fz, K):
    """``x_dot`` of the flexible-joint model (eqs. 10-11) as a tuple of 8 floats at the state
    ``s`` (8-tuple: ``q_a``, ``q_m``, ``dq_a``, ``dq_m``), with the motor torques ``tau1``,
    ``tau2`` [N.m, motor side], the external tool force ``fx``, ``fz`` [N, world x, z] and the
    constants ``K`` (:attr:`fmus.common.dynamics.ArmConstants.packed`)."""
    cdef Py_buffer view
    cdef double x[8]
    cdef double out[8]
    _state(s, x)
    cdef const Arm* k = _arm(K, &view)
    _rates(x, tau1, tau2, fx, fz, k, out)
    PyBuffer_Release(&view)
    return _tuple8(out)


def flex_step(tuple s, double tau1, double tau2, double fx, double fz, double dt, long substeps, K):
    """``substeps`` RK4 steps over ``dt`` [s] of :func:`flex_rates` from the state ``s`` (8-tuple)
    with the inputs ``tau1``, ``tau2`` [N.m], ``fx``, ``fz`` [N] held and the constants ``K``:
    the new state (8-tuple)."""
    cdef Py_buffer view
    cdef double x[8]
    cdef double y[8]
    cdef double k1[8]
    cdef double k2[8]
    cdef double k3[8]
    cdef double k4[8]
    cdef int i
    cdef long n
    cdef double h = dt / substeps
    cdef double hh = 0.5 * h, h6 = h / 6.0
    _state(s, x)
    cdef const Arm* k = _arm(K, &view)
    with nogil:
        for n in range(substeps):
            _rates(x, tau1, tau2, fx, fz, k, k1)
            for i in range(8):
                y[i] = x[i] + hh * k1[i]
            _rates(y, tau1, tau2, fx, fz, k, k2)
            for i in range(8):
                y[i] = x[i] + hh * k2[i]
            _rates(y, tau1, tau2, fx, fz, k, k3)
            for i in range(8):
                y[i] = x[i] + h * k3[i]
            _rates(y, tau1, tau2, fx, fz, k, k4)
            for i in range(8):
                x[i] = x[i] + h6 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
    PyBuffer_Release(&view)
    return _tuple8(x)

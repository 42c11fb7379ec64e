# cython: language_level=3, cdivision=True
"""The rigid-kinematics baseline's compiled kernels (:mod:`fmus.estimators.rigid_kinematics_model`):
the gravity-compensated arm angles and the FMU's estimate.

Loaded with ``cython_kernels.load("estimators.rigid_kinematics_kernels")``; the operations of
their Python forms in the tests (tests/kernel_oracles.py) in the same order, compiled without
contraction into fused multiply-adds (fmus/common/cython_kernels.py)."""
from cpython.buffer cimport PyBuffer_Release
from libc.math cimport fabs

from common.arrays cimport acquire
from common.gearbox cimport spring_inverse
from common.planar_arm cimport gravity_torques, tool_point

#: s: two times closer than this are one instant (fmus.common.sample_time.TIME_TOL; a test holds
#: them equal)
TIME_TOL = 1e-9
cdef double _TIME_TOL = TIME_TOL


cdef struct Static:
    # ArmConstants.static, in its order (8 floats)
    double g1, g2               # gravity [N.m]
    double k_hi[2]              # gearbox spring: high stiffness [N.m/rad]
    double k_soft[2]            # k_hi - k_lo [N.m/rad]
    double delta[2]             # its soft zone [rad]


cdef struct Consts:
    # rigid_kinematics_model.constants, in its order (13 floats)
    double r[2]                 # gear ratios
    double compensate           # gravity compensation (0 or 1)
    double l1, l2               # link lengths [m]
    Static static


cdef enum:
    # estimate's ``samples``: their count, then (time, q_a) of the one before and of the last
    COUNT = 0
    T0 = 1
    A0 = 2
    B0 = 3
    T1 = 4
    A1 = 5
    B1 = 6
    SAMPLES = 7


cdef void _compensated(double m1, double m2, const Static* K, double* q1, double* q2) noexcept nogil:
    # the fixed point of arm_angles from q_m / r = (m1, m2)
    cdef double D1 = 0.0, D2 = 0.0, G1, G2, n1, n2
    cdef bint guess = False
    cdef int i
    q1[0], q2[0] = m1, m2
    for i in range(8):
        gravity_torques(K.g1, K.g2, q1[0], q2[0], &G1, &G2)
        D1 = spring_inverse(K.k_hi[0], K.k_soft[0], K.delta[0], G1, D1, guess)
        D2 = spring_inverse(K.k_hi[1], K.k_soft[1], K.delta[1], G2, D2, guess)
        guess = True                             # each inversion starts from the last one
        n1, n2 = m1 - D1, m2 - D2
        if fabs(n1 - q1[0]) <= 1e-11 and fabs(n2 - q2[0]) <= 1e-11:      # error left: about 1e-14 rad
            q1[0], q2[0] = n1, n2
            return
        q1[0], q2[0] = n1, n2


def compensated(double m1, double m2, K):
    """The fixed point of :func:`~fmus.estimators.rigid_kinematics_model.arm_angles` from
    ``q_m / r = (m1, m2)`` [rad], with the constants ``K`` of
    :attr:`fmus.common.dynamics.ArmConstants.static` (8 floats): the arm angles (2-tuple)."""
    cdef Py_buffer view
    cdef double q1, q2
    acquire(K, &view, 1, False, False, sizeof(Static) // sizeof(double), "K")
    _compensated(m1, m2, <const Static*> view.buf, &q1, &q2)
    PyBuffer_Release(&view)
    return q1, q2


def estimate(q_m, double t_m, double now, consts, samples, out, Py_ssize_t first):
    """The RigidKinematics FMU's estimate at ``now`` [s] from the motor angles ``q_m`` [rad]
    stamped ``t_m`` [s]: the arm angles (``consts`` of
    :func:`~fmus.estimators.rigid_kinematics_model.constants`, 13 floats), extrapolated to
    ``now`` at the velocity of the last two distinct samples when the sample is older (the
    latency compensation of a robot controller; ``samples``, 7 floats: their count, then
    (time, q_a) of the one before and of the last, updated), then the tool position. Writes
    ``q_a_hat``, ``p_tool_hat`` into ``out[first:first + 4]``; returns the tool angle
    ``q_a_hat[0] + q_a_hat[1]``."""
    cdef Py_buffer vq, vc, vs, vo
    cdef int got = 0
    cdef const double* q
    cdef const Consts* c
    cdef double* s
    cdef double* o
    cdef double q1, q2, t0, a0, b0, t1, a1, b1, f, x, z
    try:
        acquire(q_m, &vq, 1, False, False, 2, "q_m"); got = 1
        acquire(consts, &vc, 1, False, False, sizeof(Consts) // sizeof(double), "consts"); got = 2
        acquire(samples, &vs, 1, True, False, SAMPLES, "samples"); got = 3
        acquire(out, &vo, 1, True, False, 0, "out"); got = 4
        if not 0 <= first <= vo.shape[0] - 4:
            raise IndexError(f"estimate: outputs {first} to {first + 3} beyond the {vo.shape[0]} outputs")
        q, c, s, o = <const double*> vq.buf, <const Consts*> vc.buf, <double*> vs.buf, <double*> vo.buf
        q1, q2 = q[0] / c.r[0], q[1] / c.r[1]
        if c.compensate != 0.0:
            _compensated(q1, q2, &c.static, &q1, &q2)
        if s[COUNT] > 0 and t_m <= s[T1] + _TIME_TOL:       # the same sample (or set again)
            s[T1], s[A1], s[B1] = t_m, q1, q2
        else:
            s[T0], s[A0], s[B0] = s[T1], s[A1], s[B1]
            s[T1], s[A1], s[B1] = t_m, q1, q2
            s[COUNT] = 2.0 if 2.0 < s[COUNT] + 1.0 else s[COUNT] + 1.0     # min(count + 1, 2)
        if now > t_m + _TIME_TOL and s[COUNT] == 2.0:
            t0, a0, b0, t1, a1, b1 = s[T0], s[A0], s[B0], s[T1], s[A1], s[B1]
            f = (now - t1) / (t1 - t0)
            q1, q2 = a1 + (a1 - a0) * f, b1 + (b1 - b0) * f
        tool_point(q1, q2, c.l1, c.l2, &x, &z)
        o[first], o[first + 1], o[first + 2], o[first + 3] = q1, q2, x, z
    finally:
        if got >= 4:
            PyBuffer_Release(&vo)
        if got >= 3:
            PyBuffer_Release(&vs)
        if got >= 2:
            PyBuffer_Release(&vc)
        if got >= 1:
            PyBuffer_Release(&vq)
    return q1 + q2

# cython: language_level=3, cdivision=True
"""The realistic plant's four-body chain, compiled (:class:`fmus.robot_plant.plant_dynamics.PlantChain`
with bending links: its equations written out, an LDL^T solve of the 4x4 system), on the chain's
constants (:meth:`PlantChain._pack`) read as the struct :c:type:`Chain4` (named fields, in the
array's order).

Loaded with ``cython_kernels.load("robot_plant.plant_kernels")``; held to
:class:`PlantChain`'s loops over the bodies in the tests (tests/test_plant_kernel.py); compiled
without contraction into fused multiply-adds (fmus/common/cython_kernels.py)."""
from cpython.buffer cimport PyBuffer_Release
from libc.math cimport sin, cos, tanh

from common.arrays cimport acquire
from common.gearbox cimport spring

cdef double HALF_PI = 0.5 * 3.141592653589793       # 0.5 * math.pi


cdef struct Chain4:
    # PlantChain._pack, in its order (51 floats)
    double offset[2]            # the zero offsets o_1 and o_3 (with pi/2)
    double r[2]                 # gear ratios
    double k_hi[2]              # gearbox spring: high stiffness [N.m/rad]
    double k_soft[2]            # k_hi - k_lo [N.m/rad]
    double delta[2]             # its soft zone [rad]
    double d[2]                 # gearbox damping [N.m.s/rad]
    double f_v[2]               # motor viscous friction
    double f_c[2]               # motor Coulomb friction
    double w_c[2]               # its tanh speed
    double J_m[2]               # motor inertia [kg.m2]
    double k_b1, d_b1           # bending joint of link 1: stiffness, damping
    double k_b2, d_b2           # of link 2
    double h12, h13, h14, h23, h24, h34    # L_min(j,k) g_max(j,k)
    double grav[4]              # g g_k
    double L[4]                 # body lengths [m]
    double m_diag[4]            # M_kk
    double kt[2]                # 1 + torque-constant error
    double ripple[2]            # torque ripple amplitude [N.m]
    double periods[2]           # ripple periods per motor revolution
    double sensor[2]            # the accelerometer's offset (x, z) [m]
    double offset_sum           # the sum of the offsets o_k


cdef struct Arm4:
    # the bodies' absolute angles' sines, cosines, rates, accelerations; the joint torques
    double S[4]
    double C[4]
    double W[4]
    double A[4]
    double T[4]


cdef const Chain4* _chain(object P, Py_buffer* view) except NULL:
    """The chain's constants ``P`` (a float array of 51) as its struct; ``view`` to release."""
    acquire(P, view, 1, False, False, sizeof(Chain4) // sizeof(double), "P")
    if view.shape[0] * sizeof(double) != sizeof(Chain4):
        PyBuffer_Release(view)
        raise ValueError(f"the chain's constants are {sizeof(Chain4) // sizeof(double)} floats, not {view.shape[0]}")
    return <const Chain4*> view.buf


cdef int _state(object s, double* x) except -1:
    """The 12 floats of the state ``s`` (a tuple, or any sequence) into ``x``."""
    cdef int i
    if len(s) != 12:
        raise ValueError(f"the chain's state is 12 floats, not {len(s)}")
    if type(s) is tuple:
        for i in range(12):
            x[i] = (<tuple> s)[i]
    else:
        for i in range(12):
            x[i] = s[i]
    return 0


cdef inline double _applied(const Chain4* P, int i, double tau, double qm) noexcept nogil:
    # the torque motor i applies for the command tau at the motor angle qm
    return P.kt[i] * tau + P.ripple[i] * sin(P.periods[i] * qm)


cdef void _arm(const double* s, double fx, double fz, const Chain4* P, Arm4* out) noexcept nogil:
    cdef double q1 = s[0], b1 = s[1], q2 = s[2], b2 = s[3], qm1 = s[4], qm2 = s[5]
    cdef double dq1 = s[6], db1 = s[7], dq2 = s[8], db2 = s[9], dqm1 = s[10], dqm2 = s[11]
    cdef double p1 = q1 + P.offset[0]
    cdef double p2 = p1 + b1
    cdef double p3 = p2 + q2 + P.offset[1]
    cdef double p4 = p3 + b2
    cdef double s1 = sin(p1), c1 = cos(p1), s2 = sin(p2), c2 = cos(p2)
    cdef double s3 = sin(p3), c3 = cos(p3), s4 = sin(p4), c4 = cos(p4)
    cdef double w1 = dq1
    cdef double w2 = w1 + db1
    cdef double w3 = w2 + dq2
    cdef double w4 = w3 + db2
    cdef double r1 = P.r[0], r2 = P.r[1]
    cdef double t1 = spring(P.k_hi[0], P.k_soft[0], P.delta[0], qm1 / r1 - q1) + P.d[0] * (dqm1 / r1 - dq1)
    cdef double t3 = spring(P.k_hi[1], P.k_soft[1], P.delta[1], qm2 / r2 - q2) + P.d[1] * (dqm2 / r2 - dq2)
    cdef double t2 = -(P.k_b1 * b1 + P.d_b1 * db1)
    cdef double t4 = -(P.k_b2 * b2 + P.d_b2 * db2)
    cdef double h12 = P.h12, h13 = P.h13, h14 = P.h14, h23 = P.h23, h24 = P.h24, h34 = P.h34
    # M_jk = h_jk cos(psi_j - psi_k); velocity terms h_jk sin(psi_j - psi_k) w_k^2
    cdef double c12 = c1 * c2 + s1 * s2, s12 = s1 * c2 - c1 * s2
    cdef double c13 = c1 * c3 + s1 * s3, s13 = s1 * c3 - c1 * s3
    cdef double c14 = c1 * c4 + s1 * s4, s14 = s1 * c4 - c1 * s4
    cdef double c23 = c2 * c3 + s2 * s3, s23 = s2 * c3 - c2 * s3
    cdef double c24 = c2 * c4 + s2 * s4, s24 = s2 * c4 - c2 * s4
    cdef double c34 = c3 * c4 + s3 * s4, s34 = s3 * c4 - c3 * s4
    cdef double ww1 = w1 * w1, ww2 = w2 * w2, ww3 = w3 * w3, ww4 = w4 * w4
    cdef double g1 = P.grav[0], g2 = P.grav[1], g3 = P.grav[2], g4 = P.grav[3]
    cdef double L1 = P.L[0], L2 = P.L[1], L3 = P.L[2], L4 = P.L[3]
    cdef double y1 = g1 * s1 + L1 * (fx * c1 - fz * s1) + t1 - t2 - (h12 * s12 * ww2 + h13 * s13 * ww3 + h14 * s14 * ww4)
    cdef double y2 = g2 * s2 + L2 * (fx * c2 - fz * s2) + t2 - t3 - (-h12 * s12 * ww1 + h23 * s23 * ww3 + h24 * s24 * ww4)
    cdef double y3 = g3 * s3 + L3 * (fx * c3 - fz * s3) + t3 - t4 - (-h13 * s13 * ww1 - h23 * s23 * ww2 + h34 * s34 * ww4)
    cdef double y4 = g4 * s4 + L4 * (fx * c4 - fz * s4) + t4 + (h14 * s14 * ww1 + h24 * s24 * ww2 + h34 * s34 * ww3)
    cdef double m11 = P.m_diag[0], m22 = P.m_diag[1], m33 = P.m_diag[2], m44 = P.m_diag[3]
    cdef double m12 = h12 * c12, m13 = h13 * c13, m14 = h14 * c14, m23 = h23 * c23, m24 = h24 * c24, m34 = h34 * c34
    # M = L D L^T
    cdef double l21 = m12 / m11, l31 = m13 / m11, l41 = m14 / m11
    cdef double d2 = m22 - l21 * m12
    cdef double l32 = (m23 - l31 * m12) / d2, l42 = (m24 - l41 * m12) / d2
    cdef double d3 = m33 - l31 * m13 - l32 * l32 * d2
    cdef double l43 = (m34 - l41 * m13 - l42 * l32 * d2) / d3
    cdef double d4 = m44 - l41 * m14 - l42 * l42 * d2 - l43 * l43 * d3
    y2 -= l21 * y1
    y3 -= l31 * y1 + l32 * y2
    y4 -= l41 * y1 + l42 * y2 + l43 * y3
    cdef double a4 = y4 / d4
    cdef double a3 = y3 / d3 - l43 * a4
    cdef double a2 = y2 / d2 - l32 * a3 - l42 * a4
    cdef double a1 = y1 / m11 - l21 * a2 - l31 * a3 - l41 * a4
    out.S[0] = s1; out.S[1] = s2; out.S[2] = s3; out.S[3] = s4
    out.C[0] = c1; out.C[1] = c2; out.C[2] = c3; out.C[3] = c4
    out.W[0] = w1; out.W[1] = w2; out.W[2] = w3; out.W[3] = w4
    out.A[0] = a1; out.A[1] = a2; out.A[2] = a3; out.A[3] = a4
    out.T[0] = t1; out.T[1] = t2; out.T[2] = t3; out.T[3] = t4


cdef void _rates(const double* s, double tau1, double tau2, double fx, double fz, const Chain4* P,
                 double* out) noexcept nogil:
    cdef Arm4 a
    _arm(s, fx, fz, P, &a)
    cdef double qm1 = s[4], qm2 = s[5], dqm1 = s[10], dqm2 = s[11]
    cdef int i
    for i in range(6):
        out[i] = s[6 + i]
    out[6] = a.A[0]
    out[7] = a.A[1] - a.A[0]
    out[8] = a.A[2] - a.A[1]
    out[9] = a.A[3] - a.A[2]
    out[10] = (_applied(P, 0, tau1, qm1) - P.f_v[0] * dqm1 - P.f_c[0] * tanh(dqm1 / P.w_c[0]) - a.T[0] / P.r[0]) / P.J_m[0]
    out[11] = (_applied(P, 1, tau2, qm2) - P.f_v[1] * dqm2 - P.f_c[1] * tanh(dqm2 / P.w_c[1]) - a.T[2] / P.r[1]) / P.J_m[1]


cdef void _step(double* x, double tau1, double tau2, double fx, double fz, double dt, long substeps,
                const Chain4* P) noexcept nogil:
    # substeps RK4 steps over dt of the state x, in place
    cdef double y[12]
    cdef double k1[12]
    cdef double k2[12]
    cdef double k3[12]
    cdef double k4[12]
    cdef int i
    cdef long n
    cdef double h = dt / substeps
    cdef double hh = 0.5 * h, h6 = h / 6.0
    for n in range(substeps):
        _rates(x, tau1, tau2, fx, fz, P, k1)
        for i in range(12):
            y[i] = x[i] + hh * k1[i]
        _rates(y, tau1, tau2, fx, fz, P, k2)
        for i in range(12):
            y[i] = x[i] + hh * k2[i]
        _rates(y, tau1, tau2, fx, fz, P, k3)
        for i in range(12):
            y[i] = x[i] + h * k3[i]
        _rates(y, tau1, tau2, fx, fz, P, k4)
        for i in range(12):
            x[i] = x[i] + h6 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])


cdef void _outputs(const double* s, double fx, double fz, const Chain4* P, double* y) noexcept nogil:
    # the 24 outputs of chain4_outputs at the state s
    cdef Arm4 a
    _arm(s, fx, fz, P, &a)
    cdef double px = 0.0, pz = 0.0, vx = 0.0, vz = 0.0, ax = 0.0, az = 0.0, L
    cdef int k
    for k in range(4):
        L = P.L[k]
        px += L * a.S[k]
        pz += L * a.C[k]
        vx += L * a.W[k] * a.C[k]
        vz -= L * a.W[k] * a.S[k]
        ax += L * (a.A[k] * a.C[k] - a.W[k] * a.W[k] * a.S[k])
        az -= L * (a.A[k] * a.S[k] + a.W[k] * a.W[k] * a.C[k])
    # sensor: p_tool + R(phi) o with phi = psi_last - pi/2 (cos phi = sin psi, sin phi = -cos psi)
    cdef double cphi = a.S[3], sphi = -a.C[3], w = a.W[3], acc = a.A[3]
    cdef double ox = P.sensor[0], oz = P.sensor[1]
    cdef double rx = cphi * ox + sphi * oz, rz = -sphi * ox + cphi * oz
    cdef double ex = -sphi * ox + cphi * oz, ez = -cphi * ox - sphi * oz        # d(R o)/d phi
    cdef double qm1 = s[4], qm2 = s[5]
    y[0] = s[0]; y[1] = s[2]; y[2] = s[6]; y[3] = s[8]
    y[4] = a.A[0] - 0.0; y[5] = a.A[2] - a.A[1]
    y[6] = qm1; y[7] = qm2; y[8] = s[10]; y[9] = s[11]
    y[10] = px; y[11] = pz; y[12] = vx; y[13] = vz; y[14] = ax; y[15] = az
    y[16] = 0.0 + s[0] + s[1] + s[2] + s[3] + P.offset_sum - HALF_PI      # sum(s[:4]) as Python adds
    y[17] = w
    y[18] = px + rx; y[19] = pz + rz
    y[20] = ax + acc * ex - w * w * rx
    y[21] = az + acc * ez - w * w * rz
    y[22] = spring(P.k_hi[0], P.k_soft[0], P.delta[0], qm1 / P.r[0] - s[0])
    y[23] = spring(P.k_hi[1], P.k_soft[1], P.delta[1], qm2 / P.r[1] - s[2])


cdef inline tuple _tuple4(const double* v):
    return (v[0], v[1], v[2], v[3])


cdef inline tuple _tuple12(const double* x):
    return (x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7], x[8], x[9], x[10], x[11])


def chain4_arm(s, double fx, double fz, P):
    """:meth:`PlantChain.arm` of the four-body chain: the absolute angles' sines, cosines, rates
    and accelerations, and the joint torques (five 4-tuples), at the state ``s`` (12 floats) with
    the tool force ``fx``, ``fz`` [N]; ``P`` the chain's constants (:meth:`PlantChain._pack`)."""
    cdef Py_buffer view
    cdef double x[12]
    cdef Arm4 a
    _state(s, x)
    cdef const Chain4* p = _chain(P, &view)
    _arm(x, fx, fz, p, &a)
    PyBuffer_Release(&view)
    return _tuple4(a.S), _tuple4(a.C), _tuple4(a.W), _tuple4(a.A), _tuple4(a.T)


def chain4_rates(s, double tau1, double tau2, double fx, double fz, P):
    """:meth:`PlantChain.derivatives` of the four-body chain: ``x_dot`` (12-tuple) at the state
    ``s`` (12 floats), the motor torques ``tau1``, ``tau2`` [N m] and the tool force ``fx``,
    ``fz`` [N]; ``P`` the chain's constants."""
    cdef Py_buffer view
    cdef double x[12]
    cdef double out[12]
    _state(s, x)
    cdef const Chain4* p = _chain(P, &view)
    _rates(x, tau1, tau2, fx, fz, p, out)
    PyBuffer_Release(&view)
    return _tuple12(out)


def chain4_step(s, double tau1, double tau2, double fx, double fz, double dt, long substeps, P):
    """``substeps`` RK4 steps over ``dt`` [s] of the four-body chain from the state ``s``
    (12 floats), the motor torques ``tau1``, ``tau2`` [N m] and the tool force ``fx``, ``fz`` [N]
    held; ``P`` the chain's constants (:meth:`PlantChain._pack`). Returns the new state
    (12-tuple): the operations of :meth:`fmus.common.dynamics.FlexibleRobotModel.step`, in the
    same order."""
    cdef Py_buffer view
    cdef double x[12]
    _state(s, x)
    cdef const Chain4* p = _chain(P, &view)
    with nogil:
        _step(x, tau1, tau2, fx, fz, dt, substeps, p)
    PyBuffer_Release(&view)
    return _tuple12(x)


def chain4_outputs(s, double fx, double fz, P):
    """:meth:`PlantChain.outputs` of the four-body chain (24 floats, the same operations) at the
    state ``s`` (12 floats) with the tool force ``fx``, ``fz`` [N]; ``P`` the chain's constants."""
    cdef Py_buffer view
    cdef double x[12]
    cdef double y[24]
    _state(s, x)
    cdef const Chain4* p = _chain(P, &view)
    _outputs(x, fx, fz, p, y)
    PyBuffer_Release(&view)
    return (y[0], y[1], y[2], y[3], y[4], y[5], y[6], y[7], y[8], y[9], y[10], y[11], y[12], y[13],
            y[14], y[15], y[16], y[17], y[18], y[19], y[20], y[21], y[22], y[23])


def chain4_advance(s, tau, f, double dt, long substeps, P, out, at):
    """A plant step in one call: :func:`chain4_step` over ``dt`` [s] (``substeps`` RK4 steps)
    from the state ``s`` (12 floats) with the motor torques ``tau`` [N m] and the tool force
    ``f`` [N] (float64 arrays of 2) held and the chain's constants ``P``, then the outputs at the
    new state (the 24 of :func:`chain4_outputs`, then the 2 applied torques of ``tau``): value
    ``i`` of these 26 into ``out[at[i]]`` (``out`` a float64 array) unless ``at[i]`` is negative
    (``at``: 26 int64). Returns the new state (12-tuple), the tool angle and its rate (outputs 16
    and 17)."""
    cdef Py_buffer vt, vf, vp, vo, va
    cdef double x[12]
    cdef double y[26]
    cdef int i
    cdef int got = 0
    cdef const long long* idx
    cdef double* o
    cdef const double* t
    cdef const double* ff
    cdef const Chain4* p
    _state(s, x)
    try:
        acquire(tau, &vt, 1, False, False, 2, "tau"); got = 1
        acquire(f, &vf, 1, False, False, 2, "f"); got = 2
        p = _chain(P, &vp); got = 3
        acquire(out, &vo, 1, True, False, 0, "out"); got = 4
        acquire(at, &va, 1, False, True, 26, "at"); got = 5
        idx = <const long long*> va.buf
        for i in range(26):
            if idx[i] >= vo.shape[0]:
                raise IndexError(f"chain4_advance: output index {idx[i]} beyond the {vo.shape[0]} outputs")
        t, ff, o = <const double*> vt.buf, <const double*> vf.buf, <double*> vo.buf
        with nogil:
            _step(x, t[0], t[1], ff[0], ff[1], dt, substeps, p)
            _outputs(x, ff[0], ff[1], p, y)
            y[24] = _applied(p, 0, t[0], x[4])
            y[25] = _applied(p, 1, t[1], x[5])
            for i in range(26):
                if idx[i] >= 0:
                    o[idx[i]] = y[i]
    finally:
        if got >= 5:
            PyBuffer_Release(&va)
        if got >= 4:
            PyBuffer_Release(&vo)
        if got >= 3:
            PyBuffer_Release(&vp)
        if got >= 2:
            PyBuffer_Release(&vf)
        if got >= 1:
            PyBuffer_Release(&vt)
    return _tuple12(x), y[16], y[17]

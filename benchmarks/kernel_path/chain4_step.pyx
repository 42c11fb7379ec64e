# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""A measurement prototype, not a product path (benchmarks/kernel_path.py, ARCHITECTURE.md "The
kernel path"): fmus/robot_plant/plant_dynamics.chain4_step in Cython, the same operations in the
same order; the benchmark checks it against the kernel bit for bit each time it runs."""
from libc.math cimport sin, cos, tanh

cdef inline double _spring4(const double[:] P, int i, double D) noexcept nogil:
    return P[4 + i] * D - P[6 + i] * P[8 + i] * tanh(D / P[8 + i])

cdef inline double _applied4(const double[:] P, int i, double tau, double qm) noexcept nogil:
    return P[42 + i] * tau + P[44 + i] * sin(P[46 + i] * qm)

cdef void _rates(const double* s, double tau1, double tau2, double fx, double fz,
                 const double[:] P, double* out) noexcept nogil:
    cdef double q1 = s[0], b1 = s[1], q2 = s[2], b2 = s[3], qm1 = s[4], qm2 = s[5]
    cdef double dq1 = s[6], db1 = s[7], dq2 = s[8], db2 = s[9], dqm1 = s[10], dqm2 = s[11]
    cdef double p1 = q1 + P[0]
    cdef double p2 = p1 + b1
    cdef double p3 = p2 + q2 + P[1]
    cdef double p4 = p3 + b2
    cdef double s1 = sin(p1), c1 = cos(p1), s2 = sin(p2), c2 = cos(p2)
    cdef double s3 = sin(p3), c3 = cos(p3), s4 = sin(p4), c4 = cos(p4)
    cdef double w1 = dq1
    cdef double w2 = w1 + db1
    cdef double w3 = w2 + dq2
    cdef double w4 = w3 + db2
    cdef double r1 = P[2], r2 = P[3]
    cdef double t1 = _spring4(P, 0, qm1 / r1 - q1) + P[10] * (dqm1 / r1 - dq1)
    cdef double t3 = _spring4(P, 1, qm2 / r2 - q2) + P[11] * (dqm2 / r2 - dq2)
    cdef double t2 = -(P[20] * b1 + P[21] * db1)
    cdef double t4 = -(P[22] * b2 + P[23] * db2)
    cdef double h12 = P[24], h13 = P[25], h14 = P[26], h23 = P[27], h24 = P[28], h34 = P[29]
    cdef double c12 = c1 * c2 + s1 * s2, s12 = s1 * c2 - c1 * s2
    cdef double c13 = c1 * c3 + s1 * s3, s13 = s1 * c3 - c1 * s3
    cdef double c14 = c1 * c4 + s1 * s4, s14 = s1 * c4 - c1 * s4
    cdef double c23 = c2 * c3 + s2 * s3, s23 = s2 * c3 - c2 * s3
    cdef double c24 = c2 * c4 + s2 * s4, s24 = s2 * c4 - c2 * s4
    cdef double c34 = c3 * c4 + s3 * s4, s34 = s3 * c4 - c3 * s4
    cdef double ww1 = w1 * w1, ww2 = w2 * w2, ww3 = w3 * w3, ww4 = w4 * w4
    cdef double g1 = P[30], g2 = P[31], g3 = P[32], g4 = P[33], L1 = P[34], L2 = P[35], L3 = P[36], L4 = P[37]
    cdef double y1 = g1 * s1 + L1 * (fx * c1 - fz * s1) + t1 - t2 - (h12 * s12 * ww2 + h13 * s13 * ww3 + h14 * s14 * ww4)
    cdef double y2 = g2 * s2 + L2 * (fx * c2 - fz * s2) + t2 - t3 - (-h12 * s12 * ww1 + h23 * s23 * ww3 + h24 * s24 * ww4)
    cdef double y3 = g3 * s3 + L3 * (fx * c3 - fz * s3) + t3 - t4 - (-h13 * s13 * ww1 - h23 * s23 * ww2 + h34 * s34 * ww4)
    cdef double y4 = g4 * s4 + L4 * (fx * c4 - fz * s4) + t4 + (h14 * s14 * ww1 + h24 * s24 * ww2 + h34 * s34 * ww3)
    cdef double m11 = P[38], m22 = P[39], m33 = P[40], m44 = P[41]
    cdef double m12 = h12 * c12, m13 = h13 * c13, m14 = h14 * c14, m23 = h23 * c23, m24 = h24 * c24, m34 = h34 * c34
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
    out[0] = s[6]; out[1] = s[7]; out[2] = s[8]; out[3] = s[9]; out[4] = s[10]; out[5] = s[11]
    out[6] = a1; out[7] = a2 - a1; out[8] = a3 - a2; out[9] = a4 - a3
    out[10] = (_applied4(P, 0, tau1, qm1) - P[12] * dqm1 - P[14] * tanh(dqm1 / P[16]) - t1 / P[2]) / P[18]
    out[11] = (_applied4(P, 1, tau2, qm2) - P[13] * dqm2 - P[15] * tanh(dqm2 / P[17]) - t3 / P[3]) / P[19]


def chain4_step(tuple s, double tau1, double tau2, double fx, double fz, double dt, long substeps,
                const double[:] P):
    """``substeps`` RK4 steps over ``dt`` [s] of the four-body chain from the 12-tuple ``s``
    (motor torques ``tau1``, ``tau2``, tool force ``fx``, ``fz`` held; ``P`` the chain's
    constants): the new state as a 12-tuple."""
    cdef double x[12]
    cdef double y[12]
    cdef double k1[12]
    cdef double k2[12]
    cdef double k3[12]
    cdef double k4[12]
    cdef int i, n
    cdef double h = dt / substeps
    cdef double hh = 0.5 * h, h6 = h / 6.0
    for i in range(12):
        x[i] = s[i]
    with nogil:
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
    return (x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7], x[8], x[9], x[10], x[11])

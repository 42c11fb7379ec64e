# cython: language_level=3
"""The gearbox spring on C doubles, compiled into each kernel module that cimports it
(``from common.gearbox cimport spring``: fmus/common/cython_kernels.py's rules)."""
from libc.math cimport copysign, fabs, tanh


cdef inline double spring(double k_hi, double k_soft, double delta, double D) noexcept nogil:
    """Gearbox spring torque ``tau_s(D) = k_hi D - (k_hi - k_lo) delta tanh(D / delta)`` [N.m]
    (``k_soft = k_hi - k_lo``) at the deflection ``D`` [rad]: the one definition
    (:func:`fmus.common.dynamics.spring_scalar` is it, for Python)."""
    return k_hi * D - k_soft * delta * tanh(D / delta)


cdef inline double spring_inverse(double k_hi, double k_soft, double delta, double tau, double D,
                                  bint guess) noexcept nogil:
    """The deflection ``D`` [rad] of one gearbox spring carrying the torque ``tau`` [N.m]:
    Newton's method on ``tau_s(D) = tau`` from ``D`` when ``guess``, else from the
    high-stiffness asymptote shifted by the soft zone (the one definition:
    :func:`fmus.common.dynamics.spring_inverse` is it, for Python)."""
    cdef double tol, th, f, a = fabs(tau)
    cdef int i
    if not guess:
        D = (tau + copysign(k_soft * delta * tanh(a / (k_hi * delta)), tau)) / k_hi
    tol = 1e-12 * (a if a > 1.0 else 1.0)                  # max(1.0, |tau|)
    for i in range(50):
        th = tanh(D / delta)
        f = k_hi * D - k_soft * delta * th - tau
        D -= f / (k_hi - k_soft * (1.0 - th * th))        # sech^2, no overflow
        if fabs(f) <= tol:
            break
    return D

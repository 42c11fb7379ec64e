# cython: language_level=3
"""The gearbox spring on C doubles, compiled into each kernel module that cimports it
(``from common.gearbox cimport spring``: fmus/common/cython_kernels.py's rules)."""
from libc.math cimport tanh


cdef inline double spring(double k_hi, double k_soft, double delta, double D) noexcept nogil:
    """Gearbox spring torque ``tau_s(D) = k_hi D - (k_hi - k_lo) delta tanh(D / delta)`` [N.m]
    (``k_soft = k_hi - k_lo``) at the deflection ``D`` [rad]: the one definition
    (:func:`fmus.common.dynamics.spring_scalar` is it, for Python)."""
    return k_hi * D - k_soft * delta * tanh(D / delta)

# cython: language_level=3
"""The planar two-link arm's rigid terms on C doubles, compiled into each kernel module that
cimports them (``from common.planar_arm cimport ...``: fmus/common/cython_kernels.py's rules)."""
from libc.math cimport cos, sin


cdef inline void gravity_torques(double g1, double g2, double q1, double q2, double* G1, double* G2) noexcept nogil:
    """Gravity torques of eq. 11 [N.m] into ``G1``, ``G2``: the constants ``g1``, ``g2`` of
    :class:`fmus.common.dynamics.ArmConstants` [N.m], the arm angles ``q1``, ``q2`` [rad] (the
    one definition: :func:`fmus.common.dynamics.gravity_torques` is it, for Python)."""
    cdef double cp = cos(q1 + q2)
    G1[0] = -g1 * sin(q1) - g2 * cp
    G2[0] = -g2 * cp


cdef inline void tool_point(double q1, double q2, double l1, double l2, double* x, double* z) noexcept nogil:
    """World x, z [m] of the tool at the arm angles ``q1``, ``q2`` [rad] of links ``l1``, ``l2``
    [m] (:func:`fmus.common.kinematics.tool_position` on floats)."""
    cdef double phi = q1 + q2
    x[0] = l1 * sin(q1) + l2 * cos(phi)
    z[0] = l1 * cos(q1) - l2 * sin(phi)

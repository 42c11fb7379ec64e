"""FMU adapter of EKF Complete (Henriksson et al. 2009, section III-A): tool position of the flexible
two-axis robot from motor angles and a tool accelerometer through the dynamics (eqs. 6-7).

The adapter is :class:`fmus.estimators.ekf_flexible_fmu_base.EkfFlexibleSlave` (timing and
divergence handling are documented there); the math is in :mod:`fmus.estimators.ekf_flexible_model`.
"""
from __future__ import annotations

from fmus.estimators import ekf_flexible_model as em
from fmus.estimators import ekf_flexible_fmu_base as base


class EkfComplete(base.EkfFlexibleSlave):
    """EKF Complete of the 2009 paper on the 8-state flexible-joint model (eq. 2, Euler-discretised)."""

    variant = "complete"
    parameters_class = em.EkfCompleteParameters
    description = ("EKF Complete (Henriksson et al. 2009): tool position from motor angles and a tool "
                   "accelerometer through the dynamics (eqs. 6-7)")

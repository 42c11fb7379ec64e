"""FMU adapter of EKF Motor (Henriksson et al. 2009, section III-A): tool position of the flexible
two-axis robot from motor angles only.

The adapter is :class:`fmus.estimators.ekf_flexible_fmu_base.EkfFlexibleSlave` (timing and
divergence handling are documented there); the math is in :mod:`fmus.estimators.ekf_flexible_model`.
"""
from __future__ import annotations

from fmus.estimators import ekf_flexible_model as em
from fmus.estimators import ekf_flexible_fmu_base as base


class EkfMotor(base.EkfFlexibleSlave):
    """EKF Motor of the 2009 paper on the 8-state flexible-joint model (eq. 2, Euler-discretised)."""

    variant = "motor"
    parameters_class = em.EkfMotorParameters
    description = "EKF Motor (Henriksson et al. 2009): tool position from motor angles only"

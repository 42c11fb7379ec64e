"""FMU adapter of the rigid-kinematics baseline (tool position from the motor angles)."""
from __future__ import annotations

import numpy as np

from fmus.common.fmi import FlexFusionSlave
from fmus.common.sample_time import T_MEAS_DESCRIPTION, UNSTAMPED, measurement_time
from fmus.estimators.rigid_kinematics_model import RigidKinematicsParameters, constants, estimate


class RigidKinematics(FlexFusionSlave):
    """Baseline estimator: tool position by rigid forward kinematics of the measured motor angles.

    Timing: the outputs at ``t`` are the arm angles at ``t``. A sample stamped ``t_meas`` before
    ``t`` (a Jacobi master hands it over late) is extrapolated to ``t`` at the velocity of the
    last two samples, the latency compensation of a robot controller (the baseline has no
    dynamic model to predict with); on time (``t_meas = t``, or ``t_meas`` unconnected) it is
    the plain forward kinematics, as before.
    """

    parameters_class = RigidKinematicsParameters
    description = "Rigid forward kinematics of the motor angles (baseline estimator)"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.input("q_m_meas", 2, unit="rad", description="measured motor angle, motor side")
        self.input("t_meas", unit="s", start=UNSTAMPED, description=T_MEAS_DESCRIPTION)
        feed = ("q_m_meas", "t_meas")
        self.output("q_a_hat", 2, unit="rad", description="arm angle estimate", depends_on=feed)
        self.output("p_tool_hat", 2, unit="m", description="tool position estimate, world x and z",
                    depends_on=feed)
        self.output("phi_tool_hat", unit="rad", description="tool angle estimate about world y "
                    "(q_a_hat[1] + q_a_hat[2])", depends_on=feed)

    def setup(self, params: RigidKinematicsParameters) -> None:
        self._consts = constants(params.robot(), params.gravity_compensation)
        self._samples = np.zeros(7)          # the last two distinct samples (estimate's layout)
        self._first = self.output_span("q_a_hat", "p_tool_hat").start
        self._refresh(self._time)

    def step(self, t: float, dt: float) -> None:
        self._refresh(t + dt)

    def update_outputs(self) -> None:
        self._refresh(self._time)

    def _refresh(self, now: float) -> None:
        self.phi_tool_hat = estimate(self.q_m_meas, measurement_time(self.t_meas, now), now, self._consts,
                                     self._samples, self._outputs, self._first)

"""FMU adapter of the rigid-kinematics baseline (tool position from the motor angles)."""
from __future__ import annotations

from fmus.common import kinematics
from fmus.common.fmi import FlexFusionSlave
from fmus.estimators.rigid_kinematics_model import RigidKinematicsParameters, arm_angles
from fmus.common.sample_time import T_MEAS_DESCRIPTION, TIME_TOL, UNSTAMPED, measurement_time


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
        self.robot = params.robot()
        self.compensate = bool(params.gravity_compensation)
        self._links = float(self.robot.l1), float(self.robot.l2)
        self._samples: list[tuple] = []     # the last two distinct samples (t_meas, q_a)
        self._refresh(self._time)

    def step(self, t: float, dt: float) -> None:
        self._refresh(t + dt)

    def update_outputs(self) -> None:
        self._refresh(self._time)

    def _refresh(self, now: float) -> None:
        q = arm_angles(self.q_m_meas, self.robot, self.compensate)
        t_m = measurement_time(self.t_meas, now)
        if self._samples and t_m <= self._samples[-1][0] + TIME_TOL:
            self._samples[-1] = (t_m, q)              # the same sample (or set again)
        else:
            self._samples = [*self._samples[-1:], (t_m, q)]
        if now > t_m + TIME_TOL and len(self._samples) == 2:
            (t0, (a0, b0)), (t1, (a1, b1)) = self._samples
            f = (now - t1) / (t1 - t0)
            q = (a1 + (a1 - a0) * f, b1 + (b1 - b0) * f)
        self.q_a_hat[:] = q
        self.p_tool_hat[:] = kinematics.tool_point(q[0], q[1], *self._links)
        self.phi_tool_hat = q[0] + q[1]

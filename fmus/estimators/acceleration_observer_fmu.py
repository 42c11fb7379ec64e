"""FMU adapter of the acceleration-based deterministic observer (Henriksson et al. 2009, section
III-B; De Luca et al. 2007). The math is in :mod:`fmus.estimators.acceleration_observer_model`.

Timing: no direct feedthrough. ``do_step(t, T)`` advances the estimate to ``t + T`` using the
measurement inputs as they are at the call as the measurements of ``t + T`` (under a
Gauss-Seidel master the producers' values of ``t + T``), interpolated linearly from those of the
previous step; the outputs after the step are the estimate of ``t + T``.
"""
from __future__ import annotations

from fmus.common.fmi import FlexFusionSlave
from fmus.common.frames import G
from fmus.common.kalman import FilterDivergence
from fmus.estimators import acceleration_observer_model as om


class AccelerationObserver(FlexFusionSlave):
    """Arm angles and tool position from motor angles, motor torques and a tool accelerometer
    (deterministic observer with pole placement; optional drift fix by fusion with the static
    forward kinematics).

    A non-finite state ends the step with an FMI error naming the cause, and so does every later
    step; the outputs keep the last good estimate.
    """

    parameters_class = om.AccelerationObserverParameters
    description = ("Deterministic acceleration-based observer of the tool position "
                   "(De Luca et al. 2007; Henriksson et al. 2009, section III-B)")

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.input("tau_m", 2, unit="N.m", description="motor torque, motor side")
        self.input("q_m_meas", 2, unit="rad", description="measured motor angles, motor side")
        self.input("acc_s", 3, unit="m/s2", description="accelerometer specific force, sensor frame",
                   start=(0.0, 0.0, G))
        self.output("q_a_hat", 2, unit="rad", description="estimated arm angles")
        self.output("dq_a_hat", 2, unit="rad/s", description="estimated arm angular velocities")
        self.output("p_tool_hat", 2, unit="m", description="tool position from the estimated arm "
                    "angles, world x and z")
        self.output("q_m_hat", 2, unit="rad", description="estimated motor angles, motor side")
        self.output("ddq_a_meas", 2, unit="rad/s2", description="arm acceleration computed from "
                    "the accelerometer at the estimate (section III-B)")
        self.output("jacobian_damping", unit="m", description="damping of the least-squares inverse "
                    "of the sensor Jacobian (0 away from singular poses)")

    def setup(self, params: om.AccelerationObserverParameters) -> None:
        self.model = om.AccelerationObserverModel(params)
        self._diverged = ""
        self._write()

    def _write(self) -> None:
        m = self.model
        self.q_a_hat[:] = m.q_a
        self.dq_a_hat[:] = m.dq_a
        self.q_m_hat[:] = m.q_m
        self.p_tool_hat[:] = m.tool_position()
        self.ddq_a_meas[:] = m.ddq_meas
        self.jacobian_damping = float(m.mu)

    def step(self, t: float, dt: float) -> None:
        if self._diverged:
            raise FilterDivergence(f"{self._diverged}; the outputs hold the last good estimate")
        try:
            self.model.step(self.q_m_meas, self.acc_s, self.tau_m, dt)
        except FilterDivergence as exc:
            self._diverged = f"{exc} (at t = {t:.6g} s)"
            raise FilterDivergence(self._diverged) from None
        self._write()

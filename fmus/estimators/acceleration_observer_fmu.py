"""FMU adapter of the acceleration-based deterministic observer (Henriksson et al. 2009, section
III-B; De Luca et al. 2007). The math is in :mod:`fmus.estimators.acceleration_observer_model`.

Timing: no direct feedthrough. ``do_step(t, T)`` advances the estimate to the time the
measurement inputs were taken, the optional input ``t_meas`` (the sensors' output), with the
inputs interpolated linearly from those of the previous measurement, and outputs the estimate
predicted on to ``t + T`` (the last inputs held; :mod:`fmus.common.filter_adapter`).
Unconnected, the inputs count as the measurements of ``t + T`` (under a Gauss-Seidel master the
producers' values of ``t + T``); the outputs after the step are then the estimate of ``t + T``.
"""
from __future__ import annotations

import copy

from fmus.common.filter_adapter import FilterAdapter
from fmus.common.frames import G
from fmus.common.sample_time import span
from fmus.estimators import acceleration_observer_model as om


class AccelerationObserver(FilterAdapter):
    """Arm angles and tool position from motor angles, motor torques and a tool accelerometer
    (deterministic observer with pole placement; optional drift fix by fusion with the static
    forward kinematics).

    A non-finite state ends the step with an FMI error naming the cause, and so does every later
    step; the outputs keep the last good estimate.
    """

    parameters_class = om.AccelerationObserverParameters
    description = ("Deterministic acceleration-based observer of the tool position "
                   "(De Luca et al. 2007; Henriksson et al. 2009, section III-B)")
    feedthrough = False

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.input("tau_m", 2, unit="N.m", description="motor torque, motor side")
        self.input("q_m_meas", 2, unit="rad", description="measured motor angles, motor side")
        self.input("acc_s", 3, unit="m/s2", description="accelerometer specific force, sensor frame",
                   start=(0.0, 0.0, G))
        self.declare_t_meas()
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
        self.start_fusion(om.AccelerationObserverModel(params))

    def _advanced(self, est: om.AccelerationObserverModel, t0: float, t1: float) -> om.AccelerationObserverModel:
        # one step over the whole interval: the measurements are the observer's inputs
        est = copy.copy(est)
        est.step(self.q_m_meas, self.acc_s, self.tau_m, span(t0, t1))
        return est

    def _show(self, m: om.AccelerationObserverModel) -> None:
        self.q_a_hat[:] = m.q_a
        self.dq_a_hat[:] = m.dq_a
        self.q_m_hat[:] = m.q_m
        self.p_tool_hat[:] = m.tool_position()
        self.ddq_a_meas[:] = m.ddq_meas
        self.jacobian_damping = float(m.mu)

"""FMU adapter of the six-axis flexible robot (issue 23): :mod:`fmus.robot_plant.six_axis_model`
(set-up, parameters) around its compiled kernel (``six_axis_kernels.pyx``: the step and the
outputs)."""
from __future__ import annotations

import numpy as np

from fmus.common.fmi import FlexFusionSlave
from fmus.robot_plant.six_axis_model import OUTPUT_SIZE, OUTPUTS, SixAxisParameters, SixAxisPlant

#: the scenarios' base step [s]: at initialisation the plant's stiffest mode is checked against
#: the automatic substeps at it (the host's own step is checked again at the first doStep)
NOMINAL_STEP = 1e-3

#: unit and description of each output of :data:`fmus.robot_plant.six_axis_model.OUTPUTS`
_OUTPUTS = {
    "q_m": ("rad", "motor angles of axes 1-6, motor side"),
    "dq_m": ("rad/s", "motor angular velocities, motor side"),
    "q_a": ("rad", "arm angles of axes 1-6 at the gearbox outputs (the passive joints' bending not included)"),
    "dq_a": ("rad/s", "arm angular velocities at the gearbox outputs"),
    "tau_s": ("N.m", "gearbox torques of axes 1-6 (spring, damping and hysteresis), arm side"),
    "p_tool": ("m", "tool centre point position of the real (bent) robot, world x, y, z"),
    "quat_tool": ("1", "tool orientation, unit quaternion w, x, y, z (tool frame to world, w >= 0)"),
    "v_tool": ("m/s", "tool centre point velocity, world"),
    "a_tool": ("m/s2", "tool centre point acceleration without gravity, world"),
    "omega_tool": ("rad/s", "tool angular velocity, world"),
    "p_sensor": ("m", "accelerometer mount position (sensor_offset: tool-frame x, z from the tool centre point), world"),
    "a_sensor": ("m/s2", "accelerometer mount acceleration without gravity, world"),
}
_FEEDTHROUGH = ("a_tool", "a_sensor")


class FlexibleRobot6DOF(FlexFusionSlave):
    """Flexible six-axis industrial robot (an IRB 4600-class arm): six elastic joints with
    nonlinear gearbox springs on the rigid-body dynamics of the arm, passive elastic joints
    (foundation tilt, out-of-plane and torsional bending of the arms), gearbox hysteresis,
    Stribeck and load-dependent friction, torque ripple, torque-constant errors and the current
    loop (each switchable; ``ideal = true`` turns them off).

    Inputs: ``tau_m`` (6) commanded motor torques [N m], motor side, held over a step;
    ``f_ext`` (3) a force on the tool centre point [N], world axes. The arm starts at rest in
    static equilibrium at ``q0``. Outputs at the end of a step use the state at that time and the
    inputs held over the step; the accelerations depend directly on ``f_ext``.

    Bad input is refused at initialisation naming the parameter (``fmus.common.parameters.
    ParameterError``): a start pose outside the joint ranges, a non-physical or not positive
    definite inertia, a mode too stiff for ``max_substeps`` RK4 steps at the scenarios' 1 ms
    base step (:data:`NOMINAL_STEP`); the host's own step is checked again at the first doStep.

    ``t_state`` stamps the outputs with the time they stand for, as the two-axis plant's.
    """
    role = "plant"

    parameters_class = SixAxisParameters
    description = "Flexible six-axis industrial robot (IRB 4600 class), passive elastic joints, drive-train realism"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.input("tau_m", 6, unit="N.m", description="commanded motor torques of axes 1-6, motor side")
        self.input("f_ext", 3, unit="N", description="external force on the tool centre point, world x, y, z")
        for name, size in OUTPUTS:
            unit, text = _OUTPUTS[name]
            self.output(name, size, unit=unit, description=text,
                        depends_on=("f_ext",) if name in _FEEDTHROUGH else ())
        self.output("t_state", unit="s", description="time the outputs stand for: the plant's own "
                    "time after its last step (the start time before the first)")
        span = self.output_span(OUTPUTS[0][0], OUTPUTS[-1][0])
        if span.stop - span.start != OUTPUT_SIZE:
            raise RuntimeError("the output buffer does not hold the kernel's outputs in one span")
        self._first, self._last = span.start, span.stop        # plain ints: the FMU state is data only
        self._wrench = np.zeros(6)

    def setup(self, params: SixAxisParameters) -> None:
        self.model = SixAxisPlant(params)
        self.model.substeps_for(NOMINAL_STEP)
        self._show()
        self.t_state = self._time

    def step(self, t: float, dt: float) -> None:
        self._wrench[:3] = self.f_ext
        self.model.step(self.tau_m, self._wrench, dt)
        self._show()
        self.t_state = t + dt

    def update_outputs(self) -> None:
        self._show()

    def _show(self) -> None:
        """The outputs now, with the force ``f_ext`` set."""
        self._wrench[:3] = self.f_ext
        self.model.kernel.outputs(self.model.x, self.model.current, self._wrench, self._outputs[self._first:self._last])


__all__ = ["FlexibleRobot6DOF"]

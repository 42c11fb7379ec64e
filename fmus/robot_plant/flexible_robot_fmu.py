"""FMU adapter of the flexible two-axis robot (2012 paper eqs. 10-11, 2009 paper eq. 2), with the
realism of :mod:`fmus.robot_plant.plant_dynamics` unless ``ideal``."""
from __future__ import annotations

import numpy as np

from fmus.common.fmi import FlexFusionSlave
from fmus.robot_plant import plant_dynamics
from fmus.robot_plant.plant_model import PlantParameters


class FlexibleRobot2DOF(FlexFusionSlave):
    """Flexible-joint model of axes 2 and 3 of a large industrial robot.

    Every physical parameter is an FMU parameter, so a scenario can give the estimators a model
    that differs from the plant. The arm starts at rest in static equilibrium under gravity at
    ``q_a0``. Outputs at the end of a step use the state at that time and the inputs held over
    the step; the accelerations depend directly on ``f_ext``.

    With ``ideal = false`` (the default) the plant has link bending, motor torque errors and
    static kinematic errors that no estimator's model has; ``q_a`` stays the gearbox output angle
    in the encoder's zero convention (``q_m / r - D``), while the tool and sensor outputs are
    those of the real, bent robot. The integration step ``dt / substeps`` is checked against the
    stiffest mode at the first ``doStep`` (the step size is not known before): a
    ``ParameterError`` naming ``substeps`` ends the step.

    ``t_state`` stamps the outputs with the time they stand for (the start time in
    Initialization Mode, ``t + dt`` after ``doStep(t, dt)``): wired to the sensors' ``t_truth``,
    their samples carry the right time under any master's coupling scheme (a Jacobi master such
    as libcosim hands a sensor the plant's outputs one step later than ours).
    """
    role = "plant"

    parameters_class = PlantParameters
    description = "Flexible two-axis industrial robot (axes 2 and 3), nonlinear gearbox springs"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.input("tau_m", 2, unit="N.m", description="motor torque, motor side")
        self.input("f_ext", 2, unit="N", description="external force on the tool, world x and z")
        acc = ("f_ext",)
        self.output("q_a", 2, unit="rad", description="arm angle at the gearbox output (q_m / r - deflection, encoder zero)")
        self.output("dq_a", 2, unit="rad/s", description="arm angular velocity")
        self.output("ddq_a", 2, unit="rad/s2", description="arm angular acceleration", depends_on=acc)
        self.output("q_m", 2, unit="rad", description="motor angle, motor side")
        self.output("dq_m", 2, unit="rad/s", description="motor angular velocity, motor side")
        self.output("p_tool", 2, unit="m", description="tool position of the real robot (bent, true geometry), world x and z")
        self.output("v_tool", 2, unit="m/s", description="tool velocity, world x and z")
        self.output("a_tool", 2, unit="m/s2", description="tool acceleration, world x and z", depends_on=acc)
        self.output("phi_tool", unit="rad", description="tool (flange) angle about world y of the real robot")
        self.output("omega_tool", unit="rad/s", description="tool angular rate about world y")
        self.output("p_sensor", 2, unit="m", description="accelerometer mount position, world x and z")
        self.output("a_sensor", 2, unit="m/s2", description="accelerometer mount acceleration, world x and z",
                    depends_on=acc)
        self.output("tau_s", 2, unit="N.m", description="gearbox spring torque, arm side")
        self.output("tau_applied", 2, unit="N.m", description="motor torque applied at the end of the last "
                    "step: (1 + torque_constant_error) tau_m + ripple, with the tau_m held over that step "
                    "(diagnostic), motor side")
        self.output("t_state", unit="s", description="time the outputs stand for: the plant's own "
                    "time after its last step (the start time before the first)")

        # where the model's outputs (plant_dynamics.chain4_advance's order) go in the output
        # buffer; -1: the scalars phi_tool and omega_tool, returned
        vectors = ("q_a", "dq_a", "ddq_a", "q_m", "dq_m", "p_tool", "v_tool", "a_tool", None, "p_sensor",
                   "a_sensor", "tau_s", "tau_applied")
        self._at = np.concatenate([np.r_[self.output_span(n, n)] if n else [-1, -1] for n in vectors])

    def setup(self, params: PlantParameters) -> None:
        self.model = plant_dynamics.plant_model(params)
        self._show(self.model.applied_torques(float(self.tau_m[0]), float(self.tau_m[1])))
        self.t_state = self._time

    def step(self, t: float, dt: float) -> None:
        self.model.check_step(dt)
        self.phi_tool, self.omega_tool = self.model.advance(self.tau_m, self.f_ext, dt, self._outputs, self._at)
        self.t_state = t + dt

    def update_outputs(self) -> None:
        self._show(())

    def _show(self, applied: tuple) -> None:
        """The outputs now with the force f_ext set, and the ``applied`` torques (none: kept)."""
        y = self.model.outputs(float(self.f_ext[0]), float(self.f_ext[1])) + tuple(applied)
        plant_dynamics.scatter(y, self._outputs, self._at)
        self.phi_tool, self.omega_tool = y[16], y[17]

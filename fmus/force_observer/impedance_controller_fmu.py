"""FMU adapter of the LQR impedance controller (impedance paper, eqs. 2-3, 40-41).

The math is in :mod:`fmus.force_observer.impedance_math`.
"""
from __future__ import annotations

import numpy as np
from pythonfmu.enums import Fmi2Status

from fmus.common.fmi import FlexFusionSlave
from fmus.common.parameters import ParameterError
from fmus.force_observer import impedance_math as imp


class ImpedanceController(FlexFusionSlave):
    """Impedance control normal to a contact surface: outputs a Cartesian reference offset.

    ``f_contact_hat`` is the force of the tool ON the environment (the ForceObserver's output,
    or a raw reading in the same sign). The controller drives the impedance variable
    ``z = (F - F_d) + K_z e + D_z de/dt`` (eq. 3, ``e = n.(p_tool - p_ref)``, ``F = n.f``) to
    zero with ``Delta = -L (e, de/dt) + c (F - F_d)`` (``structure = "paper"``, eq. 40) or
    ``Delta = -L (e, de/dt, integral z)`` (``"integral"``), ``L`` from an LQR at
    initialisation, and outputs ``dp_ref = n Delta``.

    Bad input: a non-finite input or ``force_fault > 0`` holds ``dp_ref`` and the integrator,
    sets ``fault`` and logs a warning when the episode begins. No NaN ever leaves.
    """
    role = "controller"

    parameters_class = imp.ImpedanceControllerParameters
    nan_inputs = "pass"
    description = "LQR impedance controller along a contact normal (reference offset output)"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.input("f_contact_hat", 2, unit="N", description="force of the tool on the environment, world")
        self.input("p_tool", 2, unit="m", description="tool position (estimate), world", start=(1.2, 0.9))
        self.input("p_ref", 2, unit="m", description="reference tool position, world", start=(1.2, 0.9))
        self.input("f_mount", 2, unit="N", description="force through the compliant tool mount (the wrist "
                   "sensor, gravity removed; sign of f_contact_hat), world: gives the deflection "
                   "-n.f_mount x tool_compliance when the tool is in the design model (tool_mass > 0)")
        self.input("f_desired", unit="N", description="desired force bias F_d along the normal")
        self.input("force_fault", unit="1", description="fault flag of the force input (0 = good)")
        all_in = ("f_contact_hat", "p_tool", "p_ref", "f_mount", "f_desired", "force_fault")
        # every input: the paper's structure feeds the force straight through (c F); the model
        # description is fixed before the structure parameter is known
        self.output("dp_ref", 2, unit="m", depends_on=all_in,
                    description="Cartesian reference offset for the MotionController, world")
        self.output("f_normal", unit="N", depends_on=("f_contact_hat",),
                    description="force along the normal used by the controller")
        self.output("e_normal", unit="m", depends_on=("p_tool", "p_ref"),
                    description="position error along the normal, n.(p_tool - p_ref)")
        self.output("z_impedance", unit="N", depends_on=all_in, description="impedance variable z (eq. 3)")
        self.output("saturated", unit="1", description="1 while |Delta| is at delta_max")
        self.output("fault", unit="1", depends_on=all_in, description="1 while a bad input holds the output")
        self.output("lqr_gain", 5, unit="1", description="LQR gain L on (e, de/dt, int z) (rigid tool model) "
                    "or (e_f, de_f/dt, dl, ddl/dt, int z) (tool in the model); unused entries 0")
        self.output("force_gain", unit="m/N", description="the paper structure's force gain c (eq. 40); "
                    "0 for the integral structure")

    def setup(self, params: imp.ImpedanceControllerParameters) -> None:
        d = params
        L = imp.design_gains(d)
        poles = imp.closed_loop_poles(d, L, d.k_env)
        if not np.all(np.real(poles) < 0):
            raise ParameterError(f"LQR design is not stable on the design model (poles {poles})")
        self.lqr_gain[:] = 0.0
        self.lqr_gain[:L.size] = L
        self.force_gain = imp.force_gain(d, L)
        self.n = np.array(params.normal, dtype=float) / np.hypot(*params.normal)
        self.law = imp.ImpedanceLaw(L, d.K_z, d.D_z, tau_v=params.tau_v, delta_max=params.delta_max,
                                    force_gain=self.force_gain)
        self._compliance = params.tool_compliance if d.compliant else None
        self._h_last = 0.0
        self._delta = 0.0
        self._in_fault = False
        self.update_outputs()

    def _bad(self) -> bool:
        vals = np.concatenate([self.f_contact_hat, self.p_tool, self.p_ref, self.f_mount,
                               [self.f_desired, self.force_fault]])
        return (not np.all(np.isfinite(vals))) or self.force_fault > 0

    def _axis(self) -> tuple[float, float, float, float | None]:
        """Force, tool position, reference and (tool in the design model) flange position along
        the normal; the flange is the forward kinematics' tool point, the tool that plus the
        mount's deflection."""
        F = float(self.n @ self.f_contact_hat)
        x = float(self.n @ self.p_tool)
        xr = float(self.n @ self.p_ref)
        if self._compliance is None:
            return F, x, xr, None
        return F, x - float(self.n @ self.f_mount) * self._compliance, xr, x

    def update_outputs(self) -> None:
        bad = self._bad()
        self.fault = 1.0 if bad else 0.0
        if bad:
            self.dp_ref[:] = self.n * self._delta
            return
        F, x, xr, xf = self._axis()
        self.f_normal, self.e_normal = F, x - xr
        self.z_impedance = self.law.impedance_variable(F, x, xr, self.f_desired, self._h_last, xf)
        self._delta = self.law.output(F, x, xr, self.f_desired, self._h_last, xf)   # last good output
        self.dp_ref[:] = self.n * self._delta

    def step(self, t: float, dt: float) -> None:
        if self._inputs_dirty:      # else the outputs are current
            self.update_outputs()
        if self.fault:
            if not self._in_fault:
                self.log(f"{self.instance_name}: bad force/position input at t = {t:.6g} s "
                         f"(f_contact_hat = {list(self.f_contact_hat)}, force_fault = {self.force_fault}, "
                         f"p_tool = {list(self.p_tool)}); holding dp_ref", Fmi2Status.warning)
            self._in_fault = True
            self.law.e_prev = None      # no derivative across the gap
        else:
            self._in_fault = False
            F, x, xr, xf = self._axis()
            self.law.advance(F, x, xr, self.f_desired, self._h_last, dt, xf)
            self.saturated = 1.0 if self.law.saturated else 0.0
            self._h_last = dt
        self.update_outputs()

"""FMU adapter of the LQR impedance controller (impedance paper, eqs. 2-3, 40-41).

The math is in :mod:`fmus.force_observer.impedance_math`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pythonfmu.enums import Fmi2Status

from fmus.common.fmi import FlexFusionSlave
from fmus.common.parameters import ParameterError, param
from fmus.force_observer import impedance_math as imp

PAPER = "García, Robertsson, Gómez Ortega, Johansson (impedance paper)"


@dataclass(frozen=True)
class ImpedanceControllerParameters:
    """Parameters of the ImpedanceController FMU."""

    structure: str = param("paper", "1", "controller structure: paper (eqs. 39-41: LQR state "
                           "feedback on (e, de/dt) plus the force gain c, no integral) or integral "
                           "(our extension: the integral of the impedance variable as a third state, "
                           "which makes the stationary contact satisfy eq. 2 by construction)",
                           choices=imp.STRUCTURES, source=f"{PAPER}, eqs. 39-41")
    K_z: float = param(2000.0, "N/m", "target stiffness along the normal (eq. 2)", low=0.0,
                       low_inclusive=False, source=f"{PAPER}, eq. 2")
    D_z: float = param(350.0, "N.s/m", "target damping along the normal (eq. 2)", low=0.0,
                       source=f"{PAPER}, eq. 2")
    normal: tuple = param((1.0, 0.0), "1", "contact normal, world x and z: the direction in which "
                          "the tool pushes into the surface (normalised)")
    m_design: float = param(150.0, "kg", "design model: effective robot mass along the normal",
                            low=0.0, low_inclusive=False)
    f_design: float = param(3.0, "Hz", "design model: bandwidth of the robot's position loop",
                            low=0.0, low_inclusive=False)
    zeta_design: float = param(0.7, "1", "design model: damping ratio of the robot's position loop",
                               low=0.0, low_inclusive=False)
    k_env: float = param(5000.0, "N/m", "design model: surface stiffness", low=0.0,
                         source=f"{PAPER}, section III (5 N/mm screen)")
    q_e: float = param(1e5, "1", "LQR weight on the position error e (1/m^2)", low=0.0)
    q_de: float = param(1e2, "1", "LQR weight on de/dt ((s/m)^2)", low=0.0)
    tool_compliance: float = param(0.0, "m/N", "design model: compliance of the tool mount as the "
                                   "designer knows it; 0: a rigid tool", low=0.0,
                                   source=f"{PAPER}, eq. 38 (Optidrive stiffness, identified)")
    tool_mass: float = param(0.0, "kg", "design model: tool mass on the compliant mount; > 0 (with "
                             "tool_compliance > 0) puts the tool in the LQR model (eq. 39: flange and "
                             "deflection states, the deflection from f_mount); 0: only the static "
                             "deflection enters the force gain", low=0.0, source=f"{PAPER}, eqs. 38-39")
    tool_damping: float = param(0.0, "N.s/m", "design model: damping of the tool mount", low=0.0,
                                source=f"{PAPER}, eq. 38")
    q_int: float = param(1.0, "1", "LQR weight on the integral of the impedance variable (1/(N.s)^2)",
                         low=0.0)
    r: float = param(4e4, "1", "LQR weight on the reference offset (1/m^2)", low=0.0, low_inclusive=False)
    tau_v: float = param(0.01, "s", "time constant of the filtered derivative of e", low=0.0)
    delta_max: float = param(0.05, "m", "largest reference offset along the normal", low=0.0,
                             low_inclusive=False)

    def check(self) -> None:
        if np.hypot(*self.normal) < 1e-9:
            raise ParameterError(f"parameter 'normal' = {self.normal} must not be the zero vector")

    def design(self) -> imp.ImpedanceDesign:
        """The math module's design settings."""
        return imp.ImpedanceDesign(K_z=self.K_z, D_z=self.D_z, m_r=self.m_design,
                                   w_r=2 * np.pi * self.f_design, zeta_r=self.zeta_design,
                                   k_env=self.k_env, q_e=self.q_e, q_de=self.q_de,
                                   q_int=self.q_int, r=self.r, structure=self.structure,
                                   tool_k=1.0 / self.tool_compliance if self.tool_compliance > 0 else 0.0,
                                   tool_m=self.tool_mass, tool_d=self.tool_damping)


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

    parameters_class = ImpedanceControllerParameters
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

    def setup(self, params: ImpedanceControllerParameters) -> None:
        d = params.design()
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

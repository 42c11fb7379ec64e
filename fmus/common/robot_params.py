"""The robot's parameters: the single source of truth for plant, controller and estimators.

Axes 2 and 3 (shoulder and elbow) of an IRB4600-class industrial robot, modelled as a planar
two-link arm in the world x-z plane with a flexible gearbox in each joint (Axelsson et al. 2012,
eqs. 10-11; Henriksson et al. 2009, eq. 2). Arm-side quantities unless a name says motor side.

Sources of the numbers (a consistent set, not any one robot's data sheet):

* [ABB] ABB IRB 4600-60/2.05 product specification: reach 2.05 m, axis 2 to axis 3 about
  1.1 m, handling 60 kg, robot mass 425 kg. Our links (0.9 m, 1.2 m to the tool) and masses
  (120 kg, 80 kg including payload) are those of DESIGN.md, scaled to this class.
* [MO] Moberg & Öhr, "A benchmark problem for robust feedback control of a flexible
  manipulator" (IEEE TCST 2009 / the public Simulink benchmark): gear ratio 220, motor inertia
  5e-3 kg m^2, nonlinear gearbox stiffness softer near zero torque (low/high stiffness ratio
  about 1:6; ours is 1:2), structural damping, viscous and Coulomb motor friction.
* [MSL] Modelica Standard Library, Mechanics.MultiBody.Examples.Systems.RobotR3: gear ratios
  105-210 and motor inertias of the same order for a smaller robot.
* Stiffness: chosen so that the lowest locked-motor resonance lies between 8 and 15 Hz, as
  measured on large robots (Henriksson 2009, section IV: "lowest resonance about 10 Hz";
  Axelsson 2012, section 4). ``benchmarks/plant.py`` prints it from the linearised model.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fmus.common.frames import G
from fmus.common.parameters import ParameterError, fields, param



@dataclass(frozen=True)
class RobotParameters:
    """Physical parameters of the flexible two-axis robot (axes 2 and 3).

    Joint 1 is axis 2 (shoulder, ``q1 = 0``: upper arm vertical), joint 2 is axis 3 (elbow,
    ``q2 = 0``: forearm horizontal when the upper arm is vertical). Vectors are (joint 1, joint 2).
    """

    l1: float = param(0.9, "m", "upper arm length, axis 2 to axis 3", low=0.0, low_inclusive=False,
                      source="DESIGN.md; [ABB] about 1.1 m")
    l2: float = param(1.2, "m", "forearm length, axis 3 to the tool point", low=0.0, low_inclusive=False,
                      source="DESIGN.md; [ABB] reach 2.05 m")
    m1: float = param(120.0, "kg", "upper arm mass", low=0.0, low_inclusive=False, source="DESIGN.md")
    m2: float = param(80.0, "kg", "forearm mass including wrist, tool and payload", low=0.0,
                      low_inclusive=False, source="DESIGN.md")
    c1: float = param(0.45, "m", "upper arm centre of mass, distance from axis 2 along the link",
                      low=0.0, source="uniform link")
    c2: float = param(0.7, "m", "forearm centre of mass, distance from axis 3 along the link",
                      low=0.0, source="uniform link plus payload at the tool")
    I1: float = param(8.1, "kg.m2", "upper arm inertia about its centre of mass", low=0.0,
                      source="slender rod m1 l1^2 / 12")
    I2: float = param(9.6, "kg.m2", "forearm inertia about its centre of mass", low=0.0,
                      source="slender rod m2 l2^2 / 12")
    gear_ratio: tuple = param((200.0, 160.0), "1", "gear ratio r (motor angle / arm angle)", low=1.0,
                              source="[MO] 220, [MSL] 105-210")
    J_m: tuple = param((5e-3, 4e-3), "kg.m2", "motor and gearbox input inertia, motor side", low=0.0,
                       low_inclusive=False, source="[MO] 5e-3 kg m^2")
    k_hi: tuple = param((8.0e5, 2.4e5), "N.m/rad", "gearbox stiffness at high torque, arm side", low=0.0,
                        low_inclusive=False, source="lowest locked-motor resonance 8-15 Hz")
    k_lo: tuple = param((4.0e5, 1.2e5), "N.m/rad", "gearbox stiffness near zero torque, arm side",
                        low=0.0, low_inclusive=False,
                        source="[MO] softens more (1:6); at 1:4 here the soft-zone mode (about 4.5 Hz) "
                        "meets the 4 Hz servo loop and the motors no longer track within 0.01 rad")
    delta: tuple = param((2e-4, 2e-4), "rad", "deflection over which the stiffness rises from k_lo "
                         "to k_hi (backlash-like softening)", low=0.0, low_inclusive=False, source="[MO]")
    d: tuple = param((1500.0, 300.0), "N.m.s/rad", "gearbox damping, arm side", low=0.0,
                     source="a few percent of critical at the lowest resonance")
    f_v: tuple = param((1e-3, 1e-3), "N.m.s/rad", "viscous motor friction, motor side", low=0.0,
                       source="[MO] order 1e-3")
    f_c: tuple = param((0.2, 0.15), "N.m", "Coulomb motor friction, motor side", low=0.0,
                       source="[MO] order 0.1-0.5 N m")
    w_c: tuple = param((0.5, 0.5), "rad/s", "motor speed over which Coulomb friction changes sign "
                       "(tanh smoothing, motor side)", low=0.0, low_inclusive=False,
                       source="smooth zero-speed friction, numerically benign at 1 kHz")
    sensor_offset: tuple = param((-0.15, 0.05), "m", "accelerometer mount point relative to the tool "
                                 "point, in the tool frame (x along the forearm, z)",
                                 source="accelerometer on the wrist flange, as in the 2012 paper")
    g: float = param(G, "m/s2", "gravity", low=0.0)

    def robot(self) -> "RobotParameters":
        """The robot part of a component's parameters (which extend these)."""
        return RobotParameters(**{f.name: getattr(self, f.name) for f in fields(RobotParameters)})

    def check(self) -> None:
        """Cross-field rules the ranges cannot state: ``c1 <= l1`` (the centre of mass lies on
        the link) and ``k_lo <= k_hi`` per joint; raises :class:`ParameterError`."""
        if self.c1 > self.l1:
            raise ParameterError(f"parameter 'c1' = {self.c1} must not exceed 'l1' = {self.l1}")
        for i, (lo, hi) in enumerate(zip(self.k_lo, self.k_hi), start=1):
            if lo > hi:
                raise ParameterError(f"parameter 'k_lo[{i}]' = {lo} must not exceed 'k_hi[{i}]' = {hi}")


@dataclass(frozen=True)
class RobotAtInitialPose(RobotParameters):
    """Robot parameters plus an initial pose at rest, as arm angles or as a tool position."""

    q_a0: tuple = param((0.0, 0.0), "rad", "initial arm angles (at rest); ignored when p_tool0 is given")
    p_tool0: tuple = param((0.0, 0.0), "m", "initial tool position (x, z), through the inverse "
                           "kinematics; (0, 0) - the axis of joint 2, never reachable - uses q_a0")

    def initial_angles(self) -> np.ndarray:
        """Arm angles at t = 0."""
        from fmus.common import kinematics
        if tuple(self.p_tool0) == (0.0, 0.0):
            return np.asarray(self.q_a0, float)
        try:
            return kinematics.inverse_kinematics(self.p_tool0, self)
        except ValueError as exc:
            raise ParameterError(f"parameter 'p_tool0' = {tuple(self.p_tool0)}: {exc}") from None

    def check(self) -> None:
        """The robot's rules, and an initial pose that exists (``p_tool0`` within reach);
        raises :class:`ParameterError`."""
        super().check()
        self.initial_angles()

"""Parameters of the plant FMU: the robot, its initial pose, integration settings and the realism
the estimators' model does not have (see :mod:`fmus.robot_plant.plant_dynamics`).

Sources of the realism defaults:

* [MWHB] Moberg, Wernholt, Hanssen, Brogardh, "Modeling and parameter estimation of robot
  manipulators using extended flexible joint models", ASME J. Dyn. Sys. Meas. Control 136 (2014):
  non-actuated elastic joints for the elasticity of large robots beyond their gearboxes (link and
  bearing bending), which the flexible-joint model misses. The 20-40 Hz target of the structural
  mode is this project's (issue "A robot the estimators do not know"); the stiffness is chosen
  for it, not taken from the paper's tables.
* [SERVO] permanent-magnet AC servo motor data sheets (the class of motors of a large robot's
  axes 2 and 3, rated torque about 10 N m): torque constant given with a tolerance of about
  +-5-10 % (and a few % lower when the magnets are hot); cogging and commutation ripple about
  1 % of the rated torque; 8-pole motors (4 pole pairs): commutation ripple at 6 x 4 = 24 periods
  per motor revolution.
* [NB] Nubiola and Bonev, "Absolute calibration of an ABB IRB 1600 robot using a laser tracker",
  Robotics and Computer-Integrated Manufacturing 29 (2013): uncalibrated mean / maximum position
  error 0.97 / 2.2 mm, 0.36 / 0.70 mm after calibration of link lengths and joint offsets;
  ISO 9283 absolute accuracy of uncalibrated industrial robots: about 0.5-1 mm. Each of our errors
  moves the tool by 0.1-0.5 mm (tests/test_plant_realism.py). The figures of [NB] and [SERVO] are
  quoted from memory of the sources, not checked against them here.
"""
from __future__ import annotations

from dataclasses import dataclass

from fmus.common.parameters import param
from fmus.common.robot_params import RobotAtInitialPose


@dataclass(frozen=True)
class PlantParameters(RobotAtInitialPose):
    """Robot parameters (the true plant), initial pose, RK4 substeps per communication step, and
    the plant's realism: link bending, motor torque errors, static kinematic errors."""

    substeps: int = param(1, "1", "RK4 steps per communication step (at 1 ms, halving the step changes "
                          "the tool path by under 1 um for the ideal plant, about 1.2 um for the realistic "
                          "one: tests/test_dynamics.py, tests/test_plant_realism.py)", low=1, high=1000)
    ideal: bool = param(False, "1", "switch every realism feature off: the plant is then exactly the "
                        "estimators' 8-state flexible-joint model (fmus/common/dynamics.py)",
                        source="the ideal case of tests and of the papers' simulations")
    link_bending: bool = param(True, "1", "elastic non-actuated joint part-way along each link (link "
                               "and bearing bending beyond the gearbox)", source="[MWHB]")
    bend_stiffness: tuple = param((3.0e6, 2.4e5), "N.m/rad", "stiffness of the bending joint of each link",
                                  low=0.0, low_inclusive=False,
                                  source="[MWHB]: with the motors locked, a bending mode of the wrist end "
                                  "at 34-36 Hz over the workspace, above the gearbox modes (benchmarks/plant.py)")
    bend_damping: tuple = param((300.0, 40.0), "N.m.s/rad", "damping of the bending joint of each link",
                                low=0.0, source="about 2 % of critical for the outer part on its joint "
                                "(structural damping, [MWHB])")
    bend_location: tuple = param((0.5, 0.8), "1", "position of the bending joint along each link, as a "
                                 "fraction of its length from the proximal axis", low=0.0, high=1.0,
                                 low_inclusive=False, high_inclusive=False,
                                 source="mid upper arm; the forearm bends near the wrist (its tube and the "
                                 "wrist bearings), so the wrist, tool and payload vibrate")
    bend_mass_fraction: tuple = param((0.5, 0.4), "1", "share of each link's mass in its inner part "
                                      "(a uniform rod up to the bending joint; the outer part has the rest "
                                      "and keeps the link's centre of mass and inertia)", low=0.0, high=1.0,
                                      low_inclusive=False, high_inclusive=False,
                                      source="uniform upper arm; the forearm's mass is mostly wrist, "
                                      "tool and payload (c2 = 0.7 m of 1.2 m)")
    ripple_amplitude: tuple = param((0.1, 0.08), "N.m", "motor torque ripple amplitude (cogging and "
                                    "commutation), motor side", low=0.0, high=2.0,
                                    source="[SERVO] about 1 % of a rated torque of about 10 N m")
    ripple_periods: tuple = param((24.0, 24.0), "1", "torque ripple periods per motor revolution (the "
                                  "ripple's frequency n |dq_m| / 2 pi passes 450 Hz, what RK4 at 1 ms resolves, "
                                  "at a motor speed of 118 rad/s: raise substeps for fast motions)",
                                  low=1.0, high=1000.0, source="[SERVO] 6 x 4 pole pairs")
    torque_constant_error: tuple = param((0.03, -0.02), "1", "relative torque-constant error: applied "
                                         "torque = (1 + error) x commanded torque tau_m", low=-0.2,
                                         high=0.2, source="[SERVO] tolerance +-5-10 %")
    dl: tuple = param((2.0e-4, -1.5e-4), "m", "true link length minus the nominal l1, l2", low=-5e-3,
                      high=5e-3, source="[NB] 0.1-0.5 mm at the tool")
    q_offset: tuple = param((2.0e-4, -1.5e-4), "rad", "arm-side joint zero error: the link's real "
                            "direction is q_a + q_offset (q_a: the encoder's arm angle)", low=-1e-2,
                            high=1e-2, source="[NB] 0.1-0.3 mm at the tool (2 m reach)")
    sensor_offset_error: tuple = param((3.0e-4, -2.0e-4), "m", "true accelerometer mount point minus "
                                       "the nominal sensor_offset (tool frame x, z)", low=-1e-2, high=1e-2,
                                       source="mounting tolerance of a few 0.1 mm, as [NB]'s tool errors")
    tool_compliance: float = param(0.0, "m/N", "compliance of the tool mount (an Optidrive-like "
                                   "spring-damper between the flange and the tool, isotropic in x, z); "
                                   "0: a rigid tool (off; ignored when ideal)", low=0.0, high=1e-2,
                                   source="force paper, section III: the Optidrive between the wrist "
                                   "sensor and the grinding tool; off by default")
    tool_mass: float = param(12.0, "kg", "tool mass on the compliant mount (used when tool_compliance > 0), "
                             "in addition to m2", low=0.0, low_inclusive=False,
                             source="force paper, section III: grinding tool of 12 kg")
    tool_damping: float = param(100.0, "N.s/m", "damping of the compliant tool mount", low=0.0,
                                source="about 15 % of critical at 1e-4 m/N and 12 kg")

    def check(self) -> None:
        """The robot's checks, and that each link's mass and inertia can be split into the two
        bodies of its bending joint (a ParameterError naming the link otherwise)."""
        super().check()
        if self.link_bending and not self.ideal:
            from fmus.robot_plant.plant_dynamics import split_link
            for i in range(2):
                split_link(self, i)

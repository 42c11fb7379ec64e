"""The six-axis flexible robot's physics (plain math, numpy, no FMI): ``FlexibleRobot6DOF``'s
continuous-time model and its fixed-step integrator (issue 23).

The arm is :mod:`fmus.common.irb4600`'s IRB4600-class arm. Each of its six axes is an elastic
joint as the two-axis plant's (:mod:`fmus.common.dynamics`, Axelsson et al. 2012, eqs. 10-11):
motor inertia ``J_m`` behind a gear ratio ``r``, the nonlinear gearbox spring ``tau_s(D) = k_hi D
- (k_hi - k_lo) delta tanh(D / delta)`` of the deflection ``D = q_m / r - q_a``, gearbox damping
``d``, motor friction. Added to the rigid-body tree, as passive revolute joints with linear
springs and dampers (the extended flexible joint model of [MWHB]: non-actuated joints at the
bearings, about the axes orthogonal to the actuated one), the elasticity no encoder sees:

* **foundation tilt** about x and y at the floor (``tilt_x``, ``tilt_y``): the fixed base
  (:data:`fmus.common.irb4600.BASE_MASS`) rocks on its bolts and the floor;
* **upper arm** out-of-plane bending (``upper_bend``, about its x axis at axis 2) and torsion
  (``upper_twist``, about its long axis z);
* **forearm** out-of-plane bending (``fore_bend``, about its z axis at axis 3) and torsion
  (``fore_twist``, about its long axis x).

The wrist's compliance is axes 4-6's gearboxes. With the motors locked the modes the passive
joints strain most lie at 9-40 Hz where the arm loads them (each joint's lowest over five
poses: 9-29 Hz for the bending and tilt joints) and up to 100-180 Hz where only a light body
turns on them (the twists about the links' own axes); the lowest mode of the arm stays its
axis-2/3 gearboxes' (6.7-8.7 Hz, within 7 % of the same arm without passive joints;
``docs/six_axis.md`` gives the poses, the figures and the reasoning).

The drive train's realism, each with its own switch (``ideal = true`` turns all of it and the
passive joints off):

* gearbox **hysteresis / lost motion**: a Bouc-Wen element in parallel with the spring (Ismail,
  Ikhouane and Rodellar 2009, the review of the model; ``n = 1``, ``beta = gamma``): torque
  ``k_h z`` with ``z' = D' - (|D'| z + D' |z|) / (2 z_0)``, ``k_h = T_h / z_0``: ``z`` follows the
  deflection and saturates at ``+-z_0``, the torque at ``+-T_h``, a loop of height ``2 T_h``;
* **Stribeck and load-dependent friction** (Bittencourt and Gunnarsson 2012, an ABB robot's
  joint; Olsson et al. 1998 for the Stribeck curve), motor side, a different form from the
  estimators' ``f_v w + f_c tanh(w / w_c)``: ``F(w, tau_g) = f_v w + (f_c + (f_s - f_c)
  exp(-(w / w_s)^2) + mu_L |tau_g| / r) tanh(w / w_c)``;
* **torque ripple** ``A sin(n q_m)`` and a **torque-constant error** ``e``: applied torque
  ``(1 + e) i + A sin(n q_m)`` ([SERVO] of :mod:`fmus.robot_plant.plant_model`);
* the **current loop**, a first-order lag of bandwidth ``f_i``: ``i' = 2 pi f_i (tau_m - i)``
  (``tau_m`` the commanded torque). With the command held over a step (zero-order hold) it is
  integrated exactly, ``i(t) = tau_m + (i_0 - tau_m) exp(-2 pi f_i t)``, and its eigenvalue does
  not limit RK4's stability (the automatic step still resolves the transient, ``2 pi f_i h <= pi``).

Rigid-body dynamics of the tree (6 actuated + up to 6 passive revolute joints, any tree: a joint
is a parent, an origin in the parent's frame and a unit axis) by Featherstone's algorithms
(Featherstone 2008, *Rigid Body Dynamics Algorithms*: RNEA, section 5.3; CRBA, section 6.2) in
world coordinates (spatial vectors at the world origin, angular part first), forward dynamics
``ddq = M^-1 (tau - RNEA(q, dq, 0))`` by Cholesky of ``M``. They, the right side and the RK4 step
are computed once, in the compiled kernel ``fmus/robot_plant/six_axis_kernels.pyx``
(:func:`kernels`; :attr:`SixAxisPlant.kernel`): this module sets the plant up (the tree, the
parameters, the static equilibrium, the step count) and analyses it (energy, linearisation,
modes) through the kernel's functions. The numpy form the kernel was written from is the tests'
oracle (``tests/six_axis_reference.py``), and Pinocchio is the tests' second implementation.

State ``x = (q (n), q_m (6), dq (n), dq_m (6), z (6))``: the tree's joint angles in tree order
(:attr:`SixAxisPlant.names`), the motor angles (motor side), their rates and the hysteresis
variables; the current ``i`` (6) is kept beside it (:attr:`SixAxisPlant.current`). Inputs: the
commanded motor torques ``tau_m`` (6) [N m] and an external wrench on the tool at the tool
centre point, world axes: force (3) [N], moment (3) [N m].

Integration: fixed-step RK4 with ``substeps`` per step; ``substeps = 0`` chooses the number from
the stiffest eigenvalue of the linearisation at the initial state, ``|lambda| h <=`` 0.7
(:data:`RK4_STEP_LIMIT`: RK4's numerical damping of that mode stays a tenth of its structural
damping; RK4 is stable up to 2.83 on the imaginary axis), and from the current loop's bandwidth,
``2 pi f_i h <= pi`` (:data:`CURRENT_STEP_LIMIT`); tests/test_six_axis_model.py shows
fourth-order convergence.

Sources of the defaults:

* [MWHB] Moberg, Wernholt, Hanssen, Brogardh, "Modeling and parameter estimation of robot
  manipulators using extended flexible joint models", ASME J. Dyn. Sys. Meas. Control 136 (2014):
  non-actuated elastic joints at the gearboxes and bearings, in the directions orthogonal to the
  actuated ones, identified on large ABB robots, with modes of 10-30 Hz beside the gearbox modes.
* [OHR] Ohr, Moberg, Wernholt, Hanssen, Pettersson, Persson, Sander, "Identification of
  flexibility parameters of 6-axis industrial manipulator models", ISMA (2006): the same kind of
  model fitted to an IRB-class robot; base and arm out-of-plane modes among the lowest ones.
* [BG] Bittencourt and Gunnarsson, "Static friction in a robot joint - modeling and
  identification of load and temperature effects", ASME J. Dyn. Sys. Meas. Control 134 (2012):
  Stribeck curve and a friction rising with the load torque, on an ABB robot's axis.
* [RV] cycloidal (RV-type) reducer catalogues, the reducers of axes 1-3 of robots of this class:
  lost motion about 1 arcmin (2.9e-4 rad) at a few % of rated torque.
* [SERVO] as :mod:`fmus.robot_plant.plant_model`: torque-constant tolerance +-5-10 %, ripple about
  1 % of rated torque, 24 ripple periods per revolution; a current loop of about 1 kHz bandwidth
  (PWM at 8-16 kHz, the loop closes about a decade below).

The figures of these sources are quoted from memory, not checked against them here: the defaults
are this project's estimates in their ranges, each chosen as its parameter's source says.
"""
from __future__ import annotations

import math
import weakref
from dataclasses import dataclass

import numpy as np

from fmus.common import cython_kernels, dynamics, irb4600
from fmus.common.parameters import ParameterError, param
from fmus.common.robot_params import RobotParameters

#: the passive (non-actuated) joints, in the order of the tilt_ and bend_ parameters
TILT = ("tilt_x", "tilt_y")
BEND = ("upper_bend", "upper_twist", "fore_bend", "fore_twist")
#: |lambda| h of the automatic step for the stiffest eigenvalue: RK4 damps an undamped mode by
#: (w h)^6 / 144 of its amplitude per step, a damping ratio of (w h)^5 / 144 = 1.2e-3 at 0.7, a
#: tenth of the plant's least structural damping (2 %); stable up to 2.83 (imaginary axis)
RK4_STEP_LIMIT = 0.7
RK4_STABILITY = 2.0 * math.sqrt(2.0)
#: 2 pi f_i h of the automatic step for the current loop: its transient, exact in the current, is
#: seen by the mechanics only at RK4's stages; at pi the tool path errs by about 1e-7 m after a
#: strike (tests/test_six_axis_model.py), ten times less than at 2 pi
CURRENT_STEP_LIMIT = math.pi
#: motor friction smoothing of axes 1, 4-6 [rad/s] (axes 2, 3: RobotParameters.w_c; the same)
W_C_OTHER = 0.5
_X, _Y, _Z = np.eye(3)
_NO_WRENCH = np.zeros(6)
_KERNELS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()   # SixAxisPlant -> its compiled Plant


#: the compiled kernel module ``six_axis_kernels.pyx``, loaded with this module: an FMU's package
#: is imported once per process, from an extraction folder the host may delete after that FMU's
#: run (fmpy's simulate_fmu does), while another FMU of the same build may build this plant later;
#: nothing of the folder may be looked up after the import (every FMU script imports every module
#: of its package when it loads). Compiled into the private cache on the first load (about 40 s
#: here once per content), an import from it afterwards.
_KERNEL_MODULE = cython_kernels.load("robot_plant.six_axis_kernels")


def kernels():
    """The compiled kernel module ``fmus/robot_plant/six_axis_kernels.pyx``."""
    return _KERNEL_MODULE


def rigid_body_dynamics(tree: "Tree"):
    """The kernel's rigid-body functions (``rnea``, ``mass_matrix``, ``external``, ``point``,
    ``tool_rotation``, ``potential_energy``) on the ``tree`` alone: a kernel ``Plant`` whose drive
    train is neutral (unit gear ratios and inertias, no springs), for users of the tree's dynamics
    that are not the plant (the six-axis controller's feed-forward)."""
    act = [tree.names.index(f"axis_{i + 1}") for i in range(6)]
    pas = [i for i, nm in enumerate(tree.names) if not nm.startswith("axis_")]
    one, zero = np.ones(6), np.zeros(6)
    return _KERNEL_MODULE.Plant(
        parent=tree.parent, origin=tree.origin, axis=tree.axis, mass=tree.mass, com=tree.com,
        inertia=tree.inertia, tool=tree.tool, tcp=tree.tcp, sensor=np.zeros(3), g=tree.g, pas=pas,
        k_p=np.zeros(len(pas)), d_p=np.zeros(len(pas)), act=act, r=one, J_m=one, k_hi=zero, k_soft=zero,
        delta=one, d=zero, f_v=zero, f_c=zero, f_s=zero, w_s=one, w_c=one, mu_L=zero, hyst=False, k_h=zero,
        z0=one, kt=one, ripple=zero, periods=one, w_i=0.0, locked=np.zeros(6, bool))


#: the plant's outputs in :meth:`SixAxisPlant.outputs`' order: (name, size); the kernel's
OUTPUTS = (("q_m", 6), ("dq_m", 6), ("q_a", 6), ("dq_a", 6), ("tau_s", 6), ("p_tool", 3), ("quat_tool", 4),
           ("v_tool", 3), ("a_tool", 3), ("omega_tool", 3), ("p_sensor", 3), ("a_sensor", 3))
OUTPUT_SIZE = sum(k for _, k in OUTPUTS)
_spring_inverse = getattr(dynamics.spring_inverse, "py_func", dynamics.spring_inverse)


@dataclass(frozen=True)
class SixAxisParameters(RobotParameters):
    """The six-axis plant: the planar robot's axis-2/3 values (inherited, the single source of
    those), the tool, the initial pose, the integration settings and the realism.

    Vectors of six are per axis 1-6; ``tilt_*`` per ``(tilt_x, tilt_y)``; ``bend_*`` per
    ``(upper_bend, upper_twist, fore_bend, fore_twist)``.
    """

    q0: tuple = param((0.0, 0.3, -0.2, 0.4, 0.5, 0.3), "rad", "initial arm angles of axes 1-6 (the "
                      "plant starts at rest in static equilibrium there); must lie in the working ranges",
                      source="a pose in the middle of the workspace, wrist turned")
    tool_mass: float = param(irb4600.TOOL_MASS, "kg", "tool with its load on the flange", low=0.0,
                             high=irb4600.HANDLING_CAPACITY, source="irb4600.TOOL_MASS (the planar arm's)")
    tool_com: tuple = param(irb4600.TOOL_COM, "m", "the tool's centre of mass in the link-6 frame",
                            low=-1.0, high=1.0, source="irb4600.TOOL_COM")
    tool_inertia: tuple = param(irb4600.TOOL_INERTIA, "kg.m2", "the tool's principal inertias about its "
                                "centre of mass (link-6 axes)", source="irb4600.TOOL_INERTIA")
    base_inertia: tuple = param((6.4, 6.4, 6.9), "kg.m2", "principal inertias of the fixed base about its "
                                "centre of mass (x, y, z): the body the foundation tilt rocks",
                                source="irb4600.BASE_MASS 115 kg as a 0.6 x 0.6 m block 0.6 m high "
                                "(m (b^2 + c^2) / 12)")
    substeps: int = param(0, "1", "RK4 steps per communication step; 0: the fewest with |lambda| h <= 0.7 "
                          "for the stiffest eigenvalue of the linearisation at the initial state and "
                          "2 pi f_i h <= pi for the current loop", low=0,
                          high=1000, source="tests/test_six_axis_model.py: fourth-order convergence")
    max_substeps: int = param(64, "1", "largest automatic substeps: a stiffer plant is refused naming "
                              "the parameter of its stiffest mode", low=1, high=1000,
                              source="64 RK4 steps per 1 ms step at |lambda| h = 0.7: a mode of about 7 kHz")
    locked: tuple = param((False,) * 6, "1", "axes held still (a brake on the arm side and the motor): "
                          "joint and motor do not move", source="tests: the two-axis plant is the six-axis "
                          "one with axes 1, 4-6 locked")
    ideal: bool = param(False, "1", "switch every realism feature and every passive joint off: six "
                        "flexible joints with the estimators' spring, damping and friction",
                        source="the ideal case of tests")
    foundation_tilt: bool = param(True, "1", "passive joints tilt_x, tilt_y at the floor",
                                  source="[MWHB], [OHR]")
    tilt_stiffness: tuple = param((6.0e6, 9.2e6), "N.m/rad", "foundation tilt stiffness about x, y",
                                  low=0.0, low_inclusive=False,
                                  source="[MWHB], [OHR]: with bend_stiffness, chosen so that the passive joints "
                                  "lower the arm's lowest mode (its axis-2/3 gearboxes') by at most 7 % and "
                                  "their own lowest modes lie at 9-40 Hz (docs/six_axis.md, 'Passive joints')")
    tilt_damping: tuple = param((800.0, 1200.0), "N.m.s/rad", "foundation tilt damping about x, y", low=0.0,
                                source="about 2 % of critical at 50 Hz, 2 zeta k / (2 pi 50 Hz) (bolted steel on concrete)")
    arm_bending: bool = param(True, "1", "passive joints upper_bend, upper_twist, fore_bend, fore_twist",
                              source="[MWHB]")
    bend_stiffness: tuple = param((1.9e6, 8.0e5, 6.4e5, 6.8e5), "N.m/rad", "stiffness of the upper "
                                  "arm's out-of-plane bending and torsion, the forearm's out-of-plane bending "
                                  "and torsion", low=0.0, low_inclusive=False,
                                  source="[MWHB]: with tilt_stiffness, chosen so that the passive joints lower the "
                                  "arm's lowest mode by at most 7 % and their own lowest modes lie at 9-40 Hz "
                                  "(docs/six_axis.md, 'Passive joints')")
    bend_damping: tuple = param((240.0, 100.0, 80.0, 80.0), "N.m.s/rad", "damping of the four arm "
                                "bending joints", low=0.0, source="about 2 % of critical at 50 Hz, 2 zeta k / (2 pi 50 Hz) (structural)")
    hysteresis: bool = param(True, "1", "gearbox hysteresis / lost motion (Bouc-Wen element)", source="[RV]")
    hysteresis_torque: tuple = param((120.0, 40.0, 12.0, 1.5, 1.5, 0.25), "N.m", "half-height T_h of "
                                     "the gearbox's hysteresis loop, arm side", low=0.0,
                                     source="[RV]: T_h = 1e-4 rad x k_lo, a loop 2 T_h / k_lo = 2e-4 rad "
                                     "(0.7 arcmin) wide at zero torque, within the catalogue's 1 arcmin lost motion")
    hysteresis_angle: tuple = param((2e-4,) * 6, "rad", "deflection z_0 over which the hysteresis "
                                    "torque builds up after a reversal", low=0.0, low_inclusive=False,
                                    source="[RV]: the soft zone's width delta, so that the element's "
                                    "small-amplitude stiffness T_h / z_0 is half of k_lo")
    friction_realism: bool = param(True, "1", "Stribeck and load-dependent motor friction", source="[BG]")
    f_s: tuple = param((0.3, 0.3, 0.22, 0.12, 0.12, 0.08), "N.m", "breakaway (static) friction, motor "
                       "side", low=0.0, source="[BG]: about 1.5 x Coulomb")
    w_s: tuple = param((3.0,) * 6, "rad/s", "Stribeck speed, motor side", low=0.0, low_inclusive=False,
                       source="[BG]: about 0.015 rad/s arm side times a gear ratio of 200")
    load_friction: tuple = param((1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4), "1", "friction rise mu_L per "
                                 "unit of gearbox torque: motor-side N m per arm-side N m", low=0.0,
                                 source="[BG]: friction rising by about half at high load (1000 N m on axis 2)")
    ripple_amplitude: tuple = param((0.1, 0.1, 0.08, 0.03, 0.03, 0.02), "N.m", "motor torque ripple "
                                    "amplitude, motor side (0: off)", low=0.0, high=2.0,
                                    source="[SERVO] about 1 % of rated motor torque")
    ripple_periods: tuple = param((24.0,) * 6, "1", "torque ripple periods per motor revolution",
                                  low=1.0, high=1000.0, source="[SERVO] 6 x 4 pole pairs")
    torque_constant_error: tuple = param((0.02, 0.03, -0.02, 0.01, -0.03, 0.02), "1", "relative "
                                         "torque-constant error (0: off)", low=-0.2, high=0.2,
                                         source="[SERVO] tolerance +-5-10 %")
    current_bandwidth: float = param(1000.0, "Hz", "current loop bandwidth (first-order lag; 0: off, the "
                                     "torque follows the command at once)", low=0.0, source="[SERVO]")

    def on(self, feature: str) -> bool:
        """Whether the realism ``feature`` (a switch's field name) is on: its switch, unless ``ideal``."""
        return not self.ideal and bool(getattr(self, feature))

    def check(self) -> None:
        """The robot's checks, the initial pose inside the working ranges and physical inertias
        of the tool and the base; raises :class:`ParameterError` naming the parameter."""
        super().check()
        if len(self.q0) != 6:
            raise ParameterError(f"parameter 'q0' needs 6 angles, got {len(self.q0)}")
        for i, q in enumerate(self.q0):
            lo, hi = irb4600.Q_MIN[i], irb4600.Q_MAX[i]
            if not lo <= q <= hi:
                raise ParameterError(f"parameter 'q0[{i + 1}]' = {q} rad is outside axis {i + 1}'s working "
                                     f"range [{lo:.4g}, {hi:.4g}] rad")
        for name in ("tool_inertia", "base_inertia"):
            ev = np.sort(np.asarray(getattr(self, name), float))
            if len(ev) != 3 or ev[0] <= 0.0 or ev[2] > ev[0] + ev[1]:
                raise ParameterError(f"parameter '{name}' = {getattr(self, name)} kg.m2 is not a physical "
                                     "inertia (principal moments positive, each at most the sum of the others)")


# ---- the tree ---------------------------------------------------------------------------------
def rotation(axis, angle: float) -> np.ndarray:
    """Rotation matrix by ``angle`` [rad] about the unit vector ``axis`` (Rodrigues' formula)."""
    a = np.asarray(axis, float)
    c, s = math.cos(angle), math.sin(angle)
    K = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return c * np.eye(3) + s * K + (1.0 - c) * np.outer(a, a)


@dataclass(frozen=True, eq=False)
class Tree:
    """A tree of revolute joints with rigid bodies: joint ``i`` (parents before children) turns
    body ``i`` about the unit ``axis[i]`` (link frame) through ``origin[i]`` [m] in the frame of
    body ``parent[i]`` (-1: the ground); body ``i`` has ``mass[i]`` [kg], centre of mass
    ``com[i]`` [m] and inertia ``inertia[i]`` [kg m^2] about it, in its frame (zero for a
    massless link). ``names``: the joints'; ``tool``: the body carrying the tool centre point
    ``tcp`` [m] (its frame); ``g`` [m/s^2] gravity along -z; ``limits`` (n, 3): lower, upper
    [rad] and speed [rad/s] (for the URDF). Build the arm's with :func:`arm_tree`."""

    names: tuple
    parent: np.ndarray
    origin: np.ndarray
    axis: np.ndarray
    mass: np.ndarray
    com: np.ndarray
    inertia: np.ndarray
    tool: int
    tcp: np.ndarray
    g: float
    limits: np.ndarray

    @property
    def n(self) -> int:
        """Number of joints."""
        return len(self.names)

    def ancestors(self) -> np.ndarray:
        """``A`` (n, n): ``A[i, j] = 1`` when joint ``j`` is joint ``i`` or one of its ancestors."""
        A = np.zeros((self.n, self.n))
        for i in range(self.n):
            j = i
            while j >= 0:
                A[i, j] = 1.0
                j = int(self.parent[j])
        return A

    def urdf(self, name: str = "irb4600_six_axis_plant") -> str:
        """URDF text of the tree (:func:`fmus.common.irb4600.tree_urdf`), the robot ``name``:
        link ``l_<joint>`` after each joint, the ``tool`` frame at ``tcp``."""
        link = [f"l_{nm}" for nm in self.names]
        rows = [(nm, link[i], "base_link" if self.parent[i] < 0 else link[int(self.parent[i])], self.origin[i],
                 self.axis[i], (self.mass[i], self.com[i], self.inertia[i]) if self.mass[i] > 0 else None,
                 self.limits[i]) for i, nm in enumerate(self.names)]
        return irb4600.tree_urdf(name, rows, link[self.tool], self.tcp)


def arm_tree(arm: irb4600.Arm, p: SixAxisParameters) -> Tree:
    """The tree of the ``arm`` (:func:`fmus.common.irb4600.arm`) with the passive joints the
    parameters ``p`` switch on (foundation tilt, arm bending); passive joints sit at the
    bearing they stand for, so at zero angles the tree is the rigid arm."""
    zero = (0.0, np.zeros(3), np.zeros((3, 3)))
    rows: list = []          # (name, parent, origin, axis, body, limits)
    passive_limits = (-0.1, 0.1, 10.0)

    def add(name, parent, origin, axis, body=zero, limits=passive_limits) -> int:
        rows.append((name, parent, np.asarray(origin, float), np.asarray(axis, float), body, limits))
        return len(rows) - 1

    link = [(float(arm.mass[i]), arm.com[i].copy(), arm.inertia[i].copy()) for i in range(6)]
    lim = [(arm.q_min[i], arm.q_max[i], arm.dq_max[i]) for i in range(6)]
    parent = -1
    if p.on("foundation_tilt"):
        base = (irb4600.BASE_MASS, np.asarray(irb4600.BASE_COM, float), np.diag(np.asarray(p.base_inertia, float)))
        parent = add("tilt_y", add("tilt_x", -1, np.zeros(3), _X), np.zeros(3), _Y, base)
    bend = p.on("arm_bending")
    j = add("axis_1", parent, arm.origins[0], arm.axes[0], link[0], lim[0])
    j = add("axis_2", j, arm.origins[1], arm.axes[1], zero if bend else link[1], lim[1])
    if bend:
        j = add("upper_twist", add("upper_bend", j, np.zeros(3), _X), np.zeros(3), _Z, link[1])
    j = add("axis_3", j, arm.origins[2], arm.axes[2], zero if bend else link[2], lim[2])
    if bend:
        j = add("fore_twist", add("fore_bend", j, np.zeros(3), _Z), np.zeros(3), _X, link[2])
    for i in (3, 4, 5):
        j = add(f"axis_{i + 1}", j, arm.origins[i], arm.axes[i], link[i], lim[i])
    return Tree(names=tuple(r[0] for r in rows), parent=np.array([r[1] for r in rows]),
                origin=np.array([r[2] for r in rows]), axis=np.array([r[3] for r in rows]),
                mass=np.array([r[4][0] for r in rows]), com=np.array([r[4][1] for r in rows]),
                inertia=np.array([r[4][2] for r in rows]), tool=j, tcp=arm.tcp.copy(), g=float(arm.g),
                limits=np.array([r[5] for r in rows], float))


# ---- the plant --------------------------------------------------------------------------------
class SixAxisPlant:
    """The six-axis flexible robot of the parameters ``p`` (:class:`SixAxisParameters`, checked),
    at rest in static equilibrium at ``p.q0``.

    Methods take the state ``x`` (the module's layout), the motor torque commands ``tau_m`` (6)
    [N m], the motor currents ``current`` (6) [N m, the torque the drive delivers before the
    torque-constant error and ripple] and the external ``wrench`` (6) on the tool (force [N],
    moment [N m], world axes, at the tool centre point).

    Raises
    ------
    ParameterError
        A non-physical inertia, a pose outside the working ranges (from ``p.check``), or an
        inertia matrix that is not positive definite, naming the parameter.
    """

    def __init__(self, p: SixAxisParameters) -> None:
        p.check()
        self.p = p
        try:
            self.arm = irb4600.arm(p.robot(), tool_mass=p.tool_mass, tool_com=p.tool_com,
                                   tool_inertia=p.tool_inertia)
        except ValueError as exc:
            text = str(exc)
            name = ("l1" if " l1 " in text else "l2" if " l2 " in text else "tool_mass" if "tool mass" in text
                    else "tool_inertia" if "tool" in text else "m2")
            raise ParameterError(f"parameter '{name}': {exc}") from None
        a = self.arm
        self.tree = tree = arm_tree(a, p)
        self.names = tree.names
        self.n = n = tree.n
        self.act = np.array([tree.names.index(f"axis_{i + 1}") for i in range(6)])
        self.pas = np.array([i for i, nm in enumerate(tree.names) if not nm.startswith("axis_")], int)
        pas_k = dict(zip(TILT, p.tilt_stiffness)) | dict(zip(BEND, p.bend_stiffness))
        pas_d = dict(zip(TILT, p.tilt_damping)) | dict(zip(BEND, p.bend_damping))
        self.k_p = np.array([pas_k[tree.names[i]] for i in self.pas], float)
        self.d_p = np.array([pas_d[tree.names[i]] for i in self.pas], float)
        self.r, self.J_m = a.gear_ratio.copy(), a.J_m.copy()
        self.k_hi, self.k_soft, self.delta = a.k_hi.copy(), a.k_hi - a.k_lo, a.delta.copy()
        self.d, self.f_v, self.f_c = a.d.copy(), a.f_v.copy(), a.f_c.copy()
        self.w_c = np.array([W_C_OTHER, p.w_c[0], p.w_c[1], W_C_OTHER, W_C_OTHER, W_C_OTHER])
        fr = p.on("friction_realism")
        self.f_s = np.asarray(p.f_s, float) if fr else self.f_c.copy()
        self.w_s = np.asarray(p.w_s, float)
        self.mu_L = np.asarray(p.load_friction, float) if fr else np.zeros(6)
        self.hyst = p.on("hysteresis")
        self.z0 = np.asarray(p.hysteresis_angle, float)
        self.k_h = np.asarray(p.hysteresis_torque, float) / self.z0 if self.hyst else np.zeros(6)
        real = not p.ideal
        self.kt = 1.0 + (np.asarray(p.torque_constant_error, float) if real else np.zeros(6))
        self.ripple = np.asarray(p.ripple_amplitude, float) if real else np.zeros(6)
        self.periods = np.asarray(p.ripple_periods, float)
        self.w_i = 2.0 * math.pi * float(p.current_bandwidth) if real else 0.0
        self.locked = np.array([bool(v) for v in p.locked])
        self.free = np.ones(n, bool)
        self.free[self.act[self.locked]] = False
        self.size = 2 * n + 18
        q = self.tree_angles(p.q0)
        try:
            np.linalg.cholesky(self.kernel.mass_matrix(q))
        except np.linalg.LinAlgError:
            raise ParameterError("parameters 'tool_inertia', 'base_inertia': the arm's inertia matrix at "
                                 f"q0 = {tuple(p.q0)} is not positive definite") from None
        self.x, self.current = self.static_equilibrium(p.q0)
        self.t = 0.0
        #: the stiffest eigenvalue's magnitude [rad/s] at the initial state, and the parameter of
        #: the elastic element its mode strains most
        self.stiffest, self.stiffest_parameter = self._stiffest()
        self._substeps: dict = {}

    @property
    def kernel(self):
        """The compiled plant (``six_axis_kernels.Plant``) of this plant's tree and drive-train
        arrays, built on first use. Kept beside the object, not in it (a weak map), so that the
        plant stays plain data (an FMU's state is copied and serialised as data only): a copy
        builds its own from its arrays."""
        k = _KERNELS.get(self)
        if k is None:
            k = _KERNELS[self] = self._build_kernel()
        return k

    def update(self) -> None:
        """Rebuild :attr:`kernel` from the tree and the drive-train arrays (``r``, ``J_m``,
        ``k_hi``, ``d``, ``f_c``, ...: after changing one of them)."""
        _KERNELS[self] = self._build_kernel()

    def _build_kernel(self):
        return kernels().Plant(
            parent=self.tree.parent, origin=self.tree.origin, axis=self.tree.axis, mass=self.tree.mass,
            com=self.tree.com, inertia=self.tree.inertia, tool=self.tree.tool, tcp=self.tree.tcp,
            sensor=(self.p.sensor_offset[0], 0.0, self.p.sensor_offset[1]), g=self.tree.g, pas=self.pas,
            k_p=self.k_p, d_p=self.d_p, act=self.act, r=self.r, J_m=self.J_m, k_hi=self.k_hi, k_soft=self.k_soft,
            delta=self.delta, d=self.d, f_v=self.f_v, f_c=self.f_c, f_s=self.f_s, w_s=self.w_s, w_c=self.w_c,
            mu_L=self.mu_L, hyst=self.hyst, k_h=self.k_h, z0=self.z0, kt=self.kt, ripple=self.ripple,
            periods=self.periods, w_i=self.w_i, locked=self.locked)

    # ---- state ----------------------------------------------------------------------------
    def split(self, x) -> tuple:
        """``(q, q_m, dq, dq_m, z)`` of the state ``x``."""
        n = self.n
        x = np.asarray(x, float)
        return x[:n], x[n:n + 6], x[n + 6:2 * n + 6], x[2 * n + 6:2 * n + 12], x[2 * n + 12:]

    def tree_angles(self, q_arm, passive=None) -> np.ndarray:
        """The tree's joint angles (n) from the six arm angles ``q_arm`` [rad] and the passive
        joints' ``passive`` [rad] (zero when ``None``)."""
        q = np.zeros(self.n)
        q[self.act] = np.asarray(q_arm, float)
        if passive is not None:
            q[self.pas] = np.asarray(passive, float)
        return q

    def gearbox_torque(self, x) -> np.ndarray:
        """Arm-side gearbox torque (6) [N m] at ``x``: spring, damping and hysteresis."""
        y = np.empty(OUTPUT_SIZE)
        self.kernel.outputs(np.ascontiguousarray(x, float), np.zeros(6), np.zeros(6), y)
        return y[24:30]

    def derivatives(self, x, current, wrench=None) -> np.ndarray:
        """``x_dot`` at the state ``x`` with the motor ``current`` (6) and the tool ``wrench``
        (6, or ``None``: none); the kernel's."""
        out = np.empty(self.size)
        w = _NO_WRENCH if wrench is None else np.ascontiguousarray(wrench, float)
        self.kernel.derivatives(np.ascontiguousarray(x, float), np.ascontiguousarray(current, float), w, out)
        return out

    def outputs(self, x=None, current=None, wrench=None) -> np.ndarray:
        """The plant's outputs (:data:`OUTPUTS`, 52 values) at the state ``x`` (default: now)
        with the motor ``current`` (default: now) and the tool ``wrench`` (6, or ``None``)."""
        y = np.empty(OUTPUT_SIZE)
        w = _NO_WRENCH if wrench is None else np.ascontiguousarray(wrench, float)
        self.kernel.outputs(np.ascontiguousarray(self.x if x is None else x, float),
                            np.ascontiguousarray(self.current if current is None else current, float), w, y)
        return y

    def current_at(self, i0, tau_m, t: float) -> np.ndarray:
        """The current loop's output [N m] a time ``t`` [s] after it was ``i0`` with the command
        ``tau_m`` held (exact; the command itself with the loop off)."""
        if self.w_i <= 0.0:
            return np.asarray(tau_m, float)
        tau_m = np.asarray(tau_m, float)
        return tau_m + (np.asarray(i0, float) - tau_m) * math.exp(-self.w_i * t)

    # ---- integration ----------------------------------------------------------------------
    def substeps_for(self, dt: float) -> int:
        """RK4 steps per step of ``dt`` [s]: ``p.substeps``, or with 0 the fewest that keep
        ``|lambda| h <=`` :data:`RK4_STEP_LIMIT` for the stiffest eigenvalue and ``2 pi f_i h <=``
        :data:`CURRENT_STEP_LIMIT` for the current loop.

        Raises
        ------
        ParameterError
            ``substeps`` too few for RK4's stability (naming it and the mode), or an automatic
            number above ``max_substeps`` (naming the parameter whose element the mode strains).
        """
        got = self._substeps.get(dt)
        if got is not None:
            return got
        lam = self.stiffest
        if self.p.substeps > 0:
            s = int(self.p.substeps)
            if lam * dt / s > RK4_STABILITY:
                raise ParameterError(
                    f"parameter 'substeps' = {s}: the step {dt / s:.3g} s does not resolve the plant's stiffest "
                    f"mode (|lambda| = {lam:.4g} rad/s, {lam / (2 * math.pi):.1f} Hz, of {self.stiffest_parameter}): "
                    f"RK4 needs |lambda| h <= 2.83; raise 'substeps' to at least {math.ceil(lam * dt / RK4_STABILITY)}")
        else:
            s = max(1, math.ceil(lam * dt / RK4_STEP_LIMIT), math.ceil(self.w_i * dt / CURRENT_STEP_LIMIT))
            if s > self.p.max_substeps:
                raise ParameterError(
                    f"parameter {self.stiffest_parameter}: the plant's stiffest mode (|lambda| = {lam:.4g} rad/s, "
                    f"{lam / (2 * math.pi):.1f} Hz) needs {s} RK4 substeps per {dt:g} s step, more than "
                    f"'max_substeps' = {self.p.max_substeps}")
        self._substeps[dt] = s
        return s

    def step(self, tau_m, wrench=None, dt: float = 1e-3) -> None:
        """Advance the state by ``dt`` [s] with the motor torque commands ``tau_m`` (6) [N m]
        and the tool ``wrench`` (6, or ``None``) held: :meth:`substeps_for` RK4 steps, the
        current loop exact at each stage's time."""
        s = self.substeps_for(dt)
        w = _NO_WRENCH if wrench is None else np.ascontiguousarray(wrench, float)
        x, current = np.array(self.x, float), np.array(self.current, float)
        self.kernel.step(x, current, np.ascontiguousarray(tau_m, float), w, float(dt), s)
        self.x, self.current = x, current
        self.t += dt

    # ---- analysis -------------------------------------------------------------------------
    def static_equilibrium(self, q_arm) -> tuple[np.ndarray, np.ndarray]:
        """The state at rest with the gearbox outputs at ``q_arm`` (6) [rad] (passive joints
        and gearbox springs carry gravity; hysteresis variables zero) and the current that holds
        it: ``(x, current)``."""
        q = self.tree_angles(q_arm)
        for _ in range(100):
            G = self.kernel.rnea(q, np.zeros(self.n), np.zeros(self.n))
            old = q[self.pas].copy()
            q[self.pas] = -G[self.pas] / self.k_p
            if np.all(np.abs(q[self.pas] - old) < 1e-15):
                break
        G = self.kernel.rnea(q, np.zeros(self.n), np.zeros(self.n))
        tau_g = G[self.act]
        D = np.array([_spring_inverse(self.k_hi[i], self.k_soft[i], self.delta[i], float(tau_g[i]), 0.0, False)
                      for i in range(6)])
        qm = self.r * (np.asarray(q_arm, float) + D)
        x = np.concatenate([q, qm, np.zeros(self.n + 6), np.zeros(6)])
        current = (tau_g / self.r - self.ripple * np.sin(self.periods * qm)) / self.kt
        return x, current

    def energy(self, x) -> float:
        """Kinetic, gravity and spring energy [J] at ``x``, with the ripple's potential
        ``(A / n) cos(n q_m)`` (the ripple torque ``A sin(n q_m)`` is its negative gradient)."""
        q, qm, dq, dqm, _ = self.split(x)
        D = qm / self.r - q[self.act]
        kin = 0.5 * dq @ self.kernel.mass_matrix(np.ascontiguousarray(q)) @ dq + 0.5 * np.sum(self.J_m * dqm ** 2)
        u = np.abs(D / self.delta)
        log_cosh = u + np.log1p(np.exp(-2.0 * u)) - math.log(2.0)          # without overflow
        spring = np.sum(0.5 * self.k_hi * D ** 2 - self.k_soft * self.delta ** 2 * log_cosh)
        passive = 0.5 * np.sum(self.k_p * q[self.pas] ** 2)
        ripple = np.sum(self.ripple / self.periods * np.cos(self.periods * qm))
        return float(kin + self.kernel.potential_energy(np.ascontiguousarray(q)) + spring + passive + ripple)

    def tool_position(self, x, point=None) -> np.ndarray:
        """World position [m] of the tool centre point (or of ``point`` [m], in the tool frame)
        at the state ``x``."""
        r = self.tree.tcp if point is None else self.tree.tcp + np.asarray(point, float)
        return self.kernel.point(np.ascontiguousarray(self.split(x)[0]), np.ascontiguousarray(r, float))

    def jacobian(self, x, current=None, h: float = 1e-7) -> np.ndarray:
        """``d x_dot / d x`` at ``x`` with the ``current`` held (the holding current when
        ``None``), by central differences of step ``h`` (relative)."""
        c = self.current if current is None else current
        x0 = np.asarray(x, float)
        J = np.empty((x0.size, x0.size))
        for i in range(x0.size):
            e = np.zeros(x0.size)
            e[i] = h * max(1.0, abs(x0[i]))
            J[:, i] = (self.derivatives(x0 + e, c) - self.derivatives(x0 - e, c)) / (2 * e[i])
        return J

    def _stiffest(self) -> tuple[float, str]:
        """:attr:`stiffest` and :attr:`stiffest_parameter` from the linearisation at :attr:`x`."""
        lam, vec = np.linalg.eig(self.jacobian(self.x))
        i = int(np.argmax(np.abs(lam)))
        v = vec[:, i]
        q, qm = v[:self.n], v[self.n:self.n + 6]
        gear = self.k_hi * np.abs(qm / self.r - q[self.act]) ** 2
        pas = self.k_p * np.abs(q[self.pas]) ** 2
        j = int(np.argmax(np.concatenate([gear, pas])))
        if j >= 6:
            nm = self.names[self.pas[j - 6]]
            name = (f"'tilt_stiffness[{TILT.index(nm) + 1}]'" if nm in TILT
                    else f"'bend_stiffness[{BEND.index(nm) + 1}]'")
        elif j in (1, 2):
            name = f"'k_hi[{j}]'"
        else:
            name = f"'tool_inertia' (against the axis-{j + 1} gearbox)"
        return float(abs(lam[i])), name

    def linearised_modes(self, x, free=None, shapes: bool = False) -> tuple:
        """Natural frequencies [Hz] and damping ratios of the linearisation at the rest state
        ``x`` with only the position coordinates ``free`` (indices into ``(q, q_m)``; all when
        ``None``) moving, the others clamped (held by constraints); ascending. With ``shapes``,
        the mode shapes as columns of the free positions (complex).

        ``M_ff y'' = K_ff y + D_ff y'`` with ``M = diag(M_tree, J_m)`` and the generalised forces'
        Jacobians ``[K, D] = M d(accelerations)/d(positions, rates)`` (at rest the accelerations
        vanish, so ``M d acc`` is the Jacobian of the forces), from :meth:`jacobian`."""
        m_all = self.n + 6
        f = list(range(m_all)) if free is None else list(free)
        M = np.zeros((m_all, m_all))
        M[:self.n, :self.n] = self.kernel.mass_matrix(np.ascontiguousarray(self.split(x)[0]))
        M[self.n:, self.n:] = np.diag(self.J_m)
        F = M @ self.jacobian(x)[m_all:2 * m_all]
        Mff = M[np.ix_(f, f)]
        K, D = F[np.ix_(f, f)], F[np.ix_(f, [m_all + i for i in f])]
        A = np.block([[np.zeros((len(f), len(f))), np.eye(len(f))],
                      [np.linalg.solve(Mff, K), np.linalg.solve(Mff, D)]])
        lam, vec = np.linalg.eig(A)
        keep = lam.imag > 1e-9
        lam, vec = lam[keep], vec[:len(f), keep]
        wn = np.abs(lam)
        order = np.argsort(wn)
        zeta = -lam.real / wn
        if shapes:
            return wn[order] / (2 * np.pi), zeta[order], vec[:, order]
        return wn[order] / (2 * np.pi), zeta[order]


__all__ = ["TILT", "BEND", "RK4_STEP_LIMIT", "CURRENT_STEP_LIMIT", "SixAxisParameters", "Tree", "arm_tree", "rotation",
           "SixAxisPlant", "OUTPUTS", "OUTPUT_SIZE", "kernels", "rigid_body_dynamics"]

"""The six-axis IRB4600-class arm (plain math, no FMI): parameters, forward kinematics, the
geometric Jacobian, the analytic inverse kinematics of its spherical wrist, and its energy.

Conventions (DESIGN.md, "The six-axis robot"): world frame at the robot base, x forward, y left,
z up; joints numbered 1-6 as ABB's. At ``q = 0`` every link frame is parallel to the world: the
upper arm vertical, the forearm horizontal (as the planar arm's ``q = 0``). Joint ``i`` turns
link ``i`` about the unit axis ``AXES[i]`` (z, y, y, x, y, x) through the point ``ORIGINS[i]`` of
link ``i - 1`` (link 0: the base); positive axis-2 motion tilts the upper arm forward, positive
axis-3 motion the forearm down, as ABB's and as :mod:`fmus.common.kinematics`. The tool frame is
the link-6 frame moved to the tool centre point (TCP): its x axis points along the flange normal
(ABB's ``tool0`` is it turned by +90 deg about y), so with axes 1, 4-6 at zero the tool
quaternion is the planar one, ``(cos(phi/2), 0, sin(phi/2), 0)`` with ``phi = q2 + q3``.

Sources
-------
* [PS] ABB, Product specification IRB 4600 (the 60/2.05 variant; document 3HAC032885-001), its
  dimension drawing and axis table: axis 2 175 mm forward of and 495 mm above the base, upper
  arm 900 mm, forearm offset 175 mm, axis 3 to axis 5 960 mm, axis 5 to the flange 135 mm;
  working ranges axis 1 +-180 deg, axis 2 +150/-90 deg, axis 3 +75/-180 deg, axis 4 +-400 deg,
  axis 5 +120/-125 deg, axis 6 +-400 deg; speeds 175, 175, 175, 250, 250, 360 deg/s; handling
  capacity 60 kg; robot mass 435 kg. The document is not kept here; the numbers agree with
  ROS-Industrial's transcription (next item), which a test holds them to.
* [ROSI] ROS-Industrial, ``abb_experimental``, ``abb_irb4600_support/urdf/
  irb4600_60_205_macro.xacro`` (commit 20b9cf86ad274e4f98540b9c9efe59f94245d2d1, 2023):
  joint origins (0, 0, 0.495), (0.175, 0, 0), (0, 0, 0.9), (0, 0, 0.175), (0.960, 0, 0),
  (0.135, 0, 0), axes z, y, y, x, y, x, limits in rad of the same ranges (rounded to 1e-3).
* [RP] :mod:`fmus.common.robot_params`: the planar robot (axes 2 and 3) whose values the six-axis
  arm keeps: upper arm ``m1``, ``c1``, ``I1``; forearm group (links 3-6 and tool) ``m2``, ``c2``,
  ``I2`` about the line from axis 3 to the tool point; gear ratios, motor inertias, stiffnesses,
  damping and friction of axes 2 and 3.
* [MO] Moberg and Ohr (2009), the flexible-manipulator benchmark: motor inertias, gear ratios,
  friction of a large robot's axes (used for axes 1, 4-6 as [RP] does for 2 and 3).

The estimates (no data sheet gives link masses or inertias) and their reasoning are in
``docs/six_axis.md``; :func:`arm` states each in a comment.

Equivalence with the planar robot (issue 23): with axes 1, 4, 5, 6 held at zero the arm is the
planar two-axis arm of [RP]. Three choices make it exact, each an approximation of the real arm:

1. The tool point lies on the horizontal line through axis 3 at ``q = 0``, ``l2`` from it: the
   reference tool is offset from the flange by ``(l2 - 1.095, 0, -0.175)`` m (link-6 frame), a
   tool reaching 175 mm below the flange axis (the planar model has no forearm offset).
2. The forearm group's centre of mass lies on that line at ``c2``, its inertia about the y axis
   through it is ``I2``: link 3 carries what links 4-6 and the tool leave (:func:`arm` derives it),
   which puts its centre of mass 8 cm below axis 3 where the real housing's is nearer axis 4.
3. The tool with its load weighs 10 kg, not the rated 60 kg: the planar forearm's 80 kg and
   ``I2 = 9.6`` kg m^2 cannot hold a 60 kg load 1.2 m out (its inertia alone would exceed ``I2``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from fmus.common import quaternion
from fmus.common.frames import rot_y
from fmus.common.quaternion import from_matrix
from fmus.common.robot_params import RobotParameters

N = 6  #: number of joints

#: joint origins, each in its parent link's frame [m] ([PS], [ROSI])
ORIGINS = np.array([[0.0, 0.0, 0.495], [0.175, 0.0, 0.0], [0.0, 0.0, 0.900],
                    [0.0, 0.0, 0.175], [0.960, 0.0, 0.0], [0.135, 0.0, 0.0]])
#: joint axes, unit vectors in the joint's own link frame ([ROSI])
AXES = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [0.0, 1.0, 0.0],
                 [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
_AXIS_INDEX = (2, 1, 1, 0, 1, 0)
_DEG = math.pi / 180.0
#: working ranges [rad] ([PS])
Q_MIN = np.array([-180.0, -90.0, -180.0, -400.0, -125.0, -400.0]) * _DEG
Q_MAX = np.array([180.0, 150.0, 75.0, 400.0, 120.0, 400.0]) * _DEG
#: maximum axis speeds [rad/s] ([PS], IRB 4600-60/2.05)
DQ_MAX = np.array([175.0, 175.0, 175.0, 250.0, 250.0, 360.0]) * _DEG
ROBOT_MASS = 435.0      #: [kg], [PS]
HANDLING_CAPACITY = 60.0  #: [kg], [PS]

# ---- estimates (docs/six_axis.md gives the reasoning) ------------------------------------------
#: fixed base (foundation frame, axis-1 gearbox housing) [kg]: what the data sheet's 435 kg leaves
#: after the moving links; not part of the joint dynamics (the foundation tilt DOF will use it)
BASE_MASS = 115.0
BASE_COM = (0.0, 0.0, 0.2)
_LINK1 = dict(mass=130.0, com=(0.05, 0.0, -0.05), inertia=(4.7, 4.7, 5.9))
_LINK4 = dict(mass=15.0, com=(0.65, 0.0, 0.0), inertia=(0.075, 0.49, 0.49))
_LINK5 = dict(mass=6.0, com=(0.03, 0.0, 0.0), inertia=(0.03, 0.035, 0.035))
_LINK6 = dict(mass=1.0, com=(0.01, 0.0, 0.0), inertia=(0.005, 0.003, 0.003))
TOOL_MASS = 10.0  #: reference tool with its load [kg] (see item 3 above)
TOOL_COM = (0.085, 0.0, -0.155)   #: its centre of mass in the link-6 frame [m]
TOOL_INERTIA = (0.07, 0.07, 0.07)  #: its principal inertias about the centre of mass [kg m^2]
_UPPER_ARM_IZZ = 1.5       # about its own long axis: a 0.9 m box 0.30 x 0.25 m, 120 kg
_FOREARM_IXX = 0.8         # link 3 about the forearm's long axis: a 0.25 m-radius housing


@dataclass(frozen=True, eq=False)
class Arm:
    """The six-axis arm: kinematics, inertial data and drive train, arrays per joint 1-6.

    ``origins`` (6, 3) and ``axes`` (6, 3): joint origin in the parent link frame [m] and unit
    axis; ``q_min``, ``q_max`` [rad], ``dq_max`` [rad/s]: working ranges and speeds; ``mass``
    [kg], ``com`` (6, 3) [m] in the link frame, ``inertia`` (6, 3, 3) [kg m^2] about the centre
    of mass in the link frame (link 6 includes the tool); ``tcp`` (3,) [m]: the tool centre
    point in the link-6 frame; ``tool_mass`` [kg]; drive train, motor side unless said:
    ``gear_ratio`` (motor angle / arm angle), ``J_m`` [kg m^2], ``k_hi``, ``k_lo`` [N.m/rad] and
    ``delta`` [rad] (gearbox spring, arm side), ``d`` [N.m.s/rad] (gearbox damping, arm side),
    ``f_v`` [N.m.s/rad], ``f_c`` [N.m] (motor friction); ``g`` [m/s^2]; ``sources``: where
    each group of numbers comes from. Build it with :func:`arm` (the joint axes are the data
    sheet's: :func:`link_frames` turns joint ``i`` about the coordinate axis of ``AXES[i]``).
    """

    origins: np.ndarray
    axes: np.ndarray
    q_min: np.ndarray
    q_max: np.ndarray
    dq_max: np.ndarray
    mass: np.ndarray
    com: np.ndarray
    inertia: np.ndarray
    tcp: np.ndarray
    tool_mass: float
    gear_ratio: np.ndarray
    J_m: np.ndarray
    k_hi: np.ndarray
    k_lo: np.ndarray
    delta: np.ndarray
    d: np.ndarray
    f_v: np.ndarray
    f_c: np.ndarray
    g: float
    sources: dict = field(default_factory=dict)


def _diag(v) -> np.ndarray:
    return np.diag(np.asarray(v, float))


def _shift(mass: float, r, inertia: np.ndarray, to) -> np.ndarray:
    """Inertia about the point ``to`` of a body of ``mass`` whose centre of mass is at ``r`` and
    whose inertia about it is ``inertia`` (parallel-axis theorem, Steiner)."""
    d = np.asarray(r, float) - np.asarray(to, float)
    return inertia + mass * (float(d @ d) * np.eye(3) - np.outer(d, d))


def combine(masses, coms, inertias) -> tuple[float, np.ndarray, np.ndarray]:
    """One rigid body from several in the same frame: total mass [kg], centre of mass [m] and
    inertia about it [kg m^2] of the bodies with ``masses`` (n,), centres of mass ``coms`` (n, 3)
    and inertias about them ``inertias`` (n, 3, 3) (Steiner's parallel-axis theorem)."""
    m = float(np.sum(masses))
    c = np.einsum("i,ij->j", np.asarray(masses, float), np.asarray(coms, float)) / m
    inertia = sum(_shift(mi, ci, np.asarray(Ii, float), c) for mi, ci, Ii in zip(masses, coms, inertias))
    return m, c, inertia


def _physical(name: str, mass: float, inertia: np.ndarray) -> None:
    """Raise ValueError unless ``mass > 0`` and ``inertia`` is a physical inertia (symmetric,
    principal moments positive and each at most the sum of the other two)."""
    ev = np.linalg.eigvalsh(inertia)
    if not mass > 0.0 or ev[0] <= 0.0 or ev[2] > ev[0] + ev[1] + 1e-12 * ev[2]:
        raise ValueError(f"{name}: mass {mass:g} kg and principal inertias {np.round(ev, 6)} kg m^2 "
                         "are not a physical rigid body")


def arm(robot: RobotParameters | None = None, tool_mass: float = TOOL_MASS, tool_com=TOOL_COM,
        tool_inertia=TOOL_INERTIA) -> Arm:
    """The IRB4600-class arm whose axes 2 and 3 are the planar ``robot``
    (:class:`~fmus.common.robot_params.RobotParameters`, defaults when ``None``), carrying a
    tool of ``tool_mass`` [kg] with centre of mass ``tool_com`` [m] (link-6 frame) and
    principal inertias ``tool_inertia`` [kg m^2] about it.

    Link 2 is the planar upper arm (``m1``, ``c1``, ``I1``). Link 3 is what the planar forearm
    (``m2`` at ``c2`` on the line from axis 3 to the tool point, ``I2``) leaves after links 4-6
    and the reference tool (:data:`TOOL_MASS` ...): with the defaults the six-axis arm with axes
    1, 4-6 at zero is the planar arm. A different tool changes only link 6.

    Raises
    ------
    ValueError
        If the planar link lengths are not the data sheet's (``l1`` must be 0.9 m and ``l2``
        reach past the flange) or the planar forearm cannot hold the wrist and the reference
        tool (link 3 would have no mass or a non-physical inertia).
    """
    p = robot if robot is not None else RobotParameters()
    if abs(p.l1 - ORIGINS[2, 2]) > 1e-12:
        raise ValueError(f"planar upper arm l1 = {p.l1:g} m is not the data sheet's {ORIGINS[2, 2]:g} m")
    flange_x = ORIGINS[4, 0] + ORIGINS[5, 0]
    if p.l2 <= flange_x:
        raise ValueError(f"planar forearm l2 = {p.l2:g} m does not reach past the flange ({flange_x:g} m)")
    offset = ORIGINS[3, 2]                       # forearm offset, axis 3 to axis 4 [m]
    tcp = np.array([p.l2 - flange_x, 0.0, -offset])  # item 1 of the module docstring
    # link 2: the planar upper arm; symmetric about its long axis (I_xx = I_yy = I1)
    m2, c2, I2 = p.m1, np.array([0.0, 0.0, p.c1]), _diag((p.I1, p.I1, _UPPER_ARM_IZZ))
    # links 4-6 and the reference tool, in the link-3 frame at q4 = q5 = q6 = 0
    frame3 = {4: ORIGINS[3], 5: ORIGINS[3] + ORIGINS[4], 6: ORIGINS[3] + ORIGINS[4] + ORIGINS[5]}
    wrist = [(_LINK4, 4), (_LINK5, 5), (_LINK6, 6),
             (dict(mass=TOOL_MASS, com=TOOL_COM, inertia=TOOL_INERTIA), 6)]
    ms = [w["mass"] for w, _ in wrist]
    cs = [frame3[k] + np.asarray(w["com"], float) for w, k in wrist]
    Is = [_diag(w["inertia"]) for w, _ in wrist]
    mw, cw, Iw = combine(ms, cs, Is)
    # link 3 = planar forearm group - (links 4-6 + reference tool)
    m3 = p.m2 - mw
    c3 = (p.m2 * np.array([p.c2, 0.0, 0.0]) - mw * cw) / m3 if m3 > 0 else np.zeros(3)
    iyy_group = p.I2 - _shift(mw, cw, Iw, (p.c2, 0.0, 0.0))[1, 1]
    iyy3 = iyy_group - m3 * ((c3[0] - p.c2) ** 2 + c3[2] ** 2)
    I3 = _diag((_FOREARM_IXX, iyy3, iyy3))      # slender about y and z alike
    _physical("link 3 (the planar forearm less links 4-6 and the reference tool)", m3, I3)
    # link 6 with the tool actually carried
    tool = (float(tool_mass), np.asarray(tool_com, float), _diag(tool_inertia))
    if tool[0] < 0.0 or tool[0] > HANDLING_CAPACITY:
        raise ValueError(f"tool mass {tool[0]:g} kg outside 0 to the handling capacity {HANDLING_CAPACITY:g} kg")
    if tool[0] > 0.0:
        _physical("tool", tool[0], tool[2])
        m6, c6, I6 = combine([_LINK6["mass"], tool[0]], [_LINK6["com"], tool[1]],
                             [_diag(_LINK6["inertia"]), tool[2]])
    else:
        m6, c6, I6 = _LINK6["mass"], np.asarray(_LINK6["com"], float), _diag(_LINK6["inertia"])
    links = [(_LINK1["mass"], np.asarray(_LINK1["com"], float), _diag(_LINK1["inertia"])),
             (m2, c2, I2), (m3, c3, I3),
             (_LINK4["mass"], np.asarray(_LINK4["com"], float), _diag(_LINK4["inertia"])),
             (_LINK5["mass"], np.asarray(_LINK5["com"], float), _diag(_LINK5["inertia"])),
             (m6, c6, I6)]
    for i, (m, _, inertia) in enumerate(links, start=1):
        _physical(f"link {i}", m, inertia)
    r = p.gear_ratio
    return Arm(
        origins=ORIGINS.copy(), axes=AXES.copy(), q_min=Q_MIN.copy(), q_max=Q_MAX.copy(),
        dq_max=DQ_MAX.copy(),
        mass=np.array([m for m, _, _ in links]), com=np.array([c for _, c, _ in links]),
        inertia=np.array([inertia for _, _, inertia in links]), tcp=tcp, tool_mass=float(tool_mass),
        # axes 1, 4, 5, 6: estimates (docs/six_axis.md); axes 2, 3: [RP]
        gear_ratio=np.array([190.0, r[0], r[1], 120.0, 120.0, 80.0]),
        J_m=np.array([5e-3, p.J_m[0], p.J_m[1], 1.5e-3, 1.5e-3, 8e-4]),
        k_hi=np.array([2.4e6, p.k_hi[0], p.k_hi[1], 3.0e4, 3.0e4, 5.0e3]),
        k_lo=np.array([1.2e6, p.k_lo[0], p.k_lo[1], 1.5e4, 1.5e4, 2.5e3]),
        delta=np.array([2e-4, p.delta[0], p.delta[1], 2e-4, 2e-4, 2e-4]),
        d=np.array([3000.0, p.d[0], p.d[1], 20.0, 20.0, 5.0]),
        f_v=np.array([1e-3, p.f_v[0], p.f_v[1], 5e-4, 5e-4, 3e-4]),
        f_c=np.array([0.2, p.f_c[0], p.f_c[1], 0.08, 0.08, 0.05]),
        g=float(p.g),
        sources={"kinematics": "[PS], [ROSI]", "links 2, 3 and axes 2, 3 drive train": "[RP]",
                 "links 1, 4-6, tool, axes 1, 4-6 drive train": "estimates, docs/six_axis.md"})


# ---- kinematics ------------------------------------------------------------------------------
def rotation(axis: int, angle: float) -> np.ndarray:
    """Rotation matrix by ``angle`` [rad] about the coordinate axis ``axis`` (0: x, 1: y, 2: z)."""
    if axis == 1:
        return rot_y(angle)
    c, s = math.cos(angle), math.sin(angle)
    if axis == 0:
        return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def link_frames(q, a: Arm | None = None) -> tuple[np.ndarray, np.ndarray]:
    """World rotation ``R`` (6, 3, 3) and origin ``o`` (6, 3) [m] of links 1-6 at the joint
    angles ``q`` [rad] of the arm ``a`` (its data-sheet kinematics; :func:`arm` when ``None``):
    ``T_i = T_(i-1) Trans(origin_i) Rot(axis_i, q_i)``."""
    origins = ORIGINS if a is None else a.origins
    R, o = np.eye(3), np.zeros(3)
    Rs, os = np.empty((N, 3, 3)), np.empty((N, 3))
    for i in range(N):
        o = o + R @ origins[i]
        R = R @ rotation(_AXIS_INDEX[i], float(q[i]))
        Rs[i], os[i] = R, o
    return Rs, os


def tool_pose(q, a: Arm | None = None, point=None) -> tuple[np.ndarray, np.ndarray]:
    """Forward kinematics: world position [m] and unit quaternion (w, x, y, z), tool frame to
    world, of the tool centre point at the joint angles ``q`` [rad] of the arm ``a``
    (:func:`arm` when ``None``), or of the ``point`` [m] given in the tool frame instead (an
    IMU's mount, say)."""
    a = a if a is not None else _default()
    R, o = link_frames(q, a)
    r = a.tcp if point is None else a.tcp + np.asarray(point, float)
    return o[5] + R[5] @ r, from_matrix(R[5])


def tool_rotation(q, a: Arm | None = None) -> np.ndarray:
    """Rotation matrix, tool frame to world, at the joint angles ``q`` [rad] of the arm ``a``."""
    return link_frames(q, a)[0][5]


def jacobian(q, a: Arm | None = None, point=None) -> np.ndarray:
    """Geometric Jacobian (6, 6) of the tool at the joint angles ``q`` [rad] of the arm ``a``:
    rows 0-2 the velocity [m/s per rad/s] of the tool centre point (or of ``point`` [m], given
    in the tool frame), rows 3-5 the tool's angular velocity, both in world axes; column ``i``
    is ``(z_i x (p - o_i), z_i)`` with ``z_i`` the world axis of joint ``i`` through ``o_i``."""
    a = a if a is not None else _default()
    R, o = link_frames(q, a)
    r = a.tcp if point is None else a.tcp + np.asarray(point, float)
    p = o[5] + R[5] @ r
    J = np.empty((6, N))
    for i in range(N):
        z = R[i] @ a.axes[i]
        J[:3, i] = np.cross(z, p - o[i])
        J[3:, i] = z
    return J


_DEFAULT: list = []


def _default() -> Arm:
    if not _DEFAULT:
        _DEFAULT.append(arm())
    return _DEFAULT[0]


# ---- inverse kinematics ----------------------------------------------------------------------
def _wrap(x: float) -> float:
    """``x`` [rad] into (-pi, pi]."""
    return x if -math.pi < x <= math.pi else x - 2.0 * math.pi * math.floor((x + math.pi) / (2.0 * math.pi))


def _pose_text(position, R) -> str:
    p = np.asarray(position, float)
    return (f"tool pose at ({p[0]:.4g}, {p[1]:.4g}, {p[2]:.4g}) m, quaternion "
            f"({', '.join(f'{c:.4g}' for c in from_matrix(R))})")


def _as_rotation(orientation) -> np.ndarray:
    o = np.asarray(orientation, float)
    if o.shape == (4,):
        try:
            return quaternion.to_matrix(quaternion.normalise(o))
        except ValueError:
            raise ValueError(f"tool quaternion {tuple(float(c) for c in o)} is not a rotation") from None
    if o.shape == (3, 3):
        return o
    raise ValueError(f"tool orientation must be a quaternion (w, x, y, z) or a 3x3 matrix, got shape {o.shape}")


def ik_solutions(position, orientation, a: Arm | None = None, q_ref=None,
                 within_limits: bool = True) -> np.ndarray:
    """Every set of joint angles (n, 6) [rad] putting the tool at ``position`` [m] (world) with
    ``orientation`` (unit quaternion w, x, y, z, or a 3x3 rotation, tool frame to world), for
    the arm ``a`` (:func:`arm` when ``None``): up to 8, from axis 1 front/back, elbow up/down and
    the wrist flip (Pieper's closed form for a spherical wrist, Pieper 1968).

    Axes 1-3 place the wrist centre (axis 5) ``p - R (tcp + flange)``: ``q1 = atan2(y, x)`` or
    ``+pi``; in the arm plane the forearm from axis 3 to the wrist centre is ``L (cos b, sin b)``
    with ``L = |(0.96, 0.175)|``, so ``|w|^2 = l1^2 + L^2 - 2 l1 L sin(q3 - b)`` as in the planar
    :func:`fmus.common.kinematics.inverse_kinematics`. Axes 4-6 are the X-Y-X Euler angles of
    ``R_3^T R``. At a wrist singularity (``q5 = 0``) only ``q4 + q6`` is fixed: ``q4`` is kept at
    ``q_ref[3]`` (0 without ``q_ref``); on axis 1 (wrist centre on the z axis) ``q1`` at
    ``q_ref[0]``. Axes 4 and 6 (range +-400 deg) are taken in (-pi, pi], or the turn nearest
    ``q_ref`` when it is given. With ``within_limits`` only the solutions inside the working
    ranges are returned.

    Raises
    ------
    ValueError
        Naming the pose: out of reach of the arm, or (with ``within_limits``) no solution inside
        the working ranges.
    """
    a = a if a is not None else _default()
    R = _as_rotation(orientation)
    p = np.asarray(position, float)
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(R))):
        raise ValueError(f"tool pose {tuple(p)} is not finite")
    ref = None if q_ref is None else np.asarray(q_ref, float)
    wc = p - R @ (a.tcp + a.origins[5])           # wrist centre (axis 5) [m]
    shoulder_x, base_z = a.origins[1, 0], a.origins[0, 2]
    l1 = a.origins[2, 2]
    fx, fz = a.origins[4, 0], a.origins[3, 2]     # axis 3 to axis 5: forward, up
    L, beta = math.hypot(fx, fz), math.atan2(fz, fx)
    rho = math.hypot(wc[0], wc[1])
    q1s = [math.atan2(wc[1], wc[0])] if rho > 1e-12 else [float(ref[0]) if ref is not None else 0.0]
    q1s.append(_wrap(q1s[0] + math.pi))
    out = []
    reach = []
    for q1 in q1s:
        u = wc[0] * math.cos(q1) + wc[1] * math.sin(q1) - shoulder_x
        z = wc[2] - base_z
        s = (l1 * l1 + L * L - (u * u + z * z)) / (2.0 * l1 * L)
        reach.append(math.hypot(u, z))
        if not -1.0 - 1e-12 <= s <= 1.0 + 1e-12:   # round-off at full stretch or fold still reaches
            continue
        s = min(1.0, max(-1.0, s))
        for th in (math.asin(s), math.pi - math.asin(s)):     # th = q3 - beta
            q3 = _wrap(th + beta)
            q2 = _wrap(math.atan2(u, z) - math.atan2(L * math.cos(th), l1 - L * math.sin(th)))
            R3 = rotation(2, q1) @ rotation(1, q2 + q3)
            M = R3.T @ R                              # = Rx(q4) Ry(q5) Rx(q6)
            sb = math.hypot(M[0, 1], M[0, 2])
            if sb < 1e-10:                            # wrist singular: q5 = 0, q4 + q6 fixed
                q4 = float(ref[3]) if ref is not None else 0.0
                wrists = [(q4, 0.0, math.atan2(M[2, 1], M[1, 1]) - q4)]
            else:
                q5 = math.atan2(sb, M[0, 0])
                wrists = [(math.atan2(M[1, 0], -M[2, 0]), q5, math.atan2(M[0, 1], M[0, 2])),
                          (math.atan2(-M[1, 0], M[2, 0]), -q5, math.atan2(-M[0, 1], -M[0, 2]))]
            for q4, q5, q6 in wrists:
                q = np.array([q1, q2, q3, _wrap(q4), q5, _wrap(q6)])
                if ref is not None:                   # axes 4, 6: the turn nearest q_ref
                    for k in (3, 5):
                        q[k] += 2.0 * math.pi * round((ref[k] - q[k]) / (2.0 * math.pi))
                out.append(q)
    if not out:
        raise ValueError(f"{_pose_text(p, R)} is out of reach: the wrist centre lies "
                         f"{min(reach):.4g} m from axis 2, the arm reaches {abs(l1 - L):.4g} to "
                         f"{l1 + L:.4g} m")
    sols = np.array(out)
    if within_limits:
        for k in (3, 5):                              # axes 4, 6: bring a turn inside the range
            sols[:, k] = np.where(sols[:, k] > a.q_max[k], sols[:, k] - 2 * math.pi, sols[:, k])
            sols[:, k] = np.where(sols[:, k] < a.q_min[k], sols[:, k] + 2 * math.pi, sols[:, k])
        ok = np.all((sols >= a.q_min) & (sols <= a.q_max), axis=1)
        if not ok.any():
            worst = sorted({i + 1 for s in sols for i in range(N) if not a.q_min[i] <= s[i] <= a.q_max[i]})
            raise ValueError(f"{_pose_text(p, R)} is reachable only outside the working range"
                             f"{'s of axes' if len(worst) > 1 else ' of axis'} {', '.join(map(str, worst))}")
        sols = sols[ok]
    return sols


def inverse_kinematics(position, orientation, q_ref, a: Arm | None = None) -> np.ndarray:
    """Joint angles [rad] putting the tool at ``position`` [m] with ``orientation`` (quaternion
    w, x, y, z or rotation matrix) that lie within the working ranges of the arm ``a`` and
    nearest the configuration ``q_ref`` [rad] (Euclidean distance in joint space): the
    :func:`ik_solutions` a controller tracks a path with.

    Raises
    ------
    ValueError
        Naming the pose, if it is out of reach or reachable only outside the working ranges.
    """
    ref = np.asarray(q_ref, float)
    sols = ik_solutions(position, orientation, a, ref, within_limits=True)
    return sols[int(np.argmin(np.sum((sols - ref) ** 2, axis=1)))]


# ---- energy: the second implementation the rigid-body library is checked against -------------
def kinetic_energy(q, dq, a: Arm | None = None) -> float:
    """Kinetic energy [J] of links 1-6 at the joint angles ``q`` [rad] and rates ``dq``
    [rad/s] of the arm ``a``: ``sum_i m_i |v_ci|^2 / 2 + w_i^T R_i I_i R_i^T w_i / 2``, with
    ``v_ci`` the velocity of link ``i``'s centre of mass and ``w_i = sum_(j <= i) z_j dq_j``
    its angular velocity (Siciliano et al. 2009, eq. 7.13; no motor inertias)."""
    a = a if a is not None else _default()
    R, o = link_frames(q, a)
    dq = np.asarray(dq, float)
    z = np.array([R[i] @ a.axes[i] for i in range(N)])
    energy = 0.0
    w = np.zeros(3)
    for i in range(N):
        w = w + z[i] * dq[i]
        c = o[i] + R[i] @ a.com[i]
        v = sum((np.cross(z[j], c - o[j]) * dq[j] for j in range(i + 1)), np.zeros(3))
        Iw = R[i] @ a.inertia[i] @ R[i].T
        energy += 0.5 * a.mass[i] * float(v @ v) + 0.5 * float(w @ Iw @ w)
    return float(energy)


def potential_energy(q, a: Arm | None = None) -> float:
    """Gravitational potential energy [J] of links 1-6 at the joint angles ``q`` [rad] of the
    arm ``a``: ``sum_i m_i g z_ci`` (zero at the base plane)."""
    a = a if a is not None else _default()
    R, o = link_frames(q, a)
    return float(sum(a.mass[i] * a.g * (o[i] + R[i] @ a.com[i])[2] for i in range(N)))


# ---- a URDF of the arm, for rigid-body libraries (Pinocchio's buildModelFromXML) --------------
def tree_urdf(name: str, joints, tcp_parent: str, tcp) -> str:
    """URDF text of a tree of revolute joints, the robot called ``name`` (URDF: ROS REP 103 axes,
    x forward, y left, z up, as this module's). ``joints``: one row per joint, parents before
    children: ``(joint, link, parent_link, origin, axis, body, limits)`` with the joint's name,
    its child link's name, the parent link's name (``"base_link"`` for the root), the joint's
    origin in the parent link frame [m] (no rotation), its unit axis, the child link's body
    ``(mass [kg], com (3,) [m], inertia (3, 3) [kg m^2] about the com, link frame)`` or ``None``
    for a massless link, and ``(lower, upper, velocity)`` [rad, rad/s]. A fixed ``tool`` frame
    sits at ``tcp`` [m] in the link ``tcp_parent``."""

    def vec(v) -> str:
        return " ".join(repr(float(x)) for x in v)

    parts = [f'<robot name="{name}">', '  <link name="base_link"/>']
    for joint, link, parent, origin, axis, body, (lower, upper, velocity) in joints:
        if body is None:
            parts.append(f'  <link name="{link}"/>')
        else:
            m, c, I = body
            parts.append(
                f'  <link name="{link}"><inertial><origin xyz="{vec(c)}" rpy="0 0 0"/>'
                f'<mass value="{float(m)!r}"/><inertia ixx="{float(I[0, 0])!r}" '
                f'ixy="{float(I[0, 1])!r}" ixz="{float(I[0, 2])!r}" iyy="{float(I[1, 1])!r}" '
                f'iyz="{float(I[1, 2])!r}" izz="{float(I[2, 2])!r}"/>'
                f'</inertial></link>')
        parts.append(
            f'  <joint name="{joint}" type="revolute"><parent link="{parent}"/>'
            f'<child link="{link}"/><origin xyz="{vec(origin)}" rpy="0 0 0"/>'
            f'<axis xyz="{vec(axis)}"/><limit lower="{float(lower)!r}" '
            f'upper="{float(upper)!r}" velocity="{float(velocity)!r}" effort="0"/></joint>')
    parts.append('  <link name="tool"/>')
    parts.append(f'  <joint name="tool_joint" type="fixed"><parent link="{tcp_parent}"/><child link="tool"/>'
                 f'<origin xyz="{vec(tcp)}" rpy="0 0 0"/></joint>')
    parts.append("</robot>")
    return "\n".join(parts) + "\n"


def urdf(a: Arm | None = None, name: str = "irb4600_60_205") -> str:
    """URDF text of the arm ``a`` (:func:`arm` when ``None``), the robot called ``name``: the
    links with their inertial data, the six revolute joints with their working ranges and
    speeds, and a fixed ``tool`` frame at the tool centre point (:func:`tree_urdf`)."""
    a = a if a is not None else _default()
    joints = [(f"joint_{i + 1}", f"link_{i + 1}", "base_link" if i == 0 else f"link_{i}", a.origins[i],
               a.axes[i], (a.mass[i], a.com[i], a.inertia[i]), (a.q_min[i], a.q_max[i], a.dq_max[i]))
              for i in range(N)]
    return tree_urdf(name, joints, "link_6", a.tcp)


__all__ = ["N", "ORIGINS", "AXES", "Q_MIN", "Q_MAX", "DQ_MAX", "ROBOT_MASS", "HANDLING_CAPACITY",
           "BASE_MASS", "BASE_COM", "TOOL_MASS", "TOOL_COM", "TOOL_INERTIA", "Arm", "arm", "combine",
           "rotation", "link_frames", "tool_pose", "tool_rotation", "jacobian", "ik_solutions",
           "inverse_kinematics", "kinetic_energy", "potential_energy", "tree_urdf", "urdf"]

"""Paths of the six-axis arm (plain math, no FMI): the joint-space references ``q``, ``dq``,
``ddq``, ``dddq`` of the IRB4600-class arm (:mod:`fmus.common.irb4600`) along 3-D tool paths
and joint-space motions, sampled on a time grid (issue 23, "Sensors and controller in 3-D").

Every path is built from :mod:`fmus.robot_plant.trajectory`'s moves (straight lines with the
quintic smooth-step velocity law, continuous jerk, blended corners or stops) in 3-D tool
positions or in joint angles, so jerk is continuous everywhere (the 2012 paper's EKF takes the
arm jerk, Axelsson et al. 2012, eqs. 13-14).

Tool paths in 3-D (:func:`iso_cube`, :func:`square_stops`) keep the tool's orientation
constant (``R``, tool to world; by default the flange normal, tool x, pointing straight down)
and map the position through the analytic inverse kinematics
(:func:`fmus.common.irb4600.inverse_kinematics`, the solution nearest the previous grid point's).
Their derivatives are exact, not differences of the IK: with the geometric Jacobian ``J(q)``
(rows ``v; omega``) and the tool twist's derivatives ``xi_k = (d^k p / dt^k, 0)``,

    J dq = xi_1,    J ddq = xi_2 - Jd dq,    J dddq = xi_3 - 2 Jd ddq - Jdd dq,

where ``Jd = dJ/dt`` and ``Jdd = d^2 J / dt^2`` along the motion are central differences of ``J``
along the Taylor curve ``q(s) = q + s dq + s^2 ddq / 2`` at ``s = +-EPS`` (``Jd`` to
``O(EPS^2)``, ``Jdd`` to ``O(EPS^2)`` and round-off ``eps |J| / EPS^2``: about 1e-8 relative at
``EPS = 1e-4`` s). ``Jd`` from ``J(q +- EPS dq)`` gives ``ddq`` first (the ``ddq`` term of the
curve cancels in the odd difference).

The 2009 paper's P1 and P2 (Henriksson et al. 2009, section IV-A) move axes 2-3 only, as the
planar paths :func:`fmus.robot_plant.trajectory.triangle_p1` / ``path_p2`` do: their arm angles
and exact derivatives are :func:`fmus.robot_plant.motion_control_model.arm_reference`'s (the
six-axis arm with axes 1, 4-6 at zero is the planar arm, ``docs/six_axis.md``); axes 1, 4, 5, 6
are held at ``hold`` or, with ``moving``, run point-to-point joint-space moves of their own
(:func:`axes_moving`) at the same time.

**The ISO 9283 cube** (ISO 9283:1998, *Manipulating industrial robots - Performance criteria
and related test methods*, sections 6.2.1 (cube and test positions) and 7.2 (test paths)): a
cube with edges parallel to the base frame in the much-used part of the workspace; the test
plane is its diagonal plane ``C1-C2-C7-C8``; the positions ``P1`` (the cube's centre) and
``P2 ... P5`` on the plane's diagonals at 10 % of the diagonal's length from the corners
``C1, C2, C7, C8``. Here the cube's edge is 0.5 m and its centre (1.2, 0, 0.9) m (world, base
frame): in front of the robot at the tool's home height, the tool pointing down, every point
reached inside the working ranges with the wrist centre 1.23-1.73 m from axis 2 (the arm
reaches 0.08-1.88 m). ``C1 = centre + (-a, -a, -a)/2``, ``C2 = centre + (-a, +a, -a)/2``,
``C7 = centre + (+a, +a, +a)/2``, ``C8 = centre + (+a, -a, +a)/2``: the plane rises away from
the robot. The path (ISO 9283, 7.2: the rectangle of the test positions and the diagonal of the
plane) at 200 mm/s, corners blended: ``P1 -> P2 -> P3 -> P4 -> P5 -> P2 -> P4 -> P1``.

**The square with stops**: the IMU paper's 30 mm square (as :func:`trajectory.square`), here
horizontal (world x-y, moving axis 1 with axes 2-3), 80 mm/s, 0.1 s stops at each corner
("fine points"), twice around.

Bad paths are refused (:class:`ValueError`) naming the path point and its time: a waypoint or
grid point the arm cannot reach (or only outside its working ranges), a joint speed above the
data sheet's (a singularity on the way), a joint-space motion outside a working range.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from fmus.common import irb4600, kinematics
from fmus.common.frames import rot_y
from fmus.common.quaternion import from_matrix
from fmus.common.robot_params import RobotParameters
from fmus.robot_plant import trajectory
from fmus.robot_plant.trajectory import PathBuilder, Trajectory

DT_GRID = 1e-3        #: reference grid [s]: the controller's 1 kHz step falls on it
T_MARGIN = 1.0        #: grid length after the path has ended [s]
EPS = 1e-4            #: time step of the Jacobian's central differences along the motion [s]
#: tool pointing down: tool x (the flange normal) along world -z, tool y along world y
TOOL_DOWN = from_matrix(rot_y(math.pi / 2.0))
CUBE_EDGE = 0.5                          #: ISO cube edge [m] (module docstring)
CUBE_CENTRE = (1.2, 0.0, 0.9)            #: ISO cube centre [m], world
#: axes 1, 4, 5, 6 held during P1/P2 (axis 5 bent, the wrist turned: a general pose) [rad]
HOLD = (0.0, 0.4, 0.5, 0.3)
#: joint-space excursion of axes 1, 4, 5, 6 when they move during P1/P2 [rad]
MOVING_AMPLITUDE = (0.3, 0.5, 0.4, 0.6)
MOVING_SPEED, MOVING_ACCEL = 0.6, 3.0    #: their moves' speed [rad/s] and acceleration [rad/s^2]
_OTHER = (0, 3, 4, 5)                    # axes 1, 4, 5, 6 (0-based)


@dataclass(frozen=True, eq=False)
class JointReference:
    """A six-axis path sampled on a grid: times ``t`` (n,) [s] and the joint references ``q``,
    ``dq``, ``ddq``, ``dddq`` (n, 6) [rad, rad/s, rad/s^2, rad/s^3]; the tool centre point's
    position ``p`` (n, 3) [m, world] (forward kinematics of ``q``); ``name``; ``duration``
    [s]: when the motion ends (at rest after it)."""

    name: str
    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    dddq: np.ndarray
    p: np.ndarray
    duration: float

    @property
    def q0(self) -> np.ndarray:
        """The joint angles at the start [rad] (the plant's initial pose ``q0``)."""
        return self.q[0].copy()


def grid(duration: float, dt: float = DT_GRID) -> np.ndarray:
    """The times ``0, dt, ...`` [s] covering ``duration`` [s] and :data:`T_MARGIN` after it."""
    return np.arange(int(math.ceil((duration + T_MARGIN) / dt)) + 2) * dt


# ---- the arm's kinematics on many configurations --------------------------------------------
def jacobians(q: np.ndarray, arm: irb4600.Arm) -> np.ndarray:
    """Geometric Jacobians (n, 6, 6) of the tool centre point at the configurations ``q`` (n, 6)
    [rad] of ``arm``: :func:`fmus.common.irb4600.jacobian` on many configurations at once
    (vectorised over the rows; ``tests/test_trajectory6.py`` holds the two equal to 1e-14: the
    per-configuration function costs about 0.15 ms, too slow for a 20 000-point grid)."""
    q = np.atleast_2d(np.asarray(q, float))
    n = q.shape[0]
    R = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    o = np.zeros((n, 3))
    z, origins = np.empty((6, n, 3)), np.empty((6, n, 3))
    for i in range(6):
        o = o + R @ arm.origins[i]
        c, s = np.cos(q[:, i]), np.sin(q[:, i])
        rot = np.zeros((n, 3, 3))
        k = irb4600._AXIS_INDEX[i]
        a, b = [(1, 2), (2, 0), (0, 1)][k]          # rotation about axis k mixes axes a and b
        rot[:, k, k] = 1.0
        rot[:, a, a], rot[:, a, b], rot[:, b, a], rot[:, b, b] = c, -s, s, c
        R = R @ rot
        z[i], origins[i] = R @ arm.axes[i], o
    p = o + R @ arm.tcp
    J = np.empty((n, 6, 6))
    for i in range(6):
        J[:, :3, i] = np.cross(z[i], p - origins[i])
        J[:, 3:, i] = z[i]
    return J


def joint_derivatives(q: np.ndarray, xi1: np.ndarray, xi2: np.ndarray, xi3: np.ndarray,
                      arm: irb4600.Arm) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``dq``, ``ddq``, ``dddq`` (n, 6) at the configurations ``q`` (n, 6) [rad] whose tool twist
    (velocity; angular velocity, world) and its first two time derivatives are ``xi1``,
    ``xi2``, ``xi3`` (n, 6) (module docstring: ``J dq = xi1`` differentiated twice, the
    Jacobian's time derivatives by central differences at ``+-EPS`` along the motion, on
    ``arm``)."""
    J = jacobians(q, arm)
    dq = np.linalg.solve(J, xi1[:, :, None])[:, :, 0]
    Jp, Jm = jacobians(q + EPS * dq, arm), jacobians(q - EPS * dq, arm)
    Jd = (Jp - Jm) / (2.0 * EPS)
    ddq = np.linalg.solve(J, (xi2 - (Jd @ dq[:, :, None])[:, :, 0])[:, :, None])[:, :, 0]
    half = 0.5 * EPS * EPS * ddq
    Jp, Jm = jacobians(q + EPS * dq + half, arm), jacobians(q - EPS * dq + half, arm)
    Jd = (Jp - Jm) / (2.0 * EPS)
    Jdd = (Jp - 2.0 * J + Jm) / (EPS * EPS)
    rhs = xi3 - 2.0 * (Jd @ ddq[:, :, None])[:, :, 0] - (Jdd @ dq[:, :, None])[:, :, 0]
    dddq = np.linalg.solve(J, rhs[:, :, None])[:, :, 0]
    return dq, ddq, dddq


# ---- checks naming the path point -------------------------------------------------------------
def _where(traj: Trajectory, t: float) -> str:
    """``the move to <label>`` of the trajectory's move running at ``t`` [s], or ``the path``."""
    for t0, t1, m in traj.move_intervals():
        if t0 <= t <= t1:
            return f"the move to {m.label}"
    return "the path"


def _point(p) -> str:
    return "(" + ", ".join(f"{c:.4g}" for c in p) + ") m"


def _check_joints(name: str, t: np.ndarray, q: np.ndarray, dq: np.ndarray, arm: irb4600.Arm,
                  traj: Trajectory | None = None) -> None:
    """Raise ValueError naming the first time [s] of ``t`` at which ``q`` (n, 6) leaves an axis's
    working range or ``dq`` exceeds its data-sheet speed."""
    for what, bad in (("outside its working range", (q < arm.q_min - 1e-12) | (q > arm.q_max + 1e-12)),
                      ("faster than its data-sheet speed", np.abs(dq) > arm.dq_max)):
        if bad.any():
            k, i = divmod(int(np.argmax(bad.reshape(-1))), 6)
            where = f" on {_where(traj, t[k])}" if traj is not None else ""
            value = q[k, i] if "range" in what else dq[k, i]
            raise ValueError(f"path '{name}': at t = {t[k]:.3f} s{where} axis {i + 1} is {what} "
                             f"({value:.4g} rad{'' if 'range' in what else '/s'}; range "
                             f"[{arm.q_min[i]:.4g}, {arm.q_max[i]:.4g}] rad, speed {arm.dq_max[i]:.4g} rad/s)")


# ---- tool paths in 3-D -------------------------------------------------------------------------
def cartesian_reference(traj: Trajectory, orientation, q_start, arm: irb4600.Arm | None = None,
                        t: np.ndarray | None = None) -> JointReference:
    """The joint references of the 3-D tool path ``traj`` (positions (x, y, z) [m], world) with
    the tool's ``orientation`` constant (quaternion w, x, y, z or rotation matrix, tool to
    world), from the IK solution nearest ``q_start`` [rad] at the start and nearest the previous
    grid point's after it, on the grid ``t`` [s] (:func:`grid` of the path when ``None``), for
    ``arm`` (:func:`fmus.common.irb4600.arm` when ``None``).

    Raises
    ------
    ValueError
        Naming the path point and its time: a waypoint or grid point out of reach or reachable
        only outside the working ranges, or a joint speed above the data sheet's.
    """
    arm = arm if arm is not None else irb4600.arm()
    R = irb4600._as_rotation(orientation)
    ref = np.asarray(q_start, float)
    arrive = [0.0] + [m.t_end / traj.time_scale for m in traj.moves]
    for w, label, tw in zip(traj.waypoints, traj.waypoint_labels, arrive):
        try:
            ref = irb4600.inverse_kinematics(w, R, ref, arm)
        except ValueError as exc:
            raise ValueError(f"path '{traj.name}': {label} at {_point(w)} (t = {tw:.3f} s): {exc}") from None
    t = grid(traj.duration) if t is None else np.asarray(t, float)
    p, v, a, j = traj.evaluate_many(t)
    q = np.empty((t.shape[0], 6))
    ref = np.asarray(q_start, float)
    for k in range(t.shape[0]):
        try:
            q[k] = irb4600.inverse_kinematics(p[k], R, ref, arm)
        except ValueError as exc:
            raise ValueError(f"path '{traj.name}': the point {_point(p[k])} at t = {t[k]:.3f} s on "
                             f"{_where(traj, t[k])}: {exc}") from None
        if k > 0:       # the nearest solution leaps: the path needs a change of configuration
            leap = np.abs(q[k] - ref) > 2.0 * arm.dq_max * (t[k] - t[k - 1]) + 1e-9
            if leap.any():
                i = int(np.argmax(leap))
                raise ValueError(f"path '{traj.name}': the point {_point(p[k])} at t = {t[k]:.3f} s on "
                                 f"{_where(traj, t[k])} needs axis {i + 1} to leap from {ref[i]:.4g} to "
                                 f"{q[k, i]:.4g} rad (a change of configuration: a working range's end or a "
                                 "singularity on the way)")
        ref = q[k]
    zero = np.zeros_like(v)
    dq, ddq, dddq = joint_derivatives(q, np.hstack([v, zero]), np.hstack([a, zero]), np.hstack([j, zero]), arm)
    _check_joints(traj.name, t, q, dq, arm, traj)
    return JointReference(traj.name, t, q, dq, ddq, dddq, p, traj.duration)


def cube_corners(edge: float = CUBE_EDGE, centre: Sequence[float] = CUBE_CENTRE) -> dict[str, np.ndarray]:
    """The ISO 9283 cube's corners ``C1, C2, C7, C8`` of the test plane and the test positions
    ``P1`` (centre) ... ``P5`` [m, world] for a cube of ``edge`` [m] about ``centre`` [m]
    (module docstring)."""
    c, h = np.asarray(centre, float), 0.5 * float(edge)
    corners = {"C1": c + (-h, -h, -h), "C2": c + (-h, h, -h), "C7": c + (h, h, h), "C8": c + (h, -h, h)}
    out = dict(corners, P1=c.copy())
    for k, name in zip(("C1", "C2", "C7", "C8"), ("P2", "P3", "P4", "P5")):
        out[name] = corners[k] + 0.2 * (c - corners[k])   # 10 % of the diagonal from the corner
    return out


def iso_cube_path(edge: float = CUBE_EDGE, centre: Sequence[float] = CUBE_CENTRE, speed: float = 0.2,
                  speed_scale: float = 1.0) -> Trajectory:
    """The ISO 9283 cube's test path (module docstring) at ``speed`` [m/s] on the cube of
    ``edge`` [m] about ``centre`` [m]: ``P1 -> P2 -> P3 -> P4 -> P5 -> P2 -> P4 -> P1``, corners
    blended (path acceleration 2 m/s^2), 0.5 s at rest before and after; run ``speed_scale``
    times faster. About 3.3 m, 17.6 s at 200 mm/s."""
    P = cube_corners(edge, centre)
    b = PathBuilder(P["P1"], speed=speed, accel=2.0, blend=1.0, hold=0.5, name="iso_cube", start_label="P1")
    for k, name in enumerate(("P2", "P3", "P4", "P5", "P2", "P4", "P1")):
        b.line_to(P[name], label=name, dwell=0.5 if k == 6 else 0.0)
    return b.build().scaled(speed_scale)


def square_path(start: Sequence[float] = (1.2, 0.0, 0.9), speed_scale: float = 1.0) -> Trajectory:
    """The IMU paper's 30 mm square with stops (module docstring) from ``start`` [m, world]:
    corners ``start + (0, 0), (30, 0), (30, 30), (0, 30)`` mm in world x-y, 80 mm/s, 1 m/s^2,
    0.1 s at each corner, twice around after 0.5 s at rest (about 5.5 s); run ``speed_scale``
    times faster."""
    p0 = np.asarray(start, float).reshape(3)
    b = PathBuilder(p0, speed=0.08, accel=1.0, blend=0.0, hold=0.5, name="square", start_label="start")
    for d in ((0.03, 0.0, 0.0), (0.03, 0.03, 0.0), (0.0, 0.03, 0.0), (0.0, 0.0, 0.0)):
        b.line_to(p0 + d, dwell=0.1)
    return b.repeat(2).build().scaled(speed_scale)


#: a start configuration near which the tool-down paths' IK solutions are taken (elbow up,
#: wrist not flipped) [rad]
Q_TOOL_DOWN = (0.0, 0.3, -0.2, 0.0, 1.47, 0.0)


def iso_cube(arm: irb4600.Arm | None = None, speed_scale: float = 1.0, edge: float = CUBE_EDGE,
             centre: Sequence[float] = CUBE_CENTRE) -> JointReference:
    """The joint references of :func:`iso_cube_path` (``edge``, ``centre``, ``speed_scale``)
    with the tool pointing down (:data:`TOOL_DOWN`), for ``arm``."""
    return cartesian_reference(iso_cube_path(edge, centre, speed_scale=speed_scale), TOOL_DOWN, Q_TOOL_DOWN, arm)


def square_stops(arm: irb4600.Arm | None = None, speed_scale: float = 1.0,
                 start: Sequence[float] = (1.2, 0.0, 0.9)) -> JointReference:
    """The joint references of :func:`square_path` (``start``, ``speed_scale``) with the tool
    pointing down, for ``arm``."""
    return cartesian_reference(square_path(start, speed_scale), TOOL_DOWN, Q_TOOL_DOWN, arm)


# ---- the 2009 paper's P1 and P2 on axes 2-3 -------------------------------------------------------
def axes_moving(duration: float, hold: Sequence[float] = HOLD, amplitude: Sequence[float] = MOVING_AMPLITUDE,
                start: float = 0.5) -> Trajectory:
    """Joint-space moves of axes 1, 4, 5, 6 (a 4-D :class:`~fmus.robot_plant.trajectory.Trajectory`
    of their angles [rad]) from ``hold`` to ``hold + amplitude`` and back, straight lines in
    joint space at :data:`MOVING_SPEED`, :data:`MOVING_ACCEL`, 0.1 s stops, starting at
    ``start`` [s] and repeated as long as they fit in ``duration`` [s]."""
    h, amp = np.asarray(hold, float), np.asarray(amplitude, float)
    b = PathBuilder(h, speed=MOVING_SPEED, accel=MOVING_ACCEL, blend=0.0, hold=start, name="axes 1, 4-6",
                    start_label="hold")
    b.line_to(h + amp, dwell=0.1, label="out").line_to(h, dwell=0.1, label="back")
    once = b.build()
    loops = max(1, int((duration - start) // (once.duration - start)))
    b = PathBuilder(h, speed=MOVING_SPEED, accel=MOVING_ACCEL, blend=0.0, hold=start, name="axes 1, 4-6",
                    start_label="hold")
    b.line_to(h + amp, dwell=0.1, label="out").line_to(h, dwell=0.1, label="back")
    return b.repeat(loops).build()


def planar_reference(name: str, moving: bool = False, hold: Sequence[float] = HOLD,
                     arm: irb4600.Arm | None = None, speed_scale: float = 1.0,
                     robot: RobotParameters | None = None) -> JointReference:
    """The 2009 paper's path ``name`` (``"p1"`` or ``"p2"``, :data:`fmus.robot_plant.trajectory.PATHS`)
    on axes 2-3 of ``arm`` (the planar ``robot``'s link lengths; defaults when ``None``), axes 1,
    4, 5, 6 held at ``hold`` [rad] or, with ``moving``, running :func:`axes_moving` from it; run
    ``speed_scale`` times faster.

    Raises
    ------
    ValueError
        Naming the path point and its time: out of the planar arm's reach, or an axis outside
        its working range or above its speed.
    """
    from fmus.robot_plant.motion_control_model import arm_reference   # the planar arm's exact references
    arm = arm if arm is not None else irb4600.arm(robot)
    rp = robot if robot is not None else RobotParameters()
    plane = trajectory.make_path(name, None, speed_scale)
    t = grid(plane.duration)
    p, v, a, j = plane.evaluate_many(t)
    _, s2 = kinematics.inverse_kinematics_many(p, rp.l1, rp.l2)
    if not np.all(np.isfinite(s2)) or np.any(np.abs(s2) > 1.0):
        k = int(np.argmax(~(np.abs(s2) <= 1.0)))
        raise ValueError(f"path '{name}': the point (x, z) = ({p[k, 0]:.4g}, {p[k, 1]:.4g}) m at t = "
                         f"{t[k]:.3f} s on {_where(plane, t[k])} is out of the arm's reach")
    q23 = arm_reference(p, v, a, j, rp.l1, rp.l2)
    q = [np.zeros((t.shape[0], 6)) for _ in range(4)]
    for k in range(4):
        q[k][:, 1:3] = q23[k]
    title = f"{name} ({'axes 1, 4-6 moving' if moving else 'axes 1, 4-6 held'})"
    if moving:
        other = axes_moving(plane.duration * speed_scale, hold).scaled(speed_scale)
        for k, x in enumerate(other.evaluate_many(t)):
            q[k][:, _OTHER] = x
    else:
        q[0][:, _OTHER] = np.asarray(hold, float)
    _check_joints(title, t, q[0], q[1], arm)
    P = np.array([irb4600.tool_pose(qk, arm)[0] for qk in q[0]])
    return JointReference(title, t, *q, P, plane.duration)


#: the six-axis paths by name: ``iso_cube``, ``square``, ``p1``, ``p2``, ``p1_moving``, ``p2_moving``
PATHS6 = ("iso_cube", "square", "p1", "p2", "p1_moving", "p2_moving")


def make_reference(name: str, arm: irb4600.Arm | None = None, speed_scale: float = 1.0,
                   robot: RobotParameters | None = None) -> JointReference:
    """The joint references of the six-axis path ``name`` (:data:`PATHS6`) for ``arm`` (whose
    planar axes 2-3 are ``robot``'s), run ``speed_scale`` times faster.

    Raises
    ------
    ValueError
        An unknown name, or a path point the arm cannot follow (naming it and its time).
    """
    if name == "iso_cube":
        return iso_cube(arm, speed_scale)
    if name == "square":
        return square_stops(arm, speed_scale)
    if name in ("p1", "p2", "p1_moving", "p2_moving"):
        return planar_reference(name[:2], name.endswith("_moving"), arm=arm, speed_scale=speed_scale, robot=robot)
    raise ValueError(f"unknown six-axis path '{name}' (known: {', '.join(PATHS6)})")


__all__ = ["JointReference", "PATHS6", "make_reference", "iso_cube", "iso_cube_path", "square_stops",
           "square_path", "planar_reference", "axes_moving", "cartesian_reference", "cube_corners",
           "jacobians", "joint_derivatives", "grid"]

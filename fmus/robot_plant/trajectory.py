"""Cartesian tool paths in the world x-z plane, time-parametrised with continuous jerk.

A path is a chain of *moves* (straight lines and circular arcs). Each move ``k`` has its own
time law ``s_k(t)`` along its arc length: a smooth velocity profile that ramps from rest to the
move's speed ``V``, cruises, and ramps back to rest,

.. math::

    \\dot s(\\tau) = V\\,[S(x) - S(y)],\\quad x = \\mathrm{clip}(\\tau/T_a),\\;
    y = \\mathrm{clip}((\\tau - T_a - T_c)/T_a),\\quad S(x) = 10x^3 - 15x^4 + 6x^5 ,

(the quintic smooth-step, whose first and second derivatives vanish at both ends), so
acceleration ``V S'/T_a`` and jerk ``V S''/T_a^2`` are continuous and vanish where the move
starts and ends. The tool position is the *superposition* of all moves' displacements,

.. math:: p(t) = p_0 + \\sum_k g_k(s_k(t)),

with ``g_k`` the displacement along move ``k``'s geometry. A move may start before the previous
one has ended (``blend``): during the overlap the velocity passes smoothly from one direction to
the next and the corner is cut, as a real robot controller's corner *zone* does; with
``blend = 0`` (or a dwell) the tool stops exactly at the waypoint ("fine point"). Because every
``s_k`` is C3 and every ``g_k`` smooth, the sum is C3 in time: position, velocity, acceleration
and jerk are continuous everywhere, which the 2012 paper's EKF needs (the arm jerk reference is
its input, eqs. 13-14 of Axelsson et al. 2012).

Peak path acceleration of a ramp is ``15/8 V/T_a`` and peak jerk ``(10/sqrt 3) V/T_a^2``; the
ramp time is chosen from the move's acceleration limit, ``T_a = 15/8 V / a_max``. A move too
short to reach its speed gets the largest speed it can reach, ``V = sqrt(8 L a_max / 15)``; an
arc's speed is limited so that its centripetal acceleration ``V^2/rho`` stays below ``a_max``.

Shipped paths (:data:`PATHS`; positions in metres, world frame with the origin at joint 2,
reachable by the arm with ``l1 = 0.9 m``, ``l2 = 1.2 m`` whose home pose puts the tool at
(1.2, 0.9)):

``p1``
    Path P1 of Henriksson et al. (2009), section IV-A: a triangle with 15-20 cm sides, driven
    point-to-point at up to 1 m/s and 6 m/s^2 (fast enough to excite the 10 Hz modes of a large
    robot), stopping at each vertex, repeated for about 7.5 s.
``p2``
    Path P2 of the same paper: a smaller motion (8-12 cm quadrilateral) in another part of the
    workspace, lower and further out.
``iso9283``
    The ISO 9283-style path of the IMU paper (Fig. 2; Moberg & Hanssen 2009) at 200 mm/s:
    straight segments, a large (r = 75 mm) and a small (r = 15 mm) circle and a staircase of
    twenty 90-degree corners, with blended corners.
``square``
    The IMU paper's 30 mm "cube" trajectory, here a 30 mm square in the x-z plane at 80 mm/s
    with brief stops at the corners ("high precision mode"), twice around.
``csv``
    User waypoints from a CSV file (:func:`from_csv`, format documented there).

The builder and the time law are not planar: lines between points of any dimension make the
six-axis robot's 3-D tool paths and joint-space moves (:mod:`fmus.robot_plant.trajectory6`).
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

# Ramp time per unit of (speed / peak acceleration) of the quintic smooth-step: max S' = 15/8.
_RAMP_PER_V_OVER_A = 15.0 / 8.0


# ---- quintic smooth-step and its integral / derivatives -----------------------------------
def _S(x: np.ndarray) -> np.ndarray:
    return x * x * x * (10.0 + x * (-15.0 + 6.0 * x))


def _S_int(x: np.ndarray) -> np.ndarray:
    """Integral of S from 0 to x (equals 1/2 at x = 1)."""
    x2 = x * x
    return x2 * x2 * (2.5 + x * (-3.0 + x))


def _S_d1(x: np.ndarray) -> np.ndarray:
    return 30.0 * x * x * (1.0 - x) ** 2


def _S_d2(x: np.ndarray) -> np.ndarray:
    return 60.0 * x * (1.0 - x) * (1.0 - 2.0 * x)


def _norm(v: np.ndarray) -> float:
    """Euclidean length of ``v``: ``np.hypot`` in the plane (the planar paths' numbers since
    they were written), ``math.hypot`` in more dimensions."""
    return float(np.hypot(*v)) if v.shape[0] == 2 else math.hypot(*v)


# ---- move geometries ------------------------------------------------------------------------
class _Line:
    """Straight line of length ``length`` along unit vector ``d``."""

    kind = "line"

    def __init__(self, d: np.ndarray, length: float) -> None:
        self.d = np.asarray(d, dtype=float)
        self.length = float(length)
        self.curvature = 0.0

    def derivatives(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """g(s), g'(s), g''(s), g'''(s), each (n, dim) (dim: the size of ``d``)."""
        n, dim = s.shape[0], self.d.shape[0]
        g0 = s[:, None] * self.d
        g1 = np.broadcast_to(self.d, (n, dim))
        zero = np.zeros((n, dim))
        return g0, g1, zero, zero

    def end_tangent(self) -> np.ndarray:
        return self.d


class _Arc:
    """Circular arc about ``center`` (relative to the arc's start point), radius ``rho``.

    The angle ``theta`` is measured from +x towards +z; ``sign = +1`` turns from +x towards +z
    (counter-clockwise with x to the right and z up), ``-1`` the other way.
    """

    kind = "arc"

    def __init__(self, center_rel: np.ndarray, rho: float, theta0: float, sign: float,
                 sweep: float) -> None:
        self.c = np.asarray(center_rel, dtype=float)
        self.rho = float(rho)
        self.theta0 = float(theta0)
        self.sign = float(sign)
        self.length = self.rho * abs(sweep)
        self.curvature = 1.0 / self.rho

    def derivatives(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        th = self.theta0 + self.sign * s / self.rho
        c, sn = np.cos(th), np.sin(th)
        radial = np.stack([c, sn], axis=1)            # unit vector centre -> point
        tangent = self.sign * np.stack([-sn, c], axis=1)
        g0 = self.c + self.rho * radial
        g1 = tangent
        g2 = -radial / self.rho
        g3 = -tangent / self.rho ** 2
        return g0, g1, g2, g3

    def end_tangent(self) -> np.ndarray:
        th = self.theta0 + self.sign * self.length / self.rho
        return self.sign * np.array([-math.sin(th), math.cos(th)])


@dataclass(frozen=True)
class Move:
    """One move of a path: a geometry and its smooth time law.

    Attributes
    ----------
    t0
        Start time [s].
    ramp
        Ramp time ``T_a`` of the acceleration and of the deceleration [s].
    cruise
        Constant-speed time ``T_c`` [s].
    speed
        Cruise speed ``V`` [m/s].
    geometry
        ``_Line`` or ``_Arc``.
    label
        Name of the waypoint the move ends at.
    """

    t0: float
    ramp: float
    cruise: float
    speed: float
    geometry: object
    label: str

    @property
    def duration(self) -> float:
        return 2.0 * self.ramp + self.cruise

    @property
    def t_end(self) -> float:
        return self.t0 + self.duration

    @property
    def kind(self) -> str:
        return self.geometry.kind  # type: ignore[attr-defined]

    def time_law(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Arc length ``s`` and its first three time derivatives at times ``t`` (module docstring)."""
        ta, tc, v = self.ramp, self.cruise, self.speed
        tau = t - self.t0
        x = np.clip(tau / ta, 0.0, 1.0)
        y = np.clip((tau - ta - tc) / ta, 0.0, 1.0)
        s = v * ta * _S_int(x) + v * np.clip(tau - ta, 0.0, tc) + v * ta * (y - _S_int(y))
        ds = v * (_S(x) - _S(y))
        dds = v / ta * (_S_d1(x) - _S_d1(y))
        ddds = v / ta ** 2 * (_S_d2(x) - _S_d2(y))
        return s, ds, dds, ddds


@dataclass
class Trajectory:
    """A time-parametrised tool path ``p(t)`` in the world x-z plane, continuous up to jerk.

    Build one with :class:`PathBuilder` or a factory of :data:`PATHS`. Before the first move the
    tool rests at :attr:`start`; after :attr:`duration` it rests at the last point.

    Attributes
    ----------
    name
        Path name.
    start
        Start point (x, z) [m].
    moves
        The moves, ordered by start time.
    waypoints
        Every waypoint including the start, (n, 2) [m]; ``waypoint_labels`` names each.
    time_scale
        Speed scale ``sigma``: the path is run ``sigma`` times faster than built
        (``p(t) = P(sigma t)``, so v, a, j scale with sigma, sigma^2, sigma^3).
    """

    name: str
    start: np.ndarray
    moves: list[Move]
    waypoints: np.ndarray
    waypoint_labels: list[str]
    time_scale: float = 1.0
    _t_end: np.ndarray = field(init=False, repr=False)
    _cum: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.start = np.asarray(self.start, dtype=float)
        self.waypoints = np.asarray(self.waypoints, dtype=float)
        self._t_end = np.array([m.t_end for m in self.moves])
        disp = [np.zeros(self.start.shape[0])]
        for m in self.moves:
            g0 = m.geometry.derivatives(np.array([m.geometry.length]))[0][0]  # type: ignore[attr-defined]
            disp.append(disp[-1] + g0)
        self._cum = np.array(disp)          # displacement after k completed moves
        if np.any(np.diff(self._t_end) < -1e-12):
            raise ValueError(f"path '{self.name}': moves must end in order (blend too large)")

    # ---- properties --------------------------------------------------------------------------
    @property
    def duration(self) -> float:
        """Time [s] at which the tool comes to rest at the end of the path (scaled)."""
        return (float(self._t_end[-1]) if self.moves else 0.0) / self.time_scale

    @property
    def end(self) -> np.ndarray:
        """Final resting point (x, z) [m]."""
        return self.start + self._cum[-1]

    def scaled(self, speed_scale: float) -> "Trajectory":
        """The same path run ``speed_scale`` times faster (all times divided by it)."""
        if not (math.isfinite(speed_scale) and speed_scale > 0):
            raise ValueError(f"speed scale must be a positive number, got {speed_scale!r}")
        return Trajectory(self.name, self.start, self.moves, self.waypoints, self.waypoint_labels,
                          self.time_scale * speed_scale)

    def move_intervals(self) -> list[tuple[float, float, Move]]:
        """(start, end, move) of every move in (scaled) time."""
        return [(m.t0 / self.time_scale, m.t_end / self.time_scale, m) for m in self.moves]

    # ---- evaluation --------------------------------------------------------------------------
    def evaluate_many(self, t: np.ndarray | Sequence[float]
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity, acceleration and jerk at every time of ``t``.

        Parameters
        ----------
        t
            Times [s], any order, shape (n,).

        Returns
        -------
        p, v, a, j
            Each of shape (n, 2) [m, m/s, m/s^2, m/s^3]. ``v = dp/dt`` etc.: with
            ``p = g(s(t))``, ``v = g' s'``, ``a = g'' s'^2 + g' s''``,
            ``j = g''' s'^3 + 3 g'' s' s'' + g' s'''``.
        """
        sig = self.time_scale
        tt = np.atleast_1d(np.asarray(t, dtype=float)) * sig
        n_done = np.searchsorted(self._t_end, tt, side="right")
        p = self.start + self._cum[n_done]
        v = np.zeros_like(p)
        a = np.zeros_like(p)
        j = np.zeros_like(p)
        ordered = bool(np.all(tt[1:] >= tt[:-1]))
        for m in self.moves:
            if ordered:     # (a table's grid) t0 < t < t_end is a slice: views, no masks
                at = slice(tt.searchsorted(m.t0, "right"), tt.searchsorted(m.t_end, "left"))
                if at.stop <= at.start:
                    continue
            else:
                at = (tt > m.t0) & (tt < m.t_end)
                if not at.any():
                    continue
            s, ds, dds, ddds = m.time_law(tt[at])
            g0, g1, g2, g3 = m.geometry.derivatives(s)  # type: ignore[attr-defined]
            ds_, dds_, ddds_ = ds[:, None], dds[:, None], ddds[:, None]
            p[at] += g0
            v[at] += g1 * ds_
            a[at] += g2 * ds_ ** 2 + g1 * dds_
            j[at] += g3 * ds_ ** 3 + 3.0 * g2 * ds_ * dds_ + g1 * ddds_
        return p, v * sig, a * sig ** 2, j * sig ** 3

    def evaluate(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity, acceleration and jerk at time ``t``, each of shape (2,)."""
        p, v, a, j = self.evaluate_many(np.array([t], dtype=float))
        return p[0], v[0], a[0], j[0]


class PathBuilder:
    """Build a :class:`Trajectory` move by move.

    Parameters
    ----------
    start
        Start point (x, z) [m]; or a point of any dimension (3-D tool positions, joint
        angles for joint-space moves: :mod:`fmus.robot_plant.trajectory6`), whose moves are
        then straight lines only (speed and acceleration in its units per s).
    speed, accel
        Default cruise speed [m/s] and path acceleration limit [m/s^2] of the moves.
    blend
        Default corner blending in [0, 1]: the next move starts ``blend * min(T_a, T_a')``
        before the previous one ends (0: stop at the waypoint; 1: full velocity blend).
    hold
        Rest time at the start before the first move [s].
    name
        Path name, used in messages.
    start_label
        Name of the start point in messages.

    Examples
    --------
    >>> traj = (PathBuilder((1.2, 0.9), speed=0.2, accel=2.0)
    ...         .line_to((1.3, 0.9)).line_to((1.3, 1.0), dwell=0.1).build())
    """

    def __init__(self, start: Sequence[float], *, speed: float, accel: float, blend: float = 1.0,
                 hold: float = 0.0, name: str = "path", start_label: str = "start") -> None:
        self.name = name
        self._start = np.asarray(start, dtype=float).reshape(-1)
        if self._start.shape[0] < 2 or not np.all(np.isfinite(self._start)):
            raise ValueError(f"path '{name}': start point {tuple(start)} is not finite")
        self._pos = self._start.copy()
        self._speed = self._check_pos("speed", speed)
        self._accel = self._check_pos("accel", accel)
        self._blend = self._check_blend(blend)
        self._hold = float(hold)
        if not (math.isfinite(self._hold) and self._hold >= 0):
            raise ValueError(f"path '{name}': hold must be >= 0, got {hold!r}")
        # pending moves: (geometry, speed, accel, blend_after, dwell_after, label)
        self._pending: list[list] = []
        self._waypoints = [self._start.copy()]
        self._labels = [start_label]

    def _check_pos(self, what: str, value: float) -> float:
        v = float(value)
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"path '{self.name}': {what} must be a positive number, got {value!r}")
        return v

    def _check_blend(self, value: float) -> float:
        b = float(value)
        if not (0.0 <= b <= 1.0):
            raise ValueError(f"path '{self.name}': blend must be in [0, 1], got {value!r}")
        return b

    @property
    def position(self) -> np.ndarray:
        """Current end point of the path being built."""
        return self._pos.copy()

    def line_to(self, p: Sequence[float], *, speed: float | None = None, accel: float | None = None,
                dwell: float = 0.0, blend: float | None = None, label: str | None = None) -> "PathBuilder":
        """Straight move to ``p``; ``dwell`` > 0 stops there for that long (no blending)."""
        target = np.asarray(p, dtype=float).reshape(self._start.shape[0])
        label = label or f"waypoint {len(self._waypoints)} ({', '.join(f'{c:.4g}' for c in target)})"
        if not np.all(np.isfinite(target)):
            raise ValueError(f"path '{self.name}': {label} is not finite")
        delta = target - self._pos
        length = _norm(delta)
        if length < 1e-9:
            # same point again: only a dwell
            return self.dwell(dwell) if dwell > 0 else self
        geom = _Line(delta / length, length)
        self._push(geom, speed, accel, dwell, blend, label, target)
        return self

    def line_by(self, dp: Sequence[float], **kw: object) -> "PathBuilder":
        """Straight move by the offset ``dp`` (see :meth:`line_to`)."""
        return self.line_to(self._pos + np.asarray(dp, dtype=float), **kw)  # type: ignore[arg-type]

    def arc(self, center: Sequence[float], angle: float, *, speed: float | None = None,
            accel: float | None = None, dwell: float = 0.0, blend: float | None = None,
            label: str | None = None) -> "PathBuilder":
        """Circular arc about the absolute point ``center`` through ``angle`` [rad].

        A positive angle turns from +x towards +z; ``2 pi`` is a full circle. The arc's speed is
        limited so that its centripetal acceleration stays below the move's ``accel``.
        """
        if self._start.shape[0] != 2:
            raise ValueError(f"path '{self.name}': arcs are planar (x, z) only")
        c = np.asarray(center, dtype=float).reshape(2)
        rel = self._pos - c
        rho = float(np.hypot(*rel))
        if rho < 1e-6 or not math.isfinite(angle) or angle == 0.0:
            raise ValueError(f"path '{self.name}': degenerate arc (radius {rho:.3g} m, angle {angle!r})")
        theta0 = math.atan2(rel[1], rel[0])
        sign = 1.0 if angle > 0 else -1.0
        geom = _Arc(-rel, rho, theta0, sign, angle)
        th1 = theta0 + angle
        target = c + rho * np.array([math.cos(th1), math.sin(th1)])
        label = label or f"waypoint {len(self._waypoints)} ({target[0]:.4g}, {target[1]:.4g})"
        acc = self._accel if accel is None else self._check_pos("accel", accel)
        v = self._speed if speed is None else self._check_pos("speed", speed)
        v = min(v, math.sqrt(acc * rho))
        self._push(geom, v, acc, dwell, blend, label, target)
        return self

    def circle(self, center: Sequence[float], *, ccw: bool = True, **kw: object) -> "PathBuilder":
        """Full circle about ``center`` back to the current point (see :meth:`arc`)."""
        return self.arc(center, 2 * math.pi if ccw else -2 * math.pi, **kw)  # type: ignore[arg-type]

    def dwell(self, duration: float) -> "PathBuilder":
        """Stop at the current point for ``duration`` seconds (before the next move)."""
        d = float(duration)
        if not (math.isfinite(d) and d >= 0):
            raise ValueError(f"path '{self.name}': dwell must be >= 0, got {duration!r}")
        if not self._pending:
            self._hold += d
        else:
            self._pending[-1][4] += d
            self._pending[-1][3] = 0.0
        return self

    def _push(self, geom: object, speed: float | None, accel: float | None, dwell: float,
              blend: float | None, label: str, target: np.ndarray) -> None:
        v = self._speed if speed is None else self._check_pos("speed", speed)
        acc = self._accel if accel is None else self._check_pos("accel", accel)
        b = self._blend if blend is None else self._check_blend(blend)
        d = float(dwell)
        if not (math.isfinite(d) and d >= 0):
            raise ValueError(f"path '{self.name}': dwell at {label} must be >= 0, got {dwell!r}")
        if d > 0:
            b = 0.0
        self._pending.append([geom, v, acc, b, d, label])
        self._pos = target.copy()
        self._waypoints.append(target.copy())
        self._labels.append(label)

    def repeat(self, n: int) -> "PathBuilder":
        """Append the moves built so far ``n - 1`` more times (the path must be closed)."""
        if n < 1:
            raise ValueError(f"path '{self.name}': repeat count must be >= 1, got {n}")
        if _norm(self._pos - self._start) > 1e-9:
            raise ValueError(f"path '{self.name}': only a closed path can be repeated")
        base = [list(m) for m in self._pending]
        wps, labels = self._waypoints[1:], self._labels[1:]
        for k in range(1, n):
            for m in base:
                self._pending.append(list(m))
            self._waypoints.extend(w.copy() for w in wps)
            self._labels.extend(f"{lab}, loop {k + 1}" for lab in labels)
        return self

    def build(self) -> Trajectory:
        """Schedule the moves in time and return the trajectory."""
        moves: list[Move] = []
        t = self._hold
        prev_ramp = None
        prev_blend = 0.0
        for geom, v, acc, blend, dwell, label in self._pending:
            length = geom.length  # type: ignore[attr-defined]
            ramp = _RAMP_PER_V_OVER_A * v / acc
            if length < v * ramp:          # too short to reach v: triangular velocity profile
                v = math.sqrt(length * acc / _RAMP_PER_V_OVER_A)
                ramp = _RAMP_PER_V_OVER_A * v / acc
                cruise = 0.0
            else:
                cruise = length / v - ramp
            if prev_ramp is not None and prev_blend > 0:
                t -= prev_blend * min(prev_ramp, ramp)
            moves.append(Move(t, ramp, cruise, v, geom, label))
            t = moves[-1].t_end + dwell
            prev_ramp, prev_blend = ramp, blend
        return Trajectory(self.name, self._start, moves, np.array(self._waypoints), list(self._labels))


# ---- the shipped paths -------------------------------------------------------------------------
def _start_or(start: Sequence[float] | None, default: tuple[float, float]) -> np.ndarray:
    return np.asarray(default if start is None else start, dtype=float).reshape(2)


def triangle_p1(start: Sequence[float] | None = None, speed_scale: float = 1.0) -> Trajectory:
    """Path P1 of Henriksson et al. (2009), section IV-A: a triangle with 15-20 cm sides.

    Point-to-point moves at up to 1 m/s, 6 m/s^2, stopping 0.1 s at each vertex, four times
    around after 0.5 s at rest: about 7.6 s. Default start (1.10, 0.80) m; vertices
    start + (0, 0), (0.20, 0), (0.10, 0.15).
    """
    p0 = _start_or(start, (1.10, 0.80))
    b = PathBuilder(p0, speed=1.0, accel=6.0, blend=0.0, hold=0.5, name="p1")
    b.line_to(p0 + (0.20, 0.0), dwell=0.1).line_to(p0 + (0.10, 0.15), dwell=0.1)
    b.line_to(p0, dwell=0.1)
    return b.repeat(4).build().scaled(speed_scale)


def path_p2(start: Sequence[float] | None = None, speed_scale: float = 1.0) -> Trajectory:
    """Path P2 of Henriksson et al. (2009): a smaller motion elsewhere in the workspace.

    A quadrilateral with 8-12 cm sides further out and lower than P1 (default start
    (1.45, 0.55) m), point-to-point at up to 0.8 m/s, 5 m/s^2, 0.1 s stops, three times around
    after 0.5 s at rest: about 6.2 s.
    """
    p0 = _start_or(start, (1.45, 0.55))
    b = PathBuilder(p0, speed=0.8, accel=5.0, blend=0.0, hold=0.5, name="p2")
    b.line_to(p0 + (0.10, 0.02), dwell=0.1).line_to(p0 + (0.08, 0.10), dwell=0.1)
    b.line_to(p0 + (-0.02, 0.08), dwell=0.1).line_to(p0, dwell=0.1)
    return b.repeat(3).build().scaled(speed_scale)


def iso9283(start: Sequence[float] | None = None, speed_scale: float = 1.0) -> Trajectory:
    """ISO 9283-style path of the IMU paper (Fig. 2) at a target tool speed of 200 mm/s.

    From the start A (default (1.00, 0.60) m): 300 mm straight in +x; a full large circle
    (radius 75 mm) above it; 100 mm in +x; 250 mm up; a full small circle (radius 15 mm);
    50 mm up; then a staircase of twenty 90-degree corners (alternately 40 mm in -x and 30 mm
    in -z) back to A. Corners are blended (path acceleration limit 3 m/s^2 per move, up to
    about 4.2 m/s^2 where two moves overlap in a 90-degree corner; the corner zone begins about
    12 mm before each corner); the tool rests 0.5 s at the start and at the end.
    Length about 1.96 m, duration about 10.5 s.
    """
    p0 = _start_or(start, (1.00, 0.60))
    b = PathBuilder(p0, speed=0.2, accel=3.0, blend=1.0, hold=0.5, name="iso9283")
    b.line_by((0.30, 0.0), label="B (end of first straight)")
    b.circle(b.position + (0.0, 0.075), ccw=True, label="B (after large circle)")
    b.line_by((0.10, 0.0), label="C")
    b.line_by((0.0, 0.25), label="D")
    b.circle(b.position + (-0.015, 0.0), ccw=True, label="D (after small circle)")
    b.line_by((0.0, 0.05), label="E")
    for k in range(10):
        b.line_by((-0.04, 0.0), label=f"stair corner {2 * k + 1}")
        b.line_by((0.0, -0.03), label=f"stair corner {2 * k + 2}",
                  dwell=0.5 if k == 9 else 0.0)
    return b.build().scaled(speed_scale)


def square(start: Sequence[float] | None = None, speed_scale: float = 1.0) -> Trajectory:
    """The IMU paper's 30 mm square at 80 mm/s with brief (0.1 s) stops at the corners.

    Default start (1.20, 0.90) m (the home pose); corners start + (0,0), (30,0), (30,30),
    (0,30) mm; acceleration limit 1 m/s^2; twice around after 0.5 s at rest: about 5.5 s.
    """
    p0 = _start_or(start, (1.20, 0.90))
    b = PathBuilder(p0, speed=0.08, accel=1.0, blend=0.0, hold=0.5, name="square")
    for d in ((0.03, 0.0), (0.03, 0.03), (0.0, 0.03), (0.0, 0.0)):
        b.line_to(p0 + d, dwell=0.1)
    return b.repeat(2).build().scaled(speed_scale)


# ---- CSV waypoints -----------------------------------------------------------------------------
CSV_DEFAULT_SPEED = 0.2
CSV_DEFAULT_ACCEL = 2.0


def from_csv(path: str | Path, start: Sequence[float] | None = None, speed_scale: float = 1.0, *,
             speed: float = CSV_DEFAULT_SPEED, accel: float = CSV_DEFAULT_ACCEL) -> Trajectory:
    """A path through user waypoints read from a CSV file.

    Format: UTF-8 text; ``#`` starts a comment (whole line or end of line); blank lines are
    ignored. The first remaining line is a header naming the columns, in any order:

    * ``x, z`` (required): waypoint position in the world frame [m];
    * ``speed`` (optional): cruise speed of the move *to* this waypoint [m/s] (default 0.2);
    * ``accel`` (optional): path acceleration limit of that move [m/s^2] (default 2);
    * ``dwell`` (optional): rest time at this waypoint [s]; 0 or empty blends through the
      corner, > 0 stops there ("fine point");
    * or ``t`` (instead of speed/accel/dwell): arrival time of the waypoint [s], strictly
      increasing; each move is then rest-to-rest and fills the time to its waypoint, a third of
      it accelerating and a third decelerating. The first row's ``t`` is the start of motion.

    The first data row is the start point (its speed is ignored, its dwell is the rest before
    the motion). Empty cells take the default. Example::

        # square with stops
        x, z, speed, dwell
        1.20, 0.90, , 0.5
        1.30, 0.90, 0.2, 0.1
        1.30, 1.00, , 0.1

    Parameters
    ----------
    path
        CSV file.
    start
        If given, the path is translated so that it starts there.
    speed_scale
        Time scaling of the whole path (see :meth:`Trajectory.scaled`).
    speed, accel
        Defaults for empty cells.

    Raises
    ------
    ValueError
        For a missing file or a malformed row, naming the file and the line.
    """
    fname = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise ValueError(f"waypoint file '{fname}' cannot be read: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise ValueError(f"waypoint file '{fname}' is not UTF-8 text") from None

    rows: list[tuple[int, list[str]]] = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        content = line.split("#", 1)[0].strip()
        if content:
            cells = next(csv.reader([content]))
            rows.append((lineno, [c.strip() for c in cells]))
    if not rows:
        raise ValueError(f"waypoint file '{fname}': no header line (expected e.g. 'x,z,speed,dwell')")
    head_line, header = rows[0]
    cols = [h.lower() for h in header]
    allowed = {"t", "x", "z", "speed", "accel", "dwell"}
    for i, c in enumerate(cols, start=1):
        if c not in allowed:      # the cell is not quoted: the file may be anything (issue 14)
            raise ValueError(f"{fname}, line {head_line}: field {i} of the header is no known column "
                             f"(allowed: x, z, speed, accel, dwell, or t, x, z)")
    if len(set(cols)) != len(cols):
        raise ValueError(f"{fname}, line {head_line}: a column is named twice in the header")
    if "x" not in cols or "z" not in cols:
        raise ValueError(f"{fname}, line {head_line}: the header must name columns 'x' and 'z'")
    timed = "t" in cols
    if timed and set(cols) & {"speed", "accel", "dwell"}:
        raise ValueError(f"{fname}, line {head_line}: column 't' cannot be combined with "
                         f"speed/accel/dwell")

    data: list[tuple[int, dict[str, float | None]]] = []
    for lineno, cells in rows[1:]:
        if len(cells) != len(cols):
            raise ValueError(f"{fname}, line {lineno}: {len(cells)} values, the header has {len(cols)}")
        rec: dict[str, float | None] = {}
        for c, cell in zip(cols, cells):
            if cell == "":
                if c in ("x", "z") or (c == "t"):
                    raise ValueError(f"{fname}, line {lineno}: column '{c}' is empty")
                rec[c] = None
                continue
            try:
                val = float(cell)
            except ValueError:
                raise ValueError(f"{fname}, line {lineno}: column '{c}' is not a number") from None
            if not math.isfinite(val):
                raise ValueError(f"{fname}, line {lineno}: column '{c}' is not finite")
            if c in ("speed", "accel") and val <= 0:
                raise ValueError(f"{fname}, line {lineno}: {c} must be > 0, got {cell}")
            if c == "dwell" and val < 0:
                raise ValueError(f"{fname}, line {lineno}: dwell must be >= 0, got {cell}")
            rec[c] = val
        data.append((lineno, rec))
    if len(data) < 2:
        raise ValueError(f"waypoint file '{fname}': needs at least two waypoints (start and one more), "
                         f"found {len(data)}")

    first = np.array([data[0][1]["x"], data[0][1]["z"]], dtype=float)
    shift = np.zeros(2) if start is None else np.asarray(start, dtype=float).reshape(2) - first
    name = f"csv:{Path(fname).name}"

    def where(lineno: int, rec: dict) -> str:
        return f"{fname}, line {lineno} ({rec['x']:.4g}, {rec['z']:.4g})"

    if timed:
        t_prev = float(data[0][1]["t"])  # type: ignore[arg-type]
        if t_prev < 0:
            raise ValueError(f"{fname}, line {data[0][0]}: t must be >= 0, got {t_prev}")
        b = PathBuilder(first + shift, speed=1.0, accel=1.0, blend=0.0, hold=t_prev, name=name,
                        start_label=where(*data[0]))
        for lineno, rec in data[1:]:
            t_k = float(rec["t"])  # type: ignore[arg-type]
            span = t_k - t_prev
            if span <= 0:
                raise ValueError(f"{fname}, line {lineno}: t = {t_k:g} must be larger than the "
                                 f"previous waypoint's t = {t_prev:g}")
            target = np.array([rec["x"], rec["z"]], dtype=float) + shift
            length = float(np.hypot(*(target - b.position)))
            if length < 1e-9:
                b.dwell(span)
            else:
                # rest-to-rest in exactly `span`: ramps of span/3, cruise span/3
                v = 1.5 * length / span
                acc = _RAMP_PER_V_OVER_A * v / (span / 3.0)
                b.line_to(target, speed=v, accel=acc, blend=0.0, label=where(lineno, rec))
            t_prev = t_k
        return b.build().scaled(speed_scale)

    hold = data[0][1].get("dwell") or 0.0
    b = PathBuilder(first + shift, speed=speed, accel=accel, blend=1.0, hold=float(hold), name=name,
                    start_label=where(*data[0]))
    for lineno, rec in data[1:]:
        target = np.array([rec["x"], rec["z"]], dtype=float) + shift
        b.line_to(target, speed=rec.get("speed"), accel=rec.get("accel"),
                  dwell=rec.get("dwell") or 0.0, label=where(lineno, rec))
    return b.build().scaled(speed_scale)


PathFactory = Callable[..., Trajectory]

#: Shipped paths by name; each factory takes ``(start=None, speed_scale=1.0)``, except
#: ``"csv"`` which takes the file first: ``from_csv(path, start=None, speed_scale=1.0)``.
PATHS: dict[str, PathFactory] = {
    "p1": triangle_p1,
    "p2": path_p2,
    "iso9283": iso9283,
    "square": square,
    "csv": from_csv,
}


def make_path(name: str, start: Sequence[float] | None = None, speed_scale: float = 1.0,
              csv_file: str | Path = "") -> Trajectory:
    """The path ``name`` of :data:`PATHS` (``csv_file`` is needed for ``"csv"``).

    Raises
    ------
    ValueError
        Unknown name, missing/malformed CSV file, or a bad speed scale.
    """
    if name not in PATHS:
        raise ValueError(f"unknown path '{name}' (known: {', '.join(PATHS)})")
    if name == "csv":
        if not str(csv_file):
            raise ValueError("path 'csv' needs a waypoint file (csv_file is empty)")
        return from_csv(csv_file, start, speed_scale)
    return PATHS[name](start, speed_scale)


__all__ = ["Move", "Trajectory", "PathBuilder", "PATHS", "make_path", "triangle_p1", "path_p2",
           "iso9283", "square", "from_csv"]

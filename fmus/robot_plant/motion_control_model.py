"""Motion control of the flexible two-axis robot: arm reference, feed-forward and motor PID.

What a real robot controller does, in three layers (the MotionController FMU is a thin adapter):

1. **Arm reference** (setup). The Cartesian tool path ``p(t)`` of :mod:`trajectory` is
   sampled on a fine grid (0.5 ms) and mapped through the closed-form inverse kinematics of the
   planar arm to the arm angles ``q_a_ref``. Their derivatives are exact, not numerical: with
   ``theta_1 = q_1``, ``theta_12 = q_1 + q_2`` and ``p = l1 u(theta_1) + l2 w(theta_12)``,
   ``u = (sin, cos)``, ``w = (cos, -sin)``, differentiating ``p`` three times gives linear
   equations ``K(theta) d^k theta = rhs_k`` for velocity, acceleration and jerk (the Jacobian
   ``K`` and the known lower-order terms; see :func:`arm_reference`). The arm jerk reference
   ``dddq_a_ref`` is the EKF input ``u_t`` of Axelsson et al. (2012), eqs. 13-14.
2. **Feed-forward** (setup). Rigid-body inverse dynamics gives the torque the gearbox must
   deliver to the arm, ``tau_a = M(q) ddq + C(q, dq) dq + g(q)`` (2012 paper, eq. 11, left
   side). The flexible-joint correction solves the gearbox spring-damper law
   ``tau_s(D) + d dD/dt = tau_a`` for the deflection ``D`` (nonlinear spring inverted by
   Newton's method, damping by fixed-point iteration), so that the motor reference
   ``q_m_ref = r (q_a_ref + D)`` makes the *arm*, not only the motor, follow the path
   (the relation behind eq. 16 of the 2012 paper). The motor torque feed-forward is the motor
   equation (eq. 10) along that reference,
   ``tau_ff = J_m ddq_m_ref + f(dq_m_ref) + tau_arm / r``. ``dD/dt`` and ``d^2D/dt^2``
   are differentiated numerically on the grid (second-order central differences).
3. **Motor PID** (run time, per joint, motor side):
   ``tau_m = tau_ff + K_p (e + I / T_i) + K_d de/dt``, ``e = q_m_ref - q_m``,
   ``de/dt = dq_m_ref_hat - dq_m_hat``, ``I = integral of e``, saturated at ``tau_max`` with
   conditional integration (no wind-up). ``q_m`` is the drive's encoder reading; the drive
   forms its speed ``dq_m_hat`` from it as a servo drive does (:class:`MotionController`):
   the backward difference of two consecutive readings, ``d_k = (q_k - q_{k-1}) / h`` over
   the servo period ``h`` (the controller's step), through a first-order low-pass of cut-off
   ``f_c`` (``velocity_cutoff``), discretised exactly for a difference held over the period:
   ``dq_m_hat_k = dq_m_hat_{k-1} + (1 - exp(-2 pi f_c h)) (d_k - dq_m_hat_{k-1})``. This is
   the fixed-time velocity estimate of Brown, Schneider and Mulligan (1992), "Analysis of
   algorithms for velocity estimation from discrete position versus time data", IEEE Trans.
   Industrial Electronics 39(1), with the first-order velocity-feedback filter of servo drives
   (e.g. the Moog DS2110 drive manual, section 5.11.2.5: a first-order low-pass on the motor
   feedback velocity closes the velocity loop, default cut-off a quarter of the velocity-loop
   rate; Synapticon's drive documentation recommends 500 Hz as a first-order starting point).
   The default 250 Hz is a quarter of the 1 kHz servo rate: it adds 0.64 ms of lag to the
   0.5 ms half-period of the difference (1.6 degrees of phase at the 4 Hz position loop,
   5 degrees at the 13 Hz motor-inertia velocity loop ``K_d / J_m``) and lowers the
   differentiated quantisation and noise of the default encoder (16-bit resolver, 2e-5 rad
   noise, read at 1 kHz) from 0.050 to 0.036 rad/s RMS (0.015 N m of torque through
   ``K_d``). The papers (Henriksson et al. 2009; Axelsson et al. 2012) use the measured motor
   angles but do not say how their drive forms its speed. The first reading after the start
   gives no difference: the estimate starts at 0
   (the robot starts at rest). The derivative term compares like with like: the motor
   reference angle (of the nominal path) passes through the same difference and filter, so
   ``de/dt`` is the filtered derivative of the error, the derivative filter of a PID
   (Astrom & Hagglund, *Advanced PID Control*, ISA 2006, sec. 3.3), and the filter's lag
   acts on the error only: compared with the tabulated exact ``dq_m_ref`` the lag would add
   ``K_d tau a_m`` of torque against every motor acceleration ``a_m`` (measured on a
   corner path with an exact model: tool tracking RMS 3.7x that of a drive given the true
   speed; with the matched reference 1.01x; in the shipped scenarios tracking within 0.2 % of
   the drive given the plant's true angle and speed, flagship 0.2825 mm either way). In a
   co-simulation step the reading is paired with the reference of the time of the torque the
   step outputs (:meth:`MotionController.step`): paired one step earlier, the mismatch acts
   as a spurious derivative action (flagship tracking then +0.2 %, 2009 P1 -13 %).
   The default gains give a motor-position loop of about 4 Hz bandwidth, damping 1 on the
   rigid (motor + reflected arm) inertia - well below the 8-15 Hz gearbox resonances, as on a
   real robot, so the arm's flexible modes are excited by the path and lightly damped.

4. **Identification excitation** (optional, :class:`Multisine`): a random-phase multisine
   torque added to the PID output before the torque limit, as a robot controller's
   identification mode does (Wernholt & Gunnarsson 2008; Moberg et al. 2014).

At run time everything is one linear interpolation in the precomputed table (a few
microseconds).

**Cartesian offset** ``dp_ref`` (from an impedance controller) is added to the path: the arm
reference is corrected by a Gauss-Newton step ``dq = J^-1 dp`` with the tabulated inverse
Jacobian, refined by one Newton iteration of the exact kinematics when ``|dp| > 0.1 mm`` (the
residual is then below 1e-9 m for offsets up to a few cm). The motor reference moves by
``r dq``; the velocity references and the feed-forward are those of the nominal path (the
offset is a slowly varying correction, as on a real robot's path-correction interface).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from fmus.common import disk_cache, dynamics, kinematics
from fmus.common.jit import bundle_id, kernel
from fmus.common.parameters import ParameterError, as_array, param
from fmus.common.robot_params import RobotParameters
from fmus.robot_plant.trajectory import PATHS, Trajectory, make_path

# ---- grid and reach --------------------------------------------------------------------------
DT_GRID = 5e-4          #: reference table resolution [s]
T_MARGIN = 1.0          #: table length after the path has ended [s]
SIN_Q2_MAX = 0.98       #: |sin q2| limit: keeps 11 deg away from the stretched/folded arm
TABLES_KEPT = 16        #: reference tables kept in the disk cache (about 5 MB for 11 s of path)
MAX_PATH_DURATION = 1200.0  #: longest path tabulated [s]: its table is 2.4 M rows of 208 bytes, 0.5 GB

# Default PID gains (motor side), see MotionControllerParameters.
DEFAULT_KP = (5.3, 3.9)
DEFAULT_KD = (0.42, 0.31)
DEFAULT_TI = (0.16, 0.16)
DEFAULT_VELOCITY_CUTOFF = 250.0  #: cut-off of the drive's velocity filter [Hz] (module docstring)


def arm_reference(p: np.ndarray, v: np.ndarray, a: np.ndarray, j: np.ndarray, l1: float, l2: float
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Arm angles and their first three derivatives along a Cartesian tool trajectory.

    Exact differentiation of ``p = l1 u(theta_1) + l2 w(theta_12)`` (module docstring):
    with ``K = [l1 u'(theta_1), l2 w'(theta_12)]`` (the Jacobian w.r.t. the absolute link
    angles), ``u'' = -u``, ``w'' = -w``::

        K dtheta   = v
        K ddtheta  = a + l1 u dth1^2 + l2 w dth12^2
        K dddtheta = j + l1 (3 u dth1 ddth1 + u' dth1^3) + l2 (3 w dth12 ddth12 + w' dth12^3)

    and ``q = (theta_1, theta_12 - theta_1)``. The jerk ``dddq`` is the EKF input of
    Axelsson et al. (2012), eqs. 13-14.

    Parameters
    ----------
    p, v, a, j
        (n, 2) tool position [m], velocity, acceleration and jerk in the world x-z plane.
    l1, l2
        Link lengths [m].

    Returns
    -------
    q, dq, ddq, dddq
        (n, 2) each [rad, rad/s, rad/s^2, rad/s^3].
    """
    q, _ = kinematics.inverse_kinematics_many(p, l1, l2)
    th1, th12 = q[:, 0], q[:, 0] + q[:, 1]
    s1, c1, s12, c12 = np.sin(th1), np.cos(th1), np.sin(th12), np.cos(th12)
    u = np.stack([s1, c1], 1)
    du = np.stack([c1, -s1], 1)
    w = np.stack([c12, -s12], 1)
    dw = np.stack([-s12, -c12], 1)
    # K = [[k00, k01], [k10, k11]]; solve by the explicit 2x2 inverse (vectorised)
    k00, k10 = l1 * du[:, 0], l1 * du[:, 1]
    k01, k11 = l2 * dw[:, 0], l2 * dw[:, 1]
    det = k00 * k11 - k01 * k10

    def solve(rhs: np.ndarray) -> np.ndarray:
        return np.stack([(k11 * rhs[:, 0] - k01 * rhs[:, 1]) / det,
                         (-k10 * rhs[:, 0] + k00 * rhs[:, 1]) / det], 1)

    dth = solve(v)
    d1, d12 = dth[:, :1], dth[:, 1:]
    ddth = solve(a + l1 * u * d1 ** 2 + l2 * w * d12 ** 2)
    dd1, dd12 = ddth[:, :1], ddth[:, 1:]
    dddth = solve(j + l1 * (3.0 * u * d1 * dd1 + du * d1 ** 3) + l2 * (3.0 * w * d12 * dd12 + dw * d12 ** 3))

    def to_q(th: np.ndarray) -> np.ndarray:
        return np.stack([th[:, 0], th[:, 1] - th[:, 0]], 1)

    return q, to_q(dth), to_q(ddth), to_q(dddth)


# ---- the controller ---------------------------------------------------------------------------
@dataclass(frozen=True)
class PidGains:
    """Motor-side PID gains per joint (arrays of shape (2,)).

    ``tau = tau_ff + kp (e + I / ti) + kd de/dt``; ``ti = 0`` disables the integral action;
    the total torque is limited to ``+-tau_max``.
    """

    kp: np.ndarray
    kd: np.ndarray
    ti: np.ndarray
    tau_max: np.ndarray

    @classmethod
    def from_values(cls, kp: Sequence[float], kd: Sequence[float], ti: Sequence[float],
                    tau_max: Sequence[float]) -> "PidGains":
        """Gains from per-joint sequences: ``kp`` (N m/rad), ``kd`` (N m s/rad), integral time
        ``ti`` (s, 0 = no integral action) and torque limit ``tau_max`` (N m), motor side."""
        return cls(*(np.array(x, dtype=float).reshape(2) for x in (kp, kd, ti, tau_max)))


class ReachError(ValueError):
    """A waypoint or path point the arm cannot reach; the message names it."""


class PathTooLong(ValueError):
    """A path longer than :data:`MAX_PATH_DURATION` (its reference table would not fit)."""


# columns of the reference table
_P, _V, _A = slice(0, 2), slice(2, 4), slice(4, 6)
_Q, _DQ, _DDQ, _DDDQ = slice(6, 8), slice(8, 10), slice(10, 12), slice(12, 14)
_QM, _DQM, _TFF, _TARM = slice(14, 16), slice(16, 18), slice(18, 20), slice(20, 22)
_JINV = slice(22, 26)
_NCOL = 26
#: Columns of a reference-table row (:meth:`MotionControlModel.sample`), by name.
COLUMNS: dict[str, slice] = {
    "p_ref": _P, "v_ref": _V, "a_ref": _A, "q_a_ref": _Q, "dq_a_ref": _DQ, "ddq_a_ref": _DDQ,
    "dddq_a_ref": _DDDQ, "q_m_ref": _QM, "dq_m_ref": _DQM, "tau_ff": _TFF, "tau_arm": _TARM,
    "jacobian_inv": _JINV,
}


def _many(fn, n: int, *arrays: np.ndarray) -> np.ndarray:
    """Apply a per-point model function to (n, 2) arrays: vectorised if it broadcasts, else a loop.

    The vectorised result is accepted only if it has shape (n, 2) and matches the per-point call
    on the first and last points.
    """
    try:
        with np.errstate(all="ignore"):
            out = np.asarray(fn(*arrays), dtype=float)
        if out.shape == (n, 2):
            for k in (0, n - 1):
                if not np.allclose(out[k], fn(*(a[k] for a in arrays)), rtol=1e-12, atol=1e-12):
                    break
            else:
                return out
    except Exception:  # noqa: BLE001 - fall back to the per-point loop below
        pass
    return np.array([fn(*(a[k] for a in arrays)) for k in range(n)], dtype=float).reshape(n, 2)


class _RobotView:
    """What the feed-forward needs from the robot model, vectorised over a grid (n, 2).

    A thin wrapper of :mod:`fmus.common.dynamics` for the parameters ``robot``.
    """

    def __init__(self, robot: RobotParameters) -> None:
        self.robot = robot
        self.l1, self.l2 = float(robot.l1), float(robot.l2)
        self.r = as_array(robot.gear_ratio)
        self.jm = as_array(robot.J_m)
        self.d = as_array(robot.d)

    def arm_torque(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """Rigid arm inverse dynamics ``M(q) ddq + C(q, dq) dq + g(q)`` (2012 paper, eq. 11)."""
        return _many(lambda a, b, c: dynamics.inverse_dynamics_rigid(a, b, c, self.robot), q.shape[0], q, dq, ddq)

    def spring(self, defl: np.ndarray) -> np.ndarray:
        """Gearbox spring torque (arm side) at the deflection ``D = q_m/r - q_a`` (no damping)."""
        zero = np.zeros_like(defl)
        return _many(lambda q, qm: dynamics.spring_torque(q, qm, self.robot), defl.shape[0], zero, self.r * defl)

    def motor_friction(self, dq_m: np.ndarray) -> np.ndarray:
        """Motor friction torque at the motor speed ``dq_m`` (motor side)."""
        return _many(lambda w: dynamics.motor_friction(w, self.robot), dq_m.shape[0], dq_m)


class MotionControlModel:
    """Precomputed references and feed-forward along a path, and the motor PID law.

    Parameters
    ----------
    trajectory
        The Cartesian tool path.
    robot
        The robot parameters the controller's model uses (may differ from the plant's).
    gains
        PID gains.
    dt_grid
        Table resolution [s].

    Raises
    ------
    ReachError
        If a waypoint or a point of the path is out of the arm's reach, naming it.
    PathTooLong
        If the path lasts longer than :data:`MAX_PATH_DURATION` (e.g. a move at a speed of
        1e-12 m/s), before anything is allocated.
    """

    def __init__(self, trajectory: Trajectory, robot: RobotParameters, gains: PidGains,
                 dt_grid: float = DT_GRID) -> None:
        self.trajectory = trajectory
        self.robot = robot
        self.gains = gains
        self.view = _RobotView(robot)
        self.l1, self.l2 = self.view.l1, self.view.l2
        self.r = self.view.r
        self.dt = float(dt_grid)
        if not trajectory.duration <= MAX_PATH_DURATION:          # (also NaN)
            raise PathTooLong(f"path '{trajectory.name}' lasts {trajectory.duration:.4g} s, longer than "
                              f"the {MAX_PATH_DURATION:g} s the controller tabulates (its references "
                              f"every {self.dt * 1e3:g} ms); is a speed or an acceleration too small?")
        self._check_waypoints()
        n = int(math.ceil((trajectory.duration + T_MARGIN) / self.dt)) + 2
        self.t_grid = np.arange(n) * self.dt
        self.table = disk_cache.cached_array("tables", self.table_key(), (n, _NCOL),
                                             lambda: self._build_table(self.t_grid), TABLES_KEPT)

    # ---- setup ---------------------------------------------------------------------------------
    def table_key(self) -> str:
        """The reference table's key in the disk cache (:mod:`fmus.common.disk_cache`): all it
        is computed from (the path, the robot model, the grid; the gains play no part), the
        code (the package's bundle id: a hash of its sources) and numpy's version and machine,
        whose elementary functions it calls. Building a table takes 0.05-0.1 s of a run's
        start-up; reading it back a few milliseconds."""
        import platform
        return disk_cache.content_key(bundle_id(), np.__version__, platform.machine(), self.trajectory,
                                      self.robot, self.dt, self.t_grid.shape[0])

    def _reach_problem(self, p: np.ndarray) -> np.ndarray:
        """Boolean mask of points out of reach (with the singularity margin)."""
        _, s2 = kinematics.inverse_kinematics_many(np.atleast_2d(p), self.l1, self.l2)
        return ~(np.abs(s2) <= SIN_Q2_MAX)

    def _reach_text(self) -> str:
        lo = math.sqrt(self.l1 ** 2 + self.l2 ** 2 - 2 * self.l1 * self.l2 * SIN_Q2_MAX)
        hi = math.sqrt(self.l1 ** 2 + self.l2 ** 2 + 2 * self.l1 * self.l2 * SIN_Q2_MAX)
        return f"the arm (l1 = {self.l1:g} m, l2 = {self.l2:g} m) reaches {lo:.3f} m to {hi:.3f} m from joint 2"

    def _check_waypoints(self) -> None:
        tr = self.trajectory
        bad = self._reach_problem(tr.waypoints)
        if bad.any():
            k = int(np.argmax(bad))
            w = tr.waypoints[k]
            raise ReachError(f"path '{tr.name}': {tr.waypoint_labels[k]} at ({w[0]:.4g}, {w[1]:.4g}) m is "
                             f"out of reach ({math.hypot(*w):.3f} m from joint 2; {self._reach_text()})")

    def _check_points(self, t: np.ndarray, p: np.ndarray) -> None:
        bad = self._reach_problem(p)
        if bad.any():
            k = int(np.argmax(bad))
            tk = t[k]
            label = "the path"
            for t0, t1, m in self.trajectory.move_intervals():
                if t0 <= tk <= t1:
                    label = f"the move to {m.label}"
                    break
            raise ReachError(f"path '{self.trajectory.name}': the point ({p[k, 0]:.4g}, {p[k, 1]:.4g}) m at "
                             f"t = {tk:.3f} s on {label} is out of reach ({self._reach_text()})")

    def _deflection(self, tau: np.ndarray, D0: np.ndarray | None = None) -> np.ndarray:
        """Solve ``spring(D) = tau`` elementwise (Newton's method with the analytic slope,
        :func:`fmus.common.dynamics.spring_deflection`, from ``D0`` if given)."""
        return dynamics.spring_deflection(tau, self.view.robot, D0)

    def _build_table(self, t: np.ndarray) -> np.ndarray:
        tr, view = self.trajectory, self.view
        p, v, a, j = tr.evaluate_many(t)
        self._check_points(t, p)
        q, dq, ddq, dddq = arm_reference(p, v, a, j, self.l1, self.l2)
        tau_arm = view.arm_torque(q, dq, ddq)
        # gearbox: spring(D) + d dD/dt = tau_arm  (fixed point on the small damping term)
        defl = self._deflection(tau_arm)
        for _ in range(3):
            ddefl = np.gradient(defl, self.dt, axis=0, edge_order=2)
            defl = self._deflection(tau_arm - view.d * ddefl, defl)
        ddefl = np.gradient(defl, self.dt, axis=0, edge_order=2)
        dddefl = np.gradient(ddefl, self.dt, axis=0, edge_order=2)
        r = self.r
        qm = r * (q + defl)
        dqm = r * (dq + ddefl)
        ddqm = r * (ddq + dddefl)
        tau_ff = view.jm * ddqm + view.motor_friction(dqm) + (view.spring(defl) + view.d * ddefl) / r
        jinv = np.linalg.inv(kinematics.jacobian_many(q, self.l1, self.l2)).reshape(-1, 4)
        table = np.empty((t.shape[0], _NCOL))
        for sl, val in ((_P, p), (_V, v), (_A, a), (_Q, q), (_DQ, dq), (_DDQ, ddq), (_DDDQ, dddq),
                        (_QM, qm), (_DQM, dqm), (_TFF, tau_ff), (_TARM, tau_arm), (_JINV, jinv)):
            table[:, sl] = val
        return table

    # ---- run time --------------------------------------------------------------------------------
    @property
    def q_a_ref0(self) -> np.ndarray:
        """Arm reference at t = 0 (set the plant's initial arm angles ``q_a0`` to this)."""
        return self.table[0, _Q].copy()

    def sample(self, t: float) -> np.ndarray:
        """The table row at time ``t`` (linear interpolation; held before 0 and after the end).

        Columns: p(2), v(2), a(2), q_a(2), dq_a(2), ddq_a(2), dddq_a(2), q_m(2), dq_m(2),
        tau_ff(2), tau_arm(2), J^-1 (4, row-major).
        """
        row = np.empty(_NCOL)
        _table_row(self.table, self.dt, t, row)
        return row

    def offset_arm_angles(self, row: np.ndarray, dp: np.ndarray) -> np.ndarray:
        """Change of the arm reference of the table ``row`` (:meth:`sample`) that moves the tool
        by ``dp`` (m, world x and z; module docstring)."""
        return np.array(_offset_arm_angles(row, float(dp[0]), float(dp[1]), self.l1, self.l2))


# ---- the run-time law, compiled ----------------------------------------------------------------
@kernel(aot="none(float64[:, :], float64, float64, float64[:])")
def _table_row(table, dt, t, row):
    """Row of the reference ``table`` (resolution ``dt``) at time ``t`` into ``row``: linear
    interpolation, held before 0 and after the end (:meth:`MotionControlModel.sample`)."""
    x = t / dt
    last = table.shape[0] - 1
    held = 0 if x <= 0.0 else (last if int(x) >= last else -1)
    for c in range(table.shape[1]):             # loops, not slices: faster to compile
        if held >= 0:
            row[c] = table[held, c]
        else:
            i = int(x)
            r0 = table[i, c]
            row[c] = r0 + (x - i) * (table[i + 1, c] - r0)


@kernel(aot="UniTuple(float64, 2)(float64[:], float64, float64, float64, float64)")
def _offset_arm_angles(row, dp0, dp1, l1, l2):
    """Change of the arm reference of the table ``row`` that moves the tool by ``(dp0, dp1)``
    (m): the tabulated inverse Jacobian, then one exact Newton step of the forward kinematics
    when ``|dp| > 0.1 mm`` (module docstring)."""
    dq0 = row[22] * dp0 + row[23] * dp1
    dq1 = row[24] * dp0 + row[25] * dp1
    if dp0 * dp0 + dp1 * dp1 > 1e-8:
        q0, q1 = row[6] + dq0, row[7] + dq1
        x, z = kinematics.tool_point(q0, q1, l1, l2)
        res_x = row[0] + dp0 - x
        res_z = row[1] + dp1 - z
        j00, j01, j10, j11 = kinematics.tool_jacobian(q0, q1, l1, l2)
        det = j00 * j11 - j01 * j10
        dq0 += (j11 * res_x - j01 * res_z) / det
        dq1 += (-j10 * res_x + j00 * res_z) / det
    return dq0, dq1


# MotionController's state, one float array (a kernel call costs about 0.1 us per array it
# takes): the table row, the law's results (q_a_ref, q_m_ref, p_ref, error, tau, wind-up
# direction: 2 each), the integral of the error, the law's constants (kp, kd, kp / ti,
# tau_max, gear ratios: 2 each, l1, l2), the drive's speeds (the last encoder reading, the
# filtered speed: 2 each, the time of the last reading, NaN before the first, the filter's
# 2 pi f_c, 0: no filter; the last reference angle, the filtered reference speed, the law's
# speed: 2 each)
_ROW, _OUT, _INTEGRAL, _K, _VEL, _WORK = 0, _NCOL, _NCOL + 12, _NCOL + 14, _NCOL + 26, _NCOL + 38


@kernel(aot="boolean(float64[:, :], float64, float64, boolean, float64[:], float64[:], float64[:], float64[:], "
            "float64[:])")
def _control_law(table, dt, t, resample, work, q_m, dq_m, dp, excitation):
    """:meth:`MotionController.evaluate` on floats: the row at ``t`` (when ``resample``), the
    references moved by the offset ``dp``, the error and the limited PID torque into the
    results of ``work`` (the state's layout above); ``excitation``: an added torque or empty.
    Returns whether the limit acted."""
    row, out, integral, k = work[_ROW:_OUT], work[_OUT:_INTEGRAL], work[_INTEGRAL:_K], work[_K:_VEL]
    if resample:
        _table_row(table, dt, t, row)
    qa0, qa1, qr0, qr1 = row[6], row[7], row[14], row[15]
    if dp[0] != 0.0 or dp[1] != 0.0:
        dq0, dq1 = _offset_arm_angles(row, dp[0], dp[1], k[10], k[11])
        qa0, qa1 = qa0 + dq0, qa1 + dq1
        qr0, qr1 = qr0 + k[8] * dq0, qr1 + k[9] * dq1
    out[0], out[1], out[2], out[3] = qa0, qa1, qr0, qr1
    out[4], out[5] = row[0] + dp[0], row[1] + dp[1]
    e0, e1 = qr0 - q_m[0], qr1 - q_m[1]
    out[6], out[7] = e0, e1
    u0 = row[18] + k[0] * e0 + k[2] * (row[16] - dq_m[0])
    u1 = row[19] + k[1] * e1 + k[3] * (row[17] - dq_m[1])
    if k[4] != 0.0 or k[5] != 0.0:
        u0 += k[4] * integral[0]
        u1 += k[5] * integral[1]
    if excitation.size:
        u0 += excitation[0]
        u1 += excitation[1]
    m0, m1 = k[6], k[7]
    saturated = abs(u0) > m0 or abs(u1) > m1
    out[10], out[11] = 0.0, 0.0
    if saturated:
        t0, t1 = min(max(u0, -m0), m0), min(max(u1, -m1), m1)
        out[10], out[11] = np.sign(u0 - t0), np.sign(u1 - t1)
        u0, u1 = t0, t1
    out[8], out[9] = u0, u1
    return saturated


@kernel(aot="void(float64[:], boolean, float64)")
def _integrate(work, saturated, dt):
    """:meth:`MotionController.advance`: the integral of the error over ``dt``, not in the
    wind-up direction of a limit that acted (the same numbers; ``work``: the state)."""
    for i in range(2):
        e = work[_OUT + 6 + i]
        if not saturated:
            work[_INTEGRAL + i] += e * dt
        elif work[_OUT + 10 + i] * e > 0:
            work[_INTEGRAL + i] += 0.0
        else:
            work[_INTEGRAL + i] += e * dt


@kernel(aot="void(float64[:], float64, float64[:], float64[:])")
def _measure_velocity(work, t, q_m, q_ref):
    """:meth:`MotionController.measure`: the encoder reading ``q_m`` taken at ``t`` into the
    drive's speed estimate of ``work`` (the state's layout above), the reference angle
    ``q_ref`` of ``t`` into the reference speed the same way: the backward difference over the
    time since the last reading through the first-order low-pass (module docstring). The first
    reading only primes the differences (both speeds stay 0); a reading at the last one's time
    or before changes nothing."""
    t_last = work[_VEL + 4]
    if t_last != t_last:                 # NaN: the first reading
        for i in range(2):
            work[_VEL + i], work[_VEL + 6 + i] = q_m[i], q_ref[i]
        work[_VEL + 4] = t
        return
    h = t - t_last
    if not h > 0.0:
        return
    w = work[_VEL + 5]
    gain = 1.0 if w <= 0.0 else 1.0 - math.exp(-w * h)
    for i in range(2):
        d = (q_m[i] - work[_VEL + i]) / h
        work[_VEL + 2 + i] += gain * (d - work[_VEL + 2 + i])
        work[_VEL + i] = q_m[i]
        d = (q_ref[i] - work[_VEL + 6 + i]) / h
        work[_VEL + 8 + i] += gain * (d - work[_VEL + 8 + i])
        work[_VEL + 6 + i] = q_ref[i]
    work[_VEL + 4] = t


@kernel(aot="void(float64[:], float64[:])")
def _law_speed(work, row):
    """:meth:`MotionController.law_speed` for the reference-table ``row`` (its tabulated
    ``dq_m_ref``), into the scratch slots of ``work``: the speed that makes the law's
    derivative term ``K_d (dq_m_ref - speed)`` the difference of the filtered reference and
    measured speeds."""
    for i in range(2):
        work[_VEL + 10 + i] = work[_VEL + 2 + i] + row[16 + i] - work[_VEL + 8 + i]


@kernel(aot="boolean(float64[:, :], float64, float64, float64, boolean, float64[:], float64[:], float64[:], "
            "float64[:], float64[:], float64[:], int64[:])")
def _control_step(table, dt, t, h, resample, work, q_m, dp, excitation, excitation_next, dest, at):
    """:meth:`MotionController.step` in one call: the encoder reading ``q_m`` and the motor
    reference angle of ``t + h`` into the speeds (the reading is the one the step's output
    torque, that of ``t + h``, is computed from), the row (``resample``: a new one; the row is
    sampled again in any case) and the law at ``t`` with them, the integral over ``h``, the
    row and the law at ``t + h`` (with ``excitation_next``); then result ``i`` (q_a_ref,
    q_m_ref, p_ref, error, tau: 2 each) into ``dest[at[i]]``, the speed estimate into
    ``dest[at[10]]``, ``dest[at[11]]`` and the row's
    column ``c`` into ``dest[at[12 + c]]`` where that is not negative. Returns whether the
    limit acted at ``t + h``."""
    row = work[_ROW:_OUT]
    t_next = t + h
    _table_row(table, dt, t_next, row)
    _measure_velocity(work, t_next, q_m, row[14:16])
    if resample or t_next != t:
        _table_row(table, dt, t, row)
    speed = work[_VEL + 10:_VEL + 12]
    _law_speed(work, row)
    saturated = _control_law(table, dt, t, False, work, q_m, speed, dp, excitation)
    _integrate(work, saturated, h)
    if t_next != t:
        _table_row(table, dt, t_next, row)
    _law_speed(work, row)
    saturated = _control_law(table, dt, t_next, False, work, q_m, speed, dp, excitation_next)
    for i in range(10):
        if at[i] >= 0:
            dest[at[i]] = work[_OUT + i]
    for i in range(2):
        if at[10 + i] >= 0:
            dest[at[10 + i]] = work[_VEL + 2 + i]
    for c in range(_NCOL):
        if at[12 + c] >= 0:
            dest[at[12 + c]] = work[_ROW + c]
    return saturated


class MotionController:
    """The motion controller's run-time state: references, PID law, integral of the error, the
    drive's velocity estimate from its encoder.

    Parameters
    ----------
    model
        The precomputed :class:`MotionControlModel`.
    excitation
        The identification experiment's torque excitation added to the PID output, or None.
    velocity_cutoff
        Cut-off [Hz] of the first-order low-pass on the backward difference of the encoder
        readings that forms the drive's speed (module docstring); 0: the raw difference.

    Notes
    -----
    A drive: :meth:`step` with each encoder reading (it forms the speeds, then runs the law).
    The law alone: call :meth:`evaluate` with a measurement ``(q_m, dq_m)`` at time ``t`` (it
    returns the torque to hold over the next interval), then :meth:`advance` to integrate the
    error over that interval. As the drive: :meth:`measure` with the encoder reading, then
    :meth:`evaluate` with the speed :meth:`law_speed`.
    """

    def __init__(self, model: MotionControlModel, excitation: "Multisine | None" = None,
                 velocity_cutoff: float = DEFAULT_VELOCITY_CUTOFF) -> None:
        self.model = model
        self.excitation = excitation
        g = model.gains
        self.kp, self.kd, self.tau_max = g.kp, g.kd, g.tau_max
        self.kpi = g.kp * np.where(g.ti > 0, 1.0 / np.where(g.ti > 0, g.ti, 1.0), 0.0)  # kp/ti or 0
        # the state (row, results, integral, constants: the layout of _WORK), updated in place
        # and read through properties (views kept as attributes would not survive a state's copy)
        self._work = np.zeros(_WORK)
        self._work[_K:_VEL] = np.concatenate([g.kp, g.kd, self.kpi, g.tau_max, model.r, [model.l1, model.l2]])
        self._work[_VEL + 4] = np.nan                                  # no encoder reading yet
        self._work[_VEL + 5] = 2.0 * math.pi * float(velocity_cutoff)
        self._excitation = np.zeros(0)
        self._saturated = False
        self._work[_ROW:_OUT] = row = model.sample(0.0)
        self._row_t = 0.0            # the time of row
        self._work[_OUT:_OUT + 6] = np.concatenate([row[_Q], row[_QM], row[_P]])

    @property
    def row(self) -> np.ndarray:
        """The reference table's row of the last :meth:`evaluate` (:meth:`MotionControlModel.sample`)."""
        return self._work[_ROW:_OUT]

    @property
    def integral(self) -> np.ndarray:
        """The integral of the motor angle error [rad s]."""
        return self._work[_INTEGRAL:_K]

    @property
    def q_a_ref(self) -> np.ndarray:
        """Arm reference of the last :meth:`evaluate` (with the offset) [rad]."""
        return self._work[_OUT + 0:_OUT + 2]

    @property
    def q_m_ref(self) -> np.ndarray:
        """Motor reference of the last :meth:`evaluate` (with the offset) [rad, motor side]."""
        return self._work[_OUT + 2:_OUT + 4]

    @property
    def p_ref(self) -> np.ndarray:
        """Tool reference of the last :meth:`evaluate` (with the offset) [m, world x and z]."""
        return self._work[_OUT + 4:_OUT + 6]

    @property
    def error(self) -> np.ndarray:
        """Motor angle error ``q_m_ref - q_m`` of the last :meth:`evaluate` [rad]."""
        return self._work[_OUT + 6:_OUT + 8]

    @property
    def tau(self) -> np.ndarray:
        """Motor torque of the last :meth:`evaluate` [N m, motor side]."""
        return self._work[_OUT + 8:_OUT + 10]

    @property
    def velocity(self) -> np.ndarray:
        """The drive's motor speed estimate from its encoder readings [rad/s, motor side]
        (:meth:`measure`; 0 before the second reading)."""
        return self._work[_VEL + 2:_VEL + 4]

    @property
    def velocity_ref(self) -> np.ndarray:
        """The motor reference speed formed as :attr:`velocity` is, from the reference angles
        [rad/s, motor side] (:meth:`measure`)."""
        return self._work[_VEL + 8:_VEL + 10]

    @property
    def row_time(self) -> float:
        """The time of :attr:`row` (updated in place when :meth:`evaluate` is given a new time)."""
        return self._row_t

    def reset(self) -> None:
        """Zero the integral state."""
        self.integral[:] = 0.0

    def measure(self, t: float, q_m: np.ndarray) -> None:
        """Take the encoder reading ``q_m`` [rad, motor side] of time ``t`` into the drive's
        speed estimate :attr:`velocity`, and the motor reference angle of ``t`` (the nominal
        path's) into :attr:`velocity_ref`, as :meth:`step` does (module docstring)."""
        q_ref = self.model.sample(t)[_QM]
        _measure_velocity(self._work, t, np.asarray(q_m, dtype=float), q_ref)

    def law_speed(self, t: float) -> np.ndarray:
        """The speed to give :meth:`evaluate` at ``t`` after :meth:`measure`: its derivative
        term ``K_d (dq_m_ref - speed)`` is then ``K_d (velocity_ref - velocity)``, the filtered
        derivative of the error, as :meth:`step` computes it."""
        _law_speed(self._work, self.model.sample(t))
        return self._work[_VEL + 10:_VEL + 12].copy()

    def evaluate(self, t: float, q_m: np.ndarray, dq_m: np.ndarray, dp_ref: np.ndarray) -> np.ndarray:
        """References at ``t`` and the motor torque for the measurement ``(q_m, dq_m)``, the
        reference moved by the Cartesian offset ``dp_ref`` (m, from the impedance controller).

        Updates :attr:`row`, :attr:`q_a_ref`, :attr:`q_m_ref`, :attr:`p_ref`, :attr:`error` and
        returns :attr:`tau` [N m, motor side] (in place: the next call overwrites them).
        """
        m = self.model
        resample = t != self._row_t
        self._row_t = t
        if self.excitation is not None:
            self._excitation = self.excitation(t)
        self._saturated = _control_law(m.table, m.dt, t, resample, self._work, np.asarray(q_m, dtype=float),
                                       np.asarray(dq_m, dtype=float), np.asarray(dp_ref, dtype=float),
                                       self._excitation)
        return self.tau

    def advance(self, dt: float) -> None:
        """Integrate the error of the last :meth:`evaluate` over ``dt`` (not while it would wind up)."""
        _integrate(self._work, self._saturated, dt)

    def step(self, t: float, dt: float, q_m: np.ndarray, dp_ref: np.ndarray,
             dest: np.ndarray, at: np.ndarray) -> None:
        """One communication step of a sampled drive in one compiled call, the numbers of
        ``measure(t + dt, q_m)``, ``evaluate(t, q_m, law_speed(t), ...)``, ``advance(dt)``,
        ``evaluate(t + dt, q_m, law_speed(t + dt), ...)``: the speeds from the encoder reading
        ``q_m`` (a float array) set at ``t``, paired with the reference of ``t + dt`` (the time
        of the torque the step outputs; under the master's Gauss-Seidel order the reading is
        the plant's at ``t + dt``), the torque and the integral for it, then the references
        at ``t + dt`` with it, the references moved by ``dp_ref`` (as in :meth:`evaluate`).
        The results are also written into ``dest``: result
        ``i`` of :attr:`q_a_ref`, :attr:`q_m_ref`, :attr:`p_ref`, :attr:`error`, :attr:`tau`
        (in this order, 2 each) at ``at[i]``, :attr:`velocity` at ``at[10]``, ``at[11]``, the
        row's column ``c`` at ``at[12 + c]``, unless negative (an int64 array; an adapter's
        output buffer)."""
        m = self.model
        resample = t != self._row_t
        excitation = excitation_next = self._excitation
        if self.excitation is not None:
            excitation, excitation_next = self.excitation(t), self.excitation(t + dt)
        self._saturated = _control_step(m.table, m.dt, t, dt, resample, self._work, q_m, dp_ref,
                                        excitation, excitation_next, dest, at)
        self._row_t = t + dt
        self._excitation = excitation_next


class Multisine:
    """Periodic random-phase multisine torque per joint, the excitation of a robot's
    identification experiment (Pintelon & Schoukens, *System Identification: A Frequency Domain
    Approach*, ch. 2; used for industrial robots by Wernholt & Gunnarsson 2008, "Estimation of
    nonlinear effects in frequency domain identification of industrial robots").

    ``u_j(t) = A_j sqrt(2 / N) sum_k cos(2 pi f_k t + phi_jk)``, ``f_k = k / T`` for the ``N``
    harmonics of the period ``T`` in the band ``[f_lo, f_hi]``; the phases ``phi_jk`` are
    uniform, independent per joint (uncorrelated inputs), from ``seed``. The RMS of ``u_j`` is
    ``A_j``, the ``amplitude`` (N m) of joint ``j``; ``band`` is ``(f_lo, f_hi)`` (Hz) and
    ``period`` is ``T`` (s).

    Raises
    ------
    ParameterError
        If the band holds no harmonic of the period.
    """

    def __init__(self, amplitude: Sequence[float], band: Sequence[float], period: float, seed: int) -> None:
        k = np.arange(math.ceil(band[0] * period - 1e-9), math.floor(band[1] * period + 1e-9) + 1)
        k = k[k > 0]
        if k.size == 0:
            raise ParameterError(f"parameter 'excitation_band' = {tuple(band)} Hz holds no harmonic of "
                                 f"the excitation period {period:g} s")
        self.omega = 2.0 * math.pi * k / period
        rng = np.random.default_rng([int(seed), 0x6d73])
        self.phase = rng.uniform(0.0, 2.0 * math.pi, (2, k.size))
        self.gain = np.asarray(amplitude, dtype=float).reshape(2, 1) * math.sqrt(2.0 / k.size)

    def __call__(self, t: float) -> np.ndarray:
        """The excitation torque [N m, motor side] at ``t``."""
        return (self.gain * np.cos(self.omega * t + self.phase)).sum(axis=1)


# ---- parameters and assembly -------------------------------------------------------------------
PATH_NAMES = tuple(PATHS)


@dataclass(frozen=True)
class MotionControllerParameters(RobotParameters):
    """Parameters of the MotionController FMU.

    The inherited :class:`RobotParameters` fields are the controller's *model* of the robot
    (used by the inverse kinematics and the feed-forward): giving them values different from the
    plant's introduces a model error, as in the 2009 paper's robustness study.
    """

    path: str = param("iso9283", "1", "tool path: p1, p2 (2009 paper), iso9283, square (IMU paper) "
                      "or csv (waypoints from csv_file)", choices=PATH_NAMES)
    path_start: tuple = param((0.0, 0.0), "m", "start point (x, z) of the path in the world frame; "
                              "(0, 0) - the axis of joint 2, never reachable - selects the path's "
                              "default start")
    speed_scale: float = param(1.0, "1", "time scaling of the whole path (2 runs it twice as fast)",
                               low=0.05, high=5.0)
    csv_file: str = param("", "1", "waypoint CSV file for path = csv (format in "
                          "fmus/robot_plant/trajectory.py); relative to the working directory")
    kp: tuple = param(DEFAULT_KP, "N.m/rad", "PID proportional gain, motor side", low=0.0,
                      source="about 4 Hz bandwidth, damping 1, on the motor plus reflected arm inertia")
    kd: tuple = param(DEFAULT_KD, "N.m.s/rad", "PID derivative gain, motor side", low=0.0)
    ti: tuple = param(DEFAULT_TI, "s", "PID integral time (0: no integral action)", low=0.0)
    velocity_cutoff: float = param(DEFAULT_VELOCITY_CUTOFF, "Hz", "cut-off of the first-order "
                                   "low-pass on the backward difference of the encoder angle that "
                                   "forms the drive's motor speed (0: the raw difference)", low=0.0,
                                   source="a quarter of the 1 kHz servo rate, the default of a "
                                   "servo drive's velocity-feedback filter (Moog DS2110 manual, "
                                   "5.11.2.5)")
    tau_max: tuple = param((60.0, 60.0), "N.m", "motor torque limit, motor side", low=0.0,
                           low_inclusive=False)
    excitation_amplitude: tuple = param((0.0, 0.0), "N.m", "RMS of the identification multisine "
                                        "torque added to the PID output, motor side (0: off)", low=0.0)
    excitation_band: tuple = param((1.0, 40.0), "Hz", "frequency band (low, high) of the multisine",
                                   low=0.0, source="covers the 8-15 Hz locked-motor modes and the "
                                   "4 Hz servo loop")
    excitation_period: float = param(1.0, "s", "period of the multisine (its frequency resolution is "
                                     "1 / period)", low=0.0, low_inclusive=False)
    excitation_seed: int = param(0, "1", "seed of the multisine's random phases", low=0)


    def check(self) -> None:
        """The robot's checks, a waypoint file when ``path = 'csv'``, an ordered excitation band."""
        super().check()
        if self.path == "csv" and not self.csv_file.strip():
            raise ParameterError("parameter 'csv_file' must name a waypoint file when path = 'csv'")
        if not self.excitation_band[0] < self.excitation_band[1]:
            raise ParameterError(f"parameter 'excitation_band' = {tuple(self.excitation_band)}: "
                                 "low must be below high")

    def excitation(self) -> Multisine | None:
        """The identification excitation, or None when its amplitude is zero."""
        if not any(self.excitation_amplitude):
            return None
        return Multisine(self.excitation_amplitude, self.excitation_band, self.excitation_period,
                         self.excitation_seed)

    @property
    def start(self) -> tuple[float, float] | None:
        """The start point, or None for the path's default."""
        return None if self.path_start == (0.0, 0.0) else tuple(self.path_start)  # type: ignore[return-value]


def build_trajectory(params: MotionControllerParameters) -> Trajectory:
    """The path the parameters ``params`` select.

    Raises
    ------
    ParameterError
        Naming ``csv_file`` for an unreadable or malformed waypoint file.
    """
    try:
        return make_path(params.path, params.start, params.speed_scale, params.csv_file)
    except ValueError as exc:
        if params.path == "csv":
            raise ParameterError(f"parameter 'csv_file' = '{params.csv_file}': {exc}") from None
        raise ParameterError(f"parameter 'path' = '{params.path}': {exc}") from None


def build_controller(params: MotionControllerParameters) -> MotionController:
    """Trajectory, reference table and PID from the FMU parameters ``params``.

    Raises
    ------
    ParameterError
        Naming the parameter: a bad waypoint file (``csv_file``), a waypoint out of reach
        (``path`` / ``path_start``) or a path too long to tabulate.
    """
    traj = build_trajectory(params)
    gains = PidGains.from_values(params.kp, params.kd, params.ti, params.tau_max)
    try:
        model = MotionControlModel(traj, params.robot(), gains)
    except (ReachError, PathTooLong) as exc:
        start = "default" if params.start is None else f"{tuple(params.path_start)}"
        names = "'csv_file'" if params.path == "csv" else "'path'"
        raise ParameterError(f"parameter {names} = '{params.csv_file if params.path == 'csv' else params.path}'"
                             f" with 'path_start' = {start}: {exc}") from None
    return MotionController(model, params.excitation(), params.velocity_cutoff)

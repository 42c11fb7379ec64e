"""Motion control of the six-axis flexible robot (plain math, no FMI): joint references,
rigid-body and flexible-joint feed-forward on the controller's own nominal model, and the six
drives' motor PID closing their loops on their encoders (issue 23; the MotionController6 FMU is
a thin adapter). The two-axis controller (:mod:`fmus.robot_plant.motion_control_model`) in six
axes, layer by layer:

1. **Joint references** (setup): :mod:`fmus.robot_plant.trajectory6`'s ``q``, ``dq``, ``ddq``,
   ``dddq`` on a 1 ms grid (the analytic inverse kinematics of the spherical wrist for the 3-D
   tool paths, exact derivatives), the tool position ``p``.
2. **Feed-forward** (setup), on the controller's *nominal* model: the arm
   :func:`fmus.common.irb4600.arm` with the controller's own parameters (its ``tool_mass``,
   link masses scaled by its ``mass_scale``, gearbox stiffnesses by its ``stiffness_scale``;
   never the plant's): rigid-body inverse dynamics
   ``tau_a = M(q) ddq + C(q, dq) dq + g(q)`` (Featherstone's RNEA,
   :class:`fmus.robot_plant.six_axis_model.RigidBodyDynamics` on the rigid arm's tree), then per
   axis the gearbox law of Axelsson et al. (2012), eqs. 10-11, inverted for the deflection:
   ``tau_s(D) + d dD/dt = tau_a`` with the nominal spring ``k_hi D - (k_hi - k_lo) delta
   tanh(D / delta)`` is a first-order lag of ``D`` behind ``tau_a`` (time constant ``d / k``,
   0.6-2 ms), integrated by RK4 on the grid from the static deflection at the start
   (:func:`fmus.common.dynamics.spring_inverse`), ``dD/dt`` from the law itself. (The two-axis
   controller's fixed-point iteration on the damping term leaves, on P1 here, up to 12.5 N m of
   the 540 N m of axis 2's gearbox law unmet where the jerk is large: it converges only for
   content below ``k / (2 pi d)``, 85 Hz on axis 2, and the grid's differences of the jerk's
   kinks are above it.) Then ``q_m_ref = r (q + D)``, and the motor equation along it,
   ``tau_ff = J_m ddq_m_ref + f_v dq_m_ref + f_c tanh(dq_m_ref / w_c) + tau_a / r``.
   The plant's passive joints, hysteresis, Stribeck and load-dependent friction, ripple,
   torque-constant error and current loop are unknown to it.
3. **The drives** (run time, per axis, motor side), each on the encoder reading ``q_m`` it
   owns: the speed ``dq_m_hat`` is the backward difference of consecutive readings through a
   first-order low-pass of cut-off ``f_c`` discretised exactly for a difference held over the
   period ``h`` (Brown, Schneider and Mulligan 1992; the two-axis drive's law,
   :mod:`~fmus.robot_plant.motion_control_model`): ``dq_hat_k = dq_hat_(k-1) + (1 - exp(-2 pi
   f_c h)) (d_k - dq_hat_(k-1))``; the reference motor angle passes through the same difference
   and filter, so the derivative term is the filtered derivative of the error;
   ``tau_m = tau_ff + K_p e + (K_p / T_i) I + K_d (dq_ref_hat - dq_hat)``, ``e = q_m_ref - q_m``,
   limited to ``+-tau_max`` with conditional integration (no wind-up: the integral of ``e`` is
   not advanced on a saturated axis whose error pushes further into the limit).

At a step ``(t, t + h)`` (:meth:`MotionController6.step`) the encoder reading set before it is
the plant's at ``t + h`` (a Gauss-Seidel master steps the plant first), so it is paired with
the references of ``t + h``, the time of the torque the step outputs, as the two-axis drive
pairs them. The first reading (at initialisation) starts the difference; the speed starts at 0
(the robot starts at rest). The PID gains by default put each axis's motor-position loop near
4 Hz with damping 1 on the motor plus the reflected arm inertia ``J_m + M_ii / r^2`` at the
P1 start pose (axes 2-3 the two-axis controller's gains).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fmus.common import disk_cache, irb4600
from fmus.common.dynamics import spring_inverse
from fmus.common.jit import bundle_id
from fmus.common.parameters import ParameterError, param
from fmus.common.robot_params import RobotParameters
from fmus.robot_plant import six_axis_model, trajectory6
from fmus.robot_plant.trajectory6 import PATHS6, JointReference

N = 6
TABLES_KEPT = 8             #: reference tables kept in the disk cache
#: the columns of the reference table, each 6 wide but ``p`` (3)
COLUMNS = ("q", "dq", "ddq", "dddq", "q_m", "dq_m", "tau_ff", "tau_arm", "p")
_WIDTH = {c: (3 if c == "p" else N) for c in COLUMNS}
_AT: dict[str, slice] = {}
_c = 0
for _name in COLUMNS:
    _AT[_name] = slice(_c, _c + _WIDTH[_name])
    _c += _WIDTH[_name]
NCOL = _c

# default gains (motor side): about 4 Hz, damping 1 on J_m + M_ii / r^2 at the P1 start pose
# (axes 2-3: the two-axis controller's DEFAULT_KP, DEFAULT_KD)
DEFAULT_KP = (4.3, 5.3, 3.9, 0.98, 0.98, 0.54)
DEFAULT_KD = (0.34, 0.42, 0.31, 0.078, 0.078, 0.043)
DEFAULT_TI = (0.16,) * N
DEFAULT_TAU_MAX = (60.0, 60.0, 60.0, 20.0, 20.0, 10.0)


@dataclass(frozen=True)
class MotionController6Parameters:
    """Parameters of the MotionController6 FMU. ``tool_mass``, ``mass_scale`` and
    ``stiffness_scale`` make the controller's *nominal model* of the robot (feed-forward and
    deflection compensation) from :func:`fmus.common.irb4600.arm`'s data: set them differently
    from the plant's to study model errors (the kinematics are the data sheet's, not
    parameters)."""

    path: str = param("p1", "1", "six-axis path: iso_cube (ISO 9283 cube at 200 mm/s), square (30 mm "
                      "square with stops), p1, p2 (the 2009 paper's, axes 1, 4-6 held), p1_moving, "
                      "p2_moving (axes 1, 4-6 moving)", choices=PATHS6)
    speed_scale: float = param(1.0, "1", "time scaling of the whole path (2 runs it twice as fast)",
                               low=0.05, high=5.0)
    tool_mass: float = param(irb4600.TOOL_MASS, "kg", "the controller's nominal tool with its load",
                             low=0.0, high=irb4600.HANDLING_CAPACITY, search=(0.0, 30.0),
                             source="irb4600.TOOL_MASS (docs/six_axis.md)")
    mass_scale: tuple = param((1.0,) * N, "1", "scale of the controller's nominal link masses and "
                              "inertias, links 1-6 (1: docs/six_axis.md's estimates)", low=0.5, high=2.0,
                              search=(0.8, 1.2), source="no data sheet gives link masses (docs/six_axis.md)")
    stiffness_scale: tuple = param((1.0,) * N, "1", "scale of the controller's nominal gearbox "
                                   "stiffnesses k_hi, k_lo, axes 1-6 (1: irb4600.arm()'s)", low=0.2, high=5.0,
                                   search=(0.5, 2.0), source="docs/six_axis.md, drive train")
    kp: tuple = param(DEFAULT_KP, "N.m/rad", "PID proportional gain per axis, motor side", low=0.0,
                      search=(0.1, 20.0), source="about 4 Hz bandwidth, damping 1, on the motor plus "
                      "reflected arm inertia at the P1 start pose")
    kd: tuple = param(DEFAULT_KD, "N.m.s/rad", "PID derivative gain per axis, motor side", low=0.0,
                      search=(0.01, 2.0))
    ti: tuple = param(DEFAULT_TI, "s", "PID integral time per axis (0: no integral action)", low=0.0)
    velocity_cutoff: float = param(250.0, "Hz", "cut-off of the first-order low-pass on the backward "
                                   "difference of the encoder angle that forms the drive's motor speed "
                                   "(0: the raw difference)", low=0.0,
                                   source="a quarter of the 1 kHz servo rate (the two-axis drive's)")
    tau_max: tuple = param(DEFAULT_TAU_MAX, "N.m", "motor torque limit per axis, motor side", low=0.0,
                           low_inclusive=False)

    def check(self) -> None:
        """Six values per axis where six are needed; raises :class:`ParameterError` naming the
        parameter."""
        for name in ("mass_scale", "stiffness_scale", "kp", "kd", "ti", "tau_max"):
            if len(getattr(self, name)) != N:
                raise ParameterError(f"parameter '{name}' needs {N} values, got {len(getattr(self, name))}")


def nominal_arm(p: MotionController6Parameters) -> irb4600.Arm:
    """The controller's nominal arm: :func:`fmus.common.irb4600.arm` with ``p.tool_mass``, each
    link's mass and inertia scaled by ``p.mass_scale``, each gearbox's stiffnesses by
    ``p.stiffness_scale``."""
    a = irb4600.arm(None, tool_mass=p.tool_mass)
    s, k = np.asarray(p.mass_scale, float), np.asarray(p.stiffness_scale, float)
    return irb4600.Arm(**{**vars(a), "mass": a.mass * s, "inertia": a.inertia * s[:, None, None],
                          "k_hi": a.k_hi * k, "k_lo": a.k_lo * k})


def friction_smoothing(p: RobotParameters | None = None) -> np.ndarray:
    """``w_c`` [rad/s] per axis: the planar robot ``p``'s ``w_c`` for axes 2-3 (defaults when
    ``None``), the plant module's :data:`~fmus.robot_plant.six_axis_model.W_C_OTHER` for the
    others."""
    p = p if p is not None else RobotParameters()
    w = six_axis_model.W_C_OTHER
    return np.array([w, p.w_c[0], p.w_c[1], w, w, w])


def reference_table(ref: JointReference, arm: irb4600.Arm, w_c: np.ndarray) -> np.ndarray:
    """The reference table (n, :data:`NCOL`, columns :data:`COLUMNS`) of the joint references
    ``ref`` on the nominal ``arm`` with the friction smoothing ``w_c`` (module docstring, layer 2)."""
    dyn = six_axis_model.RigidBodyDynamics(six_axis_model.arm_tree(arm, six_axis_model.SixAxisParameters(ideal=True)))
    n, dt = ref.t.shape[0], float(ref.t[1] - ref.t[0])
    tau_arm = np.array([dyn.rnea(ref.q[k], ref.dq[k], ref.ddq[k]) for k in range(n)])
    k_soft = arm.k_hi - arm.k_lo

    def spring(D: np.ndarray) -> np.ndarray:
        return arm.k_hi * D - k_soft * arm.delta * np.tanh(D / arm.delta)

    def rate(D: np.ndarray, tau: np.ndarray) -> np.ndarray:       # the gearbox law solved for dD/dt
        return (tau - spring(D)) / arm.d

    # tau_s(D) + d dD/dt = tau_a: from the static deflection at the start, RK4 on the grid with
    # tau_a linear in between (the law is a first-order lag of time constant d / k: 0.6-2 ms)
    D = np.empty((n, N))
    D[0] = [spring_inverse(arm.k_hi[i], k_soft[i], arm.delta[i], float(tau_arm[0, i]), 0.0, False) for i in range(N)]
    for k in range(n - 1):
        t0, t1 = tau_arm[k], tau_arm[k + 1]
        tm = 0.5 * (t0 + t1)
        k1 = rate(D[k], t0)
        k2 = rate(D[k] + 0.5 * dt * k1, tm)
        k3 = rate(D[k] + 0.5 * dt * k2, tm)
        k4 = rate(D[k] + dt * k3, t1)
        D[k + 1] = D[k] + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    dD = rate(D, tau_arm)
    ddD = np.gradient(dD, dt, axis=0, edge_order=2)
    r = arm.gear_ratio
    qm, dqm, ddqm = r * (ref.q + D), r * (ref.dq + dD), r * (ref.ddq + ddD)
    tau_ff = arm.J_m * ddqm + arm.f_v * dqm + arm.f_c * np.tanh(dqm / w_c) + tau_arm / r
    table = np.empty((n, NCOL))
    for name, val in (("q", ref.q), ("dq", ref.dq), ("ddq", ref.ddq), ("dddq", ref.dddq), ("q_m", qm),
                      ("dq_m", dqm), ("tau_ff", tau_ff), ("tau_arm", tau_arm), ("p", ref.p)):
        table[:, _AT[name]] = val
    return table


class MotionControl6Model:
    """The reference table of the path of the parameters ``p``
    (:class:`MotionController6Parameters`) on the controller's nominal arm, on a grid of ``dt``
    [s] (:data:`fmus.robot_plant.trajectory6.DT_GRID`), cached on disk
    (:mod:`fmus.common.disk_cache`) by all it is computed from.

    Raises
    ------
    ParameterError
        Naming ``path``: a path point the arm cannot follow (the point and its time).
    """

    def __init__(self, p: MotionController6Parameters) -> None:
        p.check()
        self.arm = nominal_arm(p)
        self.w_c = friction_smoothing()
        self.path, self.speed_scale = p.path, float(p.speed_scale)
        import platform
        key = disk_cache.content_key(bundle_id(), np.__version__, platform.machine(), "six-axis reference",
                                     p.path, self.speed_scale, p.tool_mass, tuple(p.mass_scale),
                                     tuple(p.stiffness_scale))
        ref: list = []

        def build() -> np.ndarray:
            ref.append(self._reference())
            return reference_table(ref[0], self.arm, self.w_c)

        n = trajectory6.grid(self._duration()).shape[0]
        self.table = disk_cache.cached_array("tables6", key, (n, NCOL), build, TABLES_KEPT)
        self.dt = trajectory6.DT_GRID

    def _reference(self) -> JointReference:
        try:
            return trajectory6.make_reference(self.path, self.arm, self.speed_scale)
        except ValueError as exc:
            raise ParameterError(f"parameter 'path' = '{self.path}': {exc}") from None

    def _duration(self) -> float:
        """The path's duration [s] (without building its references)."""
        if self.path == "iso_cube":
            return trajectory6.iso_cube_path(speed_scale=self.speed_scale).duration
        if self.path == "square":
            return trajectory6.square_path(speed_scale=self.speed_scale).duration
        from fmus.robot_plant.trajectory import make_path
        return make_path(self.path[:2], None, self.speed_scale).duration

    def sample(self, t: float) -> np.ndarray:
        """The table row at ``t`` [s] (linear interpolation; held before 0 and after the end)."""
        x = t / self.dt
        last = self.table.shape[0] - 1
        if x <= 0.0:
            return self.table[0].copy()
        i = int(x)
        if i >= last:
            return self.table[last].copy()
        w = x - i
        if w == 0.0:
            return self.table[i].copy()
        return self.table[i] + w * (self.table[i + 1] - self.table[i])

    @staticmethod
    def column(row: np.ndarray, name: str) -> np.ndarray:
        """The column ``name`` (:data:`COLUMNS`) of a table ``row``."""
        return row[_AT[name]]


class MotionController6:
    """The six drives on the reference table of ``model`` (:class:`MotionControl6Model`) with
    the gains ``kp``, ``kd``, ``ti``, ``tau_max`` (6 each, motor side) and the speed filter's
    ``velocity_cutoff`` [Hz] (module docstring, layer 3).

    :meth:`start` with the first encoder reading, then :meth:`step` per communication step;
    the results of the last call are the attributes ``row`` (the table row of its time),
    ``tau`` [N m], ``error`` [rad], ``velocity`` and ``velocity_ref`` [rad/s] (motor side).
    """

    def __init__(self, model: MotionControl6Model, kp, kd, ti, tau_max, velocity_cutoff: float) -> None:
        self.model = model
        self.kp = np.asarray(kp, float)
        self.kd = np.asarray(kd, float)
        ti = np.asarray(ti, float)
        self.kpi = np.where(ti > 0, self.kp / np.where(ti > 0, ti, 1.0), 0.0)
        self.tau_max = np.asarray(tau_max, float)
        self.w_f = 2.0 * math.pi * float(velocity_cutoff)
        self.integral = np.zeros(N)
        self.velocity = np.zeros(N)
        self.velocity_ref = np.zeros(N)
        self.last = np.zeros(N)
        self.last_ref = np.zeros(N)
        self.t_last = math.nan
        self.row = model.sample(0.0)
        self.tau = np.zeros(N)
        self.error = np.zeros(N)

    def start(self, t: float, q_m: np.ndarray) -> None:
        """The first encoder reading ``q_m`` [rad, motor side] at ``t`` [s]: the references and
        the torque at ``t`` (speed 0, no integral)."""
        self.row = self.model.sample(t)
        self.last, self.last_ref, self.t_last = np.array(q_m, float), self.row[_AT["q_m"]].copy(), t
        self.law(q_m)

    def law(self, q_m: np.ndarray) -> np.ndarray:
        """The torque [N m] for the encoder reading ``q_m`` [rad] at the time of :attr:`row`, with
        the current speeds and integral; returns which axes the limit cut."""
        row = self.row
        self.error = row[_AT["q_m"]] - q_m
        u = row[_AT["tau_ff"]] + self.kp * self.error + self.kpi * self.integral \
            + self.kd * (self.velocity_ref - self.velocity)
        self.tau = np.clip(u, -self.tau_max, self.tau_max)
        return u != self.tau

    def step(self, t: float, dt: float, q_m: np.ndarray) -> None:
        """The step from ``t`` to ``t + dt`` [s] with the encoder reading ``q_m`` [rad, motor
        side] of ``t + dt``: the speeds from it and the reference of ``t + dt``, the torque to
        hold over the next step, the integral of the error (module docstring, layer 3)."""
        t1 = t + dt
        q_m = np.asarray(q_m, float)
        self.row = self.model.sample(t1)
        q_ref = self.row[_AT["q_m"]]
        h = t1 - self.t_last
        if h > 0.0:
            a = 1.0 - math.exp(-self.w_f * h) if self.w_f > 0 else 1.0
            self.velocity += a * ((q_m - self.last) / h - self.velocity)
            self.velocity_ref += a * ((q_ref - self.last_ref) / h - self.velocity_ref)
        self.last, self.last_ref, self.t_last = q_m.copy(), q_ref.copy(), t1
        saturated = self.law(q_m)
        winding = saturated & (np.sign(self.error) == np.sign(self.tau))
        self.integral += np.where(winding, 0.0, self.error * dt)


def build_controller(p: MotionController6Parameters) -> MotionController6:
    """The drives of the parameters ``p`` on their path's reference table.

    Raises
    ------
    ParameterError
        Naming the parameter: a path point the nominal arm cannot follow (``path``), a bad
        nominal model.
    """
    model = MotionControl6Model(p)
    return MotionController6(model, p.kp, p.kd, p.ti, p.tau_max, p.velocity_cutoff)

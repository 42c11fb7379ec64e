"""Complementary filter of tool position and orientation from forward kinematics and an IMU.

The IMU paper (complementary filter vs EKF on an IRB4600, section 4.1) fuses the forward-
kinematics estimate ``p_fk = p + v`` with the IMU-integrated estimate ``p_imu = p + w`` (eq. 1)
so that the filter is *distortionless* (the complementary constraint, eq. 2)::

    P_hat(s) = G(s) P_fk(s) + (1 - G(s)) P_imu(s) = P(s) + G(s) V(s) + (1 - G(s)) W(s).

The low-pass ``G`` and the high-pass ``1 - G`` sum to one, so noise-free inputs give the true
signal whatever ``G`` is. Here ``G`` is second order with natural (cut-off) frequency ``w_c``
and damping ``zeta``::

    G(s) = (2 zeta w_c s + w_c^2) / (s^2 + 2 zeta w_c s + w_c^2),
    1 - G(s) = s^2 / (s^2 + 2 zeta w_c s + w_c^2),

(the form in which the IMU branch needs only the *measured* derivative: ``(1 - G) P_imu`` is
``A / (s^2 + ...)`` with the acceleration ``A = s^2 P_imu``, so a constant accelerometer bias
``b`` only shifts the estimate by ``b / w_c^2``, and nothing drifts). It is realised as the
error-feedback (observer) form: predict with the IMU, correct with the kinematics,

    p^- = p + T v + T^2 (a_k / 3 + a_{k+1} / 6),   v^- = v + T (a_k + a_{k+1}) / 2,
    p = p^- + L1 (p_fk - p^-),                      v = v^- + (L2 / T) (p_fk - p^-),

whose error dynamics have the poles ``exp(s_i T)`` of the continuous ``s^2 + 2 zeta w_c s +
w_c^2`` (:func:`discrete_gains`). The prediction integrates an acceleration that is linear
between samples exactly, so noise-free inputs with such an acceleration give the true position
to rounding after the start transient (the discrete complementary constraint).

Two steps per sample, as in the paper: first the orientation (unit quaternion, integrated from
the gyro and fused with the kinematic orientation by a second-order split of the same form on
SO(3); its integral state is a gyro-bias estimate), then the specific force rotated to the world with that
orientation, gravity added back (``a = R f + g_vec``, ``g_vec = (0, 0, -g)``), integrated and
fused with the kinematic position.

The paper used the same split for all states "for simplicity" and named separate ones a natural
extension; ``cutoff_orientation`` is that extension. It matters: an orientation error ``d``
leaks into the position as the gravity error ``g d`` through ``1 / (s^2 + 2 zeta w_c s +
w_c^2)``, i.e. as ``g d / w_c^2`` at low frequency, so at a low position cut-off the kinematic
orientation's deflection errors must be kept out, by a much lower orientation cut-off (the
gyro is good over a wide band).

Mounting: the filter runs on the *sensor* point and frame, where the IMU measures. The
kinematic tool pose is moved there (``p_s = p_tool + R_tool r``, ``q_s = q_tool ⊗ q_mount``,
``r`` the lever arm in the tool frame, ``q_mount`` the sensor-to-tool rotation) and the estimate
moved back (``q_tool = q_s ⊗ q_mount*``, ``p_tool = p_s - R_tool r``). Both maps are exact for a
rigid tool, so no angular acceleration is needed and the output is the tool point.
"""
from __future__ import annotations

import cmath
import math
from dataclasses import dataclass

import numpy as np

from fmus.common import quaternion as qt
from fmus.common.frames import G, RigidMount, rot_rpy
from fmus.common.parameters import ParameterError, param

PAPER = "IMU paper (CF vs EKF on an IRB4600), section 4.1"


@dataclass(frozen=True)
class ComplementaryFilterParameters:
    """Parameters of the complementary filter."""

    cutoff: float = param(28.0, "Hz", "cut-off (natural) frequency of the second-order split G(s) "
                          "of the position", low=0.0, low_inclusive=False, search=(0.2, 30.0),
                          source=f"{PAPER}: 'a cut-off frequency of slightly less than 30 Hz'")
    damping: float = param(0.7, "1", "damping ratio of G(s)", low=0.0, low_inclusive=False, search=(0.3, 3.0),
                           source="assumed (well damped)")
    cutoff_orientation: float = param(0.0, "Hz", "cut-off of the orientation split (0: the same as "
                                      "'cutoff', as in the paper: 'the same filter was used for all "
                                      "estimated states')", low=0.0, source=PAPER,
                                      search=(0.005, 30.0))   # our extension: the paper's is 0
    lever_arm: tuple = param((-0.15, 0.0, 0.05), "m", "IMU position relative to the tool point, in "
                             "the tool frame (x, y, z)",
                             source="the robot's sensor_offset (x, z) on the wrist flange")
    mount_rpy: tuple = param((0.0, 0.0, 0.0), "rad", "mounting roll, pitch, yaw of the IMU on the "
                             "tool (R_mount = Rz(yaw) Ry(pitch) Rx(roll), sensor to tool)",
                             low=-math.pi, high=math.pi)
    g: float = param(G, "m/s2", "gravity", low=0.0)

    def check(self) -> None:
        """``lever_arm`` and ``mount_rpy`` are 3-vectors; raises :class:`ParameterError`."""
        if len(self.lever_arm) != 3:
            raise ParameterError(f"parameter 'lever_arm' needs 3 elements, got {len(self.lever_arm)}")
        if len(self.mount_rpy) != 3:
            raise ParameterError(f"parameter 'mount_rpy' needs 3 elements, got {len(self.mount_rpy)}")


def discrete_gains(cutoff: float, damping: float, dt: float) -> tuple[float, float]:
    """Gains ``(L1, L2)`` of the predict-correct loop whose error dynamics
    ``[[1 - L1, (1 - L1) T], [-L2 / T, 1 - L2]]`` have the poles ``z_i = exp(s_i T)`` of
    ``s^2 + 2 zeta w_c s + w_c^2`` (the discrete equivalent of eq. 2's ``G``), for the cut-off
    ``w_c = 2 pi cutoff`` (``cutoff`` in Hz), the damping ratio ``zeta`` = ``damping`` and the
    sample period ``T`` = ``dt`` [s]. ``L2 / T`` is the velocity gain.

    The characteristic polynomial is ``z^2 - (2 - L1 - L2) z + (1 - L1)``, so
    ``L1 = 1 - z1 z2`` and ``L2 = 2 - L1 - (z1 + z2)``.
    """
    wc = 2.0 * math.pi * cutoff
    root = cmath.sqrt(damping * damping - 1.0)
    s1, s2 = wc * (-damping + root), wc * (-damping - root)
    z1, z2 = cmath.exp(s1 * dt), cmath.exp(s2 * dt)
    l1 = 1.0 - (z1 * z2).real
    l2 = 2.0 - l1 - (z1 + z2).real
    return l1, l2


def split_response(f: np.ndarray, cutoff: float, damping: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Frequency responses of the discrete low-pass ``G`` (kinematics branch) and high-pass
    ``1 - G`` (IMU branch) at ``f`` Hz; they sum to one (eq. 2). ``cutoff`` [Hz], ``damping``
    and ``dt`` [s] as in :func:`discrete_gains`."""
    l1, l2 = discrete_gains(cutoff, damping, dt)
    z = np.exp(1j * 2.0 * np.pi * np.asarray(f, float) * dt)
    # transfer from p_fk to p: closed loop of the predict-correct recursion with a = 0
    # p_{k+1} = (1 - L1)(p_k + T v_k) + L1 y, v_{k+1} = v_k - (L2/T)(p_k + T v_k) + (L2/T) y
    den = z * z - (2.0 - l1 - l2) * z + (1.0 - l1)
    g = (l1 * z * z + (l2 - l1) * z) / den
    return g, 1.0 - g


class ComplementaryFilterModel:
    """The two-step complementary filter (module docstring), one sample per :meth:`step`.

    Call :meth:`reset` with the first kinematic pose and IMU sample, then :meth:`step` with each
    new sample. Internal state: sensor position ``p_s``, velocity ``v_s`` (world), sensor
    orientation ``q_s`` (sensor to world) and gyro bias ``b_gyro`` (sensor frame); ``params`` are
    the :class:`ComplementaryFilterParameters`.

    The IMU sample of a call is the specific force ``acc_s`` [m/s^2] and the angular rate
    ``gyro_s`` [rad/s], each (x, y, z) in the sensor frame; a kinematic pose is the tool point
    [m, world x, y, z] and orientation (quaternion, tool to world).
    """

    def __init__(self, params: ComplementaryFilterParameters) -> None:
        self.params = params
        self.mount = RigidMount(params.lever_arm, rot_rpy(params.mount_rpy))
        self.g_vec = np.array([0.0, 0.0, -params.g])
        self._dt = None
        self._gains = (0.0, 0.0, 0.0, 0.0)
        self.p_s = np.zeros(3)
        self.v_s = np.zeros(3)
        self.q_s = qt.IDENTITY.copy()
        self.b_gyro = np.zeros(3)
        self._a_prev = np.zeros(3)
        self._w_prev = (0.0, 0.0, 0.0)

    # -- frames ----------------------------------------------------------------------------
    @property
    def q_tool(self) -> np.ndarray:
        """Estimated tool orientation (tool to world)."""
        return self.mount.tool_pose(self.p_s, self.q_s)[1]

    @property
    def p_tool(self) -> np.ndarray:
        """Estimated tool point (world x, y, z)."""
        return self.mount.tool_pose(self.p_s, self.q_s)[0]

    @property
    def v_tool_approx(self) -> np.ndarray:
        """Velocity of the sensor point (world): the tool's, up to the lever-arm rotation term."""
        return self.v_s.copy()

    # -- filter ----------------------------------------------------------------------------
    def _set_dt(self, dt: float) -> None:
        p = self.params
        l1, l2 = discrete_gains(p.cutoff, p.damping, dt)
        fo = p.cutoff_orientation or p.cutoff
        m1, m2 = discrete_gains(fo, p.damping, dt)
        self._gains = (l1, l2 / dt, m1, m2 / dt)
        self._dt = dt

    def world_acceleration(self, q_s, acc_s) -> np.ndarray:
        """``a = R(q_s) f + g_vec`` [m/s^2]: the specific force ``f`` = ``acc_s`` (sensor frame)
        in the world with the sensor orientation ``q_s``, gravity removed."""
        return qt.rotate(q_s, acc_s) + self.g_vec

    def reset(self, p_tool, q_tool, acc_s, gyro_s) -> None:
        """Start at the kinematic pose ``p_tool``, ``q_tool``, at rest (zero velocity and gyro
        bias), with the IMU sample ``acc_s``, ``gyro_s`` of that time."""
        self.p_s, self.q_s = self.mount.sensor_pose(p_tool, q_tool)
        self.v_s = np.zeros(3)
        self.b_gyro = np.zeros(3)
        self._w_prev = tuple(float(x) for x in gyro_s)
        self._a_prev = self.world_acceleration(self.q_s, acc_s)

    def predict(self, dt: float) -> None:
        """The estimate ``dt`` ahead without a new sample: the last rate (bias removed) and
        acceleration held (the output of a filter whose newest sample is older than now)."""
        w, b = self._w_prev, self.b_gyro
        self.q_s = qt.propagate(self.q_s, (w[0] - b[0], w[1] - b[1], w[2] - b[2]), dt)
        a = self._a_prev
        self.p_s = self.p_s + dt * self.v_s + (0.5 * dt * dt) * a
        self.v_s = self.v_s + dt * a

    def step(self, p_tool_fk, q_tool_fk, acc_s, gyro_s, dt: float) -> None:
        """Advance one sample of length ``dt`` [s] with the new kinematic pose ``p_tool_fk``,
        ``q_tool_fk`` and IMU sample ``acc_s``, ``gyro_s``."""
        if self._dt is None or abs(dt - self._dt) > 1e-12 * dt:
            if not dt > 0.0:
                raise ValueError(f"time step must be positive, got {dt!r}")
            self._set_dt(dt)
        l1, k2, m1, n2 = self._gains
        p_fk, q_fk = self.mount.sensor_pose(p_tool_fk, q_tool_fk)
        # 1. orientation: gyro (trapezoidal mean rate, bias removed), then the kinematic correction
        # (plain floats below: this runs every sample and is the point of the filter's low cost)
        wx, wy, wz = float(gyro_s[0]), float(gyro_s[1]), float(gyro_s[2])
        w0, b = self._w_prev, self.b_gyro
        h = 0.5 * dt
        q_pred = qt.multiply(self.q_s, qt.from_rotation_vector(
            ((w0[0] + wx) * h - b[0] * dt, (w0[1] + wy) * h - b[1] * dt, (w0[2] + wz) * h - b[2] * dt)))
        d = qt.to_rotation_vector(qt.multiply(qt.conjugate(q_pred), q_fk))
        self.q_s = qt.normalise(qt.multiply(q_pred, qt.from_rotation_vector(m1 * d)))
        self.b_gyro = b - n2 * d
        self._w_prev = (wx, wy, wz)
        # 2. position: specific force to world with the new orientation, gravity removed
        a = qt.rotate(self.q_s, acc_s)
        a[2] -= self.params.g
        a0, p, v = self._a_prev, self.p_s, self.v_s
        c0, c1, tt = dt * dt / 3.0, dt * dt / 6.0, dt
        p_new, v_new = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
        for i in range(3):
            ai, a0i, vi = float(a[i]), float(a0[i]), float(v[i])
            pp = float(p[i]) + tt * vi + c0 * a0i + c1 * ai
            e = float(p_fk[i]) - pp
            p_new[i] = pp + l1 * e
            v_new[i] = vi + h * (a0i + ai) + k2 * e
        self.p_s = np.array(p_new)
        self.v_s = np.array(v_new)
        self._a_prev = a


__all__ = ["ComplementaryFilterParameters", "ComplementaryFilterModel", "discrete_gains",
           "split_response"]

"""Extended Kalman filter of the tool pose from forward kinematics and an IMU (IMU paper, 4.2).

State (eq. 3), nominal::

    x = (p[3], v[3], a[3], q[4], w[3], b_acc[3], b_gyr[3])

position, velocity and acceleration of the IMU point in the world frame (constant-acceleration
model driven by white jerk), the IMU orientation as a unit quaternion (sensor to world) with a
constant body angular velocity ``w`` (sensor frame, driven by white angular acceleration), and
random-walk biases of the accelerometer and the gyro (sensor frame).

The orientation is handled as an *error-state* (multiplicative) filter: the covariance is that
of the 21-dimensional error ``(dp, dv, da, dtheta, dw, db_acc, db_gyr)`` with the true
orientation ``q = q_hat ⊗ exp(dtheta)``; after each update the error is injected into the
nominal state and reset to zero.

The update and the time update of the covariance are the shared ones of
:mod:`fmus.common.kalman` (Joseph form, Cholesky-factored innovation covariance).

Time update over ``T`` (exact for the model)::

    p += T v + T^2/2 a,  v += T a,  q = q ⊗ exp(w T),
    Phi_theta_theta = exp(w T)^T,  Phi_theta_w = T I,
    Q = G_j sigma_jerk^2 G_j^T (G_j = [T^3/6, T^2/2, T] per axis, piecewise-constant jerk)
        + the same for (theta, w) with sigma_alpha (G = [T^2/2, T])
        + diag(sigma_bias_acc^2 T, sigma_bias_gyro^2 T).

Measurements (eq. 4), all at every sample::

    y_p   = p + e                        (kinematic IMU point, from the tool pose)
    y_q   = q + e     -> residual log(q_hat* ⊗ y_q) on dtheta
    y_acc = R^T (a - g_vec) + b_acc + e  (specific force; eq. 4's R^I_B (a + g) with g = -g_vec)
    y_gyr = w + b_gyr + e

with the Jacobian ``d y_acc / d dtheta = [f_hat]x``, ``f_hat = R_hat^T (a_hat - g_vec)``.

Mounting: as in :mod:`fmus.estimators.complementary_filter_model` the filter runs on the IMU
point and frame; the kinematic tool pose is moved there and the estimate back (exact for a
rigid tool), so the lever-arm accelerations need no model.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fmus.common import quaternion as qt
from fmus.common.frames import G, RigidMount, rot_rpy
from fmus.common.kalman import measurement_update, time_update
from fmus.common.parameters import ParameterError, param

PAPER = "IMU paper (CF vs EKF on an IRB4600), section 4.2"
N = 21
P_, V_, A_, TH, W_, BA, BG = (slice(3 * i, 3 * i + 3) for i in range(7))


@dataclass(frozen=True)
class ImuEkfParameters:
    """Noise levels (standard deviations; the filter's tuning), initial uncertainty and mount."""

    sigma_jerk: float = param(300.0, "m/s3", "process noise: jerk of the IMU point, std per sample "
                              "(held over the sample)", low=0.0, low_inclusive=False, search=(1.0, 1e5),
                              source=f"{PAPER}: tuned (the paper: process noise far above the "
                              "measurement noise)")
    sigma_alpha: float = param(50.0, "rad/s2", "process noise: angular acceleration, std per sample",
                               low=0.0, low_inclusive=False, source="tuned", search=(0.1, 1e4))
    sigma_bias_acc: float = param(1e-3, "m/s2/s0.5", "accelerometer bias random-walk intensity",
                                  low=0.0, low_inclusive=False, source="the Imu's acc_bias_rw")
    sigma_bias_gyro: float = param(1e-4, "rad/s/s0.5", "gyro bias random-walk intensity",
                                   low=0.0, low_inclusive=False, source="the Imu's gyro_bias_rw")
    r_position: float = param(3e-4, "m", "forward-kinematics position error std", low=0.0,
                              low_inclusive=False, source="tuned (FK error is deflection, not white)",
                              search=(1e-6, 1e-2))
    r_orientation: float = param(3e-4, "rad", "forward-kinematics orientation error std", low=0.0,
                                 low_inclusive=False, source="tuned", search=(1e-6, 1e-1))
    r_acc: float = param(0.02, "m/s2", "accelerometer noise std", low=0.0, low_inclusive=False,
                         source="the Imu's acc_noise")
    r_gyro: float = param(0.005, "rad/s", "gyro noise std", low=0.0, low_inclusive=False,
                          source="the Imu's gyro_noise")
    p0_position: float = param(1e-3, "m", "initial position std", low=0.0, low_inclusive=False)
    p0_velocity: float = param(1e-3, "m/s", "initial velocity std", low=0.0, low_inclusive=False)
    p0_acceleration: float = param(0.1, "m/s2", "initial acceleration std", low=0.0, low_inclusive=False)
    p0_orientation: float = param(1e-3, "rad", "initial orientation std", low=0.0, low_inclusive=False)
    p0_rate: float = param(1e-2, "rad/s", "initial angular velocity std", low=0.0, low_inclusive=False)
    p0_bias_acc: float = param(0.05, "m/s2", "initial accelerometer bias std", low=0.0, low_inclusive=False)
    p0_bias_gyro: float = param(0.01, "rad/s", "initial gyro bias std", low=0.0, low_inclusive=False)
    lever_arm: tuple = param((-0.15, 0.0, 0.05), "m", "IMU position relative to the tool point, in "
                             "the tool frame (x, y, z)",
                             source="the robot's sensor_offset (x, z) on the wrist flange")
    mount_rpy: tuple = param((0.0, 0.0, 0.0), "rad", "mounting roll, pitch, yaw of the IMU on the "
                             "tool (R_mount = Rz(yaw) Ry(pitch) Rx(roll), sensor to tool)",
                             low=-math.pi, high=math.pi)
    g: float = param(G, "m/s2", "gravity", low=0.0)

    def check(self) -> None:
        """``lever_arm`` and ``mount_rpy`` are 3-vectors; raises :class:`ParameterError`."""
        for name in ("lever_arm", "mount_rpy"):
            if len(getattr(self, name)) != 3:
                raise ParameterError(f"parameter '{name}' needs 3 elements, got {len(getattr(self, name))}")


class ImuEkfModel:
    """The error-state EKF of the module docstring; :meth:`reset`, then :meth:`step` per sample.

    ``params`` are the :class:`ImuEkfParameters`. The IMU sample of a call is the specific force
    ``acc_s`` [m/s^2] and the angular rate ``gyro_s`` [rad/s], each (x, y, z) in the sensor
    frame; a kinematic pose is the tool point [m, world x, y, z] and orientation (quaternion,
    tool to world).
    """

    def __init__(self, params: ImuEkfParameters) -> None:
        self.params = params
        self.mount = RigidMount(params.lever_arm, rot_rpy(params.mount_rpy))
        self.g_vec = np.array([0.0, 0.0, -params.g])
        p = params
        self.R = np.diag(np.repeat([p.r_position ** 2, p.r_orientation ** 2, p.r_acc ** 2,
                                    p.r_gyro ** 2], 3))
        self.p = np.zeros(3)
        self.v = np.zeros(3)
        self.a = np.zeros(3)
        self.q = qt.IDENTITY.copy()
        self.w = np.zeros(3)
        self.b_acc = np.zeros(3)
        self.b_gyro = np.zeros(3)
        self.P = np.zeros((N, N))
        self._dt = None
        self._Q = None
        self._F = np.eye(N)
        self._zero = np.zeros(N)
        I3 = np.eye(3)
        self._H = np.zeros((12, N))          # the constant blocks; rows 6-8 are set per update
        self._H[0:3, P_] = I3
        self._H[3:6, TH] = I3
        self._H[6:9, BA] = I3
        self._H[9:12, W_] = I3
        self._H[9:12, BG] = I3
        self.nis = 0.0          # normalised innovation squared of the last update

    # -- frames (as the complementary filter) ----------------------------------------------
    @property
    def q_tool(self) -> np.ndarray:
        """Estimated tool orientation (tool to world)."""
        return self.mount.tool_pose(self.p, self.q)[1]

    @property
    def p_tool(self) -> np.ndarray:
        """Estimated tool point (world)."""
        return self.mount.tool_pose(self.p, self.q)[0]

    # -- filter ----------------------------------------------------------------------------
    def reset(self, p_tool, q_tool, acc_s=None, gyro_s=None) -> None:
        """Start at the kinematic pose ``p_tool``, ``q_tool`` at rest, zero biases, with the
        initial covariance; the angular velocity starts at the gyro sample ``gyro_s`` if given
        (else zero). ``acc_s`` is accepted for the common reset signature and not used (the
        acceleration starts at zero)."""
        self.p, self.q = self.mount.sensor_pose(p_tool, q_tool)
        self.v = np.zeros(3)
        self.a = np.zeros(3)
        self.w = np.zeros(3) if gyro_s is None else np.array(gyro_s, dtype=float)
        self.b_acc = np.zeros(3)
        self.b_gyro = np.zeros(3)
        p = self.params
        self.P = np.diag(np.repeat([p.p0_position, p.p0_velocity, p.p0_acceleration, p.p0_orientation,
                                    p.p0_rate, p.p0_bias_acc, p.p0_bias_gyro], 3) ** 2)

    def _process_noise(self, dt: float) -> np.ndarray:
        p = self.params
        Q = np.zeros((N, N))
        gj = np.array([dt ** 3 / 6.0, dt ** 2 / 2.0, dt])
        ga = np.array([dt ** 2 / 2.0, dt])
        qj = p.sigma_jerk ** 2 * np.outer(gj, gj)
        qa = p.sigma_alpha ** 2 * np.outer(ga, ga)
        for i in range(3):
            idx = [i, 3 + i, 6 + i]
            Q[np.ix_(idx, idx)] = qj
            idx = [9 + i, 12 + i]
            Q[np.ix_(idx, idx)] = qa
            Q[15 + i, 15 + i] = p.sigma_bias_acc ** 2 * dt
            Q[18 + i, 18 + i] = p.sigma_bias_gyro ** 2 * dt
        return Q

    def predict(self, dt: float) -> None:
        """Time update over ``dt`` (constant acceleration, constant angular velocity)."""
        if self._dt is None or abs(dt - self._dt) > 1e-12 * dt:
            if not dt > 0.0:
                raise ValueError(f"time step must be positive, got {dt!r}")
            self._Q = self._process_noise(dt)
            self._dt = dt
            I3 = np.eye(3)
            self._F = np.eye(N)
            self._F[P_, V_] = dt * I3
            self._F[P_, A_] = 0.5 * dt * dt * I3
            self._F[V_, A_] = dt * I3
            self._F[TH, W_] = dt * I3
        dq = qt.from_rotation_vector(self.w * dt)
        F = self._F
        F[TH, TH] = qt.to_matrix(dq).T
        self.P = time_update(F, self.P, self._Q, definite=False)     # first: raises before any change
        self.p = self.p + dt * self.v + (0.5 * dt * dt) * self.a
        self.v = self.v + dt * self.a
        self.q = qt.normalise(qt.multiply(self.q, dq))

    def update(self, p_tool_fk, q_tool_fk, acc_s, gyro_s) -> None:
        """Measurement update with the kinematic pose ``p_tool_fk``, ``q_tool_fk`` and the IMU
        sample ``acc_s``, ``gyro_s`` (eq. 4)."""
        p_fk, q_fk = self.mount.sensor_pose(p_tool_fk, q_tool_fk)
        Rt = qt.to_matrix(self.q).T
        f_hat = Rt @ (self.a - self.g_vec)
        r = np.empty(12)
        r[0:3] = p_fk - self.p
        r[3:6] = qt.to_rotation_vector(qt.multiply(qt.conjugate(self.q), q_fk))
        r[6:9] = np.asarray(acc_s, float) - (f_hat + self.b_acc)
        r[9:12] = np.asarray(gyro_s, float) - (self.w + self.b_gyro)
        H = self._H
        H[6:9, A_] = Rt
        H[6:9, TH] = qt.skew(f_hat)
        # the error state starts at zero: x+ is the correction to inject
        dx, self.P, self.nis = measurement_update(self._zero, self.P, r, H, self.R)
        self.p = self.p + dx[P_]
        self.v = self.v + dx[V_]
        self.a = self.a + dx[A_]
        self.q = qt.normalise(qt.multiply(self.q, qt.from_rotation_vector(dx[TH])))
        self.w = self.w + dx[W_]
        self.b_acc = self.b_acc + dx[BA]
        self.b_gyro = self.b_gyro + dx[BG]

    def step(self, p_tool_fk, q_tool_fk, acc_s, gyro_s, dt: float) -> None:
        """Predict over ``dt`` [s] and update with the sample at its end (``p_tool_fk``,
        ``q_tool_fk``, ``acc_s``, ``gyro_s`` as in :meth:`update`)."""
        self.predict(dt)
        self.update(p_tool_fk, q_tool_fk, acc_s, gyro_s)


__all__ = ["ImuEkfParameters", "ImuEkfModel"]

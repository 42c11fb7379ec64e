"""Sensor and contact models: the plain math behind the Encoder, Imu, ForceTorqueSensor and
ContactEnvironment FMUs (no FMI here).

Conventions (see the project preamble): planar arm in the world x-z plane, gravity
``g_vec = (0, 0, -g)``; the tool frame is the world frame rotated about +y by ``phi_tool``,
``Ry(phi) = [[c, 0, s], [0, 1, 0], [-s, 0, c]]``; a sensor's frame is ``R_s = Ry(phi) @ R_mount``.

:class:`SensorChannels` models the imperfections every sensor owns; the functions below give the
ideal readings (the 2012 paper's accelerometer model, eqs. 17-19, in 3-D; the impedance paper's
force-sensor relation, eq. 1) and the environment forces.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from fmus.common.noise import make_rng, random_walk_increment, white_noise
from fmus.common.sample_time import UNSTAMPED, measurement_time

G = 9.81


# ---------------------------------------------------------------------------------------------
# Sample time
# ---------------------------------------------------------------------------------------------
T_TRUTH_DESCRIPTION = ("time the truth inputs stand for, stamped by their producer (the plant's "
                       "t_state); unconnected (negative): the end of the step")


def input_time(t: float, dt: float, t_truth: float = UNSTAMPED) -> float:
    """The time the inputs of ``doStep(t, dt)`` stand for, and so the time stamp ``t_meas`` of a
    sample taken in that step, in every FlexFusion sensor (Encoder, Imu, Tracker).

    ``t_truth`` is the producer's own stamp of those inputs (the plant's ``t_state``: its time
    after its last step), an optional input of every sensor: connected (>= 0), it is the answer
    under any master. Unconnected (negative), the answer is ``t + dt``, the end of the step: a
    Gauss-Seidel master (ours) steps the producer first and sets its values of ``t + dt``, the
    plant's ``t_state`` then says the same, to the bit. A Jacobi master (libcosim) sets the values
    of ``t``, and ours the values of ``t + h`` to a sensor slower than the plant (``h`` the
    plant's step): there only the producer's stamp is right, as a sensor cannot tell these cases
    apart from its inputs. ``input_time(t_start, 0.0, t_truth)`` is the stamp in Initialization
    Mode.
    """
    return measurement_time(t_truth, t + dt)


# ---------------------------------------------------------------------------------------------
# Imperfections
# ---------------------------------------------------------------------------------------------
def butterworth_coefficients(cutoff: float, dt: float, order: int) -> tuple[np.ndarray, np.ndarray]:
    """Discrete Butterworth low-pass (bilinear transform with pre-warping) of order 1 or 2.

    Pre-warping makes the discrete magnitude exactly ``1/sqrt(2)`` (-3 dB) at ``cutoff``; the
    discrete magnitude is ``|H| = 1 / sqrt(1 + (tan(pi f dt) / tan(pi fc dt))**(2 order))``.

    Returns
    -------
    b, a
        Numerator ``b[0..order]`` and denominator ``a[0..order]`` (``a[0] = 1``).
    """
    k = math.tan(math.pi * cutoff * dt)
    if order == 1:
        b0 = k / (1.0 + k)
        return np.array([b0, b0]), np.array([1.0, (k - 1.0) / (k + 1.0)])
    if order == 2:
        r2 = math.sqrt(2.0)
        norm = 1.0 / (1.0 + r2 * k + k * k)
        b0 = k * k * norm
        return (np.array([b0, 2.0 * b0, b0]),
                np.array([1.0, 2.0 * (k * k - 1.0) * norm, (1.0 - r2 * k + k * k) * norm]))
    raise ValueError(f"filter order must be 1 or 2, got {order}")


def butterworth_magnitude(f: np.ndarray | float, cutoff: float, dt: float, order: int) -> np.ndarray:
    """Analytic magnitude at frequency ``f`` (Hz) of :func:`butterworth_coefficients`' filter of
    ``order`` 1 or 2 with ``cutoff`` (Hz), discretised at ``dt`` (s) (bilinear transform, the
    cutoff prewarped)."""
    ratio = np.tan(np.pi * np.asarray(f, dtype=float) * dt) / math.tan(math.pi * cutoff * dt)
    return 1.0 / np.sqrt(1.0 + ratio ** (2 * order))


def quantise(x: np.ndarray, resolution: np.ndarray | float) -> np.ndarray:
    """Round to the nearest multiple of ``resolution`` (a zero resolution leaves ``x`` alone)."""
    res = np.broadcast_to(np.asarray(resolution, dtype=float), np.shape(x))
    out = np.array(x, dtype=float, copy=True)
    on = res > 0.0
    out[on] = np.round(out[on] / res[on]) * res[on]
    return out


class SensorChannels:
    """``n`` sensor channels with the usual imperfections, vectorised.

    Per call of :meth:`step` (one communication step ``dt``, input ``x`` held over the step):

    1. anti-aliasing low-pass (Butterworth, order 1 or 2, ``cutoff`` Hz, 0 = off) running at the
       input rate ``1/dt``;
    2. sample-and-hold at the sensor's own ``sample_rate`` (0 = sample every step); the
       sample period must be an integer multiple of ``dt``. On a sample:
    3. scale-factor error ``(1 + scale) x``;
    4. constant ``bias`` plus a bias random walk of intensity ``bias_rw`` (per sqrt(s));
    5. white noise of standard deviation ``noise`` per sample;
    6. quantisation to ``resolution`` (0 = off, round to nearest);
    7. saturation at ``+-range`` (clipped; :attr:`saturated` flags the channels at or beyond it).

    :attr:`t_meas` is the time stamp of the held reading: the ``time`` given with the input
    that was sampled (:func:`input_time` in the FMUs).

    Every parameter is a scalar or a length-``n`` array. The white noise and the random walk use
    independent streams ``"<stream>/noise"`` and ``"<stream>/bias_rw"`` of ``seed``.

    Parameters
    ----------
    filter_order
        Order of the anti-aliasing Butterworth low-pass, 1 or 2.
    names
        FMU parameter names used in error messages, keys ``"sample_rate"`` and ``"cutoff"``.
    """

    def __init__(self, n: int, *, seed: int = 0, stream: str = "", noise: float | Sequence[float] = 0.0,
                 bias: float | Sequence[float] = 0.0, bias_rw: float | Sequence[float] = 0.0,
                 scale: float | Sequence[float] = 0.0, resolution: float | Sequence[float] = 0.0,
                 range: float | Sequence[float] = math.inf, sample_rate: float = 0.0,  # noqa: A002
                 cutoff: float = 0.0, filter_order: int = 2, names: dict[str, str] | None = None) -> None:
        def vec(v: float | Sequence[float]) -> np.ndarray:
            return np.broadcast_to(np.asarray(v, dtype=float), (n,)).copy()

        self.n = n
        self.noise, self.bias, self.bias_rw = vec(noise), vec(bias), vec(bias_rw)
        self.scale, self.resolution, self.range = vec(scale), vec(resolution), vec(range)
        self.sample_rate, self.cutoff, self.filter_order = float(sample_rate), float(cutoff), int(filter_order)
        self.names = {"sample_rate": "sample_rate", "cutoff": "cutoff", **(names or {})}
        if self.filter_order not in (1, 2):
            raise ValueError(f"filter order must be 1 or 2, got {filter_order}")
        self._rng_noise = make_rng(seed, f"{stream}/noise")
        self._rng_rw = make_rng(seed, f"{stream}/bias_rw")
        self.walk = np.zeros(n)                 # bias random-walk state
        self.output = np.zeros(n)               # held reading
        self.t_meas = math.nan                   # its time stamp
        self.saturated = np.zeros(n, dtype=bool)
        self._z = np.zeros((max(self.filter_order, 1), n))   # filter state (direct form II transposed)
        self._b = self._a = None
        self._dt_filter = None
        self._filter_ready = False
        self._dt_sample = None
        self._period_steps = 1
        self._count = 0                          # steps since the last sample

    # -- pieces ------------------------------------------------------------------------------
    def _limit(self) -> np.ndarray:
        """The largest representable magnitude (range rounded down to the resolution)."""
        lim = self.range.copy()
        q = (self.resolution > 0) & np.isfinite(lim)
        lim[q] = np.floor(lim[q] / self.resolution[q] * (1 + 1e-12)) * self.resolution[q]
        return lim

    def _finish(self, y: np.ndarray) -> np.ndarray:
        """Quantisation and saturation; sets :attr:`saturated`."""
        y = quantise(y, self.resolution)
        lim = self._limit()
        self.saturated = np.abs(y) >= lim
        return np.clip(y, -lim, lim)

    def _design(self, dt: float) -> None:
        if self.cutoff >= 0.5 / dt:
            raise ValueError(f"parameter '{self.names['cutoff']}' = {self.cutoff:g} Hz must be below "
                             f"the Nyquist frequency {0.5 / dt:g} Hz of the communication step {dt:g} s")
        self._b, self._a = butterworth_coefficients(self.cutoff, dt, self.filter_order)
        self._dt_filter = dt

    def _reset_filter(self, x: np.ndarray) -> None:
        """Steady state for a constant input ``x`` (no start-up transient)."""
        if self._b is None:
            self._z[:] = 0.0
            self._filter_ready = True
            return
        b, a = self._b, self._a
        if self.filter_order == 1:
            self._z[0] = (1.0 - b[0]) * x
        else:
            self._z[1] = (b[2] - a[2]) * x
            self._z[0] = (1.0 - b[0]) * x
        self._filter_ready = True

    def lowpass(self, x: np.ndarray, dt: float) -> np.ndarray:
        """One step of the anti-aliasing filter (identity when ``cutoff`` is 0)."""
        x = np.asarray(x, dtype=float)
        if self.cutoff <= 0.0:
            return x.copy()
        if self._dt_filter is None or abs(dt - self._dt_filter) > 1e-12 * dt:
            self._design(dt)
        if not self._filter_ready:
            self._reset_filter(x)
        b, a, z = self._b, self._a, self._z
        y = b[0] * x + z[0]
        if self.filter_order == 1:
            z[0] = b[1] * x - a[1] * y
        else:
            z[0] = b[1] * x - a[1] * y + z[1]
            z[1] = b[2] * x - a[2] * y
        return y

    def _check_period(self, dt: float) -> None:
        if not dt > 0.0:
            raise ValueError(f"communication step must be positive, got {dt!r}")
        if self._dt_sample is not None and abs(dt - self._dt_sample) <= 1e-12 * dt:
            return
        n_steps = 1
        if self.sample_rate > 0.0:
            ratio = 1.0 / (self.sample_rate * dt)
            n_steps = int(round(ratio))
            if n_steps < 1 or abs(ratio - n_steps) > 1e-9 * ratio:
                raise ValueError(
                    f"parameter '{self.names['sample_rate']}' = {self.sample_rate:g} Hz: the sample "
                    f"period {1.0 / self.sample_rate:g} s is not an integer multiple of the "
                    f"communication step {dt:g} s")
        if self._dt_sample is not None:
            self._count %= n_steps
        self._period_steps = n_steps
        self._dt_sample = dt

    # -- use ---------------------------------------------------------------------------------
    def initial(self, x: np.ndarray, time: float = 0.0) -> np.ndarray:
        """The reading before the first step, stamped ``time``: bias, scale, quantisation and
        saturation of ``x`` (no noise); the filter will start in steady state at the first
        step's input."""
        self.t_meas = float(time)
        self.output = self._finish((1.0 + self.scale) * np.asarray(x, dtype=float) + self.bias + self.walk)
        return self.output

    def step(self, x: np.ndarray, dt: float, time: float = math.nan) -> np.ndarray:
        """Advance one communication step with input ``x``, the value at ``time``; returns the
        (held) reading. A sample taken now is stamped ``time`` (:attr:`t_meas`).

        Raises
        ------
        ValueError
            Naming ``sample_rate`` if the sample period is not an integer multiple of ``dt``, or
            ``cutoff`` if the cut-off is not below the Nyquist frequency of ``dt``.
        """
        self._check_period(dt)
        y = self.lowpass(x, dt)
        if self._count == 0:
            period = self._period_steps * dt
            self.walk += random_walk_increment(self._rng_rw, self.bias_rw, period, self.n)
            y = (1.0 + self.scale) * y + self.bias + self.walk + white_noise(self._rng_noise, self.noise, self.n)
            self.output = self._finish(y)
            self.t_meas = float(time)
        self._count = (self._count + 1) % self._period_steps
        return self.output


# ---------------------------------------------------------------------------------------------
# Rotations and ideal readings
# ---------------------------------------------------------------------------------------------
def rot_y(phi: float) -> np.ndarray:
    """``Ry(phi)``: tool frame to world (rotation about +y)."""
    c, s = math.cos(phi), math.sin(phi)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_rpy(rpy: Sequence[float]) -> np.ndarray:
    """Mounting rotation from ``rpy`` = (roll, pitch, yaw) in rad (``Rz(yaw) @ Ry(pitch) @
    Rx(roll)``), sensor to tool."""
    r, p, y = (float(v) for v in rpy)
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    return rz @ ry @ rx


def sensor_rotation(phi: float, mount_rpy: Sequence[float]) -> np.ndarray:
    """``R_s = Ry(phi) @ R_mount``: sensor frame to world, for the tool angle ``phi`` (rad) and
    the mount's ``mount_rpy`` (:func:`rot_rpy`)."""
    return rot_y(phi) @ rot_rpy(mount_rpy)


def _xz(v: Sequence[float]) -> np.ndarray:
    return np.array([float(v[0]), 0.0, float(v[1])])


def imu_reading(a_world_xz: Sequence[float], phi: float, omega: float, mount_rpy: Sequence[float],
                g: float = G) -> tuple[np.ndarray, np.ndarray]:
    """Ideal 3-axis accelerometer and gyro readings in the sensor frame.

    Specific force ``acc_s = R_s^T (a - g_vec)`` (the 2012 paper's accelerometer model,
    eqs. 17-19, in 3-D; at rest +g on a vertical sensor z) and angular rate
    ``gyro_s = R_s^T (0, omega, 0)``.

    Parameters
    ----------
    a_world_xz
        Acceleration of the mount point, world x and z (m/s2).
    phi, omega
        Tool angle about +y (rad) and its rate (rad/s).
    mount_rpy
        Mounting roll, pitch, yaw of the sensor on the tool (rad).
    """
    rs = sensor_rotation(phi, mount_rpy)
    acc = rs.T @ (_xz(a_world_xz) - np.array([0.0, 0.0, -g]))
    gyro = rs.T @ np.array([0.0, float(omega), 0.0])
    return acc, gyro


def force_sensor_reading(f_ext_xz: Sequence[float], a_tool_xz: Sequence[float], phi: float,
                         m_tool: float, mount_rpy: Sequence[float], g: float = G) -> np.ndarray:
    """Ideal wrist force in the sensor frame (the impedance paper's eq. 1, in 3-D).

    ``f_s = R_s^T (m_tool (a_tool - g_vec) - f_ext)``: the force the sensor exerts on the tool
    balances inertia, weight and the contact force ``f_ext`` (``f_ext_xz``) ON the tool (world x, z). At rest
    in free space with a zero mount it reads ``+m_tool g`` on sensor z. ``a_tool_xz`` is the
    tool's acceleration (m/s^2, world x, z), ``phi`` the tool angle and ``mount_rpy`` the
    sensor's mount (:func:`sensor_rotation`).
    """
    rs = sensor_rotation(phi, mount_rpy)
    return rs.T @ (float(m_tool) * (_xz(a_tool_xz) - np.array([0.0, 0.0, -g])) - _xz(f_ext_xz))


def calibrate_tool(phis: Sequence[float], readings: np.ndarray, g: float = G
                   ) -> tuple[float, np.ndarray, float]:
    """Tool mass and force-sensor bias from static wrist-sensor readings in a few tool angles.

    At rest the sensor reads ``f_k = m u_k + b`` with ``u_k = Ry(phi_k)^T (0, 0, g)`` (the
    impedance paper's eq. 1 with ``a = 0`` and no contact, :func:`force_sensor_reading`, for the
    nominal mount) plus its bias ``b``. Stacking ``[u_k  I3] (m, b) = f_k`` over the poses gives a
    linear least-squares problem; it needs at least two different angles. What the model leaves
    out (the sensor's scale-factor error, its mounting error) goes into the estimates: that is
    the calibration's error.

    Parameters
    ----------
    phis
        Tool angles of the poses (rad).
    readings
        (len(phis), 3) mean sensor reading in each pose (N).

    Returns
    -------
    m, b, rms
        Tool mass (kg), bias (3,) (N) and the RMS residual of the fit (N).
    """
    phis = np.asarray(phis, dtype=float)
    f = np.asarray(readings, dtype=float).reshape(len(phis), 3)
    if len(np.unique(np.round(phis, 12))) < 2:
        raise ValueError("the tool calibration needs readings in at least two tool angles")
    u = np.column_stack([-g * np.sin(phis), np.zeros_like(phis), g * np.cos(phis)])
    A = np.zeros((3 * len(phis), 4))
    A[:, 0] = u.reshape(-1)
    A[:, 1:] = np.tile(np.eye(3), (len(phis), 1))
    theta, *_ = np.linalg.lstsq(A, f.reshape(-1), rcond=None)
    rms = float(np.sqrt(np.mean((A @ theta - f.reshape(-1)) ** 2)))
    return float(theta[0]), theta[1:], rms


# ---------------------------------------------------------------------------------------------
# Environment
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Wall:
    """A one-sided spring-damper wall: plane through ``point`` with unit ``normal`` (x, z)
    pointing out of the wall into free space."""

    point: tuple[float, float] = (1.30, 0.0)
    normal: tuple[float, float] = (-1.0, 0.0)
    stiffness: float = 5000.0
    damping: float = 50.0
    enabled: bool = True


def penetration(p_tool: Sequence[float], wall: Wall) -> float:
    """Depth of the tool at ``p_tool`` (m, world x, z) inside the ``wall`` along its normal (m);
    negative outside."""
    n = np.asarray(wall.normal, dtype=float)
    n = n / np.linalg.norm(n)
    return float(-(np.asarray(p_tool, dtype=float) - np.asarray(wall.point, dtype=float)) @ n)


def contact_force(p_tool: Sequence[float], v_tool: Sequence[float], wall: Wall) -> np.ndarray:
    """Force of the ``wall`` ON the tool at ``p_tool`` moving at ``v_tool`` (m, m/s; world x
    and z), world x and z (N).

    ``f = n max(0, k d - c v.n)`` when the penetration ``d > 0`` (a Kelvin-Voigt contact,
    the environment model of the impedance paper with 5 N/mm), zero outside; the clip at zero
    means the wall never pulls the tool (it lets go when the tool retracts quickly).
    """
    if not wall.enabled:
        return np.zeros(2)
    d = penetration(p_tool, wall)
    if d <= 0.0:
        return np.zeros(2)
    n = np.asarray(wall.normal, dtype=float)
    n = n / np.linalg.norm(n)
    push = wall.stiffness * d - wall.damping * float(np.asarray(v_tool, dtype=float) @ n)
    return max(push, 0.0) * n


def hammer_force(t: float, times: Sequence[float], force_xz: Sequence[float], duration: float) -> np.ndarray:
    """Half-sine hammer pulses ON the tool, world x and z (N).

    Each strike at ``t0`` in ``times`` adds ``force_xz sin(pi (t - t0) / duration)`` for
    ``t0 <= t < t0 + duration`` (impulse ``force_xz duration 2/pi``): the rubber-hammer
    excitation of the 2009 paper (section IV-A). Times ``<= 0`` or NaN are unused.
    """
    f = np.zeros(2)
    if duration <= 0.0:
        return f
    for t0 in times:
        t0 = float(t0)
        if not (t0 > 0.0) or not (t0 <= t < t0 + duration):
            continue
        f += np.asarray(force_xz, dtype=float) * math.sin(math.pi * (t - t0) / duration)
    return f


__all__ = ["UNSTAMPED", "T_TRUTH_DESCRIPTION", "input_time", "SensorChannels", "butterworth_coefficients",
           "butterworth_magnitude", "quantise", "rot_y", "rot_rpy", "sensor_rotation", "imu_reading",
           "force_sensor_reading", "calibrate_tool", "Wall", "penetration", "contact_force", "hammer_force",
           "G"]

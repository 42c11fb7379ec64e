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

import functools
import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from fmus.common import cython_kernels, irb4600, quaternion
from fmus.common.frames import G, rot_rpy, sensor_rotation
from fmus.common.noise import make_rng, normal_rows, reseed_param, reseeded_rng
from fmus.common.parameters import ParameterError, param
from fmus.common.sample_time import UNSTAMPED, measurement_time


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


# SensorChannels' state is one float array, ``work`` (a kernel call costs about 0.1 us per array
# it takes): a header (steps since the last sample, steps per sample, the next row of the drawn
# random numbers, whether the low-pass has started, its order (0: none), the number of channels
# n), the low-pass coefficients b0, b1, b2, a1, a2, the parameter table (rows _GAIN ... _LIM, n
# each), then per element (runs * n) the low-pass state (2 rows), the bias walk and the
# saturation flags (1.0: saturated)
_COUNT, _PERIOD, _ROW, _STARTED, _ORDER, _N = range(6)
_FLOAT = np.dtype(float)
_COEF = 6
_TABLE = _COEF + 5
_GAIN, _BIAS, _RW, _NOISE, _RES, _LIM = range(6)


# compiled (robot_plant/sensor_kernels.pyx: its names of the work array's parts are these;
# tests/test_compiled_kernels.py holds them equal): one step of the channels on the work array
_kernels = cython_kernels.load("robot_plant.sensor_kernels")
_channels_kernel = _kernels.channels_kernel
_channels_step = _kernels.channels_step
_HELD, _SAMPLED, _USED_UP = 0, 1, 2       # what _channels_step returns


class SensorChannels:
    """``n`` sensor channels with the usual imperfections.

    One compiled call (:func:`_channels_step`) steps every channel; the state is held in one
    array, for readings of shape :attr:`shape` (``(n,)``; the batched study engine's subclass
    :class:`~fmus.robot_plant.sensor_batched.RunSensorChannels`: ``(runs, n)``), so one
    definition serves both paths.

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
    that was sampled (:func:`input_time` in the FMUs). Each sample is a new :attr:`output`
    array (a caller may keep it), unless ``out`` is given: then every reading is written into
    that array (an FMU's output), which :attr:`output` is.

    Every parameter is a scalar or a length-``n`` array. The white noise and the random walk use
    independent streams ``"<stream>/noise"`` and ``"<stream>/bias_rw"`` of ``seed``, drawn
    ahead in blocks of :attr:`BLOCK` samples (:func:`fmus.common.noise.normal_rows`); :meth:`reseed`
    restarts both from another seed (:mod:`fmus.common.noise`).

    Parameters
    ----------
    filter_order
        Order of the anti-aliasing Butterworth low-pass, 1 or 2.
    names
        FMU parameter names used in error messages, keys ``"sample_rate"`` and ``"cutoff"``.
    out
        Float array of ``n`` the readings are written into, or None (a new array per sample).
    """

    BLOCK = 256       # samples per draw of the random numbers

    def __init__(self, n: int, *, seed: int = 0, stream: str = "", noise: float | Sequence[float] = 0.0,
                 bias: float | Sequence[float] = 0.0, bias_rw: float | Sequence[float] = 0.0,
                 scale: float | Sequence[float] = 0.0, resolution: float | Sequence[float] = 0.0,
                 range: float | Sequence[float] = math.inf, sample_rate: float = 0.0,  # noqa: A002
                 cutoff: float = 0.0, filter_order: int = 2, names: dict[str, str] | None = None,
                 out: np.ndarray | None = None) -> None:
        def vec(v: float | Sequence[float]) -> np.ndarray:
            return np.broadcast_to(np.asarray(v, dtype=float), (n,)).copy()

        self.n = n
        self.noise, self.bias, self.bias_rw = vec(noise), vec(bias), vec(bias_rw)
        self.scale, self.resolution, self.range = vec(scale), vec(resolution), vec(range)
        self.sample_rate, self.cutoff, self.filter_order = float(sample_rate), float(cutoff), int(filter_order)
        self.names = {"sample_rate": "sample_rate", "cutoff": "cutoff", **(names or {})}
        if self.filter_order not in (1, 2):
            raise ValueError(f"filter order must be 1 or 2, got {filter_order}")
        self.stream = stream
        self._rng_noise = make_rng(seed, f"{stream}/noise")
        self._rng_rw = make_rng(seed, f"{stream}/bias_rw")
        self._work = np.zeros(_TABLE + 6 * n)
        self._work[_PERIOD], self._work[_N] = 1.0, n
        # the kernel's per-channel constants; the walk's row is set with the step (_prepare)
        self._table()[:] = [1.0 + self.scale, self.bias, np.zeros(n), self.noise, self.resolution, self._limit()]
        self._dt_filter = None
        self._dt_sample = None
        self._dt = None                          # the step the checks, design and walk scale are for
        self.t_meas = math.nan                   # the held reading's time stamp
        self._bound = out is not None
        self._allocate((n,))
        if out is not None:
            self.output = out
        self._rows = np.empty((0, 2 * n))        # drawn at the first step

    def _allocate(self, shape: tuple[int, ...]) -> None:
        """The state for readings of ``shape``: :attr:`output` (the held reading), and in the
        work array the filter's, the bias walk's and the saturation flags (zero)."""
        self.shape = shape
        size = int(np.prod(shape))
        head = _TABLE + 6 * self.n
        self._work = np.concatenate([self._work[:head], np.zeros(4 * size)])
        self.output = np.zeros(shape)

    def _table(self) -> np.ndarray:
        """The parameter table in the work array, (6, n) (a view)."""
        return self._work[_TABLE:_TABLE + 6 * self.n].reshape(6, self.n)

    def _elements(self, part: int) -> np.ndarray:
        """Part ``part`` (0, 1: the filter state, 2: the bias walk, 3: the saturation flags) of
        the per-element state in the work array, of :attr:`shape` (a view)."""
        size = self.output.size
        first = _TABLE + 6 * self.n + part * size
        return self._work[first:first + size].reshape(self.shape)

    @property
    def walk(self) -> np.ndarray:
        """The bias random walk, of :attr:`shape` (a view of the state)."""
        return self._elements(2)

    @property
    def saturated(self) -> np.ndarray:
        """Whether each channel's held reading is at or beyond its range, of :attr:`shape`."""
        return self._elements(3) != 0.0

    # -- pieces ------------------------------------------------------------------------------
    def _draws(self) -> tuple[np.ndarray, np.ndarray]:
        """The next :attr:`BLOCK` samples' standard normal numbers of the walk and the noise
        streams, one row (of every channel's number) per sample."""
        return normal_rows(self._rng_rw, self.n, self.BLOCK), normal_rows(self._rng_noise, self.n, self.BLOCK)

    def _draw(self) -> None:
        self._rows = np.concatenate(self._draws(), axis=1)
        self._work[_ROW] = 0.0

    def reseed(self, seed: int) -> None:
        """Draw the noise and the bias walk from now on from ``seed``'s reseeded streams
        (:func:`fmus.common.noise.reseeded_rng`); every other state carries on."""
        self._rng_noise = reseeded_rng(seed, f"{self.stream}/noise")
        self._rng_rw = reseeded_rng(seed, f"{self.stream}/bias_rw")
        self._draw()

    def _limit(self) -> np.ndarray:
        """The largest representable magnitude (range rounded down to the resolution)."""
        lim = self.range.copy()
        q = (self.resolution > 0) & np.isfinite(lim)
        lim[q] = np.floor(lim[q] / self.resolution[q] * (1 + 1e-12)) * self.resolution[q]
        return lim

    def _design(self, dt: float) -> None:
        if self.cutoff >= 0.5 / dt:
            raise ValueError(f"parameter '{self.names['cutoff']}' = {self.cutoff:g} Hz must be below "
                             f"the Nyquist frequency {0.5 / dt:g} Hz of the communication step {dt:g} s")
        b, a = butterworth_coefficients(self.cutoff, dt, self.filter_order)
        coef = np.zeros(5)
        coef[:len(b)], coef[3:3 + len(a) - 1] = b, a[1:]
        self._work[_COEF:_COEF + 5] = coef
        self._work[_ORDER] = self.filter_order
        self._dt_filter = dt

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
            self._work[_COUNT] %= n_steps
        self._work[_PERIOD] = n_steps
        self._dt_sample = dt

    def _prepare(self, dt: float) -> None:
        """For steps of ``dt`` (one not seen at the last step): the sample period's check, the
        low-pass designed (within 1e-12 of the step it has, it stays), the walk's scale over
        one sample period, and random numbers if the last are used up."""
        self._check_period(dt)
        if self.cutoff > 0.0 and (self._dt_filter is None or abs(dt - self._dt_filter) > 1e-12 * dt):
            self._design(dt)
        self._table()[_RW] = self.bias_rw * np.sqrt(int(self._work[_PERIOD]) * dt)
        self._dt = dt
        if self._work[_ROW] == len(self._rows):
            self._draw()

    @staticmethod
    def _flat(x: np.ndarray) -> np.ndarray:
        """``x`` as the kernels take it: a 1-D float array (a view where it can be)."""
        if type(x) is not np.ndarray or x.ndim != 1 or x.dtype is not _FLOAT:
            x = np.ascontiguousarray(x, dtype=float).reshape(-1)
        return x

    # -- use ---------------------------------------------------------------------------------
    def initial(self, x: np.ndarray, time: float = 0.0) -> np.ndarray:
        """The reading before the first step, stamped ``time``: bias, scale, quantisation and
        saturation of ``x`` (no noise); the filter will start in steady state at the first
        step's input."""
        self.t_meas = float(time)
        if not self._bound:
            self.output = np.empty(self.shape)
        _channels_kernel(self._flat(x), self._work, self.output.reshape(-1), self._rows, 0, 0, False, True, False)
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
        if dt != self._dt:
            self._prepare(dt)
        work = self._work
        if not self._bound and work[_COUNT] == 0.0:
            self.output = np.empty(self.shape)       # a new array per sample (a caller may keep it)
        out = self.output if self._bound else self.output.reshape(-1)
        done = _channels_step(self._flat(x), work, out, self._rows)
        if done:
            self.t_meas = float(time)
            if done == _USED_UP:
                self._draw()
        return self.output


# ---------------------------------------------------------------------------------------------
# Rotations and ideal readings
# ---------------------------------------------------------------------------------------------
def _xz(v: Sequence[float]) -> np.ndarray:
    return np.array([float(v[0]), 0.0, float(v[1])])


@functools.lru_cache(maxsize=64)
def mount_matrix(mount_rpy: tuple) -> np.ndarray:
    """:func:`~fmus.common.frames.rot_rpy` of ``mount_rpy`` as a flat row-major array of 9
    (shared by every caller: not to be written)."""
    return np.ascontiguousarray(rot_rpy(mount_rpy), dtype=float).reshape(-1)


#: ``imu_reading_into(a_world_xz, phi, omega, mount, g, acc, gyro)``: :func:`imu_reading` of
#: ``a_world_xz``, ``phi``, ``omega`` and ``g`` into the float arrays ``acc`` and ``gyro`` (3
#: each), with the mount matrix ``mount`` of :func:`mount_matrix`: the same operations, compiled
#: (robot_plant/sensor_kernels.pyx)
imu_reading_into = _kernels.imu_reading_into


def imu_reading(a_world_xz: Sequence[float], phi: float, omega: float, mount_rpy: Sequence[float],
                g: float = G) -> tuple[np.ndarray, np.ndarray]:
    """Ideal 3-axis accelerometer and gyro readings in the sensor frame.

    Specific force ``acc_s = R_s^T (a - g_vec)`` (the 2012 paper's accelerometer model,
    eqs. 17-19, in 3-D; at rest +g on a vertical sensor z) and angular rate
    ``gyro_s = R_s^T (0, omega, 0)``, ``R_s = Ry(phi) R_mount``
    (:func:`~fmus.common.frames.sensor_rotation`) written out on plain floats
    (:func:`imu_reading_into`: this runs every step of the Imu; the same numbers as the matrix
    products to a few units of the last place).

    Parameters
    ----------
    a_world_xz
        Acceleration of the mount point, world x and z (m/s2).
    phi, omega
        Tool angle about +y (rad) and its rate (rad/s).
    mount_rpy
        Mounting roll, pitch, yaw of the sensor on the tool (rad).
    """
    acc, gyro = np.empty(3), np.empty(3)
    imu_reading_into(np.asarray(a_world_xz, dtype=float).reshape(-1), float(phi), float(omega),
                     mount_matrix(tuple(mount_rpy)), float(g), acc, gyro)
    return acc, gyro


def imu_reading_3d(a_world: Sequence[float], quat_tool: Sequence[float], omega_world: Sequence[float],
                   mount: np.ndarray, g: float = G) -> tuple[np.ndarray, np.ndarray]:
    """Ideal accelerometer and gyro readings in the sensor frame of a tool moving in 3-D (the
    six-axis robot's IMU): the 2012 paper's accelerometer model (Axelsson et al. 2012,
    eqs. 17-19) with the tool's full orientation, ``acc_s = R_s^T (a - g_vec)`` and
    ``gyro_s = R_s^T omega``, ``R_s = R_tool R_mount``, ``g_vec = (0, 0, -g)``.

    Parameters
    ----------
    a_world
        Kinematic acceleration of the mount point, world x, y, z [m/s2] (no gravity).
    quat_tool
        Tool orientation, unit quaternion (w, x, y, z), tool frame to world.
    omega_world
        The tool's angular velocity, world axes [rad/s].
    mount
        Mounting rotation, sensor to tool (3x3, or the flat 9 of :func:`mount_matrix`).
    g
        Gravity [m/s2].
    """
    R = quaternion.to_matrix(quat_tool) @ np.asarray(mount, float).reshape(3, 3)
    a = np.asarray(a_world, float)
    f = np.array([a[0], a[1], a[2] + g])
    return R.T @ f, R.T @ np.asarray(omega_world, float)


def arm_plane_reading(acc_s: Sequence[float], gyro_s: Sequence[float], q_wrist: Sequence[float],
                      mount: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The six-axis robot's IMU readings ``acc_s``, ``gyro_s`` (sensor frame) expressed in the
    frame the axis-2/3 estimators take, as on the real robots: the sensor frame of a tool at
    wrist angles zero, ``R_3 R_mount`` (``R_3``: link 3's frame, x along the forearm and z in
    the plane of axes 2-3, y along axes 2-3), from the wrist's angles ``q_wrist`` (axes 4-6
    [rad], measured: the encoders over the gear ratios) and the nominal ``mount`` (sensor to
    tool, 3x3 or flat 9): ``R_mount^T W R_mount acc_s`` with ``W = Rx(q4) Ry(q5) Rx(q6)``
    (the wrist's rotation, :mod:`fmus.common.irb4600`). Their x and z components lie in the
    plane of axes 2-3 (with ``mount`` the identity); y is out of it.
    """
    M = np.asarray(mount, float).reshape(3, 3)
    rot = irb4600.rotation
    W = rot(0, float(q_wrist[0])) @ rot(1, float(q_wrist[1])) @ rot(0, float(q_wrist[2]))
    T = M.T @ W @ M
    return T @ np.asarray(acc_s, float), T @ np.asarray(gyro_s, float)


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
def penetration(p_tool: Sequence[float], wall: ContactEnvironmentParameters) -> float:
    """Depth of the tool at ``p_tool`` (m, world x, z) inside the ``wall`` (plane through ``wall_point`` with the normal
    ``wall_normal`` pointing out of the wall into free space) along the normal (m); negative
    outside."""
    n = np.asarray(wall.wall_normal, dtype=float)
    n = n / np.linalg.norm(n)
    return float(-(np.asarray(p_tool, dtype=float) - np.asarray(wall.wall_point, dtype=float)) @ n)


def contact_force(p_tool: Sequence[float], v_tool: Sequence[float],
                  wall: ContactEnvironmentParameters) -> np.ndarray:
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
    n = np.asarray(wall.wall_normal, dtype=float)
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


RESOLVER = "16-bit resolver-to-digital conversion per motor revolution (e.g. AD2S1210 at 16 bit)"


@dataclass(frozen=True)
class EncoderParameters:
    """Parameters of the Encoder FMU (both joints share them except bias and scale)."""

    resolution: float = param(2.0 * math.pi / 2 ** 16, "rad", "quantisation step on the motor side "
                              "(2 pi / 2^16 = 9.6e-5 rad; 0 = off)", low=0.0, source=RESOLVER)
    noise: float = param(2e-5, "rad", "white noise std per sample (about 0.2 LSB)", low=0.0,
                         source="assumed resolver electrical noise, below one count")
    bias: tuple = param((0.0, 0.0), "rad", "constant offset per joint (calibrated: 0)")
    bias_rw: float = param(0.0, "rad/s0.5", "bias random-walk intensity per sqrt(s)", low=0.0)
    scale: tuple = param((0.0, 0.0), "1", "scale-factor error per joint (reading = (1+scale) q)",
                         low=-0.5, high=0.5)
    cutoff: float = param(0.0, "Hz", "anti-aliasing low-pass cut-off (0 = off; an encoder has none)",
                          low=0.0)
    filter_order: int = param(2, "1", "anti-aliasing filter order (1 or 2, Butterworth)", low=1, high=2)
    sample_rate: float = param(0.0, "Hz", "sample rate with sample-and-hold (0 = every communication "
                               "step; the papers sample at 2 kHz). Its period must be an integer "
                               "multiple of the communication step", low=0.0,
                               source="2009 and 2012 papers: 2 kHz")
    seed: int = param(1, "1", "seed of the noise streams", low=0)
    reseed: int = reseed_param()


@dataclass(frozen=True)
class Encoder6Parameters(EncoderParameters):
    """Parameters of the Encoder6 FMU: the Encoder's, bias and scale per axis 1-6."""

    bias: tuple = param((0.0,) * 6, "rad", "constant offset per axis (calibrated: 0)")
    scale: tuple = param((0.0,) * 6, "1", "scale-factor error per axis (reading = (1+scale) q)",
                         low=-0.5, high=0.5)


@dataclass(frozen=True)
class ArmPlaneImuParameters:
    """Parameters of the ArmPlaneImu FMU: what the robot's controller knows of the wrist and
    the sensor's mounting."""

    gear_ratio: tuple = param(tuple(irb4600.arm().gear_ratio[3:]), "1", "gear ratios of axes 4-6 "
                              "(motor angle / arm angle)", low=0.0, low_inclusive=False,
                              source="irb4600.arm() (docs/six_axis.md, drive train)")
    mount_rpy: tuple = param((0.0, 0.0, 0.0), "rad", "nominal mounting roll, pitch, yaw of the IMU on "
                             "the tool (the controller's knowledge; the Imu3D's true mount may differ)",
                             low=-math.pi, high=math.pi)


MEMS = ("16-bit MEMS IMU class (e.g. Bosch BMI160 / TDK ICM-20948 data sheets: +-16 g, "
        "+-2000 deg/s, 16-bit output)")
CALIBRATION = ("assumed, no user calibration: within the sensitivity tolerances of MEMS data sheets "
               "(BMI160 / ICM-20948 class: about 0.5-1.5 %)")
MOUNTING = "assumed: mounting tolerance of a bracket on the tool, about 0.1-0.3 deg"
ACC_RANGE = 16.0 * G
GYRO_RANGE = math.radians(2000.0)


@dataclass(frozen=True)
class ImuParameters:
    """Parameters of the Imu FMU."""

    mount_rpy: tuple = param((0.004, 0.003, -0.003), "rad", "mounting roll, pitch, yaw of the sensor "
                             "on the tool (R_mount = Rz(yaw) Ry(pitch) Rx(roll), sensor to tool); the "
                             "default is a misalignment the filters do not know (0 = ideal)",
                             low=-math.pi, high=math.pi, source=MOUNTING)
    acc_noise: float = param(0.02, "m/s2", "accelerometer white noise std per sample", low=0.0,
                             source="about 150 ug/sqrt(Hz) over a 200 Hz bandwidth (MEMS class)")
    acc_bias: tuple = param((0.0, 0.0, 0.0), "m/s2", "accelerometer constant bias per axis "
                            "(after calibration: 0)", low=-ACC_RANGE, high=ACC_RANGE,
                            source="2012 paper: offset calibrated (Axelsson and Norrlof 2012)")
    acc_bias_rw: float = param(1e-3, "m/s2/s0.5", "accelerometer bias random-walk intensity per sqrt(s)",
                               low=0.0, source="assumed: a few mm/s2 drift over 10 s (MEMS class)")
    acc_scale: tuple = param((0.003, -0.004, 0.002), "1", "accelerometer scale-factor error per axis "
                             "(0 = ideal)", low=-0.5, high=0.5, source=CALIBRATION)
    acc_resolution: float = param(2.0 * ACC_RANGE / 2 ** 16, "m/s2", "accelerometer quantisation step "
                                  "(16 bit over +-16 g; 0 = off)", low=0.0, source=MEMS)
    acc_range: float = param(ACC_RANGE, "m/s2", "accelerometer range (16 g): readings saturate at it",
                             low=0.0, low_inclusive=False, source=MEMS)
    acc_cutoff: float = param(200.0, "Hz", "accelerometer anti-aliasing low-pass cut-off (0 = off); "
                              "must be below the Nyquist frequency of the communication step", low=0.0,
                              source="MEMS digital low-pass about ODR/4; the 2012 paper low-pass filters "
                              "the accelerometer")
    gyro_noise: float = param(0.005, "rad/s", "gyro white noise std per sample", low=0.0,
                              source="about 0.015 deg/s/sqrt(Hz) over 400 Hz (MEMS class)")
    gyro_bias: tuple = param((0.0, 0.0, 0.0), "rad/s", "gyro constant bias per axis (calibrated: 0)",
                             low=-GYRO_RANGE, high=GYRO_RANGE)
    gyro_bias_rw: float = param(1e-4, "rad/s/s0.5", "gyro bias random-walk intensity per sqrt(s)",
                                low=0.0, source="assumed, MEMS class")
    gyro_scale: tuple = param((-0.004, 0.005, 0.003), "1", "gyro scale-factor error per axis (0 = ideal)",
                              low=-0.5, high=0.5, source=CALIBRATION)
    gyro_resolution: float = param(2.0 * GYRO_RANGE / 2 ** 16, "rad/s", "gyro quantisation step "
                                   "(16 bit over +-2000 deg/s; 0 = off)", low=0.0, source=MEMS)
    gyro_range: float = param(GYRO_RANGE, "rad/s", "gyro range (2000 deg/s)", low=0.0,
                              low_inclusive=False, source=MEMS)
    gyro_cutoff: float = param(200.0, "Hz", "gyro anti-aliasing low-pass cut-off (0 = off)", low=0.0,
                               source=MEMS)
    filter_order: int = param(2, "1", "anti-aliasing filter order (1 or 2, Butterworth)", low=1, high=2)
    sample_rate: float = param(0.0, "Hz", "sample rate with sample-and-hold (0 = every communication "
                               "step; the papers sample at 2 kHz). Its period must be an integer "
                               "multiple of the communication step", low=0.0,
                               source="2009 and 2012 papers: 2 kHz")
    g: float = param(G, "m/s2", "gravity", low=0.0)
    seed: int = param(2, "1", "seed of the noise streams", low=0)
    reseed: int = reseed_param()


PAPER = "García, Robertsson, Gómez Ortega, Johansson (impedance paper)"
JR3 = "JR3 6-DOF wrist sensor class (the impedance paper's sensor): +-660 N, 16-bit output"


@dataclass(frozen=True)
class ForceTorqueSensorParameters:
    """Parameters of the ForceTorqueSensor FMU."""

    m_tool: float = param(12.0, "kg", "tool mass between the sensor and the tool tip", low=0.0,
                          low_inclusive=False, source=f"{PAPER}, section III (12 kg grinding tool)")
    mount_rpy: tuple = param((0.002, 0.003, -0.002), "rad", "mounting roll, pitch, yaw of the sensor "
                             "on the tool (R_mount = Rz(yaw) Ry(pitch) Rx(roll), sensor to tool); the "
                             "default is a mounting error nobody compensates (0 = ideal)",
                             low=-math.pi, high=math.pi,
                             source="assumed: flange and adapter-plate tolerances of about 0.1-0.2 deg")
    noise: float = param(0.5, "N", "white noise std per sample", low=0.0,
                         source="assumed, strain-gauge sensor of this range (about 0.1 % of range)")
    bias: tuple = param((0.0, 0.0, 0.0), "N", "constant offset per axis (after taring: 0)",
                        low=-660.0, high=660.0)
    bias_rw: float = param(0.01, "N/s0.5", "bias random-walk intensity per sqrt(s) (thermal drift)",
                           low=0.0, source="assumed: about 0.1 N drift over 100 s")
    scale: tuple = param((0.008, -0.005, 0.01), "1", "scale-factor error per axis (0 = ideal)",
                         low=-0.5, high=0.5, source="assumed within the calibration accuracy of "
                         "strain-gauge F/T sensors, about 1 % (JR3 / ATI data sheets)")
    resolution: float = param(2.0 * 660.0 / 2 ** 16, "N", "quantisation step (16 bit over +-660 N; "
                              "0 = off)", low=0.0, source=JR3)
    f_range: float = param(660.0, "N", "measuring range: readings saturate at it and set 'saturated'",
                           low=0.0, low_inclusive=False, source=JR3)
    cutoff: float = param(0.0, "Hz", "anti-aliasing low-pass cut-off (0 = off); must be below the "
                          "Nyquist frequency of the communication step", low=0.0)
    filter_order: int = param(2, "1", "anti-aliasing filter order (1 or 2, Butterworth)", low=1, high=2)
    sample_rate: float = param(0.0, "Hz", "sample rate with sample-and-hold (0 = every communication "
                               "step). Its period must be an integer multiple of the communication step",
                               low=0.0)
    g: float = param(G, "m/s2", "gravity", low=0.0)
    seed: int = param(3, "1", "seed of the noise streams", low=0)
    reseed: int = reseed_param()


def reseed(seed: int, *sources: "SensorChannels") -> None:
    """A sensor's tunable ``reseed`` parameter value ``seed`` applied to its noise ``sources``
    (anything with ``reseed``): nothing for ``-1``, the parameter's "never"."""
    if seed >= 0:
        for source in sources:
            source.reseed(seed)


def sensor_channels(p: ForceTorqueSensorParameters) -> SensorChannels:
    """The force/torque sensor's imperfections (noise, bias, scale, quantisation, range, rate,
    filter) from its parameters ``p``."""
    return SensorChannels(
        3, seed=p.seed, stream="force_sensor", noise=p.noise, bias=p.bias, bias_rw=p.bias_rw,
        scale=p.scale, resolution=p.resolution, range=p.f_range, sample_rate=p.sample_rate,
        cutoff=p.cutoff, filter_order=p.filter_order)


def calibration_readings(p: ForceTorqueSensorParameters, phis: Sequence[float], n_samples: int = 500,
                         dt: float = 1e-3) -> np.ndarray:
    """Mean readings of the sensor of parameters ``p`` at rest, free of contact, ``n_samples`` samples of ``dt`` in
    each tool angle of ``phis``: the data of :func:`fmus.robot_plant.sensor_model.calibrate_tool`.
    Returns (len(phis), 3)."""
    channels = sensor_channels(p)
    out = []
    for phi in phis:
        ideal = force_sensor_reading((0.0, 0.0), (0.0, 0.0), float(phi), p.m_tool, p.mount_rpy, p.g)
        out.append(np.mean([channels.step(ideal, dt) for _ in range(n_samples)], axis=0))
    return np.array(out)


@dataclass(frozen=True)
class ContactEnvironmentParameters:
    """Parameters of the ContactEnvironment FMU."""

    enabled: bool = param(True, "1", "whether the wall exists (false: only the hammer pulses act)")
    wall_point: tuple = param((1.30, 0.0), "m", "a point of the wall plane, world x and z",
                              source="the contact study's wall at x = 1.30 m")
    wall_normal: tuple = param((-1.0, 0.0), "1", "normal of the wall plane, world x and z, pointing out "
                               "of the wall into free space (normalised; must not be zero)",
                               low=-1.0, high=1.0)
    stiffness: float = param(5000.0, "N/m", "wall stiffness (5 N/mm)", low=0.0, low_inclusive=False,
                             source=f"{PAPER}, environment of 5 N/mm")
    damping: float = param(50.0, "N.s/m", "wall damping (acts only while in contact, never pulls)",
                           low=0.0, source="assumed: damping ratio about 0.1 with the 12 kg tool")
    hammer_times: tuple = param((0.0, 0.0, 0.0, 0.0), "s", "start times of up to four hammer "
                                "strikes (0 = unused)", low=0.0,
                                source="2009 paper, section IV: rubber-hammer strikes on the tool")
    hammer_force: tuple = param((300.0, 0.0), "N", "peak hammer force ON the tool, world x and z",
                                low=-1e4, high=1e4, source="assumed: a rubber-hammer blow of a few 100 N")
    hammer_duration: float = param(0.005, "s", "duration of a half-sine hammer pulse", low=0.0,
                                   low_inclusive=False, source="assumed: rubber hammer, a few ms")

    def check(self) -> None:
        """Cross-field rule (the ranges are checked per field): ``wall_normal`` is not the zero
        vector."""
        if math.hypot(*self.wall_normal) < 1e-9:
            raise ParameterError(f"parameter 'wall_normal' = {self.wall_normal} must not be zero")


__all__ = ["UNSTAMPED", "T_TRUTH_DESCRIPTION", "input_time", "SensorChannels", "butterworth_coefficients",
           "butterworth_magnitude", "quantise", "imu_reading",
           "force_sensor_reading", "calibrate_tool", "penetration", "contact_force", "hammer_force", "EncoderParameters", "ImuParameters", "ForceTorqueSensorParameters", "sensor_channels", "reseed", "calibration_readings", "ContactEnvironmentParameters"]

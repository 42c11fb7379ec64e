"""Contact-force observers: separate the contact force from the tool's inertial force.

Reference: García, Robertsson, Gómez Ortega, Johansson, *Sensor fusion of force and
acceleration for robot force control* (the "impedance paper" of this project). A wrist force
sensor between the robot and a tool of mass ``m`` measures (eq. 1)

.. math:: u = F + m\\,\\ddot x ,

the force ``F`` the tool exerts on the environment plus the tool's inertial force. The
observers below estimate ``F`` from ``u``, an accelerometer on the tool and the tool position.

Reconstruction of the paper's equations (the source is an OCR scan; what is written here is
self-consistent and checked by the tests in ``tests/test_force_observer_math.py``):

* state ``xi = (x, xdot)`` of the tool along one axis; ``m xi2' = u - F`` (eq. 4), i.e.
  ``xi' = A xi + B (u - F)`` with ``A = [[0, 1], [0, 0]]``, ``B = (0, 1/m)`` (eqs. 5, 11);
* measurements ``y = (x, a)`` -- tool position and tool acceleration -- arranged as
  ``y = C xi + D_u u + D_F F`` with ``C = [[1, 0], [0, 0]]``, ``D_u = (0, 1/m)``,
  ``D_F = (0, -1/m)`` (eqs. 6-7, 12). The force reading ``u`` is the model's input. The
  paper's calibration gains ``c_i`` are 1 here (our sensors are already in SI units); the
  paper's gain matrix ``K`` has columns (position, force, acceleration) and the paper itself
  uses ``k12 = k22 = 0``: with the force reading as input the force column's innovation is
  identically zero, so only ``k11, k13, k21, k23`` are kept.
* static observer (eqs. 8-10): ``F^ = D_F^+ (y - D_u u) = u - m a`` with ``D_F^+ C = 0`` and
  ``D_F^+ D_F = 1``: exact without dynamics, as sensitive to noise as the sensors are. (The
  paper stacks the force reading as a third output and its left inverse also satisfies
  ``D_F^+ D_u = 0``; with ``u`` as input, as here, ``D_u u`` is subtracted explicitly.)
* dynamic (Kalman-filter) observer (eqs. 11-19): a Kalman filter of ``xi`` that ignores
  ``F``; its innovation ``y~ = y - C xi^ - D_u u`` carries ``D_F F`` and ``F^ = D_F^+ y~``
  (eq. 19, valid because ``D_F^+ C = 0``). Because ``D_F^+ C = 0`` removes the state from
  ``D_F^+ y~ = D_F^+ (y - D_u u)``, eq. 19 gives *the same number* as the static observer,
  whatever the Kalman gain (the paper's eqs. 22 and 24 give both the same covariance
  ``D_F^+ R D_F^+T``).
  The filter's state (position, velocity) is still produced and reported.
* low-pass structure (eqs. 27-35): the observer (13) with gains ``k11, k13`` (position
  equation) and ``k21, k23`` (velocity equation),

  .. math::

     \\dot{\\hat x} &= \\hat v + k_{11}(x - \\hat x) + k_{13}(a - u/m) \\\\
     \\dot{\\hat v} &= u/m + k_{21}(x - \\hat x) + k_{23}(a - u/m)

  whose error ``e = x - x^`` obeys ``e'' + l1 e' + l0 e = (k13/m) F' - ((1 - k23)/m) F``
  (eq. 28) with ``l1 = k11``, ``l0 = k21`` (eq. 29). The force estimate is Newton's law with
  the observer's acceleration (eqs. 30, 33):

  .. math:: \\hat F = u - m\\,\\dot{\\hat v} = k_{23}(u - m a) - m k_{21}(x - \\hat x) ,

  which for ``e -> 0`` is Newton's law ``F = u - m a`` only if ``k23 = 1`` (eq. 35). With
  ``k23 = 1`` the estimation error ``F~ = F - F^`` has the transfer function (eq. 32)

  .. math:: H(s) = \\frac{k_{21} k_{13}\\, s}{s^2 + k_{11} s + k_{21}} ,

  strictly stable for ``k11, k21 > 0`` with one zero at ``s = 0``: no error for a constant
  force. The position channel also removes a constant accelerometer bias from the estimate
  (the static and Kalman observers pass it on as ``m * bias``). With ``k23 < 1`` the estimate
  is low-pass in the accelerometer noise (high-frequency gain ``k23``) at the price of lag.
  The paper's gains (section V) are ``k11 = 0.38, k13 = -0.0073, k21 = 9.05, k23 = 1``. Read
  with ``c1 = 1`` (gains in 1/s, 1/s^2 and s do not depend on the length unit) they give error
  dynamics at 0.48 Hz with damping ratio 0.06: a force transient rings for ~15 s. The scan
  does not show the paper's ``c1`` (a position in mm and ``c1 = 1000`` would instead give
  15 Hz, damping ratio 2). Our defaults keep ``k13 = -0.0073`` and ``k23 = 1`` and place the
  error dynamics at 1 Hz with damping ratio 0.7: ``k11 = 8.8 /s``, ``k21 = 39.5 /s^2``.

Planar use: every observer runs on each world axis (x, z) independently. Readings come in the
sensor frame; with the tool angle ``phi`` and ``R(phi)`` mapping tool frame to world (the
project's kinematics convention), the world readings are ``u = R f_s + m g_vec`` and
``a = R acc_s + g_vec`` (``g_vec = (0, -g)``): the force sensor and the accelerometer both see
gravity, which cancels in ``u - m a = R (f_s - m acc_s)``.

Sign convention of the output: ``F`` is the force the tool exerts ON the environment, world
frame (``F = -f_ext`` with ``f_ext`` the ContactEnvironment's force on the tool).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fmus.common.frames import G
from fmus.common.parameters import ParameterError, param

OBSERVER_KINDS = ("static", "kalman", "lowpass")

# fault codes of a sensor reading (see :func:`reading_fault`)
FAULT_NONE = 0
FAULT_SATURATED = 1
FAULT_NOT_FINITE = 2


def rotation(phi: float) -> np.ndarray:
    """``R(phi)`` mapping tool-frame (x, z) to world (x, z): ``[[cos, sin], [-sin, cos]]``."""
    c, s = np.cos(phi), np.sin(phi)
    return np.array([[c, s], [-s, c]])


def world_readings(f_s_xz: np.ndarray, acc_s_xz: np.ndarray, phi: float, m: float,
                   g: float = G) -> tuple[np.ndarray, np.ndarray]:
    """World-frame force reading with gravity removed and kinematic tool acceleration.

    Parameters
    ----------
    f_s_xz, acc_s_xz
        Force reading (N) and accelerometer specific force (m/s^2), sensor-frame x and z.
    phi
        Tool angle (rad); ``R(phi)`` maps the sensor frame to the world.
    m
        Tool mass (kg) between the force sensor and the tool tip.
    g
        Gravitational acceleration (m/s^2).

    Returns
    -------
    u, a
        ``u = R f_s + m g_vec = F + m a`` (eq. 1 in world axes) and ``a = R acc_s + g_vec``.
    """
    c, s = math.cos(phi), math.sin(phi)          # R = [[c, s], [-s, c]], written out (hot path)
    fx, fz = float(f_s_xz[0]), float(f_s_xz[1])
    ax, az = float(acc_s_xz[0]), float(acc_s_xz[1])
    u = np.array([c * fx + s * fz, -s * fx + c * fz - m * g])
    a = np.array([c * ax + s * az, -s * ax + c * az - g])
    return u, a


def lever_arm_acceleration(phi: float, omega: float, alpha: float, r_tool: np.ndarray) -> np.ndarray:
    """World acceleration of a point ``r_tool`` (tool frame) away from the accelerometer, relative
    to the accelerometer: ``d^2/dt^2 (R(phi) r) = (R'(phi) alpha - R(phi) omega^2) r``.

    Add it to the accelerometer's world acceleration to get the acceleration of the tool's
    centre of mass when the two are not at the same point (``omega = phi'``, ``alpha = phi''``).
    """
    c, s = math.cos(phi), math.sin(phi)
    rx, rz = float(r_tool[0]), float(r_tool[1])
    w2 = omega * omega
    return np.array([(-s * alpha - c * w2) * rx + (c * alpha - s * w2) * rz,
                     (-c * alpha + s * w2) * rx + (-s * alpha - c * w2) * rz])


def static_force(u: np.ndarray, a: np.ndarray, m: float) -> np.ndarray:
    """Static force observer, eqs. 8-10: ``F^ = D_F^+ (y - D_u u) = u - m a``."""
    return np.asarray(u) - m * np.asarray(a)


def model_matrices(m: float) -> dict[str, np.ndarray]:
    """``A, B, C, D_u, D_F`` of eqs. 5-7 and 11-12 for one axis of a tool of mass ``m`` (kg),
    measurements ``y = (x, a)``."""
    return dict(A=np.array([[0.0, 1.0], [0.0, 0.0]]), B=np.array([[0.0], [1.0 / m]]),
                C=np.array([[1.0, 0.0], [0.0, 0.0]]), D_u=np.array([[0.0], [1.0 / m]]),
                D_F=np.array([[0.0], [-1.0 / m]]))


def force_left_inverse(D_F: np.ndarray, R: np.ndarray | None = None) -> np.ndarray:
    """``D_F^+``: the (``R^-1``-weighted) left inverse of ``D_F`` used in eqs. 8, 17-19.

    ``(D_F^T R^-1 D_F)^-1 D_F^T R^-1``; with ``R = I`` the Moore-Penrose pseudo-inverse.
    """
    W = np.eye(D_F.shape[0]) if R is None else np.linalg.inv(R)
    return np.linalg.solve(D_F.T @ W @ D_F, D_F.T @ W)


def kalman_gain(m: float, h: float, sigma_f: float, sigma_x: float, sigma_a: float) -> np.ndarray:
    """Steady-state predictor gain ``K`` of the Kalman filter of eq. 13, discretised at ``h``.

    The unknown force enters as white process noise of standard deviation ``sigma_f`` (N)
    per sample on ``u - F``; ``sigma_x`` (m) and ``sigma_a`` (m/s^2) are the position and
    accelerometer noise. Returns the 2x2 gain of ``xi^+ = Phi xi^ + Gamma u + K (y - y^)``.
    """
    Phi = np.array([[1.0, h], [0.0, 1.0]])
    Gam = np.array([[h * h / 2.0], [h]]) / m
    C = model_matrices(m)["C"]
    Q = Gam @ Gam.T * sigma_f ** 2 + 1e-18 * np.eye(2)
    R = np.diag([sigma_x ** 2, sigma_a ** 2])
    import scipy.linalg          # here: it takes 0.15 s to import, and only a design needs it
    P = scipy.linalg.solve_discrete_are(Phi.T, C.T, Q, R)
    return Phi @ P @ C.T @ np.linalg.inv(C @ P @ C.T + R)


def lowpass_matrices(m: float, k11: float, k13: float, k21: float, k23: float
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Continuous low-pass observer (eq. 27) as ``xi^' = A_o xi^ + B_o w``, ``w = (u, a, x)``.

    ``m`` is the tool mass (kg); ``k11``, ``k13`` (position row) and ``k21``, ``k23`` (velocity
    row) are the observer gains on the position and acceleration innovations (eq. 27).
    """
    A_o = np.array([[-k11, 1.0], [-k21, 0.0]])
    B_o = np.array([[-k13 / m, k13, k11],
                    [(1.0 - k23) / m, k23, k21]])
    return A_o, B_o


def zoh(A: np.ndarray, B: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation ``(Phi, Gamma)`` of ``x' = A x + B w`` over ``h``."""
    n, k = B.shape
    M = np.zeros((n + k, n + k))
    M[:n, :n] = A
    M[:n, n:] = B
    import scipy.linalg
    E = scipy.linalg.expm(M * h)
    return E[:n, :n], E[:n, n:]


def lowpass_error_tf(k11: float, k13: float, k21: float, k23: float, m: float,
                     s: complex | np.ndarray) -> np.ndarray:
    """``F~(s)/F(s)`` of the low-pass observer (eq. 32); for ``k23 = 1``
    ``k21 k13 s / (s^2 + k11 s + k21)``.

    From ``F~ = F - F^ = (1 - k23) F + m k21 e`` and eq. 28.
    """
    s = np.asarray(s, dtype=complex)
    e_over_F = (k13 * s - (1.0 - k23)) / (m * (s * s + k11 * s + k21))
    return (1.0 - k23) + m * k21 * e_over_F


def reading_fault(f_s: np.ndarray, acc_s: np.ndarray, f_range: float, acc_range: float) -> int:
    """Fault code of one reading: ``FAULT_NOT_FINITE`` if any value of the force reading
    ``f_s`` (N) or the accelerometer reading ``acc_s`` (m/s^2) is NaN/inf, else
    ``FAULT_SATURATED`` if a component is at its sensor's range ``f_range`` (N) or
    ``acc_range`` (m/s^2) (within 1e-9 relative), else ``FAULT_NONE``."""
    if not (np.all(np.isfinite(f_s)) and np.all(np.isfinite(acc_s))):
        return FAULT_NOT_FINITE
    if np.any(np.abs(f_s) >= f_range * (1.0 - 1e-9)) or np.any(np.abs(acc_s) >= acc_range * (1.0 - 1e-9)):
        return FAULT_SATURATED
    return FAULT_NONE


class ForceObserverCore:
    """One of the three observers on both world axes (x, z), configured by ``cfg``
    (:class:`ObserverConfig`), sampled with step ``h``.

    Use :meth:`output` for the estimate at the current sample (it does not change the state)
    and then :meth:`advance` to move to the next sample with the same inputs held (ZOH).
    Inputs per call: ``u`` (world force reading with gravity removed, eq. 1), ``a`` (world
    tool acceleration), ``x`` (world tool position), each shape (2,).
    """

    def __init__(self, cfg: ForceObserverParameters) -> None:
        self.cfg = cfg
        self.xi = np.zeros((2, 2))         # per axis: (position, velocity) estimate
        self.initialised = False
        self._h: float | None = None
        self._Phi = self._Gam = None
        self._K: np.ndarray | None = None
        m = cfg.m_tool
        mats = model_matrices(m)
        self.C, self.D_u = mats["C"], mats["D_u"]
        # measurement-noise weighted left inverse of D_F (eqs. 17-19)
        self.D_F_pinv = force_left_inverse(mats["D_F"], np.diag([cfg.sigma_x ** 2, cfg.sigma_a ** 2]))
        self.A_o, self.B_o = lowpass_matrices(m, cfg.k11, cfg.k13, cfg.k21, cfg.k23)

    def _discretise(self, h: float) -> None:
        if self._h == h:
            return
        cfg = self.cfg
        if cfg.observer == "lowpass":
            self._Phi, self._Gam = zoh(self.A_o, self.B_o, h)
        elif cfg.observer == "kalman":
            self._Phi = np.array([[1.0, h], [0.0, 1.0]])
            self._Gam = np.array([h * h / 2.0, h]) / cfg.m_tool
            self._K = kalman_gain(cfg.m_tool, h, cfg.sigma_f, cfg.sigma_x, cfg.sigma_a)
        self._h = h

    def reset(self, x: np.ndarray, v: np.ndarray | None = None) -> None:
        """Start the state at tool position ``x`` (and velocity ``v``, default 0)."""
        self.xi[:, 0] = x
        self.xi[:, 1] = 0.0 if v is None else v
        self.initialised = True

    def output(self, u: np.ndarray, a: np.ndarray, x: np.ndarray) -> np.ndarray:
        """Force estimate ``F^`` (force on the environment, world frame) at this sample.

        Before the first :meth:`advance` the state is taken as ``(x, 0)`` without being
        committed, so the observer starts from the inputs of its first step.
        """
        cfg = self.cfg
        if not self.initialised:
            self.xi[:, 0] = x
            self.xi[:, 1] = 0.0
        if cfg.observer == "static":
            return static_force(u, a, cfg.m_tool)
        if cfg.observer == "kalman":
            # eq. 19: F^ = D_F^+ (y - C xi^ - D_u u) with y = (x, a), per axis
            innov = np.stack([x - self.xi[:, 0], a - u / cfg.m_tool], axis=1)   # (axes, 2)
            return innov @ self.D_F_pinv[0]
        # low-pass structure, eqs. 30/33: F^ = k23 (u - m a) - m k21 (x - x^)
        return cfg.k23 * (u - cfg.m_tool * a) - cfg.m_tool * cfg.k21 * (x - self.xi[:, 0])

    def advance(self, u: np.ndarray, a: np.ndarray, x: np.ndarray, h: float) -> None:
        """Move the observer state over one step ``h`` with the inputs held."""
        cfg = self.cfg
        if not self.initialised:
            self.reset(x)
        if cfg.observer == "static":
            return
        self._discretise(h)
        if cfg.observer == "lowpass":
            # per axis: xi+ = Phi xi + Gam (u, a, x)
            self.xi = self.xi @ self._Phi.T + np.column_stack((u, a, x)) @ self._Gam.T
            return
        # Kalman predictor (eq. 13 discretised): xi+ = Phi xi + Gam u + K (y - C xi - D_u u)
        innov = np.stack([x - self.xi[:, 0], a - u / cfg.m_tool], axis=0)      # (2, axes)
        self.xi = (self._Phi @ self.xi.T + np.outer(self._Gam, u) + self._K @ innov).T

    def velocity(self) -> np.ndarray:
        """The observer's tool velocity estimate (zero for the static observer)."""
        return self.xi[:, 1].copy()

    def position(self) -> np.ndarray:
        """The observer's tool position estimate (last input position for the static one)."""
        return self.xi[:, 0].copy()


PAPER = "García, Robertsson, Gómez Ortega, Johansson (impedance paper)"


@dataclass(frozen=True)
class ForceObserverParameters:
    """Parameters of the ForceObserver FMU."""

    observer: str = param("lowpass", "1", "which observer: static (eqs. 8-10), kalman (eqs. 11-19) "
                          "or lowpass (eqs. 27-35)", choices=OBSERVER_KINDS)
    m_tool: float = param(12.0, "kg", "tool mass between the force sensor and the tool tip, as the "
                          "observer knows it: from a tool calibration (fmus.robot_plant.sensor_model."
                          "calibrate_tool), not the true mass", low=0.0, low_inclusive=False,
                          source=f"{PAPER}, section III (12 kg grinding tool); the contact scenarios "
                          "use the calibrated 12.10 kg")
    k11: float = param(8.8, "Hz", "low-pass observer gain k11 (position innovation -> position), 1/s; "
                       "with k21 it sets the error dynamics s^2 + k11 s + k21 (eq. 28)", low=0.0,
                       low_inclusive=False, source=f"1 Hz, damping 0.7 (the paper's section V has 0.38)")
    k13: float = param(-0.0073, "s", "low-pass observer gain k13 (acceleration innovation -> position), s",
                       source=f"{PAPER}, section V")
    k21: float = param(39.5, "1", "low-pass observer gain k21 (position innovation -> velocity), 1/s^2",
                       low=0.0, low_inclusive=False, source=f"1 Hz, damping 0.7 (the paper's section V has 9.05)")
    k23: float = param(1.0, "1", "low-pass observer gain k23 (acceleration innovation -> velocity); "
                       "1 makes the estimate Newton's law (eq. 35)", low=0.0, high=1.0,
                       source=f"{PAPER}, eq. 35")
    sigma_f: float = param(20.0, "N", "Kalman observer: std of the unknown force per sample (process noise)",
                           low=0.0, low_inclusive=False)
    sigma_x: float = param(1e-4, "m", "Kalman observer: std of the tool position input", low=0.0,
                           low_inclusive=False)
    sigma_a: float = param(0.05, "m/s2", "Kalman observer: std of the accelerometer", low=0.0,
                           low_inclusive=False)
    f_range: float = param(660.0, "N", "force sensor range: a component at or beyond it is flagged "
                           "as saturated", low=0.0, low_inclusive=False, source="JR3 wrist sensor class")
    acc_range: float = param(156.9, "m/s2", "accelerometer range (16 g): at or beyond it is saturated",
                             low=0.0, low_inclusive=False)
    index_x: int = param(1, "1", "index (1-based) of the sensor-frame x component in f_s and acc_s",
                         low=1, high=3)
    index_z: int = param(3, "1", "index (1-based) of the sensor-frame z component in f_s and acc_s",
                         low=1, high=3)
    g: float = param(G, "m/s2", "gravity", low=0.0)

    def check(self) -> None:
        """Cross-field rule (the ranges are checked per field): ``index_x`` and ``index_z``
        select different sensor axes."""
        if self.index_x == self.index_z:
            raise ParameterError(f"parameters 'index_x' and 'index_z' must differ (both {self.index_x})")


__all__ = ["OBSERVER_KINDS", "FAULT_NONE", "FAULT_SATURATED", "FAULT_NOT_FINITE", "rotation",
           "world_readings", "lever_arm_acceleration", "static_force", "model_matrices", "force_left_inverse", "kalman_gain",
           "lowpass_matrices", "zoh", "lowpass_error_tf", "reading_fault",
           "ForceObserverCore", "ForceObserverParameters"]

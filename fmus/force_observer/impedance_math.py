"""Impedance control normal to a contact surface, LQR-designed (impedance paper, eqs. 2-3, 39-41).

Target impedance (eq. 2) along the surface normal ``n`` (the direction in which the tool
pushes into the surface), with ``F`` the force the tool exerts on the environment, ``x`` the
tool position, ``x_r`` the reference position and ``F_d`` a desired (bias) force:

.. math:: F - F_d = K_z\\,(x_r - x) - D_z\\,\\dot x

written as the impedance variable (eq. 3) that the controller drives to zero,

.. math:: z = (F - F_d) + K_z e + D_z \\dot e, \\qquad e = x - x_r .

The controller outputs a Cartesian reference offset ``Delta`` for the robot's position
controller (the MotionController's ``dp_ref = n Delta``). As in the paper (eq. 40,
``u = -L X + c F^ + l_r x_r`` with ``L`` from an LQR on a model of the position-controlled
robot and tool, eqs. 39 and 41), the gains come from an LQR; here the design model is

.. math::

   m_r \\ddot e &= k_r(\\Delta - e) - d_r \\dot e - k_{env} e \\\\
   \\dot\\zeta &= z = (K_z + k_{env}) e + D_z \\dot e \\quad (+\\text{const})

-- the position-controlled robot along ``n`` as a mass ``m_r`` held by the position loop's
stiffness ``k_r = m_r w_r^2`` and damping ``d_r = 2 zeta_r w_r m_r``, pressed on a surface of
stiffness ``k_env`` -- with the state ``s = (e, e', zeta)`` and ``Delta = -L s``. The integral
``zeta`` of the impedance variable makes ``z = 0`` the only equilibrium: the stationary
contact satisfies the target impedance exactly, whatever the robot's static compliance or the
true surface stiffness. With a wall of stiffness ``k_w`` at ``x_w`` the stationary contact is
(:func:`stationary_contact`)

.. math::

   x_s = \\frac{F_d + K_z x_r + k_w x_w}{K_z + k_w}, \\qquad F_s = k_w (x_s - x_w)

(for ``x_s > x_w``; else no contact and ``x_s = x_r``): a stiff target (large ``K_z``) puts
``x_s`` near ``x_r``, a stiff environment near ``x_w``, as the paper notes (Fig. 4).

Two structures (``ImpedanceControllerParameters.structure``):

* ``"paper"`` (the paper's, eqs. 39-41): ``u = -L X + c F^ + l_r x_r`` -- a state feedback
  ``L`` from an LQR on the model of the position-controlled robot (and tool) with diagonal
  weights on positions and velocities (the paper's ``Q = diag(.., K, D, K_t, D_t)``,
  ``R = 1000``), *no* integral state, and a force gain ``c`` outside the LQR. Here in error
  coordinates ``e = x - x_r`` (``l_r`` absorbed), ``Delta = -L s + c (F - F_d)``, with ``c``
  chosen (:func:`force_gain`) so that the design model's static contact is the target
  impedance. On the true plant the stationary contact therefore misses eq. 2 by whatever the
  design model gets wrong (static gain of the position loop, tool compliance, force errors).
* ``"integral"`` (our extension): the states above plus the integral ``zeta`` of ``z``; the
  stationary contact then satisfies eq. 2 by construction.

Besides the controller, :func:`simulate_1dof` closes the loop on a one-axis model (robot
position loop + rigid or compliant tool + one-sided wall + force sensor + accelerometer +
force observer), used by the tests and to judge whether the paper's compliant tool matters.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fmus.common.parameters import ParameterError, param
from fmus.force_observer import force_observer_math as fom


#: The controller structures of :class:`ImpedanceControllerParameters` (module doc).
STRUCTURES = ("paper", "integral")


def lqr_gain(A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Continuous-time LQR gain ``L = R^-1 B^T P`` (``u = -L x``), ``P`` the stabilising
    solution of the algebraic Riccati equation ``A^T P + P A - P B R^-1 B^T P + Q = 0``
    (what python-control's ``control.lqr`` computes, without that dependency in the FMU)."""
    A, B, Q = (np.atleast_2d(np.asarray(M, float)) for M in (A, B, Q))
    R = np.atleast_2d(np.asarray(R, float))
    from scipy.linalg import solve_continuous_are   # here: scipy.linalg takes 0.15 s to import
    P = solve_continuous_are(A, B, Q, R)
    return np.linalg.solve(R, B.T @ P)


def design_model(d: ImpedanceControllerParameters, k_env: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(A, B)`` of the design model of the parameters ``d`` and input ``Delta``; with
    ``k_env`` (N/m) the tool is in contact with a surface of that stiffness (free motion when
    None).

    Rigid tool: states ``(e, e', zeta)``. Compliant tool (``d.compliant``; the paper's robot +
    Optidrive model, eq. 39): states ``(e_f, e_f', dl, dl', zeta)`` with ``e_f`` the flange
    (force sensor) position error and ``dl = x_tool - x_flange`` the tool deflection; the
    robot mass ``m_design`` then includes the tool, the flange carries ``m_design - tool_mass``.
    """
    ke = d.k_env if k_env is None else k_env
    if d.compliant:
        kr, dr, kc, dc, mt = d.k_r, d.d_r, d.tool_k, d.tool_damping, d.tool_mass
        mf = d.m_design - mt
        A = np.zeros((5, 5))
        B = np.zeros((5, 1))
        A[0, 1] = A[2, 3] = 1.0
        A[1] = [-kr / mf, -dr / mf, kc / mf, dc / mf, 0.0]
        B[1, 0] = kr / mf
        A[3] = np.array([-ke / mt, 0.0, -(kc + ke) / mt, -dc / mt, 0.0]) - A[1]
        B[3, 0] = -kr / mf
        A[4] = [ke + d.K_z, d.D_z, ke + d.K_z, d.D_z, 0.0]
        return A, B
    A = np.array([[0.0, 1.0, 0.0],
                  [-(d.k_r + ke) / d.m_design, -d.d_r / d.m_design, 0.0],
                  [d.K_z + ke, d.D_z, 0.0]])
    B = np.array([[0.0], [d.k_r / d.m_design], [0.0]])
    return A, B


def design_gains(d: ImpedanceControllerParameters) -> np.ndarray:
    """LQR gain ``L`` of the design parameters ``d`` for ``Delta = -L s`` (eqs. 40-41): on ``(e, e', zeta)`` (3) for a rigid
    tool, ``(e_f, e_f', dl, dl', zeta)`` (5) for the compliant one (eq. 41's diagonal form:
    weights on the robot's and the tool's position and velocity states); the ``"paper"``
    structure drops ``zeta`` (2 or 4 entries)."""
    A, B = design_model(d)
    q = [d.q_e, d.q_de, d.q_dl, d.q_ddl, d.q_int] if d.compliant else [d.q_e, d.q_de, d.q_int]
    if d.structure == "paper":          # the integral is the last state
        A, B, q = A[:-1, :-1], B[:-1], q[:-1]
    return lqr_gain(A, B, np.diag(q), np.array([[d.r]]))[0]


def force_gain(d: ImpedanceControllerParameters, L: np.ndarray) -> float:
    """The paper's force gain ``c`` (eq. 40) for ``Delta = -L s + c (F - F_d)``: the one that
    makes the static contact of the design model ``d`` with state gain ``L`` the target
    impedance (eq. 2) on the tool.

    At rest the design model's position loop (stiffness ``k_r``) holds the flange at
    ``e_f = Delta - F / k_r``, the tool mount deflects by ``dl = -C F`` (``C = 1 / tool_k``,
    the design's known tool compliance; 0 for a rigid tool) and eq. 2 wants
    ``e_f + dl = -F / K_z``; so ``e_f = F (C - 1/K_z)`` and
    ``(1 + L_0) e_f + L_2 dl + F / k_r = c F``. Zero for the ``"integral"`` structure.
    """
    if d.structure != "paper":
        return 0.0
    L = np.asarray(L, float).ravel()
    C = 1.0 / d.tool_k if d.tool_k > 0 else 0.0
    c = (1.0 + L[0]) * (C - 1.0 / d.K_z) + 1.0 / d.k_r
    if L.size == 4:                       # compliant design model: the deflection is a state
        c -= L[2] * C
    return float(c)


def closed_loop_poles(d: ImpedanceControllerParameters, L: np.ndarray, k_env: float) -> np.ndarray:
    """Poles of the design model of ``d`` with gain ``L`` on a surface of stiffness ``k_env``; for the
    ``"paper"`` structure the force term ``c F = c k_env e_tool`` (in contact) is closed too."""
    A, B = design_model(d, k_env)
    L = np.asarray(L, float).ravel()
    if L.size in (2, 4):
        A, B = A[:-1, :-1], B[:-1]
        K = L.copy()
        c = force_gain(d, L)
        K[0] -= c * k_env                 # F = k_env (e_f + dl): Delta = -(L - c k_env [1 0 1 0]) s
        if L.size == 4:
            K[2] -= c * k_env
        return np.linalg.eigvals(A - B @ K[None, :])
    return np.linalg.eigvals(A - B @ np.atleast_2d(L))


def stationary_contact(K_z: float, k_wall: float, x_r: float, x_w: float, F_d: float = 0.0
                       ) -> tuple[float, float]:
    """Stationary position and force from the impedance relation and the wall (module doc).

    The target impedance has stiffness ``K_z`` (N/m), reference ``x_r`` and desired force
    ``F_d`` (N); the wall, at ``x_w``, has stiffness ``k_wall`` (N/m). Positions along the
    normal (the tool pushes towards +x); returns ``(x_s, F_s)``.
    """
    x_free = x_r + F_d / K_z
    if x_free <= x_w:
        return x_free, 0.0
    x_s = (F_d + K_z * x_r + k_wall * x_w) / (K_z + k_wall)
    return x_s, k_wall * (x_s - x_w)


class ImpedanceLaw:
    """The sampled impedance controller on one axis (the surface normal).

    Call :meth:`output` for ``Delta`` at this sample (no state change), then :meth:`advance`
    to commit the sample. Velocities come from first-order filtered differences (time constant
    ``tau_v``); ``|Delta| <= delta_max`` with conditional integration (anti-windup).

    With a gain of length 3 (rigid tool) the state is ``(e, e', zeta)``, ``e = x - x_r``; with
    length 5 (compliant tool, :func:`design_model`) it is ``(e_f, e_f', dl, dl', zeta)`` and
    the flange position ``x_flange`` must be given; ``x`` is always the tool position, used in
    the impedance variable ``z``. Lengths 2 and 4 are the paper's structure: the same without
    ``zeta``, plus ``c (F - F_d)`` (``force_gain``, :func:`force_gain`).

    ``L`` is the state gain (:func:`design_gains`), ``K_z`` (N/m) and ``D_z`` (N s/m) the
    target stiffness and damping of the impedance variable ``z`` (eq. 3).
    """

    def __init__(self, L: np.ndarray, K_z: float, D_z: float, tau_v: float = 0.01,
                 delta_max: float = 0.05, force_gain: float = 0.0) -> None:
        self.L = np.asarray(L, dtype=float).ravel()
        if self.L.size not in (2, 3, 4, 5):
            raise ValueError(f"impedance gain must have 2 to 5 entries, not {self.L.size}")
        self.K_z, self.D_z = float(K_z), float(D_z)
        self.tau_v, self.delta_max = float(tau_v), float(delta_max)
        self.integral = self.L.size in (3, 5)     # else the paper's structure (no zeta)
        self.c = float(force_gain)
        self.zeta = 0.0
        npos = 1 if self.L.size in (2, 3) else 2
        self.q_prev: np.ndarray | None = None
        self.dq = np.zeros(npos)
        self.saturated = False

    @property
    def e_prev(self) -> float | None:
        """Last committed position error (``None`` before the first sample or after a gap)."""
        return None if self.q_prev is None else float(self.q_prev[0])

    @e_prev.setter
    def e_prev(self, value: None) -> None:
        """Forget the last sample: ``value`` must be ``None`` (a gap in the samples)."""
        if value is not None:
            raise ValueError("e_prev can only be reset to None")
        self.q_prev = None

    def _positions(self, x: float, x_r: float, x_flange: float | None) -> np.ndarray:
        if self.L.size in (2, 3):
            return np.array([x - x_r])
        if x_flange is None:
            raise ValueError("the compliant-tool impedance law needs the flange position")
        return np.array([x_flange - x_r, x - x_flange])

    def _rates(self, q: np.ndarray, h: float) -> np.ndarray:
        if self.q_prev is None or h <= 0:
            return self.dq
        alpha = h / (self.tau_v + h)
        return self.dq + alpha * ((q - self.q_prev) / h - self.dq)

    def _state(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        s = [q[0], dq[0]] if q.size == 1 else [q[0], dq[0], q[1], dq[1]]
        return np.array(s + [self.zeta] if self.integral else s)

    def _delta(self, F: float, F_d: float, q: np.ndarray, dq: np.ndarray) -> float:
        return -float(self.L @ self._state(q, dq)) + self.c * (F - F_d)

    def _z(self, F: float, F_d: float, q: np.ndarray, dq: np.ndarray) -> float:
        return (F - F_d) + self.K_z * float(np.sum(q)) + self.D_z * float(np.sum(dq))

    def output(self, F: float, x: float, x_r: float, F_d: float = 0.0, h: float = 0.0,
               x_flange: float | None = None) -> float:
        """``Delta`` (m) along the normal at this sample; ``h`` is the time since the last one."""
        q = self._positions(x, x_r, x_flange)
        delta = self._delta(F, F_d, q, self._rates(q, h))
        return float(np.clip(delta, -self.delta_max, self.delta_max))

    def impedance_variable(self, F: float, x: float, x_r: float, F_d: float = 0.0, h: float = 0.0,
                           x_flange: float | None = None) -> float:
        """``z`` of eq. 3 at this sample (N); ``h`` is the time since the last one."""
        q = self._positions(x, x_r, x_flange)
        return self._z(F, F_d, q, self._rates(q, h))

    def advance(self, F: float, x: float, x_r: float, F_d: float, h_prev: float, h: float,
                x_flange: float | None = None) -> None:
        """Commit this sample (``h_prev`` since the last one) and integrate ``z`` over ``h``."""
        q = self._positions(x, x_r, x_flange)
        dq = self._rates(q, h_prev)
        z = self._z(F, F_d, q, dq)
        delta_free = self._delta(F, F_d, q, dq)
        self.saturated = abs(delta_free) > self.delta_max
        # conditional integration: stop integrating when that would push further into the limit
        dz = -self.L[-1] * z      # sign of d(Delta)/dt due to the integrator
        if self.integral and not (self.saturated and np.sign(dz) == np.sign(delta_free)):
            self.zeta += h * z
        self.q_prev, self.dq = q, dq


# ---------------------------------------------------------------------------------------------
# one-axis closed loop (tests, compliant-tool study)
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class OneAxisPlant:
    """Robot position loop + tool + one-sided wall along one axis (SI).

    ``compliant``: the tool mass ``m_t`` hangs on a spring ``k_c`` / damper ``d_c`` between the
    force sensor (on the robot flange) and the tool (the paper's Optidrive, Fig. 3); else the
    tool is rigid and part of the robot mass.
    """

    m_r: float = 150.0           # robot effective mass incl. a rigid tool (kg)
    w_r: float = 2 * np.pi * 3.0
    zeta_r: float = 0.7
    m_t: float = 12.0            # tool mass (kg)
    compliant: bool = False
    k_c: float = 2.0e4           # tool spring (N/m)
    d_c: float = 200.0           # tool damper (N.s/m)
    k_w: float = 5000.0          # wall stiffness (N/m), 5 N/mm
    d_w: float = 50.0            # wall damping (N.s/m)
    x_w: float = 0.0             # wall position (m)
    tau_act: float = 0.005       # servo lag of the position command (s); 0 = none


def _wall(x: float, v: float, p: OneAxisPlant) -> float:
    if x <= p.x_w:
        return 0.0
    return max(0.0, p.k_w * (x - p.x_w) + p.d_w * v)


def simulate_1dof(plant: OneAxisPlant, design: ImpedanceControllerParameters, x_ref, t_end: float, *,
                  h: float = 0.004, substeps: int = 16, observer: str = "static",
                  obs_cfg: fom.ForceObserverParameters | None = None, use_raw: bool = False,
                  x0: float = -0.05, F_d: float = 0.0, noise_f: float = 0.0, noise_a: float = 0.0,
                  seed: int = 0, tau_v: float = 0.01, controller=None) -> dict[str, np.ndarray]:
    """Close the impedance loop on :class:`OneAxisPlant`.

    ``x_ref(t)`` is the reference along the normal, ``design`` the controller's
    :class:`ImpedanceDesign`, ``t_end`` (s) the duration, ``x0`` (m) the start position and
    ``F_d`` (N) the desired force. The force fed back is the observer's estimate
    (``observer`` = one of :data:`fom.OBSERVER_KINDS`, configured by ``obs_cfg`` if given) or,
    with ``use_raw``, the raw sensor reading ``u = F + m_t a``; ``noise_f`` (N) and
    ``noise_a`` (m/s^2) are the standard deviations of the force and acceleration readings'
    white noise (generator seeded with ``seed``), ``tau_v`` (s) the velocity filter's time
    constant. The plant is integrated with RK4, ``substeps`` per controller step ``h``. ``controller(t, u, a, x, x_ref) -> (F_hat, Delta)``, if given,
    replaces the built-in observer and impedance law for one sample (advancing over ``h``).
    Returns time series (``t, x, v, a, F, u, F_hat, delta, x_ref``).
    """
    rng = np.random.default_rng(seed)
    L = design_gains(design)
    law = ImpedanceLaw(L, design.K_z, design.D_z, tau_v=tau_v, force_gain=force_gain(design, L))
    cfg = obs_cfg or fom.ForceObserverParameters(observer=observer, m_tool=plant.m_t)
    obs = fom.ForceObserverCore(cfg)
    k_r = plant.m_r * plant.w_r ** 2
    d_r = 2 * plant.zeta_r * plant.w_r * plant.m_r
    m_fl = plant.m_r - plant.m_t if plant.compliant else plant.m_r

    lag = plant.tau_act > 0.0

    def deriv(s: np.ndarray, x_cmd: float) -> np.ndarray:
        # last state: the servo-filtered command (first-order lag tau_act)
        xc = s[-1] if lag else x_cmd
        dxc = (x_cmd - s[-1]) / plant.tau_act if lag else 0.0
        if plant.compliant:
            xf, vf, xt, vt = s[:4]
            f_c = plant.k_c * (xf - xt) + plant.d_c * (vf - vt)
            F = _wall(xt, vt, plant)
            af = (k_r * (xc - xf) - d_r * vf - f_c) / m_fl
            at = (f_c - F) / plant.m_t
            return np.array([vf, af, vt, at, dxc])
        x, v = s[:2]
        F = _wall(x, v, plant)
        return np.array([v, (k_r * (xc - x) - d_r * v - F) / m_fl, dxc])

    if design.compliant and not plant.compliant:
        raise ValueError("a compliant-tool design needs a compliant-tool plant")

    def measure(s: np.ndarray, x_cmd: float) -> tuple[float, float, float, float]:
        """tool position, tool acceleration, true contact force, sensor reading."""
        ds = deriv(s, x_cmd)
        if plant.compliant:
            xt, vt, at = s[2], s[3], ds[3]
            F = _wall(xt, vt, plant)
            u = plant.k_c * (s[0] - s[2]) + plant.d_c * (s[1] - s[3])
            return xt, at, F, u
        F = _wall(s[0], s[1], plant)
        return s[0], ds[1], F, F + plant.m_t * ds[1]

    n = int(round(t_end / h))
    s = np.array([x0, 0.0, x0, 0.0, x0]) if plant.compliant else np.array([x0, 0.0, x0])
    iv = 3 if plant.compliant else 1      # index of the tool velocity
    out = {k: np.empty(n) for k in ("t", "x", "v", "a", "F", "u", "F_hat", "delta", "x_ref")}
    delta = 0.0
    dt = h / substeps
    for k in range(n):
        t = k * h
        xr = float(x_ref(t))
        x_cmd_prev = xr + delta
        x_t, a_t, F, u = measure(s, x_cmd_prev)
        u_m = u + noise_f * rng.normal()
        a_m = a_t + noise_a * rng.normal()
        if controller is not None:   # e.g. the FMUs of observer and controller
            F_hat, delta = controller(t, u_m, a_m, x_t, xr)
        else:
            F_hat = float(obs.output(np.array([u_m]), np.array([a_m]), np.array([x_t]))[0])
            F_fb = u_m if use_raw else F_hat
            h_prev = h if k else 0.0
            x_fl = float(s[0]) if design.compliant else None
            delta = law.output(F_fb, x_t, xr, F_d, h_prev, x_fl)
            law.advance(F_fb, x_t, xr, F_d, h_prev, h, x_fl)
            obs.advance(np.array([u_m]), np.array([a_m]), np.array([x_t]), h)
        for key, val in (("t", t), ("x", x_t), ("v", s[iv]), ("a", a_t), ("F", F), ("u", u_m),
                         ("F_hat", F_hat), ("delta", delta), ("x_ref", xr)):
            out[key][k] = val
        x_cmd = xr + delta
        for _ in range(substeps):  # RK4 with the command held
            k1 = deriv(s, x_cmd)
            k2 = deriv(s + 0.5 * dt * k1, x_cmd)
            k3 = deriv(s + 0.5 * dt * k2, x_cmd)
            k4 = deriv(s + dt * k3, x_cmd)
            s = s + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    return out


def smooth_ramp(x0: float, x1: float, t0: float, t1: float):
    """A reference moving from ``x0`` to ``x1`` between ``t0`` and ``t1`` (quintic smooth-step)."""
    def f(t: float) -> float:
        s = min(max((t - t0) / (t1 - t0), 0.0), 1.0)
        return x0 + (x1 - x0) * s ** 3 * (10 - 15 * s + 6 * s * s)
    return f


PAPER = "García, Robertsson, Gómez Ortega, Johansson (impedance paper)"


@dataclass(frozen=True)
class ImpedanceControllerParameters:
    """Parameters of the ImpedanceController FMU."""

    structure: str = param("paper", "1", "controller structure: paper (eqs. 39-41: LQR state "
                           "feedback on (e, de/dt) plus the force gain c, no integral) or integral "
                           "(our extension: the integral of the impedance variable as a third state, "
                           "which makes the stationary contact satisfy eq. 2 by construction)",
                           choices=STRUCTURES, source=f"{PAPER}, eqs. 39-41")
    K_z: float = param(2000.0, "N/m", "target stiffness along the normal (eq. 2)", low=0.0,
                       low_inclusive=False, source=f"{PAPER}, eq. 2")
    D_z: float = param(350.0, "N.s/m", "target damping along the normal (eq. 2)", low=0.0,
                       source=f"{PAPER}, eq. 2")
    normal: tuple = param((1.0, 0.0), "1", "contact normal, world x and z: the direction in which "
                          "the tool pushes into the surface (normalised)")
    m_design: float = param(150.0, "kg", "design model: effective robot mass along the normal",
                            low=0.0, low_inclusive=False)
    f_design: float = param(3.0, "Hz", "design model: bandwidth of the robot's position loop",
                            low=0.0, low_inclusive=False)
    zeta_design: float = param(0.7, "1", "design model: damping ratio of the robot's position loop",
                               low=0.0, low_inclusive=False)
    k_env: float = param(5000.0, "N/m", "design model: surface stiffness", low=0.0,
                         source=f"{PAPER}, section III (5 N/mm screen)")
    q_e: float = param(1e5, "1", "LQR weight on the position error e (1/m^2)", low=0.0)
    q_de: float = param(1e2, "1", "LQR weight on de/dt ((s/m)^2)", low=0.0)
    tool_compliance: float = param(0.0, "m/N", "design model: compliance of the tool mount as the "
                                   "designer knows it; 0: a rigid tool", low=0.0,
                                   source=f"{PAPER}, eq. 38 (Optidrive stiffness, identified)")
    tool_mass: float = param(0.0, "kg", "design model: tool mass on the compliant mount; > 0 (with "
                             "tool_compliance > 0) puts the tool in the LQR model (eq. 39: flange and "
                             "deflection states, the deflection from f_mount); 0: only the static "
                             "deflection enters the force gain", low=0.0, source=f"{PAPER}, eqs. 38-39")
    tool_damping: float = param(0.0, "N.s/m", "design model: damping of the tool mount", low=0.0,
                                source=f"{PAPER}, eq. 38")
    q_dl: float = param(1e5, "1", "LQR weight on the tool deflection dl (compliant design model; 1/m^2)",
                        low=0.0)
    q_ddl: float = param(1e2, "1", "LQR weight on d(dl)/dt (compliant design model; (s/m)^2)", low=0.0,
                         source=f"{PAPER}, eq. 41 weighs the tool states as the robot's")
    q_int: float = param(1.0, "1", "LQR weight on the integral of the impedance variable (1/(N.s)^2)",
                         low=0.0)
    r: float = param(4e4, "1", "LQR weight on the reference offset (1/m^2)", low=0.0, low_inclusive=False)
    tau_v: float = param(0.01, "s", "time constant of the filtered derivative of e", low=0.0)
    delta_max: float = param(0.05, "m", "largest reference offset along the normal", low=0.0,
                             low_inclusive=False)

    def check(self) -> None:
        """Cross-field rule (the ranges are checked per field): the surface ``normal`` is not
        the zero vector."""
        if np.hypot(*self.normal) < 1e-9:
            raise ParameterError(f"parameter 'normal' = {self.normal} must not be the zero vector")

    @property
    def w_r(self) -> float:
        """Position-loop bandwidth of the design model (rad/s)."""
        return 2 * np.pi * self.f_design

    @property
    def tool_k(self) -> float:
        """Stiffness of the tool mount (N/m) the designer knows; 0 for a rigid tool."""
        return 1.0 / self.tool_compliance if self.tool_compliance > 0 else 0.0

    @property
    def compliant(self) -> bool:
        """Whether the design model has the compliant tool (5 states) or a rigid one (3)."""
        return self.tool_k > 0.0 and self.tool_mass > 0.0

    @property
    def k_r(self) -> float:
        """Position-loop stiffness ``m_design w_r^2`` (N/m)."""
        return self.m_design * self.w_r ** 2

    @property
    def d_r(self) -> float:
        """Position-loop damping ``2 zeta_design w_r m_design`` (N.s/m)."""
        return 2.0 * self.zeta_design * self.w_r * self.m_design


__all__ = ["lqr_gain", "design_model", "design_gains", "force_gain",
           "closed_loop_poles", "STRUCTURES",
           "stationary_contact", "ImpedanceLaw", "OneAxisPlant", "simulate_1dof", "smooth_ramp", "ImpedanceControllerParameters"]

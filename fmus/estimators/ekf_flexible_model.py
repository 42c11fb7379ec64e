"""The three extended Kalman filters of Henriksson, Norrlöf, Moberg, Wernholt and Schön (2009):
*EKF Complete*, *EKF Motor* and *EKF Integrated* (section III-A).

The estimation model (eq. 2, its Euler discretisation and the measurement functions of
eqs. 6-8) is in :mod:`fmus.estimators.henriksson2009_model`; this module holds the filters'
parameters and the filter (eqs. 3-5).

Noise (section III-C)
---------------------
The paper's parameterisation: the process noise (its ``R~_lambda``) is block diagonal with the
scalings ``lambda1 .. lambda4`` on the ``q_a``, ``q_m``, ``dq_a``, ``dq_m`` blocks of an initial
guess, and the measurement noise (``W~_lambda``) has ``lambda5`` on the motor-angle block and 1
on the second (accelerometer or velocity) block. Our initial guesses are physical: process noise
intensities ``w_*`` (per sqrt(s), so that ``Q = T diag(...)`` does not depend on the sample
rate) and sensor standard deviations ``r_*``::

    Q = T diag(l1 w_q_a^2 I, l2 w_q_m^2 I, l3 w_dq_a^2 I, l4 w_dq_m^2 I)
    R = diag(l5 r_motor^2 I, r_acc^2 I)       (complete; r_vel for integrated; motor: l5 r_motor^2 I)

The defaults are the physical guesses with every ``lambda = 1``, checked by hand on our plant
(see :data:`DEFAULT_LAMBDAS`); the automatic tuning study sets ``lambda1 .. lambda5``.

Drift correction of EKF Integrated (beyond the paper; parameter ``drift_correction``)
------------------------------------------------------------------------------------
The paper leaves EKF Integrated's low-frequency drift unsolved (section IV). Its static tool
position rests on the motor angles and the model's gearbox deflection ``D = tau_s^-1(G(q_a))``
alone: the integrated velocity carries no position, so with the stiffness 50 % low the static
deflection is doubled and the all-frequency error is as large as rigid kinematics' (which
ignores the deflection). What else is observable at low frequency? The accelerometer's gravity
component: at rest ``rho_s = g (-sin phi, cos phi)``, so it measures the tool angle
``phi = q1 + q2``, independently of the stiffness. With the motor angles that is the sum of
the two gearbox deflections ``D1 + D2``; a single unknown common stiffness factor ``sigma``
(the paper's error scales both joints) splits it between the joints through the model's own
ratio of gravity torques, so ``sigma`` and with it both arm angles are observable. An error
of the stiffness ratio between the joints is not (only the sum is), nor is an accelerometer
bias distinguishable from a tilt (``beta / g`` rad).

The filter reads the tilt through its integrated velocity: rotated with the estimated angle
``phi_used`` (the predicted ``phi`` at each sample), the integral drifts by the integral of
``(R(phi_used) - R(phi)) rho_s``, about ``g`` times the integral of the angle error. The paper's
filter mistakes that drift for sensor velocity. The corrections:

* ``"off"``: the paper's filter (8 states; the default, as the fix is not better on every
  metric in the nominal case: docs/henriksson2009_ekf_notes.md).
* ``"tilt"``: two velocity-error states ``b`` (world x, z; 10 states), the integrated
  velocity's error, with the exact dynamics ``b' = (R(phi_used) - R(phi)) rho_s`` plus a random
  walk ``w_b`` (accelerometer noise, integration error), and the measurement
  ``h = (q_m, J_s dq_a + b)``. A wrong ``phi`` now explains the drift, so the tilt is
  estimated from gravity; with the exact stiffness this removes most of the drift.
* ``"tilt_stiffness"``: ``tilt`` plus the log stiffness factor ``s`` (11 states; ``sigma =
  exp(s)`` > 0) scaling the gearbox spring torque ``tau_s(D)`` of eq. 2, a random walk with
  ``w_stiffness`` from ``N(0, p0_stiffness^2)``. With ``init_from_motors`` the start (at rest)
  is aligned with the first accelerometer sample (:meth:`EkfFlexibleModel.static_alignment`).

Measured figures of the three corrections: docs/henriksson2009_ekf_notes.md.

Euler's error (parameter ``substeps``)
--------------------------------------
The filters' Euler discretisation at 2 kHz is first-order accurate against the plant (RK4);
``substeps = k`` takes ``k`` Euler steps of ``T / k`` in the time update (``A`` stays
``I + T df/dx``). Default 1, the paper's filter.

EKF Complete and a stiffness error
----------------------------------
EKF Complete reads the accelerometer through the model's arm acceleration (eq. 7), i.e.
through the spring torque ``tau_s(D)``: with a stiffness error it scales every deflection,
static and dynamic. ``estimate_stiffness`` adds the log stiffness factor state (as
``tilt_stiffness``; 9 states); off by default, because the hammer strikes, which eq. 7
cannot explain, move the factor.

The filter (eqs. 4-5) is the shared Kalman update and time update of
:mod:`fmus.common.kalman` (Joseph form of eq. 4b). Divergence (a non-finite state or a
covariance that is not positive definite) raises :class:`FilterDivergence`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fmus.common import dynamics, kinematics
from fmus.common.frames import rot_rpy
from fmus.common.kalman import FilterDivergence, check_estimate, measurement_update, time_update
from fmus.common.parameters import ParameterError, param, replace
from fmus.common.robot_params import RobotAtInitialPose, RobotParameters
from fmus.estimators.henriksson2009_model import FlexibleModel

PAPER = "Henriksson et al. 2009"
VARIANTS = ("complete", "motor", "integrated")
#: EKF Integrated's low-frequency drift corrections (module docstring, "Drift correction").
DRIFT_CORRECTIONS = ("off", "tilt", "tilt_stiffness")

#: Default scalings ``lambda1 .. lambda5`` per variant (section III-C's free variables; 1 = the
#: physical initial guesses ``w_*``, ``r_*``). Checked by hand on P1 at 2 kHz with three hammer
#: strikes and sensor noise (tests/ekf_flexible_truth.py): a coordinate search on the exact
#: model lowered the 3-30 Hz mean error of EKF Motor and EKF Integrated (0.0028 -> 0.0025 mm,
#: 0.0099 -> 0.0023 mm) but made EKF Integrated lose its robustness to a 50 % stiffness error
#: (0.08 -> 0.23 mm); a grid over lambda1, lambda3, lambda5 in {0.01, 1, 100} found no setting
#: better on both (EKF Complete barely depends on them). Hence 1 until the tuning study.
DEFAULT_LAMBDAS = {
    "complete": (1.0, 1.0, 1.0, 1.0, 1.0),
    "motor": (1.0, 1.0, 1.0, 1.0, 1.0),
    "integrated": (1.0, 1.0, 1.0, 1.0, 1.0),
}


# ---- parameters ------------------------------------------------------------------------------
def _lambda(i: int, default: float):
    blocks = {1: "arm-angle (q_a)", 2: "motor-angle (q_m)", 3: "arm-velocity (dq_a)",
              4: "motor-velocity (dq_m)", 5: "motor-angle measurement"}
    what = "process noise" if i <= 4 else "measurement noise"
    return param(default, "1", f"scaling lambda{i} of the {blocks[i]} {what} block (section III-C)",
                 low=0.0, low_inclusive=False, search=(1e-4, 1e4),
                 source=f"{PAPER}, section III-C; default 1 (see DEFAULT_LAMBDAS)")


def _w_stiffness():
    return param(1e-3, "1", "process noise intensity of the log gearbox-stiffness factor state, per "
                 "sqrt(s) (EKF Integrated's tilt_stiffness, EKF Complete's estimate_stiffness)",
                 low=0.0, low_inclusive=False,
                 source="physical guess: the stiffness is constant (0.1 % drift per second)")


def _p0_stiffness():
    return param(0.35, "1", "initial std of the log gearbox-stiffness factor state (0.35: the "
                 "factor within x0.70 .. x1.42 at 1 sigma, the paper's 50 % error at 2 sigma)",
                 low=0.0, low_inclusive=False,
                 source="chosen on P1 for EKF Integrated: larger converges faster under a "
                 "stiffness error, smaller wanders less in the nominal case")


@dataclass(frozen=True)
class EkfMotorParameters(RobotAtInitialPose):
    """Parameters of EKF Motor (and the common part of the other two): the filter's robot model
    (inherited; values differing from the plant's are a model error), its noise model and
    initial covariance."""

    stiffness_scale: float = param(1.0, "1", "factor on the model's gearbox stiffness k_lo and k_hi "
                                   "(0.5: the paper's 50 % stiffness error, Table I)", low=0.0,
                                   low_inclusive=False, source=f"{PAPER}, section IV-C")
    lambda1: float = _lambda(1, DEFAULT_LAMBDAS["motor"][0])
    lambda2: float = _lambda(2, DEFAULT_LAMBDAS["motor"][1])
    lambda3: float = _lambda(3, DEFAULT_LAMBDAS["motor"][2])
    lambda4: float = _lambda(4, DEFAULT_LAMBDAS["motor"][3])
    lambda5: float = _lambda(5, DEFAULT_LAMBDAS["motor"][4])
    w_q_a: float = param(1e-4, "rad/s0.5", "process noise intensity of the arm angles (initial guess)",
                         low=0.0, low_inclusive=False,
                         source="physical guess: the angles follow their velocities (Euler error only)")
    w_q_m: float = param(1e-4, "rad/s0.5", "process noise intensity of the motor angles, motor side "
                         "(initial guess)", low=0.0, low_inclusive=False,
                         source="physical guess, as w_q_a (motor side)")
    w_dq_a: float = param(1.0, "rad/s/s0.5", "process noise intensity of the arm velocities: unknown "
                          "forces and model errors (initial guess)", low=0.0, low_inclusive=False,
                          source="physical guess: arm accelerations off the model by about 1 rad/s2")
    w_dq_m: float = param(10.0, "rad/s/s0.5", "process noise intensity of the motor velocities, motor "
                          "side: torque and friction errors (initial guess)", low=0.0,
                          low_inclusive=False,
                          source="physical guess: torque errors about 0.05 N m on J_m = 5e-3 kg m2")
    r_motor: float = param(1e-4, "rad", "measurement noise std of the motor angles, motor side",
                           low=0.0, low_inclusive=False,
                           source="16-bit encoder quantisation (1e-4 rad) plus noise, Encoder FMU")
    p0_q_a: float = param(1e-3, "rad", "initial std of the arm angles", low=0.0, low_inclusive=False)
    p0_q_m: float = param(1e-3, "rad", "initial std of the motor angles, motor side", low=0.0,
                          low_inclusive=False)
    p0_dq_a: float = param(1e-3, "rad/s", "initial std of the arm velocities", low=0.0, low_inclusive=False)
    p0_dq_m: float = param(1e-2, "rad/s", "initial std of the motor velocities", low=0.0,
                           low_inclusive=False)
    substeps: int = param(1, "1", "Euler steps per sample in the time update (1: the paper's "
                          "Euler forward over T, eq. 3a; k: k steps of T / k, A their product). "
                          "Euler's first-order error is the filters' main nominal error on our "
                          "plant (see the module docstring)", low=1, high=64,
                          source=f"{PAPER}, section III-A (1)")
    init_from_motors: bool = param(True, "1", "start from rest in static equilibrium at the first "
                                   "measured motor angles (off: at q_a0 / p_tool0, which must then "
                                   "match the robot's start)")

    def model_robot(self) -> RobotParameters:
        """The filter's robot model: the robot parameters with ``stiffness_scale`` applied."""
        r = self.robot()
        if self.stiffness_scale == 1.0:
            return r
        s = self.stiffness_scale
        return replace(r, k_lo=tuple(s * k for k in r.k_lo), k_hi=tuple(s * k for k in r.k_hi))


@dataclass(frozen=True)
class EkfCompleteParameters(EkfMotorParameters):
    """Parameters of EKF Complete: EKF Motor's plus the accelerometer's."""

    lambda1: float = _lambda(1, DEFAULT_LAMBDAS["complete"][0])
    lambda2: float = _lambda(2, DEFAULT_LAMBDAS["complete"][1])
    lambda3: float = _lambda(3, DEFAULT_LAMBDAS["complete"][2])
    lambda4: float = _lambda(4, DEFAULT_LAMBDAS["complete"][3])
    lambda5: float = _lambda(5, DEFAULT_LAMBDAS["complete"][4])
    r_acc: float = param(0.05, "m/s2", "measurement noise std of the accelerometer (x and z)", low=0.0,
                         low_inclusive=False, source="Imu FMU noise 0.02 m/s2, plus model error")
    mount_rpy: tuple = param((0.0, 0.0, 0.0), "rad", "mounting roll, pitch, yaw of the accelerometer "
                             "on the tool (as the Imu FMU's)", low=-math.pi, high=math.pi)
    estimate_stiffness: bool = param(False, "1", "estimate a common gearbox-stiffness factor (an "
                                     "extra state, beyond the paper; see the module docstring)")
    w_stiffness: float = _w_stiffness()
    p0_stiffness: float = _p0_stiffness()


@dataclass(frozen=True)
class EkfIntegratedParameters(EkfMotorParameters):
    """Parameters of EKF Integrated: EKF Motor's plus the integrated accelerometer's."""

    lambda1: float = _lambda(1, DEFAULT_LAMBDAS["integrated"][0])
    lambda2: float = _lambda(2, DEFAULT_LAMBDAS["integrated"][1])
    lambda3: float = _lambda(3, DEFAULT_LAMBDAS["integrated"][2])
    lambda4: float = _lambda(4, DEFAULT_LAMBDAS["integrated"][3])
    lambda5: float = _lambda(5, DEFAULT_LAMBDAS["integrated"][4])
    drift_correction: str = param("off", "1", "low-frequency drift correction (beyond "
                                  "the paper, see the module docstring): off (the paper's filter), "
                                  "tilt (velocity-error states: the accelerometer's gravity "
                                  "component measures the tool angle) or tilt_stiffness (tilt plus "
                                  "a common gearbox-stiffness factor state)",
                                  choices=DRIFT_CORRECTIONS,
                                  source="FlexFusion issue 5; the paper leaves the drift unsolved "
                                  "(section IV)")
    w_b: float = param(3e-3, "m/s2.s0.5", "process noise intensity of the integrated-velocity error "
                       "states, m/s per sqrt(s) (accelerometer noise and bias, integration error)",
                       low=0.0, low_inclusive=False,
                       source="accelerometer noise 0.02 m/s2 at 2 kHz integrates to 4.5e-4 m/s per "
                       "sqrt(s); chosen 3e-3 on P1 (larger: less drift in the nominal case, slower "
                       "stiffness-factor convergence)")
    p0_b: float = param(1e-4, "m/s", "initial std of the integrated-velocity error states (the "
                        "integration starts at rest: nearly zero)", low=0.0, low_inclusive=False)
    w_stiffness: float = _w_stiffness()
    p0_stiffness: float = _p0_stiffness()
    r_tilt: float = param(2e-3, "rad", "std of the tool angle from the accelerometer's first sample "
                          "at rest (the static alignment of tilt_stiffness with init_from_motors)",
                          low=0.0, low_inclusive=False,
                          source="accelerometer noise 0.02 m/s2 over g")
    r_vel: float = param(2e-3, "m/s", "measurement noise std of the integrated sensor velocity "
                         "(x and z)", low=0.0, low_inclusive=False,
                         source="physical guess: 0.02 m/s2 noise and small angle errors, "
                         "integrated over seconds")
    mount_rpy: tuple = param((0.0, 0.0, 0.0), "rad", "mounting roll, pitch, yaw of the accelerometer "
                             "on the tool (as the Imu FMU's)", low=-math.pi, high=math.pi)


PARAMETERS = {"complete": EkfCompleteParameters, "motor": EkfMotorParameters,
              "integrated": EkfIntegratedParameters}


# ---- the filter (eqs. 3-5) -------------------------------------------------------------------
@dataclass
class Filtered:
    """A measurement update not yet committed (see :meth:`EkfFlexibleModel.filtered`)."""

    x: np.ndarray
    P: np.ndarray
    innovation_norm: float
    u: tuple                       # the input at the sample (used by the next prediction)
    v_int: tuple = (0.0, 0.0)      # integrated velocity measurement (EKF Integrated)
    a_world: tuple = (0.0, 0.0)    # world acceleration of the sample (trapezoidal rule)
    aux: tuple = (0.0, 0.0, 0.0)   # (phi used to rotate, tool-frame fx, fz) of the sample (tilt)


class EkfFlexibleModel:
    """One of the three EKFs of section III-A on the flexible model of eq. 2.

    Parameters
    ----------
    p
        Filter parameters (an :data:`PARAMETERS` class matching ``variant``).
    variant
        ``"complete"``, ``"motor"`` or ``"integrated"``.

    Notes
    -----
    Per sample ``k``: :meth:`update` with the motor angles, the accelerometer reading and the
    motor torque at ``t_k`` gives ``x_{k|k}`` (eq. 4); :meth:`predict` gives ``x_{k+1|k}`` with the
    torque of that sample (eq. 5). :meth:`filtered` computes an update without committing it
    (for an FMU's outputs), :meth:`commit` commits it. With ``init_from_motors`` the first
    update starts from :meth:`initial_state` at the measured motor angles instead of the state
    at ``q_a0`` / ``p_tool0``.

    The arguments the methods share:

    x, P
        A state (n,) and its covariance (n, n); where optional, the filter's current estimate.
        The state is eq. 1's ``(q_a, q_m, dq_a, dq_m)`` [rad, rad/s; ``q_m`` and ``dq_m`` motor
        side], then the drift-correction states (module docstring): the velocity errors ``b``
        (world x, z) [m/s] and the log gearbox-stiffness factor ``s`` [1].
    q_m
        Measured motor angles (2,) [rad], motor side (the ``x_2`` rows of eqs. 6 and 8).
    acc_s
        Accelerometer reading: the specific force (3,) [m/s^2] in the sensor frame, turned into
        the tool frame with ``mount_rpy`` (:meth:`tool_frame`); EKF Motor ignores it (None).
    u
        Motor torque (2,) [N m], motor side: the input of eq. 2 (``u_k`` of eqs. 3-5).
    T
        Sample period [s] (eqs. 3a, 5).
    """

    def __init__(self, p: EkfMotorParameters, variant: str) -> None:
        if variant not in VARIANTS:
            raise ValueError(f"unknown EKF variant {variant!r}; expected one of {VARIANTS}")
        if not isinstance(p, PARAMETERS[variant]):
            raise TypeError(f"EKF {variant!r} needs {PARAMETERS[variant].__name__}, got {type(p).__name__}")
        self.p = p
        self.variant = variant
        self.robot = p.model_robot()
        self.model = FlexibleModel(self.robot)
        corr = p.drift_correction if variant == "integrated" else "off"
        self.drift_correction = corr
        self._tilt = corr in ("tilt", "tilt_stiffness")        # states 8, 9: velocity errors b
        self._stiff = (corr == "tilt_stiffness"                # last state: log stiffness factor
                       or (variant == "complete" and p.estimate_stiffness))
        self._i_s = 8 + 2 * self._tilt                         # its index (10, or 8 in EKF Complete)
        self.n = n = 8 + 2 * self._tilt + self._stiff
        self.m = 2 if variant == "motor" else 4
        wq = ([p.lambda1 * p.w_q_a ** 2] * 2 + [p.lambda2 * p.w_q_m ** 2] * 2
              + [p.lambda3 * p.w_dq_a ** 2] * 2 + [p.lambda4 * p.w_dq_m ** 2] * 2)
        p0 = [p.p0_q_a] * 2 + [p.p0_q_m] * 2 + [p.p0_dq_a] * 2 + [p.p0_dq_m] * 2
        if self._tilt:
            wq += [p.w_b ** 2] * 2
            p0 += [p.p0_b] * 2
        if self._stiff:
            wq += [p.w_stiffness ** 2]
            p0 += [p.p0_stiffness]
        self._wq = np.array(wq)
        r2 = [p.lambda5 * p.r_motor ** 2] * 2
        if variant == "complete":
            r2 += [p.r_acc ** 2] * 2
        elif variant == "integrated":
            r2 += [p.r_vel ** 2] * 2
        self.R = np.diag(r2)
        self._mount = rot_rpy(p.mount_rpy)[[0, 2]] if variant != "motor" else None   # sensor -> tool x, z
        self.x = np.zeros(n)
        self.x[0:8] = dynamics.static_equilibrium(p.initial_angles(), self.robot)
        self.P = np.diag(np.square(p0))
        self.u = (0.0, 0.0)
        self.innovation_norm = 0.0
        self.v_int = (0.0, 0.0)            # integrated velocity (EKF Integrated)
        self.a_world: tuple | None = None  # last world acceleration (None: before the first sample)
        self._T = 0.0                      # the last prediction's step (the integration step)
        self._aux = (0.0, 0.0, 0.0)        # (phi_used, fx, fz) of the last update (tilt states)
        self._substeps = int(p.substeps)
        self._started = False              # False until the first update is committed
        self._I = np.eye(n)

    # -- process and measurement noise
    def process_noise(self, T: float) -> np.ndarray:
        """``Q`` for the sample period ``T`` (section III-C, module docstring)."""
        return np.diag(T * self._wq)

    def tool_frame(self, acc_s) -> tuple[float, float]:
        """The accelerometer reading ``acc_s`` (sensor frame, 3 axes) [m/s^2] in the tool frame,
        x and z, through the mounting rotation of ``mount_rpy``."""
        f = self._mount @ np.asarray(acc_s, float)
        return float(f[0]), float(f[1])

    # -- eq. 3b: the measurement function of the variant
    def h(self, x, u=(0.0, 0.0)) -> np.ndarray:
        """``h(x, u)`` (eqs. 6-8) of the variant."""
        x = tuple(map(float, x))
        y = [x[2], x[3]]
        if self.variant == "complete":
            y += self.model.specific_force(x, self.model.f_scaled(x[0:8], u, self.stiffness_factor(x)))
        elif self.variant == "integrated":
            v = self.model.sensor_velocity(x)
            y += (v[0] + x[8], v[1] + x[9]) if self._tilt else v
        return np.array(y)

    def h_jacobian(self, x, u=(0.0, 0.0)) -> np.ndarray:
        """``H = dh/dx`` at the state ``x`` with the input ``u`` (``H_k`` of eqs. 4b, 5c),
        analytic."""
        x = tuple(map(float, x))
        H = np.zeros((self.m, self.n))
        H[0, 2] = H[1, 3] = 1.0
        if self.variant == "complete":
            self._complete_rows(x[0:8], u, self.stiffness_factor(x), H)
        elif self.variant == "integrated":
            H[2:4, 0:8] = self.model.sensor_velocity_jacobian(x)
            if self._tilt:
                H[2, 8] = H[3, 9] = 1.0
        return H

    def transition(self, x, u, T: float, aux=None) -> np.ndarray:
        """``F(x, u) = x + T f(x, u)`` (Euler forward, eq. 3a), with the drift-correction states'
        dynamics (module docstring) for ``aux = (phi_used, fx, fz)`` of the last update (default:
        the filter's)."""
        return self._dynamics(np.asarray(x, float), u, T, self._aux if aux is None else aux)[0]

    def transition_jacobian(self, x, u, T: float, aux=None) -> np.ndarray:
        """``A = dF/dx = I + T df/dx`` (eq. 5b's ``A_k``) at the state ``x`` with the input ``u``,
        analytic, drift-correction states included; ``aux`` as in :meth:`transition`."""
        return self._dynamics(np.asarray(x, float), u, T, self._aux if aux is None else aux)[1]

    def stiffness_factor(self, x=None) -> float:
        """The factor ``exp(s)`` on the model's gearbox stiffness of the state ``x`` (1 without
        the stiffness state of ``tilt_stiffness`` or EKF Complete's ``estimate_stiffness``)."""
        x = self.x if x is None else x
        return math.exp(min(float(x[self._i_s]), 700.0)) if self._stiff else 1.0

    def model_derivatives(self, x, u=(0.0, 0.0)) -> tuple:
        """``f(x, u)`` (eq. 2) of the first 8 states with the estimated stiffness factor."""
        return self.model.f_scaled(tuple(map(float, x[0:8])), u, self.stiffness_factor(x))

    def _complete_rows(self, xs: tuple, u, sig: float, H: np.ndarray) -> tuple[float, float]:
        """EKF Complete's accelerometer rows (eq. 7): fills ``H[2:4]`` and returns ``rho_s``, the
        arm acceleration from :meth:`FlexibleModel.f_scaled` with the stiffness factor ``sig``
        (``d rho_s / d s = d rho_s / d ddq_a  sigma df/dsigma`` for the factor state)."""
        m = self.model
        xdot = m.f_scaled(xs, u, sig)
        H[2:4, 0:8] = m.specific_force_jacobian(xs, xdot, m.jacobian(xs, xdot=xdot, sigma=sig))
        if self._stiff:
            col = m.stiffness_column(xs)
            s2, c2 = math.sin(xs[1]), math.cos(xs[1])
            l1, vx, vz = m.l1, m.vx, m.vz
            H[2, self._i_s] = sig * ((l1 * c2 + vz) * col[4] + vz * col[5])
            H[3, self._i_s] = sig * ((l1 * s2 - vx) * col[4] - vx * col[5])
        return m.specific_force(xs, xdot)

    def _dynamics(self, x: np.ndarray, u, T: float, aux) -> tuple[np.ndarray, np.ndarray]:
        """``(F(x, u), A)``: eqs. 3a and 5 plus the drift-correction states. With ``substeps``
        ``k > 1`` the state takes ``k`` Euler steps of ``T / k`` and ``A = I + T df/dx`` stays the
        first-order Jacobian of eq. 5 at ``x`` (it differs from ``dF/dx`` by ``O(T^2)``; the
        covariance needs no more, and each further Jacobian would cost as much as the step)."""
        k = self._substeps
        xn, A = self._euler(x, u, T / k if k > 1 else T, aux)
        if k == 1:
            return xn, A
        h = T / k
        for _ in range(k - 1):
            xn = self._euler(xn, u, h, aux, jacobian=False)[0]
        A = self._I + (A - self._I) * k
        return xn, A

    def _euler(self, x: np.ndarray, u, T: float, aux,
               jacobian: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """One Euler step over ``T``: ``(x + T f, I + T df/dx)`` (eqs. 3a, 5).

        Velocity errors ``b`` (tilt): ``b' = (R(phi_used) - R(phi)) f`` with the tool angle
        ``phi = q1 + q2`` of the state; log stiffness factor ``s`` (tilt_stiffness): ``s' = 0``,
        the spring torque of eq. 2 scaled by ``exp(s)``.
        """
        m = self.model
        xs = tuple(x[0:8].tolist())
        A = self._I.copy() if jacobian else None
        xn = x.copy()
        if self._stiff:
            sig = math.exp(min(float(x[self._i_s]), 700.0))      # no OverflowError: caught as divergence
            col = m.stiffness_column(xs)
            xdot = tuple(a + (sig - 1.0) * c for a, c in zip(m.f(xs, u), col))
            if jacobian:
                A[0:8, 0:8] += T * m.jacobian(xs, xdot=xdot, sigma=sig)
                A[4:8, self._i_s] = [T * sig * c for c in col[4:8]]
        else:
            xdot = m.f(xs, u)
            if jacobian:
                A[0:8, 0:8] += T * m.jacobian(xs, xdot=xdot)
        xn[0:8] += T * np.array(xdot)
        if self._tilt:
            phi_u, fx, fz = aux
            phi = xs[0] + xs[1]
            c, s = math.cos(phi), math.sin(phi)
            cu, su = math.cos(phi_u), math.sin(phi_u)
            xn[8] += T * ((cu - c) * fx + (su - s) * fz)
            xn[9] += T * ((s - su) * fx + (cu - c) * fz)
            if jacobian:
                A[8, 0] = A[8, 1] = T * (s * fx - c * fz)
                A[9, 0] = A[9, 1] = T * (c * fx + s * fz)
        return xn, A

    # -- eq. 4
    def filtered(self, q_m, acc_s=None, u=(0.0, 0.0)) -> Filtered:
        """The measurement update (eq. 4) for the sample ``(q_m, acc_s)`` with the input ``u``,
        not committed.

        Raises
        ------
        FilterDivergence
            If the result is non-finite or its covariance not positive definite.
        """
        with np.errstate(all="ignore"):      # non-finite results are caught by the checks
            return self._filtered(q_m, acc_s, (float(u[0]), float(u[1])))

    def initial_state(self, q_m, sigma: float = 1.0) -> np.ndarray:
        """The state at rest in static equilibrium (the filter's model, its spring torque scaled
        by ``sigma``) with motor angles ``q_m`` (8 states):
        ``q_a = q_m / r - D(q_a)``, ``sigma tau_s(D) = G(q_a)``, solved by fixed-point iteration
        (the gravity deflection is small: it contracts by about ``|dG/dq| / k`` per iteration)."""
        r = np.asarray(self.robot.gear_ratio, float)
        q_m = np.asarray(q_m, float)
        q = q_m / r
        for _ in range(20):
            D = dynamics.spring_deflection(dynamics.gravity_torque(q, self.robot) / sigma, self.robot)
            q_new = q_m / r - D
            done = np.abs(q_new - q).max() <= 1e-13
            q = q_new
            if done:
                break
        x = dynamics.static_equilibrium(q, self.robot)
        x[2:4] = q_m
        return x

    def static_alignment(self, q_m, acc_s) -> tuple[np.ndarray, np.ndarray]:
        """Initial state and covariance (all ``n`` states) at rest, from the first sample's motor
        angles ``q_m`` and accelerometer reading ``acc_s``, of a filter with the stiffness state
        (``tilt_stiffness``, or EKF Complete's ``estimate_stiffness`` with ``r_acc / g`` in
        place of ``r_tilt``): the log stiffness factor ``s`` that makes the static equilibrium's
        tool angle ``phi(s) = q1 + q2`` match the accelerometer's gravity direction
        ``phi_acc = atan2(-f_x, f_z)`` (at rest ``f = g (-sin phi, cos phi)`` in the tool frame),
        as the MAP estimate with the prior ``N(0, p0_stiffness^2)`` and ``r_tilt`` on
        ``phi_acc`` (Gauss-Newton); the arm angles follow ``s`` and inherit its variance through
        ``dq_a / ds``."""
        p = self.p
        fx, fz = self.tool_frame(acc_s)
        phi_acc = math.atan2(-fx, fz)
        r_tilt = p.r_tilt if self.variant == "integrated" else p.r_acc / self.model.g
        ir2, ip0 = 1.0 / r_tilt ** 2, 1.0 / p.p0_stiffness ** 2
        s, h = 0.0, 1e-4
        for _ in range(4):
            x = self.initial_state(q_m, math.exp(s))
            xp = self.initial_state(q_m, math.exp(s + h))
            dq = (xp[0:2] - x[0:2]) / h
            J = float(dq.sum())
            info = J * J * ir2 + ip0
            step = (J * (phi_acc - x[0] - x[1]) * ir2 - s * ip0) / info
            s += step
            if abs(step) < 1e-10:
                break
        x = np.zeros(self.n)
        x[0:8] = self.initial_state(q_m, math.exp(s))
        i = self._i_s
        x[i] = s
        P = self.P.copy()
        pss = 1.0 / info
        P[i, :] = P[:, i] = 0.0
        P[i, i] = pss
        P[0:2, 0:2] += np.outer(dq, dq) * pss
        P[0:2, i] = P[i, 0:2] = dq * pss
        return x, P

    def _filtered(self, q_m, acc_s, u: tuple) -> Filtered:
        from scipy.linalg.lapack import dpotrf, dpotrs   # here: scipy.linalg takes 0.15 s to import
        x0, P = self.x, self.P
        if not self._started and self.p.init_from_motors:
            if self._stiff:
                x0, P = self.static_alignment(q_m, acc_s)
            else:
                x0 = x0.copy()
                x0[0:8] = self.initial_state(q_m)
        xs = tuple(x0[0:8].tolist())
        m = self.model
        aux = self._aux
        H = np.zeros((self.m, self.n))
        H[0, 2] = H[1, 3] = 1.0
        y = [float(q_m[0]), float(q_m[1])]
        hx = [xs[2], xs[3]]
        v_int, a_w = self.v_int, self.a_world
        if self.variant == "complete":
            y += self.tool_frame(acc_s)
            hx += self._complete_rows(xs, u, self.stiffness_factor(x0), H)
        elif self.variant == "integrated":
            fx, fz = self.tool_frame(acc_s)
            phi = xs[0] + xs[1]
            c, s = math.cos(phi), math.sin(phi)
            a_w = (c * fx + s * fz, -s * fx + c * fz - self.model.g)      # R(phi) rho + g_vec
            if self.a_world is not None:
                h2 = 0.5 * self._T
                a0 = self.a_world
                v_int = (v_int[0] + h2 * (a0[0] + a_w[0]), v_int[1] + h2 * (a0[1] + a_w[1]))
            y += v_int
            vx, vz = m.sensor_velocity(xs)
            H[2:4, 0:8] = m.sensor_velocity_jacobian(xs)
            if self._tilt:
                vx, vz = vx + float(x0[8]), vz + float(x0[9])
                H[2, 8] = H[3, 9] = 1.0
                aux = (phi, fx, fz)
            hx += (vx, vz)
        nu = np.array(y) - np.array(hx)
        xf, Pf, nis = measurement_update(x0, P, nu, H, self.R)        # eq. 4 (fmus.common.kalman)
        return Filtered(xf, Pf, math.sqrt(nis), u, v_int, a_w, aux)

    def commit(self, r: Filtered) -> np.ndarray:
        """Make the :meth:`filtered` result ``r`` the current estimate ``x_{k|k}``; returns it."""
        self.x, self.P, self.innovation_norm, self.u = r.x, r.P, r.innovation_norm, r.u
        self._started = True
        self.v_int, self.a_world, self._aux = r.v_int, r.a_world, r.aux
        return self.x

    def update(self, q_m, acc_s=None, u=(0.0, 0.0)) -> np.ndarray:
        """Measurement update (eq. 4) with the sample ``(q_m, acc_s)`` and the input ``u`` at
        ``t_k``; commits and returns ``x_{k|k}``."""
        return self.commit(self.filtered(q_m, acc_s, u))

    # -- eq. 5
    def predict(self, T: float, u=None) -> np.ndarray:
        """Time update over ``T`` (eqs. 5a-b), with the input of the last update unless ``u``."""
        u = self.u if u is None else (float(u[0]), float(u[1]))
        T = float(T)
        with np.errstate(all="ignore"):
            x, A = self._dynamics(self.x, u, T, self._aux)
        # A P A^T + Q is positive definite if P is: finiteness suffices here (the measurement
        # update checks definiteness)
        P = time_update(A, self.P, self.process_noise(T), definite=False)
        check_estimate(x, P, "EKF diverged in the time update", definite=False)
        self.x, self.P, self._T = x, P, T
        self._started = True
        return x

    # -- outputs
    def tool_position(self, x=None) -> np.ndarray:
        """Tool position (world x, z) [m] from the arm angles of the state ``x`` (rigid forward
        kinematics)."""
        return kinematics.tool_position((self.x if x is None else x)[0:2], self.robot)

    def tool_position_variance(self, x=None, P=None) -> float:
        """Trace of the tool position covariance ``J P_qa J^T`` [m^2] of the state ``x`` and its
        covariance ``P`` (``J``: the tool Jacobian at the arm angles, ``P_qa``: their block)."""
        x = self.x if x is None else x
        P = self.P if P is None else P
        J = kinematics.jacobian(x[0:2], self.robot)
        return float(np.einsum("ij,jk,ik->", J, P[0:2, 0:2], J))


def make_filter(variant: str, **params) -> EkfFlexibleModel:
    """An :class:`EkfFlexibleModel` of ``variant`` with validated parameters ``params``.

    Raises
    ------
    ParameterError
        Naming an invalid parameter.
    """
    from fmus.common.parameters import validate
    if variant not in VARIANTS:
        raise ParameterError(f"unknown EKF variant {variant!r}; expected one of {VARIANTS}")
    return EkfFlexibleModel(validate(PARAMETERS[variant](**params)), variant)


__all__ = ["EkfCompleteParameters", "EkfFlexibleModel", "EkfIntegratedParameters", "EkfMotorParameters",
           "Filtered", "DRIFT_CORRECTIONS", "PARAMETERS", "VARIANTS",
           "DEFAULT_LAMBDAS",
           "make_filter"]

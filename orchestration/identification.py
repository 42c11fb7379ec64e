"""Grey-box identification of the flexible-joint model from closed-loop experiments.

The estimators' model is the 8-state flexible-joint model of :mod:`fmus.common.dynamics`
(Axelsson 2012, eqs. 10-11; Henriksson 2009, eq. 2). Its parameters come, as on a real robot,
"from a separate identification procedure" (Henriksson 2009, section IV, citing Wernholt &
Moberg 2008): an experiment with the robot's own controller in the loop, a multisine torque
added to the controller output around working points, measured through what a real
identification has - the commanded motor torque, the motor encoders and a tool accelerometer.

**Method: closed-loop output error in the time domain.** For a parameter vector ``theta`` each
experiment is simulated with the *same known controller* (the robot's
:class:`~fmus.robot_plant.motion_control_model.MotionController`: its reference table,
feed-forward, PID and the multisine excitation, all the controller's own, known settings) in a
loop with the model, and ``scipy.optimize.least_squares`` minimises the whitened differences
between the measured and the simulated encoder angles and accelerometer readings (the
accelerometer's data-sheet anti-aliasing filter applied to the simulated specific force). Why
this formulation:

* Wernholt & Gunnarsson (2008) and Wernholt & Moberg (2008, "Frequency-domain gray-box
  identification of industrial robots") identify in the frequency domain from nonparametric
  FRFs at several working points; that needs periodic steady state, long experiments and a
  linearisation per working point, which the gearbox's nonlinear (soft near zero torque)
  spring and the Coulomb friction violate - exactly the parameters we must fit here.
* Moberg, Wernholt, Hanssen & Brogardh (2014, "Modeling and parameter estimation of robot
  manipulators using extended flexible joint models", J. Dyn. Sys. Meas. Control) fit
  *extended* flexible-joint models (elasticity beyond the gearbox); the estimators' model here
  is the basic one, so on a plant with such extra elasticity the fit is biased - reported, not
  hidden. A time-domain nonlinear fit of the whole model over several working points (here)
  uses the nonlinear spring and friction as they are instead of linearising them per working
  point. Because the rigid-body mode of the arm is only marginally stable without feedback, the
  model is simulated with the known feedback (closed-loop output error; Ljung 1999, on
  identification in closed loop) rather than open loop from the measured torque.
* Output error is consistent when the measurement noise does not enter the loop (true here:
  the drive feeds back its own motor angle, the encoder and accelerometer only measure). Its
  uncertainty is *not* ``s^2 (J^T J)^-1`` (Ljung 1999, ch. 9), which assumes white residuals:
  the prefiltered, decimated residuals are coloured, and on a plant with dynamics the model
  lacks the misfit is a coloured, low-frequency part of them. Measured on main (realistic plant):
  5 of 16 true values inside those 95 % intervals, worst error 35 std. See *Uncertainty*.

**Uncertainty** (:func:`hac_covariance`; chosen by measurement, tests/test_identification.py).
The covariance is the sandwich ``(J^T J)^-1 J^T Omega J (J^T J)^-1`` (White 1980) with ``Omega``
from the autocovariances of the scores ``J_t^T f_t`` per experiment, Bartlett-weighted up to
the lag of Newey & West's (1994, Rev. Econ. Stud. 61) automatic rule (Newey & West 1987,
Econometrica 55: the estimator); residuals leverage-adjusted (MacKinnon & White 1985, J.
Econometrics 29, "HC2"), and the 95 % interval ``value exp(+-c std_log)`` with the fixed-b
critical value ``c`` of Kiefer & Vogelsang (2005, Econometric Theory 21) for that lag over the
experiment's length (:func:`fixed_b_critical_value`). Why each piece, measured on the ideal
plant (the model exact; sensors at their data-sheet noise and quantisation) with a linearised
Monte Carlo of 300 noise draws, two experiments of 0.8 s (40 decimated samples each, 36
parameters with the calibration and the start angles): the plain sandwich with the automatic
lag covers 79-93 % per parameter (mean 86 %): with so many parameters per sample it is biased
low, and more so the longer the lag; HC2 and the fixed-b value bring it to at least 91 % (mean 95 %).
Repeated identifications (tests/test_identification.py, full version): 30 noise seeds, the
study's three working points at 1.2 s, every parameter covered in 27-30 of 30 (95.8 % overall).
The white ``s^2 (J^T J)^-1`` covers as well there (92-96 %) *once the start angles are
estimated*: what made it fail on the ideal plant was the model started from the first, noisy,
quantised encoder reading, an error that colours the whole start transient (repeated fits: the
elbow's friction covered in 20-25 % of 20 runs, ``s^2`` 1.4-2.9); hence
``Criterion.initial_state``. On the realistic plant the residuals are dominated by coloured
misfit, which only the sandwich sees. A block bootstrap over experiments and working points
was not chosen: with the study's three experiments there are three blocks (no distribution),
and every replicate is a full refit (minutes each), against one Jacobian for the sandwich.
The interval covers the noise; on a plant with dynamics the model lacks, the estimates converge
to *effective* values, not to the plant's (the study compares with those: ``--effective``).

**Parameters.** Fitted, per joint (log-scale, so relative errors): gearbox stiffness ``k_lo``,
``k_hi``, damping ``d``, motor inertia ``J_m``, friction ``f_v``, ``f_c``, the spring's soft-zone
width ``delta`` and the friction's smoothing speed ``w_c`` (started away from the plant's values,
:data:`INITIAL_GUESS`: a real lab does not know them). Of the rigid links only four
combinations enter the model (:class:`fmus.common.dynamics.ArmConstants`): ``a`` and ``c`` of the
inertia matrix, the forearm's first moment ``m2 c2`` (both ``e = m2 l1 c2`` and
``g2 = g m2 c2``) and the shoulder's gravity moment ``m1 c1 + m2 l1``; these four base
parameters are fitted and mapped to one consistent :class:`RobotParameters`. Held at nominal
values (:data:`FIXED`, each with its reason in :data:`FIXED_REASONS`), none of them a value only
the plant knows: gear ratios (data sheet), link lengths (kinematic calibration), the
accelerometer's mount point (flange drawing; the calibration absorbs its error), gravity, and
the masses ``m1``, ``m2``, which do not enter the model (they only split the base parameters
into ``c``, ``I``). Per experiment the initial motor angles are estimated too (nuisance
parameters, ``Criterion.initial_state``).

**What a practitioner adds on a real robot** (:class:`Criterion`; :func:`fit` defaults to the
plain output error, the study to :data:`PRACTICE`):

* *Prefilter* ``L(q)`` of the output error (Ljung 1999, sections 7.4 and 14.4: prefiltering
  the prediction errors is a frequency weighting of the fit, which pushes the model's misfit
  to the frequencies the filter removes): a zero-phase Butterworth low-pass at ``prefilter``
  Hz keeps the band the model is meant for - the servo loop and the gearbox modes, 8-20 Hz
  here - and drops the structural modes the flexible-joint model lacks (link bending about
  35 Hz, a local mode about 220 Hz), as Wernholt & Gunnarsson (2008) fit the model's frequency
  response only around the gearbox modes, below the structural ones. The filtered error is
  band-limited, so it is decimated to twice the cut-off and whitened by the filter's noise
  gain: ``s^2`` stays about 1 for white accelerometer noise and ``s^2 (J^T J)^-1`` keeps its
  meaning (approximately: the Butterworth roll-off leaves some correlation between samples; the
  encoder's filtered error keeps the model's start from the first, noisy, reading, which
  raises its variance to about 1.8). On a plant with unmodelled in-band dynamics ``s^2`` is
  larger with the prefilter than without (the misfit is low-frequency, the noise is reduced).
* *Accelerometer calibration* as nuisance parameters: an affine map of the nominally mounted
  reading, ``acc = C^T [f; 1]`` with ``f`` the model's reading at the nominal mounting - per
  axis a scale, the cross-axis terms of a small mounting rotation, and a bias (the Imu's
  mounting and scale errors are unknown to the fit, as on a real robot: Axelsson & Norrlof
  2012 calibrate them separately; here they are estimated with the robot). ``C`` enters
  linearly and is eliminated at every residual evaluation by linear least squares over all
  experiments (variable projection, Golub & Pereyra 1973), so the optimiser and its
  finite-difference Jacobian see only the robot's parameters and the covariance accounts for
  the calibration (the Jacobian of the projected residual).
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from fmus.common.frames import G, rot_rpy
from fmus.common import dynamics, kinematics
from fmus.common.parameters import as_array, fields
from fmus.common.robot_params import RobotParameters
from fmus.robot_plant.motion_control_model import (MotionController, MotionControllerParameters,
                                                   build_controller)
from fmus.robot_plant.sensor_model import butterworth_coefficients

JOINT_PARAMETERS = ("k_lo", "k_hi", "d", "J_m", "f_v", "f_c", "delta", "w_c")
#: The base parameters of the rigid links (the combinations the model depends on).
BASE_PARAMETERS = ("inertia_a", "inertia_c", "moment_m2c2", "moment_g1")
#: Fitted parameters, in the order of ``theta`` (``theta = log(value)``).
NAMES = tuple(f"{n}[{j}]" for n in JOINT_PARAMETERS for j in (1, 2)) + BASE_PARAMETERS
#: Parameters held at their nominal value, each for a stated reason (:data:`FIXED_REASONS`):
#: none of them is a value only the plant knows.
FIXED = ("l1", "l2", "m1", "m2", "gear_ratio", "sensor_offset", "g")
#: Why each of :data:`FIXED` is not fitted.
FIXED_REASONS = {
    "l1": "link length from the kinematic calibration (the same lengths the forward kinematics uses)",
    "l2": "link length from the kinematic calibration (the same lengths the forward kinematics uses)",
    "m1": "does not enter the model: only the base parameters do (a choice of parametrisation, "
          "it sets how c1, I1 are split, not the motion)",
    "m2": "does not enter the model: only the base parameters do (a choice of parametrisation, "
          "it sets how c2, I2 are split, not the motion)",
    "gear_ratio": "gear data sheet",
    "sensor_offset": "accelerometer mount point on the flange drawing (CAD); its residual error is "
                     "absorbed by the estimated accelerometer calibration",
    "g": "local gravity (a constant of the site)",
}

#: The starting point of the fit: what one knows before the experiment - DESIGN.md's ranges
#: (stiffness 1e5-1e6 N m/rad, motor inertia about 5e-3 kg m^2, Moberg & Ohr's friction
#: orders) and a CAD model of uniform links without payload (``c = l / 2``, ``I = m l^2 / 12``).
#: Stated physical ranges of the parameters whose effect can vanish from the data (the fit is
#: bounded to them): the soft zone ``delta`` (rad, a few arc-seconds to a quarter degree) and
#: the friction smoothing ``w_c`` (rad/s on the motor). Noisy short records can leave ``w_c``
#: undetermined (measured on the realistic plant: the shoulder's ``w_c`` ran towards zero,
#: relative std 12, and the fit did not converge in 40 evaluations); an estimate that ends on
#: a bound is reported as such, with the range as its interval (:attr:`Fit.at_bound`).
RANGES = {"delta": (2e-5, 5e-3), "w_c": (0.02, 20.0)}

#: The soft zone's width ``delta`` starts at 5e-4 rad (Moberg & Ohr's backlash-like zones are a
#: few 1e-4 rad) and the friction smoothing ``w_c`` at 1 rad/s (motor side: a few hundredths of
#: a turn per second), neither at the plant's value.
INITIAL_GUESS = {"k_lo": (3.0e5, 1.0e5), "k_hi": (6.0e5, 3.0e5), "d": (1000.0, 200.0),
                 "J_m": (4e-3, 4e-3), "f_v": (2e-3, 2e-3), "f_c": (0.3, 0.3),
                 "delta": (5e-4, 5e-4), "w_c": (1.0, 1.0)}


class IdentificationError(RuntimeError):
    """The fit did not converge (``message`` says why); ``best`` is the best :class:`Fit` found
    (or None)."""

    def __init__(self, message: str, best: "Fit | None" = None) -> None:
        super().__init__(message)
        self.best = best


# ---------------------------------------------------------------------------------------------
# parameters <-> theta
# ---------------------------------------------------------------------------------------------
def base_parameters(p: RobotParameters) -> dict[str, float]:
    """The rigid links' base parameters of ``p`` (see the module docstring)."""
    k = dynamics.arm_constants(p)
    return {"inertia_a": k.a, "inertia_c": k.c, "moment_m2c2": p.m2 * p.c2,
            "moment_g1": p.m1 * p.c1 + p.m2 * p.l1}


def parameter_values(p: RobotParameters) -> np.ndarray:
    """The fitted quantities of ``p`` in the order of :data:`NAMES`."""
    joint = [float(getattr(p, n)[j]) for n in JOINT_PARAMETERS for j in (0, 1)]
    base = base_parameters(p)
    return np.array(joint + [base[n] for n in BASE_PARAMETERS])


def robot_from_values(values: Sequence[float], nominal: RobotParameters) -> RobotParameters:
    """The :class:`RobotParameters` with the fitted ``values`` (order :data:`NAMES`), the
    :data:`FIXED` ones from ``nominal``: ``c2 = (m2 c2) / m2``, ``I2 = c - m2 c2^2``,
    ``c1 = (m1 c1 + m2 l1 - m2 l1) / m1``, ``I1 = a - m1 c1^2 - I2 - m2 (l1^2 + c2^2)``.

    Not validated (a trial point of the optimiser may have ``I1 < 0``: the model only sees the
    base parameters); :func:`fmus.common.parameters.validate` the final result.
    """
    v = [float(x) for x in values]
    joint = {n: (v[2 * i], v[2 * i + 1]) for i, n in enumerate(JOINT_PARAMETERS)}
    a, c, m2c2, mg1 = v[2 * len(JOINT_PARAMETERS):]
    m1, m2, l1 = nominal.m1, nominal.m2, nominal.l1
    c2 = m2c2 / m2
    i2 = c - m2 * c2 ** 2
    c1 = (mg1 - m2 * l1) / m1
    i1 = a - m1 * c1 ** 2 - i2 - m2 * (l1 ** 2 + c2 ** 2)
    return dataclasses.replace(nominal, c1=c1, c2=c2, I1=i1, I2=i2, **joint)


def initial_guess(nominal: RobotParameters) -> np.ndarray:
    """:data:`INITIAL_GUESS` and the uniform-link CAD model of the ``nominal`` parameters, in
    the order of :data:`NAMES`."""
    cad = dataclasses.replace(nominal, c1=nominal.l1 / 2, c2=nominal.l2 / 2,
                              I1=nominal.m1 * nominal.l1 ** 2 / 12, I2=nominal.m2 * nominal.l2 ** 2 / 12,
                              **INITIAL_GUESS)
    return parameter_values(cad)


# ---------------------------------------------------------------------------------------------
# experiments and their simulation
# ---------------------------------------------------------------------------------------------
@dataclass
class Experiment:
    """One identification experiment: the known settings and the measured signals.

    ``time`` (n+1,) from 0 with the step ``dt`` of controller, plant and sensors; ``tau_m``
    (n+1, 2) the commanded motor torque, ``q_m`` (n+1, 2) the encoder readings, ``acc`` (n+1, 3)
    the accelerometer's specific force (sensor frame). ``controller`` the controller's
    parameters (its settings, path and excitation); ``acc_cutoff``, ``acc_filter_order``,
    ``mount_rpy`` and ``g`` the accelerometer's data-sheet filter and its mounting.

    The fit does not need ``tau_m``: the controller law that produced it is known and simulated
    with the model (closed-loop output error); it is kept with the data, as in a real log.
    """

    name: str
    time: np.ndarray
    tau_m: np.ndarray
    q_m: np.ndarray
    acc: np.ndarray
    controller: MotionControllerParameters
    acc_cutoff: float = 200.0
    acc_filter_order: int = 2
    mount_rpy: tuple = (0.0, 0.0, 0.0)
    g: float = G

    @property
    def dt(self) -> float:
        """The sample period (s)."""
        return float(self.time[1] - self.time[0])

    def built_controller(self) -> MotionController:
        """The experiment's controller (reference table built once per process and setting),
        to be copied: ``MotionController(c.model, c.excitation, cutoff)`` starts a fresh run."""
        c = self.controller
        ctrl = _CONTROLLERS.get(c)
        if ctrl is None:
            if len(_CONTROLLERS) >= 32:
                _CONTROLLERS.clear()
            ctrl = _CONTROLLERS[c] = build_controller(c)
        return ctrl


_CONTROLLERS: dict[MotionControllerParameters, MotionController] = {}


def rest_state(q_m0: Sequence[float], p: RobotParameters) -> np.ndarray:
    """The state at rest of the robot ``p`` whose motor angles are ``q_m0``: arm angles with
    ``tau_s(q_m0 / r - q_a) = G(q_a)`` (fixed point; the deflection is small)."""
    qm = np.asarray(q_m0, dtype=float)
    r = as_array(p.gear_ratio)
    q_a = qm / r
    for _ in range(30):
        q_new = qm / r - dynamics.spring_deflection(dynamics.gravity_torque(q_a, p), p)
        if np.max(np.abs(q_new - q_a)) < 1e-14:
            break
        q_a = q_new
    return np.concatenate([q_a, qm, np.zeros(4)])


def specific_force(a_xz: np.ndarray, phi: np.ndarray, mount_rpy: Sequence[float], g: float) -> np.ndarray:
    """Accelerometer reading ``R_s^T (a - g_vec)`` in the sensor frame, vectorised over samples
    (n, 3): :func:`fmus.robot_plant.sensor_model.imu_reading` for arrays. ``a_xz`` (n, 2) is
    the mount point's acceleration (world x, z), ``phi`` (n,) the tool angle, ``mount_rpy`` the
    sensor's mount and ``g`` the gravitational acceleration."""
    c, s = np.cos(phi), np.sin(phi)
    ax, azg = a_xz[:, 0], a_xz[:, 1] + g
    tool = np.stack([c * ax - s * azg, np.zeros_like(ax), s * ax + c * azg], axis=1)   # Ry(phi)^T v
    return tool @ rot_rpy(mount_rpy)                                                    # R_mount^T


def simulate(p: RobotParameters, exp: Experiment, q_m0: Sequence[float] | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
    """Encoder angles (n+1, 2) and accelerometer readings (n+1, 3) the model ``p`` predicts for
    the experiment ``exp``, in closed loop with the experiment's controller, from rest at the
    motor angles ``q_m0`` (default the first encoder reading).

    The timing is the co-simulation master's (Gauss-Seidel; the plant, whose outputs have no
    direct feedthrough, steps first): the plant integrates over ``[t, t + dt)`` (RK4) with the
    torque the controller computed at ``t``, then the controller reads the motor angle at
    ``t + dt`` (its encoder, noise-free), forms its speed from it as the drive does
    (:meth:`MotionController.measure` at ``t + dt``), integrates its error over the step and computes the
    torque of ``t + dt``;
    the sensors sample the plant at ``t + dt``, the accelerometer's anti-aliasing filter starting
    in steady state at its first input. ``tests/test_study_identify.py`` checks the result
    against the FMUs.
    """
    dt = exp.dt
    n = len(exp.time) - 1
    template = exp.built_controller()
    ctrl = MotionController(template.model, template.excitation, exp.controller.velocity_cutoff)
    plant = dynamics.FlexibleRobotModel(p, np.zeros(2))
    plant.x = rest_state(exp.q_m[0] if q_m0 is None else q_m0, p)
    zero = np.zeros(2)
    states = np.empty((n + 1, 8))
    acc = np.empty((n + 1, 2))
    s = plant.state
    states[0] = s
    acc[0] = kinematics.point_motion(s[0:2], s[4:6], plant.arm_acceleration(0.0, 0.0), p, "sensor")[4:6]
    tau = ctrl.evaluate(0.0, np.array(s[2:4]), ctrl.law_speed(0.0), zero)
    for i in range(n):
        plant.step(tau, zero, dt)
        s = plant.state
        states[i + 1] = s
        acc[i + 1] = kinematics.point_motion(s[0:2], s[4:6], plant.arm_acceleration(0.0, 0.0), p, "sensor")[4:6]
        qm = np.array(s[2:4])
        ctrl.measure((i + 1) * dt, qm)          # the drive's speeds from its (noise-free) encoder
        ctrl.evaluate(i * dt, qm, ctrl.law_speed(i * dt), zero)
        ctrl.advance(dt)
        tau = ctrl.evaluate((i + 1) * dt, qm, ctrl.law_speed((i + 1) * dt), zero)
    ideal = specific_force(acc, states[:, 0] + states[:, 1], exp.mount_rpy, exp.g)
    if exp.acc_cutoff > 0.0:
        from scipy.signal import lfilter, lfilter_zi
        b, a = butterworth_coefficients(exp.acc_cutoff, dt, exp.acc_filter_order)
        filtered, _ = lfilter(b, a, ideal[1:], axis=0, zi=lfilter_zi(b, a)[:, None] * ideal[1])
        ideal = np.vstack([ideal[:1], filtered])
    return states[:, 2:4], ideal


# ---------------------------------------------------------------------------------------------
# the residual and the fit
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class NoiseLevels:
    """Standard deviations that whiten the residual: the sensors' data-sheet noise and
    quantisation (``sqrt(noise^2 + resolution^2 / 12)``), never estimated from the plant."""

    q_m: float = 3.5e-5       # rad: Encoder noise 2e-5 and 16-bit resolution 9.6e-5
    acc: float = 0.02         # m/s^2: Imu noise 0.02 and resolution 4.8e-3

    @classmethod
    def of_sensors(cls, encoder_noise: float, encoder_resolution: float, acc_noise: float,
                   acc_resolution: float) -> "NoiseLevels":
        """From sensor data-sheet values: white noise ``encoder_noise`` (rad) and ``acc_noise``
        (m/s^2), each with the noise ``q / sqrt(12)`` of its quantisation step
        ``encoder_resolution`` / ``acc_resolution`` added in quadrature; a level of zero is
        floored at 1e-9 of the unit."""
        return cls(max(math.hypot(encoder_noise, encoder_resolution / math.sqrt(12)), 1e-9),
                   max(math.hypot(acc_noise, acc_resolution / math.sqrt(12)), 1e-9))


@dataclass(frozen=True)
class Criterion:
    """How the output errors are weighted (module docstring: what a practitioner adds).

    ``prefilter`` the cut-off (Hz) of the zero-phase low-pass prefilter ``L(q)`` of the output
    error, 0 for none; ``prefilter_order`` its Butterworth order (applied forward and backward);
    ``acc_calibration`` whether the accelerometer's affine calibration (per-axis scale,
    cross-axis terms of the mounting, bias) is estimated with the robot; ``initial_state``
    whether each experiment's initial motor angles are estimated (two nuisance parameters per
    experiment) instead of taken from the first, noisy and quantised, encoder reading.
    """

    prefilter: float = 0.0
    prefilter_order: int = 4
    acc_calibration: bool = False
    initial_state: bool = False

    def __post_init__(self) -> None:
        if not (math.isfinite(self.prefilter) and self.prefilter >= 0.0):
            raise ValueError(f"prefilter cut-off must be a frequency >= 0 Hz (0 = off), not {self.prefilter}")
        if self.prefilter_order not in range(1, 9):
            raise ValueError(f"prefilter order must be 1..8, not {self.prefilter_order}")


#: The criterion of the study (``flexfusion study identify``): the prefilter keeps the servo
#: loop and the gearbox modes (8-20 Hz, DESIGN.md) with margin and attenuates the link bending
#: mode at about 35 Hz by 12 dB (order 4, forward and backward: ``|L|^2 = 1 / (1 + (f/fc)^8)``)
#: and everything above by far more; the accelerometer's calibration is estimated. Measured on
#: the realistic plant (``flexfusion study identify``, amplitude 0.5 N m): the prefilter moves
#: the estimates by a few percent only (k_lo[1] -11 -> -10 %, d[1] -35 -> -38 %): the biases
#: there come from in-band effects (the ripple acting as a motor-side spring, the torque-constant
#: error, the bending's series compliance), which no prefilter can remove. The calibration
#: recovers the Imu's scale (x +0.37 %, true +0.3 %; z +0.24 %, true +0.2 %) and makes the fit
#: insensitive to the mounting, scale and kinematic errors (switching them off changes nothing).
PRACTICE = Criterion(prefilter=25.0, acc_calibration=True, initial_state=True)


class _Weighting:
    """The prefilter, decimation and whitening of one experiment's signals (``Criterion``)."""

    def __init__(self, criterion: Criterion, dt: float, noise: NoiseLevels) -> None:
        self.sos, self.step, gain = None, 1, 1.0
        if criterion.prefilter > 0.0:
            from scipy.signal import butter
            if criterion.prefilter >= 0.5 / dt:
                raise ValueError(f"prefilter cut-off {criterion.prefilter:g} Hz is not below the Nyquist "
                                 f"frequency {0.5 / dt:g} Hz of the data")
            self.sos = butter(criterion.prefilter_order, criterion.prefilter, fs=1.0 / dt, output="sos")
            impulse = np.zeros((4002, 1))
            impulse[2001] = 1.0
            gain = float(np.sum(self(impulse) ** 2))                 # white-noise variance gain
            self.step = max(1, int(1.0 / (2.0 * criterion.prefilter * dt)))      # Nyquist of the band
        self.q_m = 1.0 / (noise.q_m * math.sqrt(gain))
        self.acc = 1.0 / (noise.acc * math.sqrt(gain))

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """Samples 1..n of ``x`` (n+1, k), filtered forward and backward and decimated. The
        filter starts from rest, without padding: scipy's ``sosfiltfilt`` pads or starts from the
        edge sample, which gives one noisy sample the weight of many; the start transient is the
        same in the measured and the simulated signal (the filter is linear) and cancels in the
        output error."""
        if self.sos is None:
            return x[1:]
        from scipy.signal import sosfilt
        forward = sosfilt(self.sos, x[1:], axis=0)
        return sosfilt(self.sos, forward[::-1], axis=0)[::-1][::self.step]


def model_outputs(theta: Sequence[float], exp: Experiment, nominal: RobotParameters,
                  q_m0: Sequence[float] | None = None) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`simulate` of the experiment ``exp`` at ``theta = log(values)`` (order
    :data:`NAMES`; the other parameters from ``nominal``) from rest at ``q_m0`` (default the
    first encoder reading); None if the model's simulation diverges."""
    p = robot_from_values(np.exp(np.asarray(theta, dtype=float)), nominal)
    with np.errstate(all="ignore"):
        try:
            q_m, acc = simulate(p, exp, q_m0)
        except (OverflowError, ValueError, ZeroDivisionError, FloatingPointError):
            return None
    return (q_m, acc) if np.all(np.isfinite(q_m)) and np.all(np.isfinite(acc)) else None


class Residual:
    """Whitened output errors of a set of experiments from the model's outputs
    (:func:`model_outputs`, one per experiment): encoder angles over ``noise.q_m``, accelerometer
    over ``noise.acc``, after the ``criterion``'s prefilter, with the accelerometer calibration
    eliminated by linear least squares over all experiments when the criterion estimates it."""

    def __init__(self, experiments: Sequence[Experiment], noise: NoiseLevels, criterion: Criterion) -> None:
        self.weights = [_Weighting(criterion, e.dt, noise) for e in experiments]
        self.calibrate = criterion.acc_calibration
        self.q_m = [w.q_m * w(e.q_m) for w, e in zip(self.weights, experiments)]
        self.acc = [w.acc * w(e.acc) for w, e in zip(self.weights, experiments)]
        self.size = sum(q.size + a.size for q, a in zip(self.q_m, self.acc))

    def calibration(self, outputs: Sequence[tuple[np.ndarray, np.ndarray]]) -> np.ndarray | None:
        """The accelerometer calibration ``C`` (4, 3): reading ``= [f_x, f_y, f_z, 1] @ C`` with
        ``f`` the model's reading at the nominal mounting (None if not estimated)."""
        return self._solve([w(_affine(acc)) for w, (_, acc) in zip(self.weights, outputs)])

    def _solve(self, acc_sim: Sequence[np.ndarray]) -> np.ndarray | None:
        if not self.calibrate:
            return None
        reg = np.vstack([w.acc * a for w, a in zip(self.weights, acc_sim)])
        return np.linalg.lstsq(reg, np.vstack(self.acc), rcond=1e-10)[0]

    def __call__(self, outputs: Sequence[tuple[np.ndarray, np.ndarray] | None]) -> np.ndarray:
        if any(o is None for o in outputs):
            return np.full(self.size, np.nan)
        acc_sim = [w(_affine(acc)) for w, (_, acc) in zip(self.weights, outputs)]    # with L(1)
        cal = self._solve(acc_sim)
        acc_sim = [a[:, :3] if cal is None else a @ cal for a in acc_sim]
        return np.concatenate([(q - w.q_m * w(q_sim)).ravel() for w, q, (q_sim, _) in
                               zip(self.weights, self.q_m, outputs)]
                              + [(a - w.acc * a_sim).ravel() for w, a, a_sim in zip(self.weights, self.acc, acc_sim)])

    def calibration_leverage(self, outputs: Sequence[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
        """Per element of the residual, its leverage in the calibration's linear least squares
        (the diagonal of the projection on the calibration's regressors; zero for the encoder's
        residuals and without calibration)."""
        lev = np.zeros(self.size)
        if not self.calibrate:
            return lev
        reg = np.vstack([w.acc * w(_affine(acc)) for w, (_, acc) in zip(self.weights, outputs)])
        u, sv, _ = np.linalg.svd(reg, full_matrices=False)
        h = np.sum(u[:, sv > 1e-10 * sv[0]] ** 2, axis=1)
        n_q = sum(q.size for q in self.q_m)
        lev[n_q:] = np.repeat(h, self.acc[0].shape[1])
        return lev

    def series(self) -> list[np.ndarray]:
        """Per experiment, the positions in the residual vector of each sample time: an integer
        array (samples, 5) - the two encoder and the three accelerometer residuals of that time
        (the time series the autocorrelation-consistent covariance runs over)."""
        out, q_at, a_at = [], 0, sum(q.size for q in self.q_m)
        for q, a in zip(self.q_m, self.acc):
            n = len(q)
            out.append(np.column_stack([q_at + np.arange(q.size).reshape(n, -1),
                                        a_at + np.arange(a.size).reshape(n, -1)]))
            q_at, a_at = q_at + q.size, a_at + a.size
        return out


def _affine(a: np.ndarray) -> np.ndarray:
    """``[a, 1]``: the regressors of the calibration (the filter is applied to both)."""
    return np.column_stack([a, np.ones(len(a))])


def experiment_residual(theta: Sequence[float], exp: Experiment, nominal: RobotParameters,
                        noise: NoiseLevels, criterion: Criterion = Criterion()) -> np.ndarray:
    """:class:`Residual` of one experiment ``exp`` at ``theta`` (other parameters from
    ``nominal``), whitened by ``noise`` and weighted by ``criterion``; non-finite if the model
    diverges."""
    return Residual([exp], noise, criterion)([model_outputs(theta, exp, nominal)])


Mapper = Callable[[Callable[..., Any], list[tuple]], list[Any]]


def _serial_map(fn: Callable[..., Any], jobs: list[tuple]) -> list[Any]:
    return [fn(*job) for job in jobs]


@dataclass
class Fit:
    """Result of :func:`fit`: ``robot`` the identified parameters; per name of :data:`NAMES`
    ``values`` and ``std`` (one standard deviation, from the autocorrelation-consistent
    covariance :func:`hac_covariance`, by the delta method from ``std_log``, that of
    ``log(value)``); ``std_white`` / ``std_log_white`` the same from the white-residual
    ``s^2 (J^T J)^-1`` (for comparison); ``hac_lag`` the Bartlett truncation over ``hac_samples``
    samples per experiment and ``critical_value`` the two-sided 95 % value of
    :func:`fixed_b_critical_value` (the 95 % interval is ``value exp(+-critical_value std_log)``);
    ``s2`` the residual variance factor (about 1 when the noise levels are right and the model
    fits), ``cost`` half the sum of squared whitened residuals, ``n_residuals``, ``nfev`` residual
    evaluations, ``converged`` and the optimiser's ``message``; ``correlation`` of the estimates;
    ``acc_calibration`` the accelerometer calibration ``C`` (:meth:`Residual.calibration`) when
    the criterion estimates it; ``initial_motor_angles`` per experiment (rad) when it estimates
    them; ``at_bound`` per name the range of :data:`RANGES` whose bound the estimate ended on
    (not determined by the data), else None."""

    robot: RobotParameters
    values: dict[str, float]
    std: dict[str, float]
    s2: float
    cost: float
    n_residuals: int
    nfev: int
    converged: bool
    message: str
    correlation: np.ndarray | None = None
    acc_calibration: np.ndarray | None = None
    std_log: dict[str, float] | None = None
    std_white: dict[str, float] | None = None
    std_log_white: dict[str, float] | None = None
    hac_lag: int | None = None
    critical_value: float = 1.959963984540054
    hac_samples: int | None = None
    initial_motor_angles: list[list[float]] | None = None
    at_bound: dict[str, tuple[float, float] | None] | None = None


def _covariance(jac: np.ndarray, s2: float, rcond: float = 1e-10) -> np.ndarray:
    """``s2 (J^T J)^-1`` by the SVD of ``J``; a direction the data do not determine (singular
    value below ``rcond`` times the largest) gets an infinite variance, not the pseudo-inverse's
    zero."""
    _, sv, vt = np.linalg.svd(jac, full_matrices=False)
    ok = sv > rcond * sv[0]
    cov = s2 * (vt[ok].T / sv[ok] ** 2) @ vt[ok]
    if not ok.all():
        null = np.abs(vt[~ok]).max(axis=0) > 1e-6
        cov[null, :] = cov[:, null] = np.inf
    return cov


def newey_west_bandwidth(scores: Sequence[np.ndarray]) -> int:
    """Lag truncation ``L`` of the Bartlett kernel by Newey & West's (1994) automatic rule:
    from the scores ``h_t`` (one (T_e, p) array per experiment, columns scaled to unit variance
    and summed, ``w = 1``) the autocovariances ``sigma_j`` up to ``n = floor(4 (T / 100)^(2/9))``
    give ``s0 = sigma_0 + 2 sum sigma_j``, ``s1 = 2 sum j sigma_j`` and
    ``L = floor(1.1447 ((s1 / s0)^2)^(1/3) T^(1/3))`` (their eq. 3.8 and Table I, Bartlett), with
    ``T`` the (shortest) experiment's number of samples; at least 1, at most ``T - 1``."""
    t = min(len(h) for h in scores)
    scale = np.sqrt(np.mean(np.vstack(scores) ** 2, axis=0))
    scale = np.where(scale > 0, scale, 1.0)
    series = [np.sum(h / scale, axis=1) for h in scores]
    n = max(1, int(4.0 * (t / 100.0) ** (2.0 / 9.0)))
    sigma = np.zeros(n + 1)
    for x in series:
        for j in range(n + 1):
            sigma[j] += float(x[j:] @ x[:len(x) - j])
    s0 = sigma[0] + 2.0 * sigma[1:].sum()
    s1 = 2.0 * float(np.arange(1, n + 1) @ sigma[1:])
    if s0 <= 0.0:
        return 1
    lag = int(1.1447 * ((s1 / s0) ** 2) ** (1.0 / 3.0) * t ** (1.0 / 3.0))
    return int(min(max(lag, 1), t - 1))


def fixed_b_critical_value(lag: int, samples: int) -> float:
    """Two-sided 95 % critical value of the t statistic whose variance is a Bartlett-kernel
    long-run variance with truncation ``lag`` estimated from ``samples`` samples, by fixed-b
    asymptotics (Kiefer & Vogelsang 2005, Econometric Theory 21, the Bartlett polynomial of their
    Table: ``1.96 + 2.9694 b + 0.4160 b^2 - 0.5324 b^3``, ``b = (lag + 1) / samples``, the
    kernel's bandwidth ``M = lag + 1`` over the sample size). Wider than 1.96 because the
    long-run variance is itself estimated, with a downward bias growing with ``b``."""
    b = min((lag + 1.0) / samples, 1.0)
    return 1.959963984540054 + 2.9694 * b + 0.4160 * b ** 2 - 0.5324 * b ** 3


def hac_covariance(jac: np.ndarray, f: np.ndarray, series: Sequence[np.ndarray], n_par: int,
                   lag: int | None = None, rcond: float = 1e-10,
                   leverage: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """Heteroscedasticity- and autocorrelation-consistent (sandwich) covariance of a least-squares
    estimate (White 1980; Newey & West 1987):
    ``(J^T J)^-1 [sum_e sum_{|l| <= L} (1 - |l| / (L + 1)) Gamma_e(l)] (J^T J)^-1``
    with ``Gamma_e(l) = sum_t h_t h_{t-l}^T`` the autocovariances of the scores
    ``h_t = sum_i J_ti f~_ti`` of experiment ``e`` (the rows ``i`` of one sample time ``t``:
    ``series``, see :meth:`Residual.series`); experiments are independent (no cross terms).

    The residuals are leverage-adjusted, ``f~_i = f_i / sqrt(1 - h_i)`` (MacKinnon & White
    1985, their HC2): a fit of many parameters to short records leaves residuals smaller than
    the errors (the sum of the leverages is the number of parameters), which biases the plain
    sandwich low; ``h_i`` is the diagonal of ``J (J^T J)^-1 J^T`` plus ``leverage`` (that of
    parameters eliminated before ``J``: the accelerometer calibration). Without ``leverage`` the
    residuals are used as they are and the sandwich scaled by ``n / (n - n_par)`` instead.

    ``jac`` (n, k) the Jacobian of the residual ``f`` (n,) at the estimate, ``n_par`` every
    estimated parameter (the eliminated calibration included), ``lag`` the Bartlett truncation
    ``L`` (default :func:`newey_west_bandwidth`), ``rcond`` as in :func:`_covariance`. Returns
    the covariance and ``L``; use it with :func:`fixed_b_critical_value`."""
    n = len(f)
    if leverage is not None:
        u, sv, _ = np.linalg.svd(jac, full_matrices=False)
        h = np.sum(u[:, sv > rcond * sv[0]] ** 2, axis=1) + leverage
        f = f / np.sqrt(np.clip(1.0 - h, 1e-3, None))
    scores = [np.einsum("tck,tc->tk", jac[idx], f[idx]) for idx in series]
    if lag is None:
        lag = newey_west_bandwidth(scores)
    meat = np.zeros((jac.shape[1], jac.shape[1]))
    for h_t in scores:
        meat += h_t.T @ h_t
        for j in range(1, min(lag, len(h_t) - 1) + 1):
            g = h_t[j:].T @ h_t[:-j]
            meat += (1.0 - j / (lag + 1.0)) * (g + g.T)
    if leverage is None:
        meat *= n / max(n - n_par, 1)
    bread = _covariance(jac, 1.0, rcond)
    finite = np.all(np.isfinite(bread), axis=0)
    cov = np.full_like(bread, np.inf)
    b = bread[np.ix_(finite, finite)]
    cov[np.ix_(finite, finite)] = b @ meat[np.ix_(finite, finite)] @ b
    return cov, int(lag)


def fit(experiments: Sequence[Experiment], nominal: RobotParameters, *, noise: NoiseLevels = NoiseLevels(),
        criterion: Criterion = Criterion(), theta0: Sequence[float] | None = None, max_nfev: int = 40,
        map_fn: Mapper | None = None, diff_step: float = 1e-6, xtol: float = 1e-8, ftol: float = 1e-8,
        progress: Callable[[float], None] | None = None) -> Fit:
    """Closed-loop output-error fit of the flexible-joint model (module docstring).

    Parameters
    ----------
    experiments
        The measured experiments.
    nominal
        The nominal (CAD / data-sheet) parameters: source of :data:`FIXED`.
    noise
        Measurement noise levels that whiten the residual.
    criterion
        Prefilter and accelerometer calibration (:class:`Criterion`; default the plain output
        error, the study uses :data:`PRACTICE`).
    theta0
        Starting ``log`` values (order :data:`NAMES`); default :func:`initial_guess`.
    max_nfev
        Limit of residual evaluations of the optimiser (Jacobians not counted).
    map_fn
        ``map_fn(fn, jobs) -> results`` running ``fn(*job)`` (e.g. on a study executor);
        default serial. The residual maps over experiments, the Jacobian (forward
        differences of step ``diff_step`` in ``log`` space) over experiments x parameters.
    xtol, ftol
        The optimiser's (scipy's ``least_squares``) tolerances on the step and the cost.
    progress
        Called with the cost after each residual evaluation.

    Raises
    ------
    IdentificationError
        If the optimiser stops at ``max_nfev`` or the residual is not finite at the start or at
        the end; ``best`` holds the best fit seen.
    """
    from scipy.optimize import least_squares

    exps = list(experiments)
    x0 = np.log(initial_guess(nominal)) if theta0 is None else np.asarray(theta0, dtype=float)
    objective = _Objective(exps, nominal, Residual(exps, noise, criterion), map_fn or _serial_map,
                           diff_step, progress, noise.q_m if criterion.initial_state else None)
    x0 = np.concatenate([x0, np.zeros(objective.n_start)])
    f0 = objective.residual(x0)
    if not np.all(np.isfinite(f0)):
        raise IdentificationError("the residual is not finite at the initial guess (the model "
                                  "diverges in the experiment's closed loop)", None)
    lower, upper = log_bounds(objective.n_start)
    x0 = np.clip(x0, lower + 1e-9, upper - 1e-9)
    res = least_squares(objective.residual, x0, jac=objective.jacobian, method="trf", x_scale=1.0,
                        max_nfev=max_nfev, xtol=xtol, ftol=ftol, gtol=1e-12, bounds=(lower, upper))
    best = objective.best
    if best.f is None or not np.all(np.isfinite(best.f)):
        raise IdentificationError("the residual is not finite at the end of the fit", None)
    if res.status == 0:
        raise IdentificationError(f"the identification did not converge within {max_nfev} residual "
                                  f"evaluations (cost {best.cost:.6g}); best fit so far kept",
                                  objective.result(False, res.message))
    return objective.result(True, res.message)


def log_bounds(n_extra: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bounds of ``theta`` (order :data:`NAMES`, then ``n_extra`` unbounded
    entries): the ``log`` of :data:`RANGES`, infinite elsewhere."""
    lower = np.full(len(NAMES) + n_extra, -np.inf)
    upper = np.full(len(NAMES) + n_extra, np.inf)
    for i, name in enumerate(NAMES):
        rng = RANGES.get(name.split("[")[0])
        if rng is not None:
            lower[i], upper[i] = math.log(rng[0]), math.log(rng[1])
    return lower, upper


def at_bound(values: dict[str, float], tol: float = 1e-3) -> dict[str, tuple[float, float] | None]:
    """Per name of :data:`NAMES` the range of :data:`RANGES` if ``values`` lies on one of its
    bounds (within ``tol`` in ``log``), else None."""
    out: dict[str, tuple[float, float] | None] = {}
    for name in NAMES:
        rng = RANGES.get(name.split("[")[0])
        hit = rng is not None and min(abs(math.log(values[name] / b)) for b in rng) < tol
        out[name] = rng if hit else None
    return out


@dataclass
class _Point:
    """A point of the fit: ``log`` parameters ``x``, whitened residual ``f``, its cost
    ``f @ f / 2`` and the experiments' model outputs."""
    cost: float = math.inf
    x: np.ndarray | None = None
    f: np.ndarray | None = None
    outputs: list[Any] | None = None


class _Objective:
    """:func:`fit`'s residual and its forward-difference Jacobian (step ``diff_step`` in
    ``log`` space), the model outputs of each mapped over the experiments (and the parameters)
    with ``map_fn``. Keeps the best point seen (the one reported, which the optimiser's last
    need not be) and the last Jacobian (the optimiser asks again for the same point)."""

    def __init__(self, experiments: list[Experiment], nominal: RobotParameters, assemble: Residual,
                 map_fn: Mapper, diff_step: float, progress: Callable[[float], None] | None,
                 start_scale: float | None = None) -> None:
        self.experiments, self.nominal, self.assemble = experiments, nominal, assemble
        self.map_fn, self.diff_step, self.progress = map_fn, diff_step, progress
        #: with ``start_scale``, ``x`` ends with each experiment's initial motor angles as offsets
        #: from its first encoder reading, in units of ``start_scale`` (rad: the encoder's noise)
        self.start_scale = start_scale
        self.n_start = 0 if start_scale is None else 2 * len(experiments)
        self._last: tuple[np.ndarray | None, list[Any] | None] = (None, None)
        self.best = _Point()
        self.nfev = 0                                   # residual evaluations
        self._jacobian: tuple[np.ndarray | None, np.ndarray | None] = (None, None)

    def residual(self, x: np.ndarray) -> np.ndarray:
        """The whitened residual at ``log`` parameters ``x``."""
        best = self.best
        if best.f is not None and np.array_equal(best.x, x):
            return best.f
        outputs = self.map_fn(model_outputs, [self._job(x, i) for i in range(len(self.experiments))])
        self._last = (np.array(x), outputs)
        f = self.assemble(outputs)
        self.nfev += 1
        cost = 0.5 * float(f @ f) if np.all(np.isfinite(f)) else math.inf
        if cost < best.cost:
            self.best = _Point(cost, np.array(x), f, outputs)
        if self.progress is not None:
            self.progress(cost)
        return f

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """Forward differences of the residual at ``x``, one column per parameter."""
        if self._jacobian[0] is not None and np.array_equal(self._jacobian[0], x):
            return self._jacobian[1]
        f0 = self.residual(x)
        base = self.best.outputs if np.array_equal(self.best.x, x) else self._last[1]
        m, n_robot = len(self.experiments), len(x) - self.n_start
        jobs = []
        for k in range(n_robot):
            xk = np.array(x)
            xk[k] += self.diff_step
            jobs += [self._job(xk, i) for i in range(m)]
        for k in range(self.n_start):                   # a start angle moves its experiment only
            xk = np.array(x)
            xk[n_robot + k] += self.diff_step
            jobs.append(self._job(xk, k // 2))
        outputs = self.map_fn(model_outputs, jobs)
        cols = [(self.assemble(outputs[k * m:(k + 1) * m]) - f0) / self.diff_step for k in range(n_robot)]
        for k in range(self.n_start):
            moved = list(base)
            moved[k // 2] = outputs[n_robot * m + k]
            cols.append((self.assemble(moved) - f0) / self.diff_step)
        self._jacobian = (np.array(x), np.column_stack(cols))
        return self._jacobian[1]

    def _job(self, x: np.ndarray, i: int) -> tuple:
        """The arguments of :func:`model_outputs` for experiment ``i`` at ``x``."""
        exp = self.experiments[i]
        if not self.n_start:
            return (x, exp, self.nominal)
        n_robot = len(x) - self.n_start
        return (x[:n_robot], exp, self.nominal, exp.q_m[0] + self.start_scale * x[n_robot + 2 * i:n_robot + 2 * i + 2])

    def result(self, converged: bool, message: str) -> Fit:
        """The :class:`Fit` at the best point: values, their standard deviations from the
        Jacobian there (the delta method on ``log`` values) and correlations."""
        x, f = self.best.x, self.best.f
        k = len(x) - self.n_start
        values = np.exp(x[:k])
        jac = self.jacobian(x)
        calibration = self.assemble.calibration(self.best.outputs)
        n_res = len(f)
        n_par = len(x) + (0 if calibration is None else calibration.size)
        s2 = float(f @ f) / max(n_res - n_par, 1)
        white = _covariance(jac, s2)[:k, :k]
        series = self.assemble.series()
        cov, lag = hac_covariance(jac, f, series, n_par,
                                  leverage=self.assemble.calibration_leverage(self.best.outputs))
        cov = cov[:k, :k]
        samples = min(len(t) for t in series)
        std_log = np.sqrt(np.maximum(np.diag(cov), 0.0))
        d = np.where((std_log > 0) & np.isfinite(std_log), std_log, 1.0)
        std_white = np.sqrt(np.maximum(np.diag(white), 0.0))
        return Fit(robot=robot_from_values(values, self.nominal),
                   values=dict(zip(NAMES, map(float, values))),
                   std=dict(zip(NAMES, map(float, values * std_log))),     # delta method
                   s2=s2, cost=0.5 * float(f @ f), n_residuals=n_res, nfev=self.nfev,
                   converged=converged, message=message, correlation=cov / np.outer(d, d),
                   acc_calibration=calibration,
                   std_log=dict(zip(NAMES, map(float, std_log))),
                   std_white=dict(zip(NAMES, map(float, values * std_white))),
                   std_log_white=dict(zip(NAMES, map(float, std_white))), hac_lag=lag,
                   critical_value=fixed_b_critical_value(lag, samples), hac_samples=samples,
                   at_bound=at_bound(dict(zip(NAMES, map(float, values)))),
                   initial_motor_angles=None if not self.n_start else
                   [list(map(float, e.q_m[0] + self.start_scale * x[k + 2 * i:k + 2 * i + 2]))
                    for i, e in enumerate(self.experiments)])


# ---------------------------------------------------------------------------------------------
# report
# ---------------------------------------------------------------------------------------------
def physical_parameters(p: RobotParameters) -> dict[str, Any]:
    """Every field of the :class:`RobotParameters` part of ``p`` (vectors as lists)."""
    out: dict[str, Any] = {}
    for f in fields(RobotParameters):
        v = getattr(p, f.name)
        out[f.name] = [float(x) for x in v] if isinstance(v, tuple) else float(v)
    return out


__all__ = ["Experiment", "Fit", "IdentificationError", "NoiseLevels", "Criterion", "PRACTICE", "Residual",
           "model_outputs", "NAMES", "FIXED", "FIXED_REASONS", "RANGES", "hac_covariance",
           "newey_west_bandwidth", "fixed_b_critical_value", "log_bounds", "at_bound",
           "BASE_PARAMETERS", "JOINT_PARAMETERS", "INITIAL_GUESS", "base_parameters",
           "parameter_values", "robot_from_values", "initial_guess", "rest_state",
           "specific_force", "simulate", "experiment_residual", "fit", "physical_parameters"]

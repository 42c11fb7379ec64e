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
* Output error is consistent when the measurement noise is white and does not enter the loop
  (true here: the drive feeds back its own motor angle, the encoder and accelerometer only
  measure), and gives the uncertainty from the Jacobian at the optimum,
  ``cov = s^2 (J^T J)^-1`` (Ljung 1999, ch. 9). On a plant with dynamics the model lacks the
  estimates are biased and the covariance does not cover that bias.

**Parameters.** Fitted, per joint (log-scale, so relative errors): gearbox stiffness ``k_lo``,
``k_hi``, damping ``d``, motor inertia ``J_m``, friction ``f_v``, ``f_c``. Of the rigid links
only four combinations enter the model (:class:`fmus.common.dynamics.ArmConstants`): ``a`` and ``c`` of the
inertia matrix, the forearm's first moment ``m2 c2`` (both ``e = m2 l1 c2`` and
``g2 = g m2 c2``) and the shoulder's gravity moment ``m1 c1 + m2 l1``; these four base
parameters are fitted and mapped to one consistent :class:`RobotParameters` with the masses
``m1``, ``m2``, the lengths, gear ratios, spring softening width ``delta``, friction smoothing
``w_c``, accelerometer offset and gravity fixed at their nominal CAD / data-sheet values
(:data:`FIXED`).

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

JOINT_PARAMETERS = ("k_lo", "k_hi", "d", "J_m", "f_v", "f_c")
#: The base parameters of the rigid links (the combinations the model depends on).
BASE_PARAMETERS = ("inertia_a", "inertia_c", "moment_m2c2", "moment_g1")
#: Fitted parameters, in the order of ``theta`` (``theta = log(value)``).
NAMES = tuple(f"{n}[{j}]" for n in JOINT_PARAMETERS for j in (1, 2)) + BASE_PARAMETERS
#: Parameters held at their nominal CAD / data-sheet value (not identifiable from these
#: experiments, or known better from elsewhere: kinematic calibration, gear data sheets).
FIXED = ("l1", "l2", "m1", "m2", "gear_ratio", "delta", "w_c", "sensor_offset", "g")

#: The starting point of the fit: what one knows before the experiment - DESIGN.md's ranges
#: (stiffness 1e5-1e6 N m/rad, motor inertia about 5e-3 kg m^2, Moberg & Ohr's friction
#: orders) and a CAD model of uniform links without payload (``c = l / 2``, ``I = m l^2 / 12``).
INITIAL_GUESS = {"k_lo": (3.0e5, 1.0e5), "k_hi": (6.0e5, 3.0e5), "d": (1000.0, 200.0),
                 "J_m": (4e-3, 4e-3), "f_v": (2e-3, 2e-3), "f_c": (0.3, 0.3)}


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


def simulate(p: RobotParameters, exp: Experiment) -> tuple[np.ndarray, np.ndarray]:
    """Encoder angles (n+1, 2) and accelerometer readings (n+1, 3) the model ``p`` predicts for
    the experiment ``exp``, in closed loop with the experiment's controller.

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
    plant.x = rest_state(exp.q_m[0], p)
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
    cross-axis terms of the mounting, bias) is estimated with the robot.
    """

    prefilter: float = 0.0
    prefilter_order: int = 4
    acc_calibration: bool = False

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
PRACTICE = Criterion(prefilter=25.0, acc_calibration=True)


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


def model_outputs(theta: Sequence[float], exp: Experiment, nominal: RobotParameters
                  ) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`simulate` of the experiment ``exp`` at ``theta = log(values)`` (order
    :data:`NAMES`; the other parameters from ``nominal``); None if the model's simulation
    diverges."""
    p = robot_from_values(np.exp(np.asarray(theta, dtype=float)), nominal)
    with np.errstate(all="ignore"):
        try:
            q_m, acc = simulate(p, exp)
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
    ``values`` and ``std`` (one standard deviation, from ``s^2 (J^T J)^-1``); ``s2`` the
    residual variance factor (about 1 when the noise levels are right and the model fits),
    ``cost`` half the sum of squared whitened residuals, ``n_residuals``, ``nfev`` residual
    evaluations, ``converged`` and the optimiser's ``message``; ``acc_calibration`` the
    accelerometer calibration ``C`` (:meth:`Residual.calibration`) when the criterion estimates it."""

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
                           diff_step, progress)
    f0 = objective.residual(x0)
    if not np.all(np.isfinite(f0)):
        raise IdentificationError("the residual is not finite at the initial guess (the model "
                                  "diverges in the experiment's closed loop)", None)
    res = least_squares(objective.residual, x0, jac=objective.jacobian, method="trf", x_scale=1.0,
                        max_nfev=max_nfev, xtol=xtol, ftol=ftol, gtol=1e-12)
    best = objective.best
    if best.f is None or not np.all(np.isfinite(best.f)):
        raise IdentificationError("the residual is not finite at the end of the fit", None)
    if res.status == 0:
        raise IdentificationError(f"the identification did not converge within {max_nfev} residual "
                                  f"evaluations (cost {best.cost:.6g}); best fit so far kept",
                                  objective.result(False, res.message))
    return objective.result(True, res.message)


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
                 map_fn: Mapper, diff_step: float, progress: Callable[[float], None] | None) -> None:
        self.experiments, self.nominal, self.assemble = experiments, nominal, assemble
        self.map_fn, self.diff_step, self.progress = map_fn, diff_step, progress
        self.best = _Point()
        self.nfev = 0                                   # residual evaluations
        self._jacobian: tuple[np.ndarray | None, np.ndarray | None] = (None, None)

    def residual(self, x: np.ndarray) -> np.ndarray:
        """The whitened residual at ``log`` parameters ``x``."""
        best = self.best
        if best.f is not None and np.array_equal(best.x, x):
            return best.f
        outputs = self.map_fn(model_outputs, [(x, e, self.nominal) for e in self.experiments])
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
        jobs = []
        for k in range(len(x)):
            xk = np.array(x)
            xk[k] += self.diff_step
            jobs += [(xk, e, self.nominal) for e in self.experiments]
        outputs = self.map_fn(model_outputs, jobs)
        m = len(self.experiments)
        cols = [(self.assemble(outputs[k * m:(k + 1) * m]) - f0) / self.diff_step for k in range(len(x))]
        self._jacobian = (np.array(x), np.column_stack(cols))
        return self._jacobian[1]

    def result(self, converged: bool, message: str) -> Fit:
        """The :class:`Fit` at the best point: values, their standard deviations from the
        Jacobian there (the delta method on ``log`` values) and correlations."""
        x, f = self.best.x, self.best.f
        values = np.exp(x)
        jac = self.jacobian(x)
        calibration = self.assemble.calibration(self.best.outputs)
        n_res = len(f)
        n_par = len(x) + (0 if calibration is None else calibration.size)
        s2 = float(f @ f) / max(n_res - n_par, 1)
        cov = _covariance(jac, s2)
        std_log = np.sqrt(np.maximum(np.diag(cov), 0.0))
        d = np.where((std_log > 0) & np.isfinite(std_log), std_log, 1.0)
        return Fit(robot=robot_from_values(values, self.nominal),
                   values=dict(zip(NAMES, map(float, values))),
                   std=dict(zip(NAMES, map(float, values * std_log))),     # delta method
                   s2=s2, cost=0.5 * float(f @ f), n_residuals=n_res, nfev=self.nfev,
                   converged=converged, message=message, correlation=cov / np.outer(d, d),
                   acc_calibration=calibration)


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
           "model_outputs", "NAMES", "FIXED",
           "BASE_PARAMETERS", "JOINT_PARAMETERS", "INITIAL_GUESS", "base_parameters",
           "parameter_values", "robot_from_values", "initial_guess", "rest_state",
           "specific_force", "simulate", "experiment_residual", "fit", "physical_parameters"]

"""The posterior Cramér-Rao lower bound (CRLB) of Axelsson, Karlsson and Norrlöf (2012), section 2.3
and 4.2: the stationary Riccati solution of the EKF at every point of the true trajectory.

General bound (eqs. 7-9)
------------------------
For a linear(ised) model ``x_{t+1} = F x_t + G w_t``, ``y_t = H x_t + e_t``, ``Cov(w) = Q``,
``Cov(e) = R``, the predicted stationary covariance ``P_p`` solves the filter Riccati equation
(eq. 7, with ``K`` of eq. 8)::

    P_p = F (P_p - K H P_p) F^T + G Q G^T,   K = P_p H^T (H P_p H^T + R)^-1,

and the bound is the filtered covariance ``P = P_p - K H P_p`` (eq. 9). :func:`crlb_linear`
solves it with :func:`scipy.linalg.solve_discrete_are`, whose equation is the control Riccati
equation ``X = A^T X A - A^T X B (R + B^T X B)^-1 B^T X A + Q``; the filter equation is its
dual, so it is called with ``A = F^T``, ``B = H^T``, ``Q = G Q G^T``.

The robot (eqs. 21-25)
----------------------
State ``x = (q_a, dq_a, ddq_a)`` (arm side, 6 states), the motor angles and their rates as known
inputs ``u = (q_m, dq_m, ddq_m)`` (motor side). Eq. 21 solves the arm equation (eq. 11) for the
acceleration::

    k(q_a, dq_a; q_m, dq_m) = M(q_a)^-1 (tau_s(q_m / r - q_a) + d (dq_m / r - dq_a) - C dq_a - G(q_a)),

with the plant's nonlinear gearbox spring ``tau_s`` (the paper's linear ``k (r_g q_m - q_a)``,
see :mod:`fmus.common.dynamics`). Eq. 22: ``x_dot = (dq_a, ddq_a, L)`` with the jerk
``L = dk/dt = k_q dq_a + k_dq ddq_a + k_qm dq_m + k_dqm ddq_m`` (the paper differentiates ``k``
symbolically; here ``L`` is the directional derivative of ``k`` computed with a complex step,
exact to rounding). Eqs. 23-24: ``A_c = df_c/dx`` at the true state, its last block row
``dL/dx`` by central differences of ``L`` (as the paper, "numerically around the true
trajectory"). Eq. 25: ``F = expm(A_c T)``.

How the process noise enters (a choice, documented here)
--------------------------------------------------------
The true plant of a Monte Carlo study has no process noise at all (only the sensor noise
changes from run to run), so a bound with ``Q = 0`` would be zero and not stationary. The paper
uses its filter's ``Q = 4e-6 I`` (eq. 26) in the bound. DESIGN.md asks for the bound "for the
same models the EKF uses". So here the bound uses exactly the EKF's noise model:

* ``Q = q_jerk I_2``: the EKF's jerk-noise variance per sample (parameter ``q_jerk``),
* entering like the jerk, zero-order hold over the sample period:
  ``G = int_0^T expm(A_c s) ds B``, ``B = (0, 0, I)^T`` -- which is the EKF's ``G_w`` of eq. 14
  (``(T^3/6 I, T^2/2 I, T I)``) when ``A_c`` is the EKF's chain of integrators,
* ``H``: the EKF's own measurement Jacobian (eq. 16 without damping, eqs. 17-19;
  :meth:`fmus.estimators.axelsson2012_model.MeasurementModel.jacobian`) at the true state,
  with or without the accelerometer, bias states off (section 4.3),
* ``R``: the EKF's ``diag(r_motor I, r_acc I)`` (motor side, sensor frame).

The only difference to the EKF's model is therefore the system matrix: the physical
flexible-joint dynamics of eq. 22 (with ``dq_m`` known) instead of the EKF's integrators -- which
is what the paper names as the cause of the gap between its EKF and the bound.
``robot_crlb(..., dynamics="ekf")`` gives the same construction with the EKF's integrators (the
covariance the EKF's own model allows at the true state), to separate the two effects.

With the filter's ``Q`` and a plant without process noise, this is a reference, not a lower
bound: a filter can go below it (measured on the section-4 scenario: the motor-only EKF at about
0.55x). :func:`validation_case` is the case where the true system carries the noise the bound
assumes; there the EKF attains the bound and does not beat it.

Caveats (measured on the section-4 scenario, see ``orchestration/scenarios/axelsson2012.toml``):

* the paper's bound treats the motor velocity ``dq_m`` (and ``q_m``) as a known, noise-free
  input of eq. 21, information that the filters (which see noisy motor angles only) do not
  have; it pins the arm velocity to the motor velocity through the stiff gearbox. With eq. 26's
  motor-side noise and ``q_jerk`` = 1 the angle bound is 3.9e-6 rad with the accelerometer
  (the EKF's own model: 5.2e-6) and 1.1e-5 rad without (own model: 6.4e-6);
* freezing ``A_c`` at each time makes the slow "position" modes of eq. 24 slightly unstable or
  stable depending on the velocity-dependent terms of ``dL/dq`` (eigenvalues of order
  +-0.05 1/s while the arm moves, 0 at rest); with a tiny ``Q`` (eq. 26's 4e-6) the stationary
  position bound follows them.

Cost
----
For ``N`` time points: ``2 x 6`` evaluations of ``L`` (each one complex evaluation of ``k``),
vectorised over all points; one batched ``expm`` of ``N`` 8x8 matrices (``F`` and ``G`` together,
Van Loan's block form); and ``N`` DAREs of size 6, solved together by a vectorised doubling
algorithm (``method="doubling"``, numpy only) with :func:`scipy.linalg.solve_discrete_are` as the
reference and fallback. The 400 points of a 4 s trajectory at 100 Hz take about 0.3 s. (scipy's
DARE per point is as fast on an idle machine, but its small LAPACK calls slow down about 20x when
the BLAS threads compete with other processes for the cores.)
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from fmus.common.robot_params import RobotParameters
from fmus.estimators import axelsson2012_model as am
from fmus.estimators import ekf_accelerometer_model as em
from fmus.estimators.ekf_accelerometer_batched import BatchedEkfModel, BatchedMeasurement

from .metrics import rmse_over_runs


class CrlbError(ValueError):
    """The Riccati equation of the bound has no stabilising solution (or bad input shapes)."""


# ---------------------------------------------------------------------------------------------
# eqs. 7-9: the stationary bound of a linear model
# ---------------------------------------------------------------------------------------------
def _dare_doubling(A, G0, H0, max_iter: int = 100, rtol: float = 1e-13):
    """Structure-preserving doubling (Chu, Fan and Lin 2005) for a stack of DAREs
    ``X = A^T X (I + G X)^-1 A + H0`` (``G = B R^-1 B^T``), vectorised over the leading axis.
    Returns ``(X, converged)``; quadratic convergence, about 20-30 iterations here."""
    Ak, Gk, Hk = A.copy(), G0.copy(), H0.copy()
    n = A.shape[-1]
    eye = np.eye(n)
    done = np.zeros(A.shape[0], bool)
    with np.errstate(all="ignore"):
        for _ in range(max_iter):
            W = eye + Gk @ Hk
            WA = np.linalg.solve(W, Ak)                           # W^-1 A_k
            WG = np.linalg.solve(W, Gk)                           # W^-1 G_k
            At = np.swapaxes(Ak, -1, -2)
            H_new = Hk + At @ Hk @ WA
            Gk = Gk + Ak @ WG @ At
            Ak = Ak @ WA
            change = np.abs(H_new - Hk).max(axis=(1, 2))
            Hk = 0.5 * (H_new + np.swapaxes(H_new, -1, -2))
            done = change <= rtol * np.abs(Hk).max(axis=(1, 2))
            if done.all() or not np.all(np.isfinite(Hk)):
                break
    return Hk, done & np.all(np.isfinite(Hk), axis=(1, 2))


def crlb_linear(F, H, Q, R, G=None, *, predicted: bool = False, method: str = "scipy"):
    """Stationary posterior CRLB of a linear-Gaussian model (eqs. 7-9).

    Parameters
    ----------
    F : (n, n) or (N, n, n)
        System matrix (a stack: one bound per matrix).
    H : (m, n) or (N, m, n)
        Measurement matrix.
    Q : (p, p) or (N, p, p)
        Process noise covariance (of ``w``; ``G`` maps it to the states).
    R : (m, m) or (N, m, m)
        Measurement noise covariance (positive definite).
    G : (n, p) or (N, n, p), optional
        Noise input matrix; default the identity (``Q`` is then ``n x n``).
    predicted
        Return ``(P, P_p)``: also the predicted covariance of eq. 7.
    method
        ``"scipy"``: :func:`scipy.linalg.solve_discrete_are` per matrix (called with ``F^T``,
        ``H^T``: the filter Riccati equation is the dual of its control one). ``"doubling"``:
        a doubling algorithm vectorised over the stack (numpy only; much faster for long stacks,
        and immune to the BLAS thread over-subscription that makes scipy's small LAPACK calls
        20x slower on a loaded machine); an entry that does not converge falls back to scipy.

    Returns
    -------
    P : (n, n) or (N, n, n)
        The filtered stationary covariance ``P_p - K H P_p`` (eq. 9).

    Raises
    ------
    CrlbError
        If the Riccati equation has no stabilising solution (``(F, H)`` not detectable, or a
        mode on the unit circle that the noise does not excite), naming the time index.
    """
    if method not in ("scipy", "doubling"):
        raise CrlbError(f"method must be 'scipy' or 'doubling', not {method!r}")
    F = np.asarray(F, float)
    stacked = F.ndim == 3
    Fs = F if stacked else F[None]
    N, n = Fs.shape[0], Fs.shape[-1]

    def stack(a, name: str) -> np.ndarray:
        a = np.asarray(a, float)
        if a.ndim == 2:
            a = np.broadcast_to(a, (N, *a.shape))
        if a.ndim != 3 or a.shape[0] != N:
            raise CrlbError(f"{name} has shape {np.shape(a)}; expected a matrix (or a stack of {N})")
        return a

    Hs, Qs, Rs = stack(H, "H"), stack(Q, "Q"), stack(R, "R")
    Gs = stack(np.eye(n) if G is None else G, "G")
    if (Fs.shape[1] != n or Hs.shape[2] != n or Gs.shape[1] != n or Gs.shape[2] != Qs.shape[1]
            or Rs.shape[1] != Hs.shape[1]):
        raise CrlbError(f"inconsistent shapes: F {Fs.shape[1:]}, H {Hs.shape[1:]}, G {Gs.shape[1:]}, "
                        f"Q {Qs.shape[1:]}, R {Rs.shape[1:]}")
    Ht = np.swapaxes(Hs, -1, -2)
    GQG = Gs @ Qs @ np.swapaxes(Gs, -1, -2)
    GQG = 0.5 * (GQG + np.swapaxes(GQG, -1, -2))
    X = np.empty((N, n, n))
    todo = np.ones(N, bool)
    if method == "doubling":
        try:
            Ginfo = Ht @ np.linalg.solve(Rs, Hs)                   # H^T R^-1 H
        except np.linalg.LinAlgError:
            raise CrlbError("R is singular: the measurement noise covariance must be positive "
                            "definite") from None
        Xd, ok = _dare_doubling(np.swapaxes(Fs, -1, -2).copy(), Ginfo, GQG)
        X[ok] = Xd[ok]
        todo = ~ok
    for i in np.flatnonzero(todo):
        try:
            X[i] = scipy.linalg.solve_discrete_are(Fs[i].T, Ht[i], GQG[i], Rs[i])
        except (np.linalg.LinAlgError, ValueError) as exc:
            where = f" at time index {i}" if stacked else ""
            raise CrlbError(f"the CRLB Riccati equation (eq. 7) has no stabilising solution{where}: "
                            f"{exc} -- (F, H) must be detectable and every mode of F on the unit "
                            "circle must be excited by the process noise G Q G^T") from None
    X = 0.5 * (X + np.swapaxes(X, -1, -2))
    S = Hs @ X @ Ht + Rs
    K = np.swapaxes(np.linalg.solve(S, Hs @ X), -1, -2)          # eq. 8
    P = X - K @ Hs @ X                                           # eq. 9
    P = 0.5 * (P + np.swapaxes(P, -1, -2))
    closed = np.abs(np.linalg.eigvals(Fs - Fs @ K @ Hs)).max(axis=-1)
    bad = ~(np.all(np.isfinite(P), axis=(1, 2)) & (closed < 1.0))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        where = f" at time index {i}" if stacked else ""
        raise CrlbError(f"the CRLB Riccati equation (eq. 7) has no stabilising solution{where} "
                        f"(closed-loop spectral radius {closed[i]:.6g})")
    if not stacked:
        P, X = P[0], X[0]
    return (P, X) if predicted else P


# ---------------------------------------------------------------------------------------------
# eqs. 21-24: the continuous robot model and its numerical linearisation
# ---------------------------------------------------------------------------------------------
class RobotCrlbModel:
    """Eqs. 21-22 for the robot ``p``: ``k`` (arm acceleration) and ``L = dk/dt`` (arm jerk),
    vectorised over leading axes and safe for complex arguments (complex-step derivatives).

    Parameters
    ----------
    p
        The true robot's parameters (the plant's).
    """

    def __init__(self, p: RobotParameters) -> None:
        self.p = p
        m = am.MeasurementModel(p, am.Layout(False, False))    # inertia/gravity constants of eq. 11
        self.a, self.c, self.e, self.g1, self.g2 = m.a, m.c, m.e, m.g1, m.g2
        self.r = np.asarray(p.gear_ratio, float)
        self.k_hi = np.asarray(p.k_hi, float)
        self.k_soft = self.k_hi - np.asarray(p.k_lo, float)
        self.delta = np.asarray(p.delta, float)
        self.d = np.asarray(p.d, float)

    def acceleration(self, q, dq, qm, dqm) -> np.ndarray:
        """``k(q_a, dq_a; q_m, dq_m)`` of eq. 21 (arm acceleration, no external force) at arm
        angles ``q`` and rates ``dq`` and motor angles ``qm`` and rates ``dqm`` (motor side),
        each (..., 2)."""
        q, dq, qm, dqm = (np.asarray(v) for v in (q, dq, qm, dqm))
        D = qm / self.r - q
        tau = (self.k_hi * D - self.k_soft * self.delta * np.tanh(D / self.delta)
               + self.d * (dqm / self.r - dq))
        q1, q2 = q[..., 0], q[..., 1]
        dq1, dq2 = dq[..., 0], dq[..., 1]
        s2, c2 = np.sin(q2), np.cos(q2)
        b, bd = -self.e * s2, -self.e * c2
        m11, m12, m22 = self.a + 2 * b, self.c + b, self.c
        cp = np.cos(q1 + q2)
        # rhs = tau - C dq - G  (dynamics: C dq = (bd (2 dq1 dq2 + dq2^2), -bd dq1^2),
        # G = (-g1 sin q1 - g2 cos phi, -g2 cos phi))
        rhs1 = tau[..., 0] - bd * (2 * dq1 * dq2 + dq2 * dq2) + self.g1 * np.sin(q1) + self.g2 * cp
        rhs2 = tau[..., 1] + bd * dq1 * dq1 + self.g2 * cp
        det = m11 * m22 - m12 * m12
        return np.stack([(m22 * rhs1 - m12 * rhs2) / det, (m11 * rhs2 - m12 * rhs1) / det], -1)

    def jerk(self, x, u) -> np.ndarray:
        """``L(q_a, dq_a, ddq_a) = dk/dt`` of eq. 22b at the state ``x = (q_a, dq_a, ddq_a)``
        (..., 6) and input ``u = (q_m, dq_m, ddq_m)`` (..., 6): the derivative of ``k`` along
        ``(dq_a, ddq_a, dq_m, ddq_m)``, by a complex step (exact to rounding)."""
        x = np.asarray(x, float)
        u = np.asarray(u, float)
        h = 1e-30
        z = self.acceleration(x[..., 0:2] + 1j * h * x[..., 2:4], x[..., 2:4] + 1j * h * x[..., 4:6],
                              u[..., 0:2] + 1j * h * u[..., 2:4], u[..., 2:4] + 1j * h * u[..., 4:6])
        return z.imag / h

    def system_matrix(self, x, u, rel_step: float = 1e-6) -> np.ndarray:
        """``A_c = df_c/dx`` of eqs. 23-24 at ``(x, u)``, shape (..., 6, 6): the kinematic chain
        and ``dL/dx`` by central differences (step ``rel_step * max(1, |x_j|)``)."""
        x = np.asarray(x, float)
        u = np.asarray(u, float)
        A = np.zeros(x.shape[:-1] + (6, 6))
        A[..., 0:2, 2:4] = np.eye(2)
        A[..., 2:4, 4:6] = np.eye(2)
        for j in range(6):
            hj = rel_step * np.maximum(1.0, np.abs(x[..., j]))
            xp, xm = x.copy(), x.copy()
            xp[..., j] += hj
            xm[..., j] -= hj
            A[..., 4:6, j] = (self.jerk(xp, u) - self.jerk(xm, u)) / (2 * hj[..., None])
        return A


def discretise(A, T: float, B=None) -> tuple[np.ndarray, np.ndarray]:
    """``F = expm(A T)`` (eq. 25) and the zero-order-hold noise input ``G = int_0^T expm(A s) ds B``
    (Van Loan's block exponential), for a stack ``A`` (..., n, n); ``B`` default ``(0, 0, I)^T``
    (the noise enters like the jerk)."""
    A = np.asarray(A, float)
    n = A.shape[-1]
    if B is None:
        B = np.zeros((n, 2))
        B[n - 2:] = np.eye(2)
    B = np.asarray(B, float)
    p = B.shape[-1]
    M = np.zeros(A.shape[:-2] + (n + p, n + p))
    M[..., :n, :n] = A * T
    M[..., :n, n:] = B * T
    E = scipy.linalg.expm(M)
    return E[..., :n, :n], E[..., :n, n:]


# ---------------------------------------------------------------------------------------------
# the robot's bound along a trajectory
# ---------------------------------------------------------------------------------------------
@dataclass
class RobotCrlb:
    """The bound along a trajectory: ``P`` (N, 6, 6) per time, and the square roots of the traces
    of its angular position, velocity and acceleration blocks (the paper's Fig. 3 quantity)."""

    P: np.ndarray

    def _rt(self, s: slice) -> np.ndarray:
        return np.sqrt(np.trace(self.P[:, s, s], axis1=1, axis2=2))

    @property
    def position(self) -> np.ndarray:
        """``sqrt(tr P_qq)`` per time (rad)."""
        return self._rt(slice(0, 2))

    @property
    def velocity(self) -> np.ndarray:
        """``sqrt(tr P_dqdq)`` per time (rad/s)."""
        return self._rt(slice(2, 4))

    @property
    def acceleration(self) -> np.ndarray:
        """``sqrt(tr P_ddqddq)`` per time (rad/s^2)."""
        return self._rt(slice(4, 6))


def robot_crlb(q_a, dq_a, ddq_a, q_m, dq_m, ddq_m, T: float, ekf: am.EkfAccelerometerParameters,
               use_accelerometer: bool, plant: RobotParameters | None = None,
               rel_step: float = 1e-6, method: str = "doubling",
               dynamics: str = "physical") -> RobotCrlb:
    """The posterior CRLB of the robot along the true trajectory (eqs. 7-9, 21-25).

    Parameters
    ----------
    q_a, dq_a, ddq_a : (N, 2)
        True arm angles, velocities and accelerations at the N times of the bound.
    q_m, dq_m, ddq_m : (N, 2)
        True motor angles, rates and accelerations (motor side), the known inputs of eq. 21.
    T
        Sample period of the filter (eq. 25).
    ekf
        The EKF's parameters: its ``q_jerk`` (``Q``), ``r_motor``, ``r_acc`` (``R``) and its
        measurement model (robot parameters, accelerometer indices) give ``Q``, ``H``, ``R``.
    use_accelerometer
        Bound with (True) or without (False) the accelerometer measurements.
    plant
        The true robot for the dynamics of eq. 21 (default: the EKF's robot model).
    rel_step
        Relative step of the central differences of eq. 24.
    method
        Riccati solver (:func:`crlb_linear`).
    dynamics
        ``"physical"`` (the paper's bound): ``A_c`` of eqs. 22-24. ``"ekf"``: the EKF's own chain
        of integrators (eq. 13) instead -- then the "bound" is the stationary covariance the EKF
        itself would reach when linearised at the true state with a correct jerk input; the gap
        between the two shows what the EKF's simplified dynamics cost.

    Returns
    -------
    RobotCrlb
    """
    x = np.concatenate([np.atleast_2d(q_a), np.atleast_2d(dq_a), np.atleast_2d(ddq_a)], axis=-1)
    u = np.concatenate([np.atleast_2d(q_m), np.atleast_2d(dq_m), np.atleast_2d(ddq_m)], axis=-1)
    if x.shape != u.shape or x.shape[-1] != 6:
        raise CrlbError(f"the true states and inputs must be (N, 2) arrays of one length; got "
                        f"states {x.shape}, inputs {u.shape}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(u))):
        raise CrlbError("the true trajectory contains non-finite values")
    if not T > 0 or not math.isfinite(T):
        raise CrlbError(f"the sample period T must be positive, got {T!r}")
    if dynamics == "physical":
        model = RobotCrlbModel(plant if plant is not None else ekf.robot())
        A = model.system_matrix(x, u, rel_step)
    elif dynamics == "ekf":
        A = am.continuous_model(am.Layout(False, False))[0][None]     # the same at every time
    else:
        raise CrlbError(f"dynamics must be 'physical' or 'ekf', not {dynamics!r}")
    F, G = (np.broadcast_to(m, (len(x),) + m.shape[1:]) for m in discretise(A, T))
    layout = am.Layout(bool(use_accelerometer), False)
    meas = am.MeasurementModel(ekf.robot(), layout)
    H = BatchedMeasurement(meas).h_and_jacobian(x)[1]       # meas.jacobian at every time, vectorised
    Q = ekf.q_jerk * np.eye(2)
    R = am.measurement_noise(ekf, layout)
    return RobotCrlb(crlb_linear(F, H, Q, R, G, method=method))


# ---------------------------------------------------------------------------------------------
# validation: a true system that carries the process noise the bound assumes
# ---------------------------------------------------------------------------------------------
def validation_case(ekf: am.EkfAccelerometerParameters, q_true: float, runs: int, *, T: float = 0.01,
                    stop_time: float = 2.0, after: float = 0.5, path: str = "square",
                    overtune: float = 10.0, seed: int = 1) -> dict:
    """Monte Carlo of the EKF on a true system that is the bound's own model: the EKF must not
    beat the bound (eqs. 7-9), and with the true noise it should attain it.

    Why a separate true system: the section-4 plant has no process noise (only the sensor noise
    changes between runs), so a bound built with the filter's tuning ``Q`` is no bound there
    (the true ``Q`` is zero). Here the truth is the estimation model of eqs. 13-15 itself: the
    arm states follow the constant-acceleration model driven by the jerk reference of the
    scenario's path (:func:`fmus.robot_plant.motion_control_model.arm_reference`) plus white
    jerk noise ``w ~ N(0, q_true I)`` per sample (``G_w`` of eq. 14), the initial state is drawn
    from the EKF's ``p(x_0)``, and the measurements are ``h(x)`` of eq. 15 (motor angles through
    eq. 16, accelerometer eqs. 17-19) plus Gaussian noise with the EKF's ``R``. The bound is
    :func:`robot_crlb` with ``dynamics="ekf"`` along each run's true states, which for this
    system is the model the data come from.

    Four filters see the same data, with and without the accelerometer: ``matched``
    (``q_jerk = q_true``) and ``overtuned`` (``q_jerk = overtune * q_true``: the situation of
    section 4, a filter ``Q`` above the truth's). Each is reported against the bound both ways:
    with the truth's ``Q`` (``crlb_true_q``, a real bound) and with its own tuning ``Q``
    (``crlb_filter_q``, the paper's construction).

    Parameters
    ----------
    ekf
        The filters' parameters (their ``R``, ``p(x_0)``; ``q_jerk`` is set per filter).
    q_true
        Intensity of the truth's white jerk noise.
    runs
        Number of Monte Carlo runs.
    T, stop_time, after
        Sample period, run length and start of the averaging window (s).
    path
        The motion controller's path whose jerk reference drives the truth.
    overtune
        Factor of the overtuned filters' ``q_jerk`` over ``q_true``.
    seed
        Seed of the runs' random numbers.

    Returns
    -------
    dict
        ``time`` (K,), and per filter ``{"q_jerk", "use_accelerometer", "rmse", "crlb_true_q",
        "crlb_filter_q"}``, each of the last three ``{group: time average over t >= after}``
        of eq. 27's RMSE and of ``sqrt(mean over runs of trace P)``, plus the per-time angle
        RMSE and bounds (``"per_time"``).
    """
    if runs < 1:
        raise CrlbError(f"runs must be at least 1, not {runs}")
    t = np.arange(int(round(stop_time / T)) + 1) * T
    variants = {f"{tag}_{'acc' if acc else 'motor'}": (q, acc)
                for tag, q in (("matched", q_true), ("overtuned", overtune * q_true))
                for acc in (True, False)}
    truth, err = _validation_runs(ekf, q_true, variants, runs, t, T, path, seed)
    bounds = {(q, acc): _bound_over_runs(ekf, q, acc, truth, T) for q, acc in variants.values()}
    keep = t >= after
    out: dict = {"time": t, "q_true": q_true, "runs": runs, "after": after, "stop_time": stop_time,
                 "T": T, "path": path, "per_time": {}}
    groups = ("position", "velocity", "acceleration")
    for k, (q, acc) in variants.items():
        e = err[k]
        rmse = np.stack([rmse_over_runs(e[:, :, s:s + 2]) for s in (0, 2, 4)])
        b_true, b_filter = bounds[q_true, acc], bounds[q, acc]
        out[k] = {"q_jerk": q, "use_accelerometer": acc,
                  **{name: {g: float(np.mean(v[gi][keep])) for gi, g in enumerate(groups)}
                     for name, v in (("rmse", rmse), ("crlb_true_q", b_true), ("crlb_filter_q", b_filter))}}
        out["per_time"][k] = {"rmse_position": rmse[0], "crlb_true_q_position": b_true[0],
                              "crlb_filter_q_position": b_filter[0]}
    return out


def _validation_runs(ekf: am.EkfAccelerometerParameters, q_true: float, variants: dict[str, tuple[float, bool]],
                     runs: int, t: np.ndarray, T: float, path: str, seed: int
                     ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """:func:`validation_case`'s Monte Carlo, all runs at once (a leading run axis): the true
    states ``(runs, K, 6)`` and each filter's estimation error (same shape) at the samples
    ``t`` (period ``T``); filter ``k`` of ``variants`` has ``q_jerk, use_accelerometer = variants[k]``. Run
    ``j`` draws from ``default_rng([seed, j])`` in the order x_0 (6), then per sample the
    measurement noise (4) and the jerk noise (2)."""
    from dataclasses import replace

    from fmus.robot_plant.motion_control_model import arm_reference
    from fmus.robot_plant.trajectory import make_path

    robot = ekf.robot()
    pr, vr, ar, jr = make_path(path, ekf.p_tool0).evaluate_many(t)
    u = arm_reference(pr, vr, ar, jr, robot.l1, robot.l2)[3]       # jerk reference, (K, 2)
    layout = am.Layout(True, False)
    F, Gu, Gw = am.transition_matrices(T, layout)
    h = BatchedMeasurement(am.MeasurementModel(robot, layout))
    Lr = np.sqrt(np.diag(am.measurement_noise(ekf, layout)))
    x0 = np.concatenate([ekf.initial_angles(), np.zeros(4)])
    L0 = np.linalg.cholesky(am.initial_covariance(ekf, am.Layout(False, False)))
    K = len(t)
    draws = np.stack([np.random.default_rng([seed, j]).standard_normal(6 + 6 * K) for j in range(runs)])
    noise = draws[:, 6:].reshape(runs, K, 6)
    x = x0 + (L0 @ draws[:, :6, None])[:, :, 0]
    filters = {k: BatchedEkfModel(replace(ekf, q_jerk=q, use_accelerometer=acc, use_bias=False))
               for k, (q, acc) in variants.items()}
    est = {k: (np.repeat(f.single.x[None], runs, 0), np.repeat(f.single.P[None], runs, 0))
           for k, f in filters.items()}
    err = {k: np.zeros((runs, K, 6)) for k in variants}
    truth = np.zeros((runs, K, 6))
    Gw2 = Gw[:, 0:2]
    for i in range(K):
        truth[:, i] = x
        y = h.h_and_jacobian(x)[0] + Lr * noise[:, i, 0:4]
        ui = np.broadcast_to(u[i], (runs, 2))
        for k, f in filters.items():
            xf, Pf, _ = f.filtered(y if f.layout.use_accelerometer else y[:, 0:2], *est[k])
            err[k][:, i] = xf[:, 0:6] - x
            est[k] = f.predicted(ui, T, xf, Pf)
        x = (x @ F.T + u[i] @ Gu.T) + (math.sqrt(q_true) * noise[:, i, 4:6]) @ Gw2.T
    return truth, err


def _bound_over_runs(ekf: am.EkfAccelerometerParameters, q_jerk: float, use_accelerometer: bool,
                     truth: np.ndarray, T: float) -> np.ndarray:
    """The bound of :func:`robot_crlb` (``dynamics="ekf"``, tuning ``q_jerk``) along every
    run's true states ``(runs, K, 6)``: ``sqrt(mean over runs of trace P)`` per time for the
    position, velocity and acceleration, ``(3, K)``."""
    from dataclasses import replace

    runs, K = truth.shape[:2]
    flat = truth.reshape(-1, 6)
    zeros = np.zeros((len(flat), 2))
    b = robot_crlb(flat[:, 0:2], flat[:, 2:4], flat[:, 4:6], zeros, zeros, zeros, T,
                   replace(ekf, q_jerk=q_jerk), use_accelerometer, dynamics="ekf")
    return np.stack([np.sqrt(np.mean(np.reshape(g ** 2, (runs, K)), axis=0))
                     for g in (b.position, b.velocity, b.acceleration)])


__all__ = ["CrlbError", "crlb_linear", "RobotCrlbModel", "discretise", "RobotCrlb", "robot_crlb",
           "validation_case"]

"""The particle filter of Axelsson, Karlsson and Norrlöf (2012): arm angles from the motor angles
and a tool accelerometer, with the estimation model of the EKF.

Model
-----
Exactly the model of :mod:`fmus.estimators.axelsson2012_model` (section 3.2, eqs. 12-19):
the state, the transition matrices ``F, G_u, G_w`` (eq. 14), ``Q`` and ``R`` (eq. 26, the
EKF's parameters) and the measurement function ``h`` (eq. 15), evaluated for all particles by
the compiled :mod:`fmus.estimators.axelsson2012_batched` (the scalar
:class:`~fmus.estimators.axelsson2012_model.MeasurementModel`'s kernels, particle by particle,
the gearbox's Newton warm-started and stopped on its error bound). Sampling and weighting run as
one compiled pass over the particles (:func:`propose_and_weigh`).

Algorithm (section 2.2, Algorithm 1)
------------------------------------
Each update with the measurement ``y_t`` samples the particles ``x_t^(i)`` from the proposal
and weights them (step 2 and 4 of Algorithm 1), forms the MMSE estimate (eq. 6) and a weighted
covariance, then resamples (step 3; systematic resampling, one uniform draw) always (the paper,
section 4.3) or when the effective sample size ``1 / sum(g_i^2)`` falls below
``ess_threshold * N``. The prior of particle ``i`` is Gaussian, ``x = m_i + L e``,
``e ~ N(0, I_k)``:

* after a time update, ``m_i = F x_{t-1}^(i) + G_u u_{t-1}`` and ``L = G_w chol(Q)`` (eqs. 13-14;
  ``k`` is the number of noise inputs, 2 without the bias states);
* at the first update (Algorithm 1, step 1: ``p(x_0)``), ``m_i = x_0`` and ``L = chol(P_0)``.

Proposals (noise coordinates ``e``, where the transition density is not degenerate; the
Jacobian of ``x = m_i + L e`` is common to the transition density and the proposal and cancels
in the weight):

* ``"prior"`` (bootstrap, eq. 28): ``e ~ N(0, I)``, weight ``g_i *= p(y_t | x_t^(i))``;
* ``"ekf"`` (eq. 30): one EKF measurement update per particle, linearised at its prior mean
  ``m_i``: with ``H_e = H(m_i) L``, ``A = I + H_e^T R^-1 H_e`` (the information form of eq. 30's
  covariance ``(H^T R^-1 H + Q^-1)^-1``, well conditioned where the measurements are precise)
  the proposal is ``N(A^-1 H_e^T R^-1 (y_t - h(m_i)), A^-1)`` and the weight
  ``g_i *= p(y_t | x_t^(i)) N(e; 0, I) / N(e; mu_i, A^-1)`` (Algorithm 1, step 2).

Regularisation (after resampling)
---------------------------------
The process noise is the jerk (rank 2 of 6 states): per step (100 Hz, ``q_jerk`` = 10) it moves
the angles by about 5e-7 rad and the velocities by 1.6e-4 rad/s, far below their posterior
spread (about 3e-4 rad and 1e-3 rad/s in the scenario ``axelsson2012_pf``). The copies made by
resampling therefore stay copies in the angles and velocities for hundreds of steps, the cloud's
spread there performs a random walk towards zero (path degeneracy), and a cloud narrower than
the posterior no longer listens to the measurements and drifts away with a high effective
sample size (measured: the angle spread a fifth of the EKF's after 0.5-1 s, RMSE 10-60 times
the EKF's in some runs). After each resampling, :func:`kernel_move` therefore replaces every
particle by a draw of a Gaussian kernel centred on it and shrunk towards the estimate so that
the cloud keeps the estimate ``x_hat`` and the covariance ``P / (1 - sum g_i^2)`` (the
weighted covariance, debiased for the effective sample size) — the regularised particle
filter (Musso, Oudjane, Le Gland 2001) with the shrinkage of Liu and West (2001). The bandwidth
``h = bandwidth * h_opt(ESS, n)`` (:func:`optimal_bandwidth`, Silverman's rule with the
effective sample size; ``h`` = 0.47 at ESS = 1000 and n = 6, 0.58 at ESS = 120). ``bandwidth
= 0`` gives the plain Algorithm 1. The kernel blurs only shapes beyond the second moment; the
posterior here is close to Gaussian.

Degeneracy
----------
If no particle keeps a finite weight and state (every likelihood underflows to zero, e.g. an
absurd measurement, or the states overflow), the filter does not return NaN: it re-initialises
the cloud around the last good estimate, propagated to the current time with the model, with
the initial covariance ``P_0``, and fuses the measurement again from that prior; if even that
gives no finite weight, the measurement is skipped (the cloud is the re-initialised prior,
equal weights). Each such event increments :attr:`ParticleFilterModel.n_reinit` (the FMU logs
a warning). Only if the last good estimate itself cannot be propagated to a finite value does
the filter raise :class:`~fmus.common.kalman.FilterDivergence`.

Limits (measured, see tests/test_particle_filter_model.py and the study below)
-----------------------------------------------------------------------------
The 20-run study ``flexfusion study montecarlo orchestration/scenarios/axelsson2012_pf.toml``
(motor angles 1 mrad arm side, accelerometer 0.01 m/s^2, ``q_jerk`` = 10, 1000 particles):
angle RMSE (time average after 0.5 s) against the EKF's 1.02-1.03 with the EKF proposal
(seeds 1-20 and 21-40; 1.00 with ``resampling = "ess"``; ESS about 860 of 1000 per update) and
1.4-1.6 with the bootstrap proposal. Its ESS is about 120 of 1000 per update, as predicted by
``E[w]^2 / E[w^2]`` of the Gaussian approximation along the EKF (0.12; 0.93 for the motor
angles alone, 0.14 for the accelerometer alone: it resolves the arm acceleration much more
finely than the one-step prior spread of the jerk noise); with 8000 particles (ESS about 1000)
the bootstrap is at 1.02. Without the regularisation: 11.6 and 94, growing with time.

* the bootstrap proposal needs a prior of the initial angles of the order of the motor-angle
  noise when that is small (the tests' 5 urad arm side: ``p0_q`` about 1e-5 rad); with the
  default 1 mrad one particle survives the first update (the paper found the same on its
  experimental data, section 5.2, and used eq. 30);
* neither proposal recovers from a true initial state far outside ``p(x_0)`` (e.g. an arm
  already moving at 0.15 rad/s with ``p0_dq`` = 0.01 rad/s): the jerk noise cannot move the
  cloud's velocities there; the EKF's linear update can. Start the filter at rest, or widen
  ``p0_*`` only together with many more particles.

Randomness
----------
One stream, ``make_rng(seed, "particle_filter")``, whose state is a value of the filter
(``rng_state``): :meth:`ParticleFilterModel.filtered` draws from a scratch generator set to it,
so recomputing the update for changed inputs (as an FMU does when a master sets inputs more
than once) draws the same random numbers, and a copy of the filter shares no generator;
:meth:`commit` stores the advanced state.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fmus.common import kinematics
from fmus.common.noise import make_rng
from fmus.common.kalman import FilterDivergence
from fmus.common.jit import kernel
from fmus.common.parameters import param
from fmus.estimators.axelsson2012_batched import measure_many
from fmus.estimators.axelsson2012_model import (DDQ_, DQ_, Q_, EkfAccelerometerParameters, Layout,
                                                MeasurementModel, initial_covariance, measurement_noise,
                                                process_noise, transition_matrices)

PAPER = "Axelsson, Karlsson, Norrlöf 2012"
PROPOSALS = ("prior", "ekf")
RESAMPLING = ("always", "ess")
RNG_STREAM = "particle_filter"


@dataclass(frozen=True)
class ParticleFilterParameters(EkfAccelerometerParameters):
    """Parameters of the particle filter: those of the EKF (same model, noise, initial
    estimate) plus the number of particles, the proposal, the resampling rule and the seed."""

    n_particles: int = param(1000, "1", "number of particles N", low=1, high=10_000_000,
                             source=f"{PAPER}, section 4.3")
    proposal: str = param("ekf", "1", "proposal density: prior (bootstrap, eq. 28) or ekf "
                          "(per-particle EKF update, eq. 30)", choices=PROPOSALS,
                          source=f"{PAPER}, eqs. 28 and 30; ekf: the paper's choice for high SNR")
    resampling: str = param("always", "1", "resample always (the paper, section 4.3) or when the "
                            "effective sample size is below ess_threshold * N", choices=RESAMPLING,
                            source=f"{PAPER}, section 4.3")
    ess_threshold: float = param(0.5, "1", "resampling threshold as a fraction of N (resampling = ess)",
                                 low=0.0, high=1.0)
    seed: int = param(0, "1", "seed of the filter's random numbers", low=0)
    bandwidth: float = param(1.0, "1", "regularisation after each resampling: Gaussian kernel "
                             "bandwidth h = bandwidth * (4 / (ESS (n + 2)))^(1 / (n + 4)) "
                             "(n states), moment-preserving shrinkage; 0: none (plain Algorithm 1)",
                             low=0.0, high=1.0,
                             source="Musso, Oudjane, Le Gland 2001; Liu, West 2001; Silverman 1986")


def optimal_bandwidth(n_eff: float, n_states: int) -> float:
    """Silverman's bandwidth ``h_opt = (4 / (N (n + 2)))^(1 / (n + 4))`` of a Gaussian kernel that
    minimises the mean integrated squared error of a Gaussian density estimated from ``N``
    equally weighted samples in ``n = n_states`` dimensions (Silverman 1986, section 4.3.2; the
    regularised particle filter's choice, Musso, Oudjane, Le Gland 2001). For weighted particles
    ``N`` is their effective sample size ``n_eff`` (Kish; clipped below at 1): resampling copies
    ``N`` particles but adds no information. Below 1 for ``n_eff >= 1``
    (``(4 / (n + 2))^(1 / (n + 4)) < 1``)."""
    return (4.0 / (max(n_eff, 1.0) * (n_states + 2))) ** (1.0 / (n_states + 4))


# ---- Algorithm 1, building blocks -------------------------------------------------------------
def normalise_log_weights(logw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normalised weights ``g_i`` (Algorithm 1, step 2) and their logarithms, by log-sum-exp,
    from the unnormalised log-weights ``logw`` (N,).

    Non-finite log-weights count as zero weight. The caller checks that one is finite.
    """
    lmax = np.max(logw)
    w = np.exp(logw - lmax)
    s = w.sum()
    return w / s, logw - (lmax + math.log(s))


def effective_sample_size(w: np.ndarray) -> float:
    """``1 / sum g_i^2`` of the normalised weights ``w`` (N,) (Kish's effective sample size: N for
    equal weights, 1 for one particle)."""
    return float(1.0 / np.dot(w, w))


@kernel(aot="int64[:](float64[:], float64)")
def systematic_resample(w: np.ndarray, u: float) -> np.ndarray:
    """Indices (N,) of systematic resampling (Algorithm 1, step 3) of the particles with the
    weights ``w`` (N,), non-negative and normalised here by their sum, with one uniform ``u`` in
    [0, 1).

    The points ``(u + j) / N``, ``j = 0..N-1``, select the particle whose cumulative weight
    interval contains them: particle ``i`` is copied ``floor(N g_i)`` or ``ceil(N g_i)`` times
    (unbiased: the expected count is ``N g_i``) and never when ``g_i = 0``. One pass over the
    points and the cumulative weights (both ascend).
    """
    n = w.shape[0]
    c = np.cumsum(w)
    c /= c[-1]                                   # exactly 1 at the end
    idx = np.empty(n, np.int64)
    i = 0
    for j in range(n):
        t = (u + j) / n
        while i < n - 1 and c[i] <= t:           # the first i with c_i > t (the last at most)
            i += 1
        idx[j] = i
    return idx


@kernel(aot="Tuple((float64[:], float64[:, :]))(float64[:, :], float64[:])")
def weighted_mean_cov(X: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The MMSE estimate ``sum g_i x_i`` (eq. 6) and the weighted covariance
    ``sum g_i (x_i - x_hat)(x_i - x_hat)^T`` of the particles ``X`` (N, n) with the normalised
    weights ``w`` (N,) (summing to 1; the covariance is the plug-in one, not debiased)."""
    N, n = X.shape
    x = np.zeros(n)
    for i in range(N):
        for p in range(n):
            x[p] += w[i] * X[i, p]
    P = np.zeros((n, n))
    d = np.empty(n)
    for i in range(N):
        for p in range(n):
            d[p] = X[i, p] - x[p]
        for p in range(n):
            wd = w[i] * d[p]
            for q in range(p + 1):
                P[p, q] += wd * d[q]
    for p in range(n):
        for q in range(p):
            P[q, p] = P[p, q]
    return x, P


def kernel_move(X: np.ndarray, x: np.ndarray, P: np.ndarray, h: float, Z: np.ndarray,
                sum_w2: float = 0.0, idx: np.ndarray | None = None) -> np.ndarray:
    """Regularisation after resampling: ``x_i <- a x_i + (1 - a) x_hat + c S z_i``.

    Each resampled particle is replaced by a draw from a Gaussian kernel centred on it and
    shrunk towards the estimate, ``a = sqrt(1 - h^2)`` (Liu and West 2001's shrinkage of the
    regularised particle filter of Musso, Oudjane and Le Gland 2001), so that the cloud keeps
    the mean ``x_hat`` and has the covariance ``P / (1 - sum_w2)``: ``c^2 = 1 / (1 - sum_w2) - a^2``
    (``c = h`` for ``sum_w2 = 0``: ``a^2 P + h^2 P = P``). ``P / (1 - sum g_i^2)`` is the
    weighted covariance without its bias (reliability weights: the plug-in estimate is low by
    the factor ``1 - 1/ESS``, which compounds over the steps). Copies of one particle become
    distinct in every direction of the state, also in those the process noise reaches only
    through many steps (here the angles and velocities: the noise is the jerk).

    Parameters
    ----------
    X
        Resampled particles (N, n), equally weighted; or, with ``idx``, the particles before
        resampling, and ``X[idx]`` the resampled ones (the copies are not made).
    x, P
        The weighted mean (eq. 6) and covariance of the particles before resampling.
    h
        Kernel bandwidth, ``0 <= h < 1`` (:func:`optimal_bandwidth`).
    Z
        Standard normals (N, n).
    sum_w2
        ``sum g_i^2`` of the weights before resampling (``1 / ESS``); 0: no debiasing.
    idx
        Indices (N,) of the resampled particles in ``X`` (:func:`systematic_resample`); None:
        ``X`` is resampled already.

    Returns
    -------
    numpy.ndarray
        The moved particles (N, n). ``S = V sqrt(Lambda)`` (``S S^T = P``) from the
        eigendecomposition of ``P`` with negative round-off eigenvalues set to zero (``P`` may
        be singular, e.g. one survivor).
    """
    lam, V = np.linalg.eigh(0.5 * (P + P.T))
    S = V * np.sqrt(np.clip(lam, 0.0, None))
    a = math.sqrt(1.0 - h * h)
    c = math.sqrt(1.0 / (1.0 - sum_w2) - a * a) if sum_w2 < 1.0 else h
    out = np.empty((Z.shape[0], X.shape[1]))
    _move(X, np.arange(len(X)) if idx is None else idx, x, np.ascontiguousarray(S), a, c, Z, out)
    return out


@kernel(aot="none(float64[:, :], int64[:], float64[:], float64[:, :], float64, float64, "
            "float64[:, :], float64[:, :])")
def _move(X, idx, x, S, a, c, Z, out):
    """``out_j = a X_idx_j + (1 - a) x + c S z_j`` (:func:`kernel_move`), row by row."""
    n = X.shape[1]
    for j in range(idx.shape[0]):
        i = idx[j]
        for p in range(n):
            s = 0.0
            for q in range(n):
                s += Z[j, q] * S[p, q]
            out[j, p] = a * X[i, p] + (1.0 - a) * x[p] + c * s


@kernel(aot="none(float64[:, :], float64[:, :], float64[:], float64[:], float64[:], float64[:, "
            ":], boolean, float64[:], boolean, boolean, float64[:, :], float64[:, :], float64[:])")
def propose_and_weigh(M, L, logw_prev, y, r_inv, Z, ekf, k_model, use_accelerometer, use_bias, D, X, logw):
    """Algorithm 1, steps 2 and 4, in one compiled call over the particles: sample
    ``x_i = m_i + L e_i`` from the proposal and weight it (the module docstring's formulas).

    Parameters
    ----------
    M, L
        The prior: means (N, n) and noise factor (n, k).
    logw_prev
        The particles' log-weights before the update (N,).
    y, r_inv
        The measurement (m,) and the inverse of the diagonal of ``R`` (m,).
    Z
        Standard normals (N, k), one row per particle.
    ekf
        True: the EKF proposal (eq. 30), ``e = A^-1 H_e^T R^-1 (y - h(m_i)) + C^-T z`` with
        ``A = I + H_e^T R^-1 H_e = C C^T``, ``H_e = H(m_i) L``; false: the prior (eq. 28), ``e = z``.
    k_model, use_accelerometer, use_bias
        The measurement model: its constants and layout switches
        (:func:`~fmus.estimators.axelsson2012_batched.measure_many`, with Newton's bound as the
        stopping rule).
    D
        In: the gearbox deflections (N, 2) of the particles the means ``M`` were predicted
        from (NaN: none), where the Newton iterations start (for the means, then for the new
        particles from the means'); out: those of the new particles ``X``.
    X, logw
        Outputs: the particles (N, n) and their unnormalised log-weights (N,):
        ``logw_prev - nu^T R^-1 nu / 2`` (+ ``log N(e; 0, I) - log N(e; mu, A^-1)``), ``-inf``
        (and the particle zero) where the weight or the state is not finite.
    """
    N, n = M.shape
    k = L.shape[1]
    m = 4 if use_accelerometer else 2
    Yh = np.empty((N, m))
    dlog = np.zeros(N)
    if ekf:                                    # eq. 30: one EKF update per particle, at m_i
        Hm = np.zeros((N, m, n))
        measure_many(M, k_model, use_accelerometer, use_bias, True, D, Yh, Hm, D)
        He, C = np.empty((m, k)), np.empty((k, k))
        nu, e, z = np.empty(m), np.empty(k), np.empty(k)
    for i in range(N):
        if ekf:
            H = Hm[i]
            for a in range(m):
                nu[a] = y[a] - Yh[i, a]
                for j in range(k):
                    s = 0.0
                    for p in range(n):
                        s += H[a, p] * L[p, j]
                    He[a, j] = s
            # A's lower triangle into C and b into z; then C: its Cholesky factor, in place
            total = 0.0
            for j in range(k):
                for l in range(j + 1):
                    s = 0.0
                    for a in range(m):
                        s += He[a, j] * r_inv[a] * He[a, l]
                    C[j, l] = s + 1.0 if j == l else s
                    total += C[j, l]
                s = 0.0
                for a in range(m):
                    s += He[a, j] * r_inv[a] * nu[a]
                z[j] = s
                total += s
            if not math.isfinite(total):      # an overflowed particle: any proposal, weight 0 below
                for j in range(k):
                    for l in range(j + 1):
                        C[j, l] = 1.0 if j == l else 0.0
                    z[j] = 0.0
            logdet_half = 0.0
            for j in range(k):
                s = C[j, j]
                for p in range(j):
                    s -= C[j, p] * C[j, p]
                C[j, j] = math.sqrt(s)
                logdet_half += math.log(C[j, j])
                for l in range(j + 1, k):
                    s = C[l, j]
                    for p in range(j):
                        s -= C[l, p] * C[j, p]
                    C[l, j] = s / C[j, j]
            for j in range(k):                 # C z = b
                s = z[j]
                for p in range(j):
                    s -= C[j, p] * z[p]
                z[j] = s / C[j, j]
            for j in range(k - 1, -1, -1):     # C^T mu = z (into z), C^T v = Z_i (into e)
                s, t = z[j], Z[i, j]
                for p in range(j + 1, k):
                    s -= C[p, j] * z[p]
                    t -= C[p, j] * e[p]
                z[j] = s / C[j, j]
                e[j] = t / C[j, j]
            zz, ee = 0.0, 0.0
            for j in range(k):                 # e = mu + v
                zz += Z[i, j] * Z[i, j]
                e[j] += z[j]
                ee += e[j] * e[j]
            # log N(e; 0, I) - log N(e; mu, A^-1), (e - mu)^T A (e - mu) = Z^T Z
            dlog[i] = 0.5 * (zz - ee) - logdet_half
            for p in range(n):
                s = 0.0
                for j in range(k):
                    s += L[p, j] * e[j]
                X[i, p] = M[i, p] + s
        else:                                  # eq. 28: the prior
            for p in range(n):
                s = 0.0
                for j in range(k):
                    s += L[p, j] * Z[i, j]
                X[i, p] = M[i, p] + s
    # p(y | x) (Gaussian e_t)
    measure_many(X, k_model, use_accelerometer, use_bias, True, D, Yh, None, D)
    for i in range(N):
        q, total = 0.0, 0.0
        for a in range(m):
            d = y[a] - Yh[i, a]
            q += d * d * r_inv[a]
        for p in range(n):
            total += X[i, p]
        lw = logw_prev[i] - 0.5 * q + dlog[i]
        if math.isfinite(lw) and math.isfinite(total):
            logw[i] = lw
        else:
            logw[i] = -math.inf
            X[i] = 0.0


@dataclass
class FilterStep:
    """The result of one measurement update (not yet committed)."""

    X: np.ndarray            #: particles after resampling (N, n)
    logw: np.ndarray         #: their normalised log-weights
    x: np.ndarray            #: MMSE estimate (eq. 6), before resampling
    P: np.ndarray            #: weighted covariance, before resampling
    ess: float               #: effective sample size before resampling
    D: np.ndarray            #: gearbox deflections of the particles ``X`` (before their move)
    resampled: bool
    reinit: str              #: "" or why the cloud was re-initialised
    rng_state: dict


class ParticleFilterModel:
    """The particle filter of Algorithm 1 with the model of eqs. 12-19 (the EKF's).

    Parameters
    ----------
    p
        Filter parameters (the EKF's plus particles, proposal, resampling, seed).

    Notes
    -----
    Per sample: :meth:`update` with ``y_t`` (sampling from the proposal, weighting, eq. 6,
    resampling), then :meth:`predict` with the jerk reference ``u_t`` and the period ``T``
    (prior means of the next update, eqs. 13-14). :meth:`filtered` computes an update without
    committing it (for an FMU's outputs); :meth:`commit` stores it. Several predictions without
    an update between them (a measurement over several periods) compose: the prior's means move
    on and its noise factor gains a block per period (eq. 14 applied twice).
    """

    def __init__(self, p: ParticleFilterParameters) -> None:
        self.p = p
        self.layout = Layout(bool(p.use_accelerometer), bool(p.use_bias))
        self.meas = MeasurementModel(p.robot(), self.layout)
        self.Q = process_noise(p, self.layout)
        self.R = measurement_noise(p, self.layout)
        self.r_inv = 1.0 / np.diag(self.R)
        self.P0 = initial_covariance(p, self.layout)
        self.L0 = np.linalg.cholesky(self.P0)
        self.N = int(p.n_particles)
        self.proposal = p.proposal
        self.resample_always = p.resampling == "always"
        self.ess_min = float(p.ess_threshold) * self.N
        self.bandwidth = float(p.bandwidth)
        # the generator's state is a value of the estimate (a copy of the filter shares no
        # generator); each update draws from the scratch generator set to it
        self.rng_state = make_rng(int(p.seed), RNG_STREAM).bit_generator.state
        self._work = make_rng(int(p.seed), RNG_STREAM)
        n = self.layout.n
        self.x = np.zeros(n)
        self.x[Q_] = p.initial_angles()
        self.P = self.P0.copy()
        self.ess = float(self.N)
        self.n_reinit = 0
        self.X: np.ndarray | None = None             # no particles before the first update
        self.D = np.full((self.N, 2), np.nan)        # their gearbox deflections (Newton's start)
        self.logw = np.full(self.N, -math.log(self.N))
        # the prior of the next update: means M (N, n), factor L (n, k); and the last good
        # estimate propagated to the time of the next update
        self.M = np.broadcast_to(self.x, (self.N, n))
        self.L = self.L0
        self.x_prior = self.x.copy()
        self._predicted = False                      # predicted since the last update
        self._T: float | None = None

    # -- eqs. 13-14
    def _matrices(self, T: float) -> None:
        if self._T != T:
            self.F, self.Gu, Gw = transition_matrices(T, self.layout)
            self.Lw = Gw @ np.linalg.cholesky(self.Q)
            self._T = T

    def measurement_vector(self, q_m, acc_xz=None) -> np.ndarray:
        """``y`` of eq. 15 from the motor angles ``q_m`` (rad) and, if the filter uses it, the
        accelerometer's ``acc_xz`` (m/s^2): :meth:`Layout.measurement_vector`."""
        return self.layout.measurement_vector(q_m, acc_xz)

    def predict(self, u, T: float) -> np.ndarray:
        """Time update over ``T`` with the jerk reference ``u`` held (eqs. 13-14): the prior
        means ``F x^(i) + G_u u`` of the next update (its noise is drawn there, by the
        proposal). Returns the predicted estimate ``F x_hat + G_u u``.

        Raises
        ------
        FilterDivergence
            If the predicted estimate is not finite (the jerk input or the period overflow it).
        """
        self._matrices(float(T))
        if self.X is None:                         # predict before any measurement: move x_0
            self.X = np.broadcast_to(self.x, (self.N, self.layout.n))
        with np.errstate(all="ignore"):
            Gu_u = self.Gu @ np.asarray(u, float)
            if self._predicted:                    # the prior of an update periods ahead
                x_prior = self.F @ self.x_prior + Gu_u
                M = self.M @ self.F.T + Gu_u
                L = np.hstack([self.F @ self.L, self.Lw])     # L L^T = F L L^T F^T + Gw Q Gw^T
            else:
                x_prior = self.F @ self.x + Gu_u
                M = self.X @ self.F.T + Gu_u
                L = self.Lw
        if not np.all(np.isfinite(x_prior)):
            raise FilterDivergence("particle filter diverged in the time update: the predicted "
                                   "estimate is not finite")
        self.M, self.L, self.x_prior, self._predicted = M, L, x_prior, True
        return x_prior

    # -- Algorithm 1, steps 2-4, one measurement
    def _sample_and_weight(self, M, L, logw_prev, D, y, rng) -> tuple | None:
        """Sample ``x = M + L e`` from the proposal and weight it (:func:`propose_and_weigh`;
        ``D``, the deflections to start from, is overwritten); ``None`` if no particle has a
        finite weight and state."""
        Z = rng.standard_normal((M.shape[0], L.shape[1]))
        X, logw = np.empty(M.shape), np.empty(M.shape[0])
        propose_and_weigh(np.ascontiguousarray(M), np.ascontiguousarray(L), logw_prev, y, self.r_inv, Z,
                          self.proposal == "ekf", self.meas.constants, *self.meas.switches, D, X, logw)
        if not np.isfinite(logw).any():
            return None
        w, logw = normalise_log_weights(logw)
        x, P = weighted_mean_cov(X, w)
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(P))):
            return None
        return X, D, w, logw, x, P

    def _resample(self, X, D, w, logw, x, P, rng) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
        ess = effective_sample_size(w)
        if self.resample_always or ess < self.ess_min:
            idx = systematic_resample(w, float(rng.random()))
            if self.bandwidth > 0.0:
                h = self.bandwidth * optimal_bandwidth(ess, self.layout.n)
                X = kernel_move(X, x, P, h, rng.standard_normal(X.shape), float(np.dot(w, w)), idx)
            else:
                X = X[idx]
            return X, D[idx], np.full(self.N, -math.log(self.N)), True
        return X, D, logw, False

    def filtered(self, y) -> FilterStep:
        """The update with the measurement ``y`` (Algorithm 1, steps 2-4, eq. 6), not committed.

        Raises
        ------
        FilterDivergence
            Only if the re-initialised cloud is not finite either (see the module docstring).
        """
        y = np.asarray(y, float)
        rng = self._work
        rng.bit_generator.state = self.rng_state
        reinit = ""
        with np.errstate(all="ignore"):           # non-finite weights and states are handled
            r = self._sample_and_weight(self.M, self.L, self.logw, self.D.copy(), y, rng)
            if r is None:
                reinit = "all particle weights underflowed or were not finite"
                M0 = np.broadcast_to(self.x_prior, (self.N, self.layout.n))
                r = self._sample_and_weight(M0, self.L0, np.zeros(self.N), np.full((self.N, 2), np.nan), y, rng)
                if r is None:                     # the measurement cannot be fused at all
                    reinit += "; the measurement was skipped"
                    X = M0 + rng.standard_normal((self.N, self.layout.n)) @ self.L0.T
                    w = np.full(self.N, 1.0 / self.N)
                    x, P = weighted_mean_cov(X, w)
                    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(P))):
                        raise FilterDivergence("particle filter diverged: the re-initialised "
                                               "particle cloud is not finite")
                    r = X, np.full((self.N, 2), np.nan), w, np.log(w), x, P
            X, D, w, logw, x, P = r
            ess = effective_sample_size(w)
            X, D, logw, resampled = self._resample(X, D, w, logw, x, P, rng)
        return FilterStep(X, logw, x, P, ess, D, resampled, reinit, rng.bit_generator.state)

    def commit(self, s: FilterStep) -> np.ndarray:
        """Store the update ``s`` (from :meth:`filtered` on the current state); returns ``x_hat``."""
        self.X, self.logw, self.x, self.P, self.ess, self.D = s.X, s.logw, s.x, s.P, s.ess, s.D
        self.n_reinit += bool(s.reinit)
        self.rng_state = s.rng_state
        self._predicted = False
        return self.x

    def update(self, y) -> np.ndarray:
        """Measurement update (Algorithm 1, steps 2-4, eq. 6) with the measurement ``y`` (eq. 15,
        as stacked by :meth:`measurement_vector`); commits and returns ``x_{t|t}``."""
        return self.commit(self.filtered(y))

    def tool_position(self, x=None) -> np.ndarray:
        """Tool position (world x, z) [m] from the arm angles of the state ``x`` (default: the
        filter's estimate) by the rigid forward kinematics (eq. 29)."""
        return kinematics.tool_position((self.x if x is None else x)[Q_], self.meas.p)


__all__ = ["ParticleFilterParameters", "ParticleFilterModel", "FilterStep", "propose_and_weigh",
           "systematic_resample", "kernel_move", "optimal_bandwidth", "effective_sample_size",
           "normalise_log_weights", "weighted_mean_cov", "PROPOSALS", "RESAMPLING", "DQ_", "DDQ_", "Q_"]

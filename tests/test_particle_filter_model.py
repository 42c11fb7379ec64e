"""The particle filter's math (Axelsson et al. 2012, Algorithm 1, eqs. 6, 28, 30): the compiled
sampling and weighting against the numpy code, resampling, the Kalman filter limit, tracking,
degeneracy."""
from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from fmus.common.kalman import FilterDivergence
from fmus.common.parameters import ParameterError, validate
from fmus.estimators import axelsson2012_model as am
from fmus.estimators import ekf_accelerometer_model as em
from fmus.estimators import particle_filter_model as pm
import pf_numpy_reference as numpy_reference
from pf_numpy_reference import NumpyMeasurement
from pf_numpy_reference import propose_and_weigh as propose_and_weigh_numpy

T = 0.01


def _motion(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """State (q, dq, ddq) and jerk of ``q = q0 + A (1 - cos w t)^2`` at the times ``t``."""
    q0, A, w = np.array([0.2, -0.1]), np.array([0.05, 0.03]), np.array([3.0, 5.0])
    c, s = np.cos(np.outer(t, w)), np.sin(np.outer(t, w))
    S = 1 - c
    x = np.column_stack([q0 + A * S * S, 2 * A * w * S * s, 2 * A * w * w * (s * s + S * c)])
    return x, 2 * A * w ** 3 * (3 * s * c - S * s)


def signals_from_rest(n: int, p: am.EkfAccelerometerParameters, seed: int = 0):
    """The motion of the EKF tests' ``_signals`` (same amplitudes, frequencies and noise) but
    starting at rest: ``q = q0 + A (1 - cos w t)^2``, so that velocity, acceleration and jerk
    are zero at t = 0, where the filters' prior ``p(x_0)`` (at rest) has it. Returns the noisy
    motor angles, the noisy accelerometer (x, z), the jerk and the true state (n, 6)."""
    x, u = _motion(np.arange(n) * T)
    mm = am.MeasurementModel(p.robot(), am.Layout(True, False))
    rng = np.random.default_rng(seed)
    qm = np.array([mm.motor_angles(xk) for xk in x]) + rng.normal(0, 1e-3, (n, 2))
    f = np.array([mm.specific_force(xk) for xk in x]) + rng.normal(0, 1e-2, (n, 2))
    return qm, f, u, x


def test_signals_are_consistent() -> None:
    t = np.linspace(0.0, 3.0, 301)
    h = 1e-5          # central differences: truncation h^2/6 |x'''| < 1e-8, rounding < 1e-10
    (xp, up), (xm, um) = _motion(t + h), _motion(t - h)
    x, u = _motion(t)
    assert_allclose((xp[:, 0:4] - xm[:, 0:4]) / (2 * h), x[:, 2:6], atol=1e-7)
    assert_allclose((xp[:, 4:6] - xm[:, 4:6]) / (2 * h), u, atol=1e-7)
    assert_allclose(x[0], [0.2, -0.1, 0, 0, 0, 0], atol=1e-15)
    assert_allclose(u[0], 0.0, atol=1e-15)


# ---- resampling, weights -----------------------------------------------------------------------
def test_systematic_resampling_is_unbiased_and_deterministic() -> None:
    rng = np.random.default_rng(7)
    for n in (1, 5, 100, 1000):
        w = rng.exponential(size=n) ** 3
        w[rng.random(n) < 0.2] = 0.0               # zero weights are never drawn
        if w.sum() == 0:
            w[0] = 1.0
        w /= w.sum()
        expected = n * w
        total = np.zeros(n)
        J = 500
        for j in range(J):
            u = (j + 0.5) / J
            idx = pm.systematic_resample(w, u)
            counts = np.bincount(idx, minlength=n)
            assert counts.sum() == n
            assert np.all(np.abs(counts - expected) < 1.0 + 1e-9), (n, u)
            assert np.all(counts[w == 0] == 0)
            assert np.all(np.diff(idx) >= 0)
            assert_array_equal(pm.systematic_resample(w, u), idx)      # deterministic in u
            total += counts
        # the mean count over u (a midpoint rule over [0, 1)) is N w_i: the counts are unbiased;
        # each count is a step function of u with at most 2 steps: quadrature error <= 2 / J
        assert_allclose(total / J, expected, atol=2.0 / J)


def test_effective_sample_size_and_log_sum_exp() -> None:
    assert pm.effective_sample_size(np.full(8, 1 / 8)) == pytest.approx(8.0)
    assert pm.effective_sample_size(np.r_[1.0, np.zeros(7)]) == 1.0
    w, lw = pm.normalise_log_weights(np.array([-1e4, -1e4 + math.log(3), -np.inf]))   # exp underflows
    assert_allclose(w, [0.25, 0.75, 0.0])
    assert_allclose(lw[:2], np.log([0.25, 0.75]))


def test_parameters_are_checked() -> None:
    with pytest.raises(ParameterError, match="proposal"):
        validate(pm.ParticleFilterParameters(proposal="optimal"))
    with pytest.raises(ParameterError, match="n_particles"):
        validate(pm.ParticleFilterParameters(n_particles=0))
    with pytest.raises(ParameterError, match="ess_threshold"):
        validate(pm.ParticleFilterParameters(ess_threshold=1.5))


# ---- the linear-Gaussian limit: the Kalman filter ----------------------------------------------
def _linear(**kw) -> pm.ParticleFilterParameters:
    """A robot for which eq. 15 is linear: no gravity, forearm centre of mass on axis 3 (no
    Coriolis or inertia change), linear springs; motor angles only. The EKF is then the exact
    Kalman filter. The motor noise is raised to the prior's scale (arm side 5e-4 rad) so that
    the prior proposal keeps a useful sample size."""
    return validate(pm.ParticleFilterParameters(g=0.0, c2=0.0, k_lo=(8.0e5, 2.4e5), use_accelerometer=False,
                                                r_motor=1e-2, q_a0=(0.3, -0.2), **kw))


@pytest.mark.parametrize("proposal", pm.PROPOSALS)
def test_one_update_converges_to_the_kalman_filter(proposal: str) -> None:
    """From the prior N(x_0, P_0), one update: the weighted particles are an importance sample
    of the Gaussian posterior, so their mean and covariance differ from the Kalman filter's by
    sampling error only, of standard deviation sqrt(P_ii / ESS) and P_ii sqrt(2 / ESS)."""
    n = 40_000
    p = _linear(proposal=proposal, n_particles=n, seed=11)
    pf, kf = pm.ParticleFilterModel(p), em.EkfAccelerometerModel(p)
    y = kf.meas.h(kf.x) + np.array([0.05, -0.08])          # motor side, 0.5 to 1 sigma
    s = pf.filtered(y)
    kf.update(y)
    if proposal == "ekf":       # the EKF proposal is the exact posterior here: equal weights
        assert s.ess == pytest.approx(n, rel=1e-9)
    else:
        assert 0.1 * n < s.ess < 0.9 * n
    sd = np.sqrt(np.diag(kf.P))
    assert np.all(np.abs(s.x - kf.x) < 4.5 * sd / math.sqrt(s.ess)), (s.x - kf.x) / sd * math.sqrt(s.ess)
    assert_allclose(np.diag(s.P), np.diag(kf.P), rtol=4.5 * math.sqrt(2 / s.ess))
    # the posterior moved: the test is not passed by the prior
    assert np.abs(kf.x[0:2] - pf.x[0:2]).min() > 10 * sd[0:2].max() / math.sqrt(s.ess)


def _linear_run(p: pm.ParticleFilterParameters, steps: int):
    """The PF and the KF (the EKF on the linear model) on one simulated run; the filtered
    estimates of the last step."""
    pf, kf = pm.ParticleFilterModel(p), em.EkfAccelerometerModel(p)
    rng = np.random.default_rng(2)                  # the same data for every PF seed
    x_true = kf.x.copy()
    F, Gu, Gw = am.transition_matrices(T, kf.layout)
    for k in range(steps):
        if k:
            u = np.array([5.0, -3.0]) * math.sin(k / 3)
            x_true = F @ x_true + Gu @ u + Gw @ rng.normal(0, math.sqrt(p.q_jerk), 2)
            kf.predict(u, T)
            pf.predict(u, T)
        y = kf.meas.h(x_true) + rng.normal(0, math.sqrt(p.r_motor), 2)
        kf.update(y)
        s = pf.filtered(y)
        pf.commit(s)
    return s, kf.x, kf.P


def test_filter_follows_the_kalman_filter_over_steps() -> None:
    """Fifteen steps of the linear model with the EKF proposal (eq. 30, here the optimal
    proposal). Over several steps the Monte Carlo error of a particle filter accumulates through
    resampling and has no closed form, so it is measured: R runs with independent seeds. Their
    mean must agree with the Kalman filter within its standard error (Student t with R - 1
    degrees of freedom, 5.0: two-sided p < 0.5 % per component: no bias), and the Monte Carlo
    spread of one run must be small against the posterior spread (below 0.25 sd_KF at
    N = 8000; it falls like 1/sqrt(N): about 0.3 at 500, 0.15 at 4000, 0.06 at 32000)."""
    R, n, steps = 6, 8000, 15
    runs = [_linear_run(_linear(n_particles=n, seed=100 + r, q_jerk=1e6), steps) for r in range(R)]
    x_kf, P_kf = runs[0][1], runs[0][2]
    sd = np.sqrt(np.diag(P_kf))
    xs = np.array([s.x for s, _, _ in runs])
    mc_sd = xs.std(axis=0, ddof=1)
    assert np.all(np.abs(xs.mean(axis=0) - x_kf) < 5.0 * mc_sd / math.sqrt(R)), (xs.mean(0) - x_kf) / mc_sd
    assert np.all(mc_sd < 0.25 * sd), mc_sd / sd
    cov_ratio = np.array([np.diag(s.P) for s, _, _ in runs]) / np.diag(P_kf)
    assert_allclose(cov_ratio.mean(axis=0), 1.0, atol=5.0 * cov_ratio.std(axis=0, ddof=1).max() / math.sqrt(R))


# ---- tracking the robot (nonlinear model) --------------------------------------------------------
def _run(pf: pm.ParticleFilterModel, qm, f, u) -> np.ndarray:
    est = []
    for k in range(len(u)):
        est.append(pf.update(pf.measurement_vector(qm[k], f[k])).copy())
        pf.predict(u[k], T)
    return np.array(est)


@pytest.mark.parametrize("proposal,kw,ratio", [
    ("ekf", dict(), 1.15),
    ("ekf", dict(resampling="ess"), 1.15),
    ("prior", dict(p0_q=1e-5), 2.0),
], ids=["ekf", "ekf-ess", "prior"])
def test_tracks_like_the_ekf(proposal: str, kw: dict, ratio: float) -> None:
    """1000 particles on the EKF tests' motion (from rest): angle and velocity RMSE after a
    transient of 0.2 s within 15 % of the EKF's with the EKF proposal, within a factor 2 with
    the bootstrap proposal (its effective sample size is about 60 of 1000: the measurements
    are much more precise than the prior of one step). The bootstrap proposal (eq. 28) needs a prior of
    the initial angles of the order of the motor-angle noise (arm side 5 urad): with
    p0_q = 1 mrad one particle of 1000 survives the first update and the cloud cannot follow
    (the paper's finding on its high-SNR experiment)."""
    n, skip = 150, 20
    p = validate(pm.ParticleFilterParameters(q_a0=(0.2, -0.1), proposal=proposal, **kw))
    qm, f, u, x = signals_from_rest(n, p)
    est = _run(pm.ParticleFilterModel(p), qm, f, u)
    ekf = em.EkfAccelerometerModel(p)
    est_ekf = []
    for k in range(n):
        est_ekf.append(ekf.update(ekf.measurement_vector(qm[k], f[k])).copy())
        ekf.predict(u[k], T)
    rmse = np.sqrt(np.mean((est[skip:, 0:4] - x[skip:, 0:4]) ** 2, axis=0))
    rmse_ekf = np.sqrt(np.mean((np.array(est_ekf)[skip:, 0:4] - x[skip:, 0:4]) ** 2, axis=0))
    assert np.all(rmse < ratio * rmse_ekf), (rmse, rmse_ekf)
    assert np.all(rmse[0:2] < 1e-5)               # 10 urad: twice the motor noise, arm side


# ---- degeneracy, determinism ---------------------------------------------------------------------
@pytest.mark.parametrize("proposal", pm.PROPOSALS)
def test_absurd_measurement_reinitialises_without_nan(proposal: str) -> None:
    n = 80
    p = validate(pm.ParticleFilterParameters(q_a0=(0.2, -0.1), proposal=proposal, n_particles=500,
                                             p0_q=1e-5))
    qm, f, u, x = signals_from_rest(n, p)
    pf = pm.ParticleFilterModel(p)
    _run(pf, qm[:30], f[:30], u[:30])
    x_good = pf.x_prior.copy()
    s = pf.filtered(pf.measurement_vector(qm[30], (1e200, 0.0)))    # squares overflow: no weight left
    assert s.reinit and "skipped" in s.reinit
    assert np.all(np.isfinite(s.x)) and np.all(np.isfinite(s.P)) and np.all(np.isfinite(s.X))
    # the cloud is the re-initialised prior: around the last good estimate, with P_0
    assert np.all(np.abs(s.x - x_good) < 5 * np.sqrt(np.diag(pf.P0)) / math.sqrt(pf.N))
    assert_allclose(np.diag(s.P), np.diag(pf.P0), rtol=5 * math.sqrt(2 / pf.N))
    pf.commit(s)
    assert pf.n_reinit == 1
    pf.predict(u[30], T)
    est = _run(pf, qm[31:], f[31:], u[31:])
    assert pf.n_reinit == 1 and np.all(np.isfinite(est))
    if proposal == "ekf":       # tracks again (the bootstrap cannot: P_0's velocity spread is
        assert np.abs(est[-20:, 0:2] - x[-20:, 0:2]).max() < 3e-5      # too wide for its prior)


def test_nonfinite_prediction_is_a_named_divergence() -> None:
    pf = pm.ParticleFilterModel(pm.ParticleFilterParameters(n_particles=10))
    pf.update(pf.meas.h(pf.x))
    with pytest.raises(FilterDivergence, match="time update"):
        pf.predict((np.inf, 0.0), T)


@pytest.mark.parametrize("proposal", pm.PROPOSALS)
def test_deterministic_for_a_seed_and_filtered_does_not_commit(proposal: str) -> None:
    p = validate(pm.ParticleFilterParameters(q_a0=(0.2, -0.1), proposal=proposal, n_particles=300,
                                             resampling="ess"))
    qm, f, u, x = signals_from_rest(30, p)
    a, b = pm.ParticleFilterModel(p), pm.ParticleFilterModel(p)
    for k in range(30):
        y = a.measurement_vector(qm[k], f[k])
        b.filtered(y + 1e-3)              # recomputed for other inputs, not committed
        s1, s2 = b.filtered(y), b.filtered(y)
        assert_array_equal(s1.X, s2.X)
        b.commit(s1)
        a.update(y)
        assert_array_equal(a.x, b.x)
        assert_array_equal(a.X, b.X)
        assert_array_equal(a.logw, b.logw)
        a.predict(u[k], T)
        b.predict(u[k], T)
    c = pm.ParticleFilterModel(validate(pm.ParticleFilterParameters(
        q_a0=(0.2, -0.1), proposal=proposal, n_particles=300, resampling="ess", seed=1)))
    c.update(a.measurement_vector(qm[0], f[0]))
    assert not np.array_equal(c.X, _first(p, qm, f))       # another seed, other particles


def _first(p, qm, f) -> np.ndarray:
    pf = pm.ParticleFilterModel(p)
    pf.update(pf.measurement_vector(qm[0], f[0]))
    return pf.X


def test_corrupted_cloud_is_reinitialised_and_the_measurement_fused() -> None:
    """Particles whose predicted measurement overflows (a corrupted cloud) carry no weight: the
    cloud is re-initialised around the last good estimate and the measurement is fused."""
    p = validate(pm.ParticleFilterParameters(q_a0=(0.2, -0.1), n_particles=500))
    qm, f, u, x = signals_from_rest(40, p)
    pf = pm.ParticleFilterModel(p)
    _run(pf, qm[:30], f[:30], u[:30])
    pf.M = pf.M.copy()
    pf.M[:, 2] = 1e200                                   # dq^2 overflows in eqs. 17-19
    s = pf.filtered(pf.measurement_vector(qm[30], f[30]))
    assert s.reinit == "all particle weights underflowed or were not finite"
    assert np.all(np.isfinite(s.X)) and np.abs(s.x[0:2] - x[30, 0:2]).max() < 2e-5


def test_resampling_rule() -> None:
    """``always`` resamples every update (the paper, section 4.3); ``ess`` only below the
    threshold: never at 0, always at 1 (the ESS is below N unless all weights are equal)."""
    qm, f, u, x = signals_from_rest(3, pm.ParticleFilterParameters())
    steps = {}
    for name, kw in (("always", dict()), ("never", dict(resampling="ess", ess_threshold=0.0)),
                     ("ess1", dict(resampling="ess", ess_threshold=1.0))):
        pf = pm.ParticleFilterModel(validate(pm.ParticleFilterParameters(q_a0=(0.2, -0.1), proposal="prior",
                                                                         n_particles=400, seed=3, **kw)))
        steps[name] = pf.filtered(pf.measurement_vector(qm[0], f[0]))
    assert steps["always"].resampled and steps["ess1"].resampled and not steps["never"].resampled
    assert_allclose(steps["always"].logw, -math.log(400))
    assert steps["never"].ess < 400 and np.ptp(steps["never"].logw) > 0
    w = np.exp(steps["never"].logw)
    assert_allclose(w.sum(), 1.0)
    assert_allclose(w @ steps["never"].X, steps["never"].x)       # eq. 6 from the kept weights
    assert steps["never"].ess == steps["always"].ess == steps["ess1"].ess       # same draws


@pytest.mark.parametrize("proposal", pm.PROPOSALS)
@pytest.mark.parametrize("acc,bias", [(True, False), (True, True), (False, True)])
def test_compiled_sampling_and_weighting_equal_the_numpy_code(proposal: str, acc: bool, bias: bool) -> None:
    """propose_and_weigh against the numpy code it replaced (tests/pf_numpy_reference.py), on a
    cloud after 20 updates, with the prior of one period (k = 2 or 4 noise inputs) and of two
    (k = 4 or 8: the Cholesky loop against LAPACK), with a few overflowed particles."""
    p = pm.ParticleFilterParameters(q_a0=(0.2, -0.1), proposal=proposal, n_particles=500, p0_q=1e-5,
                                    use_accelerometer=acc, use_bias=bias)
    f = pm.ParticleFilterModel(p)
    qm, acc_xz, u, _ = signals_from_rest(24, p, seed=5)
    for k in range(20):
        f.update(f.measurement_vector(qm[k], acc_xz[k]))
        f.predict(u[k], T)
    one = (f.M.copy(), f.L)
    f.predict(u[20], T)
    y = f.measurement_vector(qm[21], acc_xz[21])
    ref = NumpyMeasurement(f.meas)
    for M, L in (one, (f.M, f.L)):
        M = np.array(M)
        M[[3, 7]] = [np.inf, np.nan, 0, 0, 0, 0, *[0] * (f.layout.n - 6)][:f.layout.n]
        Z = np.random.default_rng(2).standard_normal((len(M), L.shape[1]))
        X, logw = np.empty_like(M), np.empty(len(M))
        D = f.D.copy()                         # the deflections Newton starts from
        pm.propose_and_weigh(M, np.ascontiguousarray(L), f.logw, y, f.r_inv, Z, proposal == "ekf",
                             f.meas.constants, *f.meas.switches, D, X, logw)
        X_ref, logw_ref = propose_and_weigh_numpy(ref, proposal, f.r_inv, M, L, f.logw, y, Z)
        assert np.isneginf(logw[[3, 7]]).all() and not X[[3, 7]].any()
        assert_allclose(D[:3], NumpyMeasurement(f.meas).deflection(X[:3]), rtol=1e-12)
        assert_allclose(X, X_ref, rtol=1e-12, atol=0)
        # the log-weight -nu^2 / 2R cancels h(x) (motor angles about 20 rad) down to an innovation
        # nu of about 1e-3: its round-off is about eps |h| |nu| / R, 5e-12 per unit (3e-11 seen)
        assert_allclose(logw, logw_ref, rtol=1e-12, atol=1e-10)


def test_compiled_resampling_and_moments_equal_the_numpy_code() -> None:
    rng = np.random.default_rng(9)
    for n in (1, 2, 17, 1000, 5000):
        w = rng.exponential(size=n) ** rng.uniform(0, 8)
        w[rng.random(n) < 0.3] = 0.0
        w[0] += 1e-3
        for u in (0.0, rng.random(), 1 - 1e-12):
            assert_array_equal(pm.systematic_resample(w, u), numpy_reference.systematic_resample(w, u))
        w /= w.sum()
        X = rng.normal(size=(n, 6)) * [1e-5, 1e-5, 1e-3, 1e-3, 1e-1, 1e-1] + [0.3, -0.2, 0, 0, 0, 0]
        x, P = pm.weighted_mean_cov(X, w)
        x_ref, P_ref = numpy_reference.weighted_mean_cov(X, w)
        assert_allclose(x, x_ref, rtol=1e-12, atol=0)
        assert_allclose(P, P_ref, rtol=1e-12, atol=1e-12 * np.abs(P_ref).max())
        idx = pm.systematic_resample(w, 0.5)
        Z = rng.normal(size=(n, 6))
        moved = numpy_reference.kernel_move(X[idx], x, P, 0.4, Z, float(w @ w))
        scale = np.abs(moved).max(axis=0)        # per state: entries near zero are differences
        assert_allclose(pm.kernel_move(X, x, P, 0.4, Z, float(w @ w), idx) / scale, moved / scale,
                        rtol=1e-12, atol=1e-12)


# ---- regularisation after resampling (the cloud keeps its spread) --------------------------------
def test_optimal_bandwidth_is_silvermans() -> None:
    assert_allclose(pm.optimal_bandwidth(1000, 6), (4 / 8000) ** 0.1, rtol=1e-14)
    assert_allclose(pm.optimal_bandwidth(120, 6), (4 / 960) ** 0.1, rtol=1e-14)
    assert pm.optimal_bandwidth(120, 6) > pm.optimal_bandwidth(1000, 6)      # fewer samples: wider
    assert pm.optimal_bandwidth(1.0, 10) < 1.0 and pm.optimal_bandwidth(1e-3, 6) == pm.optimal_bandwidth(1.0, 6)


def _whitened(n: int, k: int, seed: int) -> np.ndarray:
    """Standard normals with exactly zero sample mean and identity sample covariance."""
    Z = np.random.default_rng(seed).normal(size=(n, k))
    Z -= Z.mean(axis=0)
    return Z @ np.linalg.inv(np.linalg.cholesky(Z.T @ Z / n)).T


def test_kernel_move_keeps_mean_and_covariance() -> None:
    """Copies of one particle (the extreme of resampling) become a cloud of mean ``x_hat`` and
    covariance ``h^2 P`` (exactly, for whitened draws), inflated to
    ``(1 / (1 - sum w^2) - a^2) P`` when the weighted covariance is debiased; a spread cloud of
    covariance ``P`` keeps it (sampling error only); a singular ``P`` gives no NaN."""
    rng = np.random.default_rng(3)
    B = rng.normal(size=(6, 6))
    D = np.diag([1e-4, 1e-4, 1e-3, 1e-3, 1e-2, 1e-2])       # angles, velocities, accelerations
    P = D @ (B @ B.T + 0.1 * np.eye(6)) @ D                  # correlated, scales far apart
    x = rng.normal(size=6)
    n, h = 4000, 0.47
    Z = _whitened(n, 6, 5)
    for sum_w2, var in ((0.0, h * h), (0.1, 1 / 0.9 - (1 - h * h))):
        Xn = pm.kernel_move(np.tile(x, (n, 1)), x, P, h, Z, sum_w2)
        assert_allclose(Xn.mean(axis=0), x, rtol=1e-12, atol=1e-12)
        assert_allclose(np.cov(Xn.T, bias=True), var * P, rtol=1e-9, atol=1e-12 * np.abs(P).max())
    n = 100_000
    X = x + _whitened(n, 6, 6) @ np.linalg.cholesky(P).T
    Xn = pm.kernel_move(X, x, P, h, rng.standard_normal((n, 6)))
    sd = np.sqrt(np.diag(P))
    assert np.all(np.abs(Xn.mean(axis=0) - x) < 4.5 * sd / math.sqrt(n))
    assert_allclose(np.diag(np.cov(Xn.T)), np.diag(P), rtol=4.5 * math.sqrt(2 / n))
    P1 = np.outer(sd, sd)                                     # rank 1
    Xs = pm.kernel_move(np.tile(x, (10, 1)), x, P1, h, rng.standard_normal((10, 6)))
    assert np.all(np.isfinite(Xs))


def _model_signals(n: int, p: pm.ParticleFilterParameters, seed: int):
    """A run of the filter's own model (eqs. 13-15: the jerk reference of :func:`_motion` plus
    jerk noise of variance ``q_jerk``, measurement noise ``R``), so the EKF is near optimal."""
    rng = np.random.default_rng(seed)
    layout = am.Layout(True, False)
    mm = am.MeasurementModel(p.robot(), layout)
    F, Gu, Gw = am.transition_matrices(T, layout)
    x0, u = _motion(np.arange(n) * T)
    x = np.empty((n, 6))
    x[0] = x0[0]
    for k in range(1, n):
        x[k] = F @ x[k - 1] + Gu @ u[k - 1] + Gw @ rng.normal(0, math.sqrt(p.q_jerk), 2)
    qm = np.array([mm.motor_angles(xk) for xk in x]) + rng.normal(0, math.sqrt(p.r_motor), (n, 2))
    f = np.array([mm.specific_force(xk) for xk in x]) + rng.normal(0, math.sqrt(p.r_acc), (n, 2))
    return qm, f, u, x


def _run_sd(m, qm, f, u) -> tuple[np.ndarray, np.ndarray]:
    est, sd = [], []
    for k in range(len(u)):
        est.append(m.update(m.measurement_vector(qm[k], f[k])).copy())
        sd.append(np.sqrt(np.diag(m.P)))
        m.predict(u[k], T)
    return np.array(est), np.array(sd)


def test_regularisation_keeps_the_cloud_spread_over_many_steps() -> None:
    """The noise of the scenario axelsson2012_pf (motor angles 1 mrad arm side, accelerometer
    0.01 m/s^2, q_jerk = 10), 2 s of the filter's own model, EKF proposal, 1000 particles. The
    process noise is the jerk: per step it moves the angles by about 5e-7 rad and the
    velocities by 1.6e-4 rad/s, far below their posterior spread (about 3e-4 rad, 1e-3 rad/s),
    so resampling's copies stay copies there and the angle/velocity spread of the plain
    Algorithm 1 collapses (a fifth of the EKF's), the cloud stops listening to the
    measurements and drifts (an RMSE many times the EKF's). With the kernel move after
    resampling the spread stays the EKF's (within 20 %) and the RMSE within 20 % of the EKF's.
    """
    n, skip = 200, 50
    kw = dict(q_a0=(0.2, -0.1), q_jerk=10.0, r_motor=0.04, r_acc=1e-4)
    p = validate(pm.ParticleFilterParameters(**kw))
    qm, f, u, x = _model_signals(n, p, seed=0)
    est_e, sd_e = _run_sd(em.EkfAccelerometerModel(p), qm, f, u)
    rmse_e = np.sqrt(np.mean((est_e[skip:, 0:4] - x[skip:, 0:4]) ** 2, axis=0))
    out = {}
    for bw in (1.0, 0.0):
        pf = pm.ParticleFilterModel(validate(pm.ParticleFilterParameters(bandwidth=bw, **kw)))
        est, sd = _run_sd(pf, qm, f, u)
        rmse = np.sqrt(np.mean((est[skip:, 0:4] - x[skip:, 0:4]) ** 2, axis=0))
        out[bw] = rmse / rmse_e, np.median(sd[skip:, 0:4] / sd_e[skip:, 0:4], axis=0)
    rmse_ratio, sd_ratio = out[1.0]
    assert np.all(rmse_ratio < 1.2), out
    assert_allclose(sd_ratio, 1.0, rtol=0.2)
    rmse_ratio, sd_ratio = out[0.0]                      # the cause: plain Algorithm 1 collapses
    assert np.all(sd_ratio[0:2] < 0.5) and np.all(rmse_ratio[0:2] > 5.0), out


def test_bandwidth_is_checked_and_zero_is_plain_algorithm_1() -> None:
    for bad in (-0.1, 1.5):
        with pytest.raises(ParameterError, match="bandwidth"):
            validate(pm.ParticleFilterParameters(bandwidth=bad))
    qm, f, u, x = signals_from_rest(2, pm.ParticleFilterParameters())
    s = {}
    for bw in (0.0, 1.0):
        pf = pm.ParticleFilterModel(validate(pm.ParticleFilterParameters(q_a0=(0.2, -0.1), n_particles=300,
                                                                         bandwidth=bw)))
        s[bw] = pf.filtered(pf.measurement_vector(qm[0], f[0]))
    assert_array_equal(s[0.0].x, s[1.0].x)           # the same draws and weights: same estimate
    # plain: the resampled particles are copies of the weighted ones; with the kernel all differ
    assert len(np.unique(s[0.0].X[:, 0])) < 300 and len(np.unique(s[1.0].X[:, 0])) == 300

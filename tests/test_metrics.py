"""Metrics on signals with known answers."""
from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from orchestration import metrics as m
from orchestration.scenario import MetricSpec


def test_rmse_is_root_mean_squared_euclidean_error():
    truth = np.zeros((4, 2))
    est = np.array([[3.0, 4.0], [0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])    # |e| = 5, 0, 1, 1
    assert_allclose(m.rmse(est, truth), np.sqrt((25 + 0 + 1 + 1) / 4))   # eq. 27
    assert_allclose(m.rmse(np.array([1.0, -1.0]), np.zeros(2)), 1.0)     # 1-D
    assert_allclose(m.max_error(est, truth), 5.0)
    assert_allclose(m.rmse(est, 0.0), m.rmse(est, truth))               # RMS of a signal


def test_rmse_over_runs_is_eq_27_per_time():
    """Per time, the RMSE over runs is the RMSE of the runs' errors at that time taken as
    samples; a hand case: errors (3, 4), (0, 0), (0, 5) at one time give sqrt(50 / 3)."""
    e = np.random.default_rng(2).standard_normal((7, 5, 2))
    assert_allclose(m.rmse_over_runs(e), [m.rmse(e[:, k], 0.0) for k in range(5)], rtol=1e-15)
    assert_allclose(m.rmse_over_runs([[[3.0, 4.0]], [[0.0, 0.0]], [[0.0, 5.0]]]), [np.sqrt(50 / 3)])


def test_bandpass_halves_a_sine_at_a_corner_and_keeps_the_shape():
    # a Butterworth band-pass has gain 1/sqrt(2) at either corner; forwards and backwards squares it
    fs = 1000.0
    t = np.arange(0, 8.0, 1 / fs)
    mid = (t > 3.0) & (t < 5.0)
    for f in (3.0, 30.0):
        y = m.bandpass(np.sin(2 * np.pi * f * t), fs)
        assert y.shape == t.shape
        assert_allclose(np.max(np.abs(y[mid])), 0.5, rtol=0.02)
    assert_allclose(np.max(np.abs(m.bandpass(np.sin(2 * np.pi * 10 * t), fs)[mid])), 1.0, rtol=0.01)
    with pytest.raises(ValueError, match="more than"):
        m.bandpass(np.zeros(20), fs)


def _butterworth_bandpass_gain(f: float, fs: float, low: float, high: float, order: int) -> float:
    """The squared magnitude of the digital Butterworth band-pass (the bilinear transform of the
    analog prototype, corners pre-warped), in closed form: the zero-phase gain of running it
    forwards and backwards. Independent of how scipy designs or runs the filter."""
    def warp(x: float) -> float:
        return 2 * fs * np.tan(np.pi * x / fs)
    w, wl, wh = warp(f), warp(low), warp(high)
    return 1.0 / (1.0 + ((w * w - wl * wh) / ((wh - wl) * w)) ** (2 * order))


def test_bandpass_gain_is_the_closed_form_in_and_out_of_band():
    """A tone's steady-state amplitude after the band-pass is |H(f)|^2 to 1e-8 relative, from
    deep in the stop band (0.7 Hz: 4e-6) through the corners to 150 Hz (the transfer-function
    form (b, a) of the same filter misses by up to 5e-5), with no phase (zero-phase)."""
    fs = 1000.0
    t = np.arange(0, 12.0, 1 / fs)
    mid = (t > 4.0) & (t < 8.0)
    for f in (0.7, 1.5, 3.0, 7.0, 30.0, 60.0, 150.0):
        y = m.bandpass(np.sin(2 * np.pi * f * t), fs)
        basis = np.column_stack([np.sin(2 * np.pi * f * t[mid]), np.cos(2 * np.pi * f * t[mid])])
        (in_phase, quadrature), *_ = np.linalg.lstsq(basis, y[mid], rcond=None)
        gain = _butterworth_bandpass_gain(f, fs, 3.0, 30.0, 4)
        assert_allclose(in_phase, gain, rtol=1e-8)
        assert abs(quadrature) < 1e-8 * gain


def test_bandpass_is_not_moved_by_round_off():
    """A last-bit change of the input moves the output by round-off only (well-conditioned)."""
    rng = np.random.default_rng(0)
    x = rng.normal(size=20000) * 1e-4
    nudged = x * (1 + 1e-16 * rng.normal(size=x.size))
    y = m.bandpass(x, 1000.0)
    assert np.max(np.abs(m.bandpass(nudged, 1000.0) - y)) < 1e-12 * np.max(np.abs(y))


def test_bandpass_keeps_the_pass_band_and_removes_the_rest():
    fs = 1000.0
    t = np.arange(0, 4.0, 1 / fs)
    a = 2e-3
    inband = a * np.c_[np.cos(2 * np.pi * 10 * t), np.sin(2 * np.pi * 10 * t)]   # |e| = a
    drift = np.c_[0.5 * t, 0.1 + 0 * t]                                          # DC + ramp
    fast = 1e-2 * np.c_[np.sin(2 * np.pi * 150 * t), np.cos(2 * np.pi * 150 * t)]
    keep = (t > 1.0) & (t < 3.0)   # away from the filtfilt edges
    mx, mean = m.bandpass_errors(inband + drift + fast, np.zeros_like(t)[:, None], fs, keep=keep)
    assert_allclose([mx, mean], [a, a], rtol=0.03)
    mx0, mean0 = m.bandpass_errors(drift + fast, np.zeros((len(t), 2)), fs, keep=keep)
    assert mx0 < 0.05 * a
    with pytest.raises(ValueError, match="low < high < fs/2"):
        m.bandpass_errors(inband, 0 * inband, 50.0)


def test_compute_maps_specs_and_applies_after():
    t = np.arange(0, 1.0, 0.001)
    truth = np.zeros((len(t), 2))
    est = np.where(t[:, None] < 0.5, 10.0, 1.0) * np.ones((1, 2))
    out = m.compute(MetricSpec("rmse", "r", "a.x", "b.x", after=0.5), t, est, truth)
    assert_allclose(out["r"], np.sqrt(2.0))
    out = m.compute(MetricSpec("max", "mx", "a.x", "b.x", after=0.0), t, est, truth)
    assert_allclose(out["mx"], 10 * np.sqrt(2.0))
    # whole periods, odd about both ends: filtfilt's odd padding continues it exactly
    t = np.linspace(0.0, 1.0, 1001)
    sig = 1e-3 * np.c_[np.sin(2 * np.pi * 10 * t), np.zeros_like(t)]
    out = m.compute(MetricSpec("bandpass", "bp", "a.x", "b.x", after=0.2), t, sig, 0 * sig)
    assert set(out) == {"bp_max", "bp_mean"}
    assert_allclose(out["bp_max"], 1e-3, rtol=0.03)
    assert_allclose(out["bp_mean"], 2e-3 / np.pi, rtol=0.03)    # mean of |sin|


def test_at_sample_times_keeps_fresh_samples_at_their_stamps():
    """A truth held for 3 rows and stamped one row late: the fresh rows only, the estimate
    linearly interpolated to the stamps (here a ramp, so exactly the ramp at the stamp)."""
    from orchestration.metrics import at_sample_times
    t = np.arange(10) * 0.1
    est = np.column_stack([2.0 * t, -t])
    stamp = np.maximum(np.floor((t - 0.1 + 1e-9) / 0.3) * 0.3, 0.0)     # held, stamped late
    truth = np.column_stack([2.0 * stamp, -stamp])
    s, e, tr = at_sample_times(t, est, truth, stamp)
    assert_allclose(s, [0.0, 0.3, 0.6])
    assert_allclose(e, tr, atol=1e-12)
    assert_allclose(e, np.column_stack([2.0 * s, -s]), atol=1e-12)


# ---- consistency: NEES and NIS --------------------------------------------------------------

def test_nees_uses_the_unpacked_covariance_and_its_marginal_block():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(5, 3, 3))
    P = A @ A.transpose(0, 2, 1) + np.eye(3)
    rows, cols = np.tril_indices(3)
    packed = P[:, rows, cols]
    assert_allclose(m.unpack_covariance(packed), P)
    e = rng.normal(size=(5, 3))
    assert_allclose(m.nees(e, packed), [ei @ np.linalg.inv(Pi) @ ei for ei, Pi in zip(e, P)], rtol=1e-12)
    e2 = e[:, :2]                  # the first two states: their marginal covariance P[:2, :2]
    assert_allclose(m.nees(e2, packed), [ei @ np.linalg.inv(Pi[:2, :2]) @ ei for ei, Pi in zip(e2, P)],
                    rtol=1e-12)
    with pytest.raises(ValueError, match="n \\(n \\+ 1\\) / 2 elements, got 4"):
        m.unpack_covariance(np.zeros((1, 4)))
    assert_allclose(m.nis([1.0, 2.0], squared=False), [1.0, 4.0])


def test_chi2_band_of_two_dof_is_the_exponential_quantiles():
    # chi-square with 2 dof is exponential with mean 2: quantile q is -2 ln(1 - q)
    assert_allclose(m.chi2_band(2), (-2 * np.log(0.975), -2 * np.log(0.025)), rtol=1e-10)
    lo, hi = m.chi2_band(6, 50)             # the average of 50 runs: narrower, around 6
    assert 5.0 < lo < 6.0 < hi < 7.2


def _kalman_monte_carlo(q_filter: float, runs: int = 50, steps: int = 200, seed: int = 7):
    """A linear-Gaussian Kalman filter on a 1-D constant-velocity target (white-noise
    acceleration of intensity q = 1, position measured with R = 0.25, T = 0.1 s; Bar-Shalom
    et al. 2001, section 6.3.2) whose model uses ``q_filter``: NEES (2 states) and NIS (1
    measurement) per run and step."""
    T, q, R = 0.1, 1.0, 0.25
    F = np.array([[1.0, T], [0.0, 1.0]])
    Qn = np.array([[T ** 3 / 3, T ** 2 / 2], [T ** 2 / 2, T]])
    H = np.array([[1.0, 0.0]])
    rng = np.random.default_rng(seed)
    L = np.linalg.cholesky(q * Qn)
    nees, nis = np.zeros((runs, steps)), np.zeros((runs, steps))
    for r in range(runs):
        P = np.diag([1.0, 1.0])
        x = rng.multivariate_normal([0.0, 1.0], P)      # the truth drawn from the prior
        xh = np.array([0.0, 1.0])
        for k in range(steps):
            x = F @ x + L @ rng.normal(size=2)
            y = H @ x + np.sqrt(R) * rng.normal(size=1)
            xh, P = F @ xh, F @ P @ F.T + q_filter * Qn
            S = H @ P @ H.T + R
            nu = y - H @ xh
            K = P @ H.T / S
            xh, P = xh + (K @ nu), (np.eye(2) - K @ H) @ P
            nis[r, k] = float(nu @ nu / S[0, 0])
            rows, cols = np.tril_indices(2)
            nees[r, k] = m.nees((xh - x)[None, :], P[rows, cols][None, :])[0]
    return nees, nis


def test_nees_and_nis_of_a_kalman_filter_stay_in_their_95_percent_bands():
    nees, nis = _kalman_monte_carlo(q_filter=1.0)
    a = m.monte_carlo_consistency(nees, dof=2)
    assert a["band"] == m.chi2_band(2, 50)
    assert_allclose(a["mean"], 2.0, rtol=0.05)            # E[NEES] = number of states
    assert a["fraction_in_band"] >= 0.9                     # about 95 % of the times
    b = m.monte_carlo_consistency(nis, dof=1)
    assert_allclose(b["mean"], 1.0, rtol=0.05)
    assert b["fraction_in_band"] >= 0.9


def test_a_mistuned_kalman_filter_leaves_the_band():
    nees, nis = _kalman_monte_carlo(q_filter=0.01)          # 100 times too little process noise
    a = m.monte_carlo_consistency(nees, dof=2)
    assert a["mean"] > 2 * a["band"][1] and a["fraction_in_band"] < 0.1    # overconfident
    assert m.monte_carlo_consistency(nis, dof=1)["fraction_in_band"] < 0.5


def test_compute_nees_and_nis_specs():
    t = np.arange(6) * 0.1
    e = np.array([[1.0, 0.0]] * 6)
    P = np.array([[4.0, 0.0, 1.0]] * 6)               # diag(4, 1): NEES = 1 / 4
    spec = MetricSpec("nees", "c", "f.q_hat", "p.q", after=0.2, covariance="f.P", dof=2)
    out = m.compute(spec, t, e, np.zeros_like(e), covariance=P)
    lo, hi = m.chi2_band(2)
    assert_allclose(out["c"], 0.25)
    assert out["c_in_band"] == float(lo <= 0.25 <= hi)
    spec = MetricSpec("nis", "n", "f.innovation_norm", "", dof=1)
    out = m.compute(spec, t, np.array([0.0, 1.0, 2.0, 1.0, 0.0, 3.0]), None)
    assert_allclose(out["n"], (0 + 1 + 4 + 1 + 0 + 9) / 6)
    entry = m.entries(spec, out)["n"]
    assert entry["dof"] == 1 and entry["band_95"] == list(m.chi2_band(1))


def test_a_run_imports_scipy_signal_only_to_design_a_band_pass_once(tmp_path) -> None:
    """Importing it cost every run 0.9 s of CPU (issue 26: 40 % of a flagship run): the metrics
    module imports it only to design a band-pass it has not designed before (the design is
    cached), and filters without it."""
    import os
    import subprocess
    import sys
    code = ("import sys, numpy as np; import orchestration.master, orchestration.metrics as m; "
            "m.rmse(np.zeros((5, 2)), np.ones((5, 2))); assert 'scipy.signal' not in sys.modules; "
            "m.bandpass_errors(np.random.default_rng(0).normal(size=(2000, 2)), np.zeros((2000, 2)), 1000.0); "
            "print('scipy.signal' in sys.modules)")
    env = {**os.environ, "FLEXFUSION_CACHE_DIR": str(tmp_path)}
    imported = [subprocess.run([sys.executable, "-c", code], check=True, env=env, capture_output=True,
                               text=True).stdout.split()[-1] for _ in range(2)]
    assert imported == ["True", "False"]


@pytest.mark.parametrize("n, d, fs, low, high, order", [
    (11001, 2, 1000.0, 3.0, 30.0, 4),       # the 2009 paper's band on a flagship-length record
    (300, 1, 1000.0, 3.0, 30.0, 4),         # shorter than three periods of the low corner
    (5000, 3, 500.0, 0.7, 120.0, 6),
    (2001, 1, 2000.0, 10.0, 400.0, 1)])
def test_bandpass_is_scipys_sosfiltfilt_bit_for_bit(n, d, fs, low, high, order) -> None:
    """The cached design and the compiled section cascade give what ``scipy.signal`` gives: the
    same numbers, to the last bit (1-D input for ``d == 1``)."""
    from scipy.signal import butter, sosfiltfilt
    x = np.random.default_rng(n).normal(size=(n, d)).cumsum(axis=0)
    x = x[:, 0] if d == 1 else x
    padlen = min(n - 1, max(3 * (2 * order + 1), int(np.ceil(3 * fs / low))))
    expected = sosfiltfilt(butter(order, [low, high], btype="bandpass", fs=fs, output="sos"), x, axis=0,
                           padlen=padlen)
    got = m.bandpass(x, fs, low, high, order)
    assert got.shape == expected.shape and np.array_equal(got, expected)


# ---------------------------------------------------------------------------------------------
# the innovation criterion (tuning without truth): a linear-Gaussian case with a known Q and R
# ---------------------------------------------------------------------------------------------
def _white_acceleration_case(q: float, r: float, n: int, seed: int) -> np.ndarray:
    """Positions of a constant-velocity target driven by white acceleration of intensity ``q``
    (discretised at 100 Hz), measured with noise variance ``r``."""
    dt = 0.01
    F = np.array([[1.0, dt], [0.0, 1.0]])
    g = np.array([dt * dt / 2, dt])
    rng = np.random.default_rng(seed)
    x, y = np.zeros(2), np.empty(n)
    for k in range(n):
        x = F @ x + g * rng.normal() * np.sqrt(q)
        y[k] = x[0] + rng.normal() * np.sqrt(r)
    return y


def _kalman_nis(y: np.ndarray, q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """NIS per step (rows) of the Kalman filter of the same model with process noise ``q`` and
    measurement noise ``r`` (one filter per column, vectorised)."""
    dt = 0.01
    F = np.array([[1.0, dt], [0.0, 1.0]])
    g = np.array([dt * dt / 2, dt])
    Qd = np.outer(g, g)
    x, P = np.zeros((len(q), 2)), np.tile(np.eye(2), (len(q), 1, 1))
    out = np.empty((len(y), len(q)))
    for k, yk in enumerate(y):
        x = x @ F.T
        P = F @ P @ F.T + q[:, None, None] * Qd
        S = P[:, 0, 0] + r
        nu = yk - x[:, 0]
        gain = P[:, :, 0] / S[:, None]
        x = x + gain * nu[:, None]
        P = P - gain[:, :, None] * P[:, None, 0, :]
        out[k] = nu * nu / S
    return out


def test_the_innovation_criterion_picks_the_true_q_and_r_of_a_linear_gaussian_case() -> None:
    """No truth: over a log grid of Q and R (factors 0.01-100, steps of 10^0.25 = 1.78x) the
    criterion's minimum is within 2x of the true Q (and R) on each of three noise seeds. The
    average NIS alone has a ridge of (Q, R) pairs (one equation, two unknowns); the whiteness
    term (the filter with too little Q lags: correlated innovations) picks the point on it."""
    q_true, r_true = 4.0, 1e-6
    f = np.logspace(-2, 2, 17)
    Q, R = (a.ravel() for a in np.meshgrid(q_true * f, r_true * f, indexing="ij"))
    for seed in (1, 2, 3):
        s = _kalman_nis(_white_acceleration_case(q_true, r_true, 3000, seed), Q, R)[50:]   # P0's start left out
        cost = np.array([m.innovation_criterion(s[:, i], dof=1)["cost"] for i in range(len(Q))])
        best = int(np.argmin(cost))
        assert 0.5 <= Q[best] / q_true <= 2.0, (seed, Q[best] / q_true)
        assert 0.5 <= R[best] / r_true <= 2.0, (seed, R[best] / r_true)
    # at the truth: ANIS inside its 95 % band and the Box-Pierce statistic below its 95 % quantile;
    # with Q 100x too small the innovations are far from white
    right = m.innovation_criterion(_kalman_nis(_white_acceleration_case(q_true, r_true, 3000, 1),
                                                     np.array([q_true, q_true / 100]),
                                                     np.array([r_true, r_true]))[50:, 0], dof=1)
    assert right["anis_band_95"][0] <= right["anis"] <= right["anis_band_95"][1]
    assert right["box_pierce"] < right["box_pierce_95"]
    wrong = m.innovation_criterion(_kalman_nis(_white_acceleration_case(q_true, r_true, 3000, 1),
                                                     np.array([q_true / 100]), np.array([r_true]))[50:, 0], dof=1)
    assert wrong["box_pierce"] > 10 * wrong["box_pierce_95"] and wrong["anis"] > right["anis_band_95"][1]


def test_the_autocorrelation_and_the_held_statistic() -> None:
    """rho_l of a known series; a held NIS (repeated rows) is one update, not a correlation."""
    x = np.array([1.0, -1.0] * 50)              # alternating: rho_1 = -(n-1)/n, rho_2 = (n-2)/n
    assert_allclose(m.autocorrelation(x, 2), [-99 / 100, 98 / 100], rtol=1e-12)
    rng = np.random.default_rng(0)
    s = rng.chisquare(2, 2000)
    held = np.repeat(s, 3)                      # a filter updating every third row
    assert_allclose(m.innovation_criterion(held, 2)["cost"], m.innovation_criterion(s, 2)["cost"],
                    rtol=1e-12)
    with pytest.raises(ValueError, match="samples"):
        m.autocorrelation(np.ones(5), 10)

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


def test_a_run_imports_scipy_signal_only_for_a_band_pass() -> None:
    """Importing it cost every run 0.6-2 s of start-up (issue 16): the metrics module leaves it
    to the band-pass metric."""
    import subprocess
    import sys
    code = ("import sys, numpy as np; import orchestration.master, orchestration.metrics as m; "
            "m.rmse(np.zeros((5, 2)), np.ones((5, 2))); assert 'scipy.signal' not in sys.modules; "
            "m.bandpass_errors(np.random.default_rng(0).normal(size=(2000, 2)), np.zeros((2000, 2)), 1000.0); "
            "assert 'scipy.signal' in sys.modules")
    subprocess.run([sys.executable, "-c", code], check=True)

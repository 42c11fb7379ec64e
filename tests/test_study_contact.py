"""Contact study: metrics on known series, the Figs. 6-8 plots, the one-axis tool study."""
from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from fmus.force_observer import impedance_math as imp
from orchestration import study_contact as sc


def synthetic_run(bounces: int = 0, n: int = 2000, h: float = 0.004):
    """A known run: free motion with inertia, a touch (with ``bounces`` losses), stationary contact."""
    t = np.arange(n) * h
    setup = sc.ContactSetup(normal=(1.0, 0.0), x_wall=1.3, k_wall=5000.0, K_z=2000.0,
                            free_window=(0.0, 2.0), steady_window=(6.0, 7.9))
    xr = 1.32
    xs, Fs = imp.stationary_contact(setup.K_z, setup.k_wall, xr, setup.x_wall)
    a = np.zeros((n, 2))
    a[t < 2.0, 0] = 4.0 * np.sin(2 * np.pi * t[t < 2.0])
    F = np.zeros((n, 2))
    ramp = (t >= 3.0)
    F[ramp, 0] = Fs * (1 + 0.1 * np.exp(-(t[ramp] - 3.0) / 0.2))     # 10 % overshoot
    for b in range(bounces):                                          # short losses after touch
        F[(t >= 3.1 + 0.1 * b) & (t < 3.12 + 0.1 * b), 0] = 0.0
    raw = F + 12.0 * a
    hat = F + 0.01 * raw                                               # 1 % leak of the raw reading
    p = np.zeros((n, 2))
    p[:, 0] = np.where(t >= 3.0, xs, 1.25)
    pr = np.zeros((n, 2))
    pr[:, 0] = xr
    return dict(t=t, F_true=F, F_hat=hat, F_raw=raw, F_fb=hat, p_tool=p, p_ref=pr, a_meas=a), setup, xs, Fs


def test_metrics_on_known_series():
    s, setup, xs, Fs = synthetic_run(bounces=0)
    m = sc.contact_metrics(s, setup)
    assert_allclose(m["free_ratio"], 0.01, rtol=1e-9)
    assert_allclose(m["pred_F"], Fs)
    assert_allclose(m["steady_x_pen"], xs - 1.3, rtol=1e-12)
    assert m["steady_x_err"] < 1e-12
    assert_allclose(m["steady_F_err"], 0.0, atol=1e-6)
    assert_allclose(m["overshoot"], 0.1, rtol=1e-9)
    assert m["contact_losses"] == 0
    assert_allclose(m["first_touch"], 3.0)
    assert m["finite"]


@pytest.mark.parametrize("bounces", [1, 3])
def test_metrics_count_contact_losses(bounces):
    s, setup, *_ = synthetic_run(bounces=bounces)
    assert sc.contact_metrics(s, setup)["contact_losses"] == bounces


def test_contact_losses_helper():
    assert sc.contact_losses(np.array([0, 0, 1, 2, 0, 3, 0, 0, 1.0])) == (2, 2)
    assert sc.contact_losses(np.zeros(5)) == (0, None)


def test_metrics_flag_nan():
    s, setup, *_ = synthetic_run()
    s["F_fb"] = s["F_fb"].copy()
    s["F_fb"][100, 0] = np.nan
    assert not sc.contact_metrics(s, setup)["finite"]


def test_plots_written(tmp_path):
    s, setup, *_ = synthetic_run()
    files = sc.plot_contact({"observer": s, "raw": s}, setup, tmp_path)
    assert [f.name for f in files] == ["contact_fig6_observer.png", "contact_fig7_observer.png",
                                       "contact_fig7_raw.png", "contact_fig8_position.png"]
    for f in files:
        assert f.exists() and f.stat().st_size > 10_000


@pytest.mark.parametrize("structure", imp.STRUCTURES)
def test_compliant_tool_study_reports_each_case(structure):
    res = sc.compliant_tool_study(imp.ImpedanceControllerParameters(structure=structure), t_end=2.0, speed=0.05)
    assert set(res) == {f"{c}/{fb}" for c in ("rigid", "compliant", "compliant_designed")
                        for fb in ("observer", "raw")}
    # rigid tool, and compliant tool with the tool in the LQR model: stable, force as predicted;
    # except the paper's structure with the raw reading on a rigid tool, which chatters at the
    # sampling rate (test_impedance_math.test_paper_structure_with_the_raw_reading_chatters)
    good = ["rigid/observer", "compliant_designed/observer", "compliant_designed/raw"]
    if structure == "paper":
        assert abs(res["rigid/raw"]["F_end"] / res["rigid/raw"]["F_pred"] - 1) > 0.1
    else:
        good.append("rigid/raw")
    for k in good:
        assert_allclose(res[k]["F_end"], res[k]["F_pred"], rtol=0.02)
        assert res[k]["contact_losses"] == 0
        assert res[k]["v_max"] < 1.5 * 0.05
    # compliant tool fed back through a rigid-tool design: the loop oscillates (tool speed
    # far above the 0.05 m/s commanded), which is why the compliance matters
    assert res["compliant/observer"]["v_max"] > 5 * 0.05


def test_one_axis_study_meets_the_targets(tmp_path):
    """The three phases on the one-axis model, observer vs raw reading in the loop."""
    m = sc.run_study_1dof(tmp_path)
    obs, raw = m["observer"], m["raw"]
    assert obs["free_ratio"] <= 0.2
    assert obs["steady_hat_err"] <= 0.02
    assert obs["steady_x_err"] <= 0.05 and obs["steady_F_err"] <= 0.05
    assert obs["contact_losses"] <= raw["contact_losses"]
    assert obs["finite"] and raw["finite"]
    assert (tmp_path / "one_axis_fig8_position.png").exists()

"""ForceObserver and ImpedanceController built and exercised through fmpy."""
from __future__ import annotations


import numpy as np
import pytest
from numpy.testing import assert_allclose

from fmus.common.frames import G
from fmus.force_observer import force_observer_math as fom
from fmus.force_observer import impedance_math as imp
from fmu_host import Slave

M = 12.0
H = 0.004


def sensor_signals(n: int, phi: float = 0.3):
    """Sensor-frame readings (3-vectors, planar x at index 1, z at 3) of a known motion + force."""
    t = np.arange(n) * H
    w = 2 * np.pi * 1.5
    a = np.stack([3 * np.cos(w * t), -2 * np.sin(w * t)], axis=1)
    x = np.stack([1.2 + 3 / w ** 2 * (1 - np.cos(w * t)), 0.9 + 2 / w ** 2 * np.sin(w * t) - 2 / w * t], axis=1)
    F = np.stack([np.where(t > 0.2, 30.0, 0.0), np.where(t > 0.2, -4.0, 0.0)], axis=1)
    R = fom.rotation(phi)
    g = np.array([0.0, -G])
    f_s2 = (R.T @ (M * (a - g) + F).T).T            # F = force on the environment = -f_ext
    acc2 = (R.T @ (a - g).T).T
    to3 = lambda v: np.stack([v[:, 0], np.zeros(len(v)), v[:, 1]], axis=1)
    return t, to3(f_s2), to3(acc2), x, F


@pytest.mark.parametrize("kind", fom.OBSERVER_KINDS)
def test_observer_fmu_matches_math_and_recovers_force(fmu_dir, kind):
    n, phi = 150, 0.3
    t, f_s, acc_s, x, F = sensor_signals(n, phi)
    s = Slave(fmu_dir / "ForceObserver.fmu", {"observer": kind})
    s.init()
    core = fom.ForceObserverCore(fom.ForceObserverParameters(observer=kind, m_tool=M))
    out = np.empty((n, 2))
    for k in range(n):
        s.set(f_s=f_s[k], acc_s=acc_s[k], p_tool=x[k], phi_tool=phi)
        out[k] = s.get("f_contact_hat", 2)
        u, a = fom.world_readings(f_s[k, [0, 2]], acc_s[k, [0, 2]], phi, M)
        assert_allclose(s.get("f_raw", 2), u, atol=1e-9)
        assert_allclose(out[k], core.output(u, a, x[k]), atol=1e-9)
        core.advance(u, a, x[k], H)
        s.step(H)
    assert s.get("fault") == 0.0 and s.get("n_faults") == 0.0
    s.close()
    if kind != "lowpass":
        assert_allclose(out, F, atol=1e-8)
    else:
        assert_allclose(out[-1], F[-1], rtol=0.05)


def test_observer_fmu_flags_nan_and_saturation(fmu_dir):
    s = Slave(fmu_dir / "ForceObserver.fmu", {"observer": "static", "f_range": 200.0})
    s.init()
    good_f, good_a = np.array([10.0, 0.0, 117.72]), np.array([0.0, 0.0, G])
    s.set(f_s=good_f, acc_s=good_a, p_tool=[1.2, 0.9], phi_tool=0.0)
    est = s.get("f_contact_hat", 2)
    assert_allclose(est, [10.0, 0.0], atol=1e-9)
    s.step(H)
    s.set(f_s=[np.nan, 0.0, 117.72])
    assert s.get("fault") == 2.0
    assert_allclose(s.get("f_contact_hat", 2), est)            # held, finite
    s.step(H)
    s.step(H)
    assert s.get("n_faults") == 2.0
    assert sum("not finite" in m for m in s.log) == 1            # one warning per episode
    s.set(f_s=[250.0, 0.0, 117.72])                              # beyond the 200 N range
    assert s.get("fault") == 1.0
    assert np.all(np.isfinite(s.get("f_contact_hat", 2)))
    s.step(H)
    assert any("saturated" in m for m in s.log)
    s.set(f_s=good_f)
    s.step(H)
    assert s.get("fault") == 0.0 and s.get("n_faults") == 3.0
    s.close()


def test_observer_fmu_rejects_unknown_kind(fmu_dir):
    s = Slave(fmu_dir / "ForceObserver.fmu", {"observer": "magic"})
    with pytest.raises(Exception):
        s.init()
    assert any("observer" in m and "magic" in m for m in s.log)
    s.fmu.freeInstance()


@pytest.mark.parametrize("structure", imp.STRUCTURES)
def test_impedance_fmu_matches_math(fmu_dir, structure):
    params = {"K_z": 1500.0, "D_z": 300.0, "q_int": 5.0, "structure": structure, "tool_compliance": 2e-5}
    s = Slave(fmu_dir / "ImpedanceController.fmu", params)
    s.init()
    d = imp.ImpedanceControllerParameters(**params)
    L = imp.design_gains(d)
    assert_allclose(s.get("lqr_gain", 5)[:L.size], L, rtol=1e-12)
    c = imp.force_gain(d, L)
    assert (c != 0.0) == (structure == "paper")
    assert_allclose(s.get("force_gain"), c, rtol=1e-12)
    law = imp.ImpedanceLaw(L, d.K_z, d.D_z, force_gain=c)
    rng = np.random.default_rng(4)
    h_prev = 0.0
    for k in range(100):
        F = np.array([20.0 + rng.normal(), rng.normal()])
        p = np.array([1.5 + 1e-3 * rng.normal(), 0.9])
        pr = np.array([1.51, 0.9])
        s.set(f_contact_hat=F, p_tool=p, p_ref=pr, f_desired=5.0)
        dp = s.get("dp_ref", 2)
        ref = law.output(F[0], p[0], pr[0], 5.0, h_prev)
        assert_allclose(dp, [ref, 0.0], atol=1e-12)
        law.advance(F[0], p[0], pr[0], 5.0, h_prev, H)
        h_prev = H
        s.step(H)
    s.close()


def test_impedance_fmu_holds_on_bad_input(fmu_dir):
    s = Slave(fmu_dir / "ImpedanceController.fmu", {"normal[1]": 0.0, "normal[2]": -2.0})
    s.init()
    for _ in range(20):
        s.set(f_contact_hat=[0.0, 10.0], p_tool=[1.2, 0.9], p_ref=[1.2, 0.89])
        s.step(H)
    dp = s.get("dp_ref", 2)
    assert dp[0] == 0.0 and dp[1] != 0.0                       # along the (normalised) normal only
    assert_allclose(s.get("f_normal"), -10.0)
    s.set(f_contact_hat=[np.nan, 10.0])
    assert s.get("fault") == 1.0
    assert_allclose(s.get("dp_ref", 2), dp)
    s.step(H)
    s.step(H)
    assert_allclose(s.get("dp_ref", 2), dp)
    assert sum("holding dp_ref" in m for m in s.log) == 1
    s.set(f_contact_hat=[0.0, 10.0], force_fault=1.0)
    assert s.get("fault") == 1.0
    s.set(force_fault=0.0)
    s.step(H)
    assert s.get("fault") == 0.0 and np.all(np.isfinite(s.get("dp_ref", 2)))
    s.close()


@pytest.mark.parametrize("use_raw", [False, True])
def test_fmus_close_the_impedance_loop_like_the_math(fmu_dir, use_raw):
    """Observer + controller FMUs on the one-axis plant reproduce the math-only loop."""
    d = imp.ImpedanceControllerParameters()
    plant = imp.OneAxisPlant(x_w=1.30)
    ref = imp.smooth_ramp(1.25, 1.32, 0.1, 1.0)
    obs = Slave(fmu_dir / "ForceObserver.fmu", {"observer": "lowpass"})
    ctl = Slave(fmu_dir / "ImpedanceController.fmu", {})
    obs.init()
    ctl.init()

    def through_fmus(t, u, a, x, xr):
        g = G
        obs.set(f_s=[u, 0.0, M * g], acc_s=[a, 0.0, g], p_tool=[x, 0.9], phi_tool=0.0)
        f_hat = obs.get("f_contact_hat", 2)
        f_fb = obs.get("f_raw", 2) if use_raw else f_hat
        ctl.set(f_contact_hat=f_fb, p_tool=[x, 0.9], p_ref=[xr, 0.9], f_desired=0.0,
                force_fault=obs.get("fault"))
        dp = ctl.get("dp_ref", 2)
        obs.step(H)
        ctl.step(H)
        return float(f_hat[0]), float(dp[0])

    via_fmu = imp.simulate_1dof(plant, d, ref, 2.0, x0=1.25, observer="lowpass", use_raw=use_raw,
                                controller=through_fmus)
    direct = imp.simulate_1dof(plant, d, ref, 2.0, x0=1.25, observer="lowpass", use_raw=use_raw)
    obs.close()
    ctl.close()
    assert_allclose(via_fmu["delta"], direct["delta"], rtol=1e-9, atol=1e-12)
    assert_allclose(via_fmu["F_hat"], direct["F_hat"], rtol=1e-9, atol=1e-9)
    assert via_fmu["F"][-1] > 20.0                     # it did press on the wall


def test_impedance_fmu_with_the_tool_in_the_design_model(fmu_dir):
    """tool_mass > 0: the eq. 39 design (flange and deflection states); the flange is the
    forward kinematics' tool point, the deflection -n.f_mount x tool_compliance."""
    C = 1e-5
    params = {"structure": "paper", "tool_compliance": C, "tool_mass": 12.0, "tool_damping": 600.0}
    s = Slave(fmu_dir / "ImpedanceController.fmu", params)
    s.init()
    d = imp.ImpedanceControllerParameters(**params)
    L = imp.design_gains(d)
    assert L.shape == (4,)
    assert_allclose(s.get("lqr_gain", 5), list(L) + [0.0], rtol=1e-12)
    law = imp.ImpedanceLaw(L, d.K_z, d.D_z, force_gain=imp.force_gain(d, L))
    rng = np.random.default_rng(5)
    h_prev = 0.0
    for k in range(50):
        F = np.array([20.0 + rng.normal(), 0.0])
        fm = np.array([25.0 + rng.normal(), 1.0])
        p = np.array([1.5 + 1e-3 * rng.normal(), 0.9])
        pr = np.array([1.51, 0.9])
        s.set(f_contact_hat=F, p_tool=p, p_ref=pr, f_mount=fm)
        x_tool = p[0] - fm[0] * C
        assert_allclose(s.get("dp_ref", 2), [law.output(F[0], x_tool, pr[0], 0.0, h_prev, p[0]), 0.0],
                        atol=1e-12)
        law.advance(F[0], x_tool, pr[0], 0.0, h_prev, H, p[0])
        h_prev = H
        s.step(H)
    s.close()

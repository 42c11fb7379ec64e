"""LQR impedance design and the closed loop on a one-axis mass/wall model."""
from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from fmus.common.parameters import ParameterError, replace, validate
from fmus.force_observer import impedance_math as imp


@pytest.mark.parametrize("q1,q2,r", [(1.0, 0.0, 1.0), (4.0, 2.0, 0.5), (1e6, 1e2, 4e4)])
def test_lqr_matches_analytic_double_integrator(q1, q2, r):
    """x'' = u, Q = diag(q1, q2), R = r: L = (sqrt(q1/r), sqrt(q2/r + 2 sqrt(q1/r)))."""
    A = np.array([[0.0, 1.0], [0.0, 0.0]])
    B = np.array([[0.0], [1.0]])
    L = imp.lqr_gain(A, B, np.diag([q1, q2]), np.array([[r]]))
    l1 = np.sqrt(q1 / r)
    assert_allclose(L[0], [l1, np.sqrt(q2 / r + 2 * l1)], rtol=1e-9)


def test_lqr_matches_analytic_first_order():
    """x' = a x + b u, q, r: L = (a + sqrt(a^2 + b^2 q / r)) / b."""
    a, b, q, r = 0.5, 2.0, 3.0, 0.7
    L = imp.lqr_gain(np.array([[a]]), np.array([[b]]), np.array([[q]]), np.array([[r]]))
    assert_allclose(L[0, 0], (a + np.sqrt(a * a + b * b * q / r)) / b, rtol=1e-10)


@pytest.mark.parametrize("structure,size", [("paper", 2), ("integral", 3)])
def test_design_stable_from_free_space_to_stiff_contact(structure, size):
    d = imp.ImpedanceControllerParameters(structure=structure)
    L = imp.design_gains(d)
    assert L.shape == (size,)
    for ke in (0.0, 1000.0, 5000.0, 20000.0):
        assert np.all(np.real(imp.closed_loop_poles(d, L, ke)) < 0), ke


def test_unknown_structure_is_rejected():
    with pytest.raises(ParameterError, match="'structure'.*pid"):
        validate(imp.ImpedanceControllerParameters(structure="pid"))


@pytest.mark.parametrize("tool", [{}, {"tool_mass": 12.0, "tool_compliance": 1 / 3e4, "tool_damping": 360.0},
                                  {"tool_compliance": 1 / 3e4}])
def test_paper_force_gain_puts_the_design_models_equilibrium_on_eq2(tool):
    """Closed paper loop on the design model (rigid, compliant, rigid with a known static tool
    compliance): the equilibrium for a wall at the reference's level satisfies eq. 2 on the tool.
    Solved from the state equations directly, not from force_gain's formula."""
    d = imp.ImpedanceControllerParameters(structure="paper", **tool)
    L = imp.design_gains(d)
    c = imp.force_gain(d, L)
    A, B = imp.design_model(d)
    A, B = A[:-1, :-1], B[:-1, 0]
    n = A.shape[0]
    # a constant force F of the surface on the tool: x' = A0 x + B Delta + f F, f the column
    # that k_env multiplies in A (the surface pushes back with k_env times the tool's position)
    f = (imp.design_model(replace(d, k_env=1.0))[0][:-1, :-1] - imp.design_model(
        replace(d, k_env=0.0))[0][:-1, :-1])[:, 0]
    F = 30.0
    # equilibrium of x' = (A0 - B L) x + (f + B c) F with A0 the model without the surface
    A0 = imp.design_model(replace(d, k_env=0.0))[0][:-1, :-1]
    x = np.linalg.solve(A0 - np.outer(B, L), -(f + B * c) * F)
    e_tool = x[0] + (x[2] if n == 4 else -F / d.tool_k if d.tool_k > 0 else 0.0)
    assert_allclose(e_tool, -F / d.K_z, rtol=1e-9)


def test_design_model_equilibrium_is_the_impedance_relation():
    """At an equilibrium of the design model with integral action, z = 0."""
    d = imp.ImpedanceControllerParameters()
    A, B = imp.design_model(d)
    # zeta' = (K_z + k_env) e + D_z e' : the third row of A
    assert_allclose(A[2], [d.K_z + d.k_env, d.D_z, 0.0])
    assert_allclose(B[:, 0], [0.0, d.k_r / d.m_design, 0.0])
    assert_allclose(d.k_r, d.m_design * d.w_r ** 2)


def test_stationary_contact_formula():
    K, kw, xr, xw, Fd = 2000.0, 5000.0, 0.02, 0.0, 3.0
    xs, Fs = imp.stationary_contact(K, kw, xr, xw, Fd)
    # both relations hold: the target impedance and the wall
    assert_allclose(Fs - Fd, K * (xr - xs), rtol=1e-12)
    assert_allclose(Fs, kw * (xs - xw), rtol=1e-12)
    # no contact when the reference (plus bias) stays before the wall
    assert imp.stationary_contact(K, kw, -0.01, 0.0, 0.0) == (-0.01, 0.0)


@pytest.mark.parametrize("use_raw,observer,structure", [(False, "static", "paper"), (False, "lowpass", "paper"),
                                                       (False, "static", "integral"), (True, "static", "integral")])
def test_closed_loop_steady_state_matches_impedance_relation(use_raw, observer, structure):
    d = imp.ImpedanceControllerParameters(structure=structure)
    plant = imp.OneAxisPlant()
    xr = imp.smooth_ramp(-0.05, 0.02, 0.1, 1.0)
    # low-pass observer with well-damped gains (1 Hz, zeta 0.7); the paper's settle in ~15 s
    cfg = imp.fom.ForceObserverParameters(observer=observer, m_tool=plant.m_t, k11=8.8, k21=39.5)
    out = imp.simulate_1dof(plant, d, xr, 3.0, obs_cfg=cfg, use_raw=use_raw, F_d=4.0)
    xs, Fs = imp.stationary_contact(d.K_z, plant.k_w, 0.02, plant.x_w, 4.0)
    assert_allclose(out["F"][-1], Fs, rtol=0.01)
    assert_allclose(out["x"][-1], xs, rtol=0.01)
    assert_allclose(out["F_hat"][-1], out["F"][-1], rtol=0.01)


def test_integral_action_enforces_impedance_despite_model_errors():
    """A plant unlike the design model (mass, bandwidth, wall): same stationary impedance with
    the integral; the paper's structure (no integral) misses it by the design model's error."""
    d = imp.ImpedanceControllerParameters(structure="integral")
    plant = imp.OneAxisPlant(m_r=100.0, w_r=2 * np.pi * 4.0, k_w=9000.0, x_w=0.01)
    xr = imp.smooth_ramp(-0.05, 0.03, 0.1, 1.0)
    out = imp.simulate_1dof(plant, d, xr, 3.0, observer="static")
    xs, Fs = imp.stationary_contact(d.K_z, plant.k_w, 0.03, plant.x_w)
    assert_allclose(out["F"][-1], Fs, rtol=0.01)
    # the paper's structure: at rest e = Delta - F / k_r(plant), Delta = -L_0 e + c F, so
    # (1 + L_0) e = (c - 1/k_r) F with F = k_w (x_r + e - x_w): off eq. 2 by the design's k_r error
    dp = replace(d, structure="paper")
    L = imp.design_gains(dp)
    g = (imp.force_gain(dp, L) - 1.0 / (plant.m_r * plant.w_r ** 2)) / (1.0 + L[0])
    F_paper = plant.k_w * (0.03 - plant.x_w) / (1.0 - plant.k_w * g)
    out0 = imp.simulate_1dof(plant, dp, xr, 3.0, observer="static")
    assert_allclose(out0["F"][-1], F_paper, rtol=1e-4)
    assert abs(F_paper - Fs) > 1e-3 * Fs


def test_paper_structure_with_the_raw_reading_chatters():
    """The raw reading carries m_t a: through the paper's force gain c it feeds the tool's
    acceleration back (an added mass c m_t k_r, about 4x the robot's, one sample late) and the
    loop chatters at the sampling rate, bounded only by the one-sided wall; the observer's
    estimate does not."""
    d = imp.ImpedanceControllerParameters(structure="paper")
    plant = imp.OneAxisPlant()
    xr = imp.smooth_ramp(-0.05, 0.02, 0.1, 1.0)
    last = slice(-250, None)
    raw = imp.simulate_1dof(plant, d, xr, 4.0, use_raw=True)
    obs = imp.simulate_1dof(plant, d, xr, 4.0, use_raw=False)
    assert np.std(raw["a"][last]) > 1.0
    assert np.std(obs["a"][last]) < 1e-6


def test_free_space_tracks_reference():
    d = imp.ImpedanceControllerParameters()
    plant = imp.OneAxisPlant(x_w=1.0)          # wall far away
    xr = imp.smooth_ramp(-0.05, 0.02, 0.1, 1.0)
    out = imp.simulate_1dof(plant, d, xr, 2.5, observer="static")
    assert np.all(out["F"] == 0.0)
    assert abs(out["x"][-1] - 0.02) < 1e-4


def test_anti_windup_stops_integration_at_the_limit():
    law = imp.ImpedanceLaw(np.array([1.0, 0.0, 0.01]), K_z=1000.0, D_z=0.0, delta_max=0.001)
    h = 0.004
    for k in range(500):       # a large force error pushes Delta into its limit
        law.output(500.0, 0.0, 0.0, 0.0, h if k else 0.0)
        law.advance(500.0, 0.0, 0.0, 0.0, h if k else 0.0, h)
    assert law.saturated
    assert abs(law.output(500.0, 0.0, 0.0, 0.0, h)) == pytest.approx(0.001)
    # the first step (h z = 2 N.s) reached the limit; integration stopped there (not 500 * 2 N.s)
    assert law.zeta == pytest.approx(2.0)
    # a force error of the other sign integrates again
    law.advance(-500.0, 0.0, 0.0, 0.0, h, h)
    assert law.zeta == pytest.approx(0.0, abs=1e-12)


def test_compliant_tool_keeps_eq1_identity():
    """Mass on spring-damper (the paper's Optidrive): the sensor still reads F + m_t a_tool."""
    d = imp.ImpedanceControllerParameters(tool_mass=12.0, tool_compliance=1 / 3e4, tool_damping=360.0)     # tool in the LQR model
    plant = imp.OneAxisPlant(compliant=True, k_c=3e4, d_c=360.0)
    xr = imp.smooth_ramp(-0.05, 0.02, 0.1, 1.5)
    out = imp.simulate_1dof(plant, d, xr, 4.0, observer="static")
    assert_allclose(out["u"], out["F"] + plant.m_t * out["a"], atol=1e-9)
    assert_allclose(out["F_hat"], out["F"], atol=1e-9)
    xs, Fs = imp.stationary_contact(d.K_z, plant.k_w, 0.02, plant.x_w)
    assert_allclose(out["F"][-1], Fs, rtol=0.01)


@pytest.mark.parametrize("structure,size", [("paper", 4), ("integral", 5)])
def test_compliant_tool_design_is_stable_and_needs_the_flange(structure, size):
    d = imp.ImpedanceControllerParameters(tool_mass=12.0, tool_compliance=1 / 3e4, tool_damping=360.0, structure=structure)
    assert d.compliant
    L = imp.design_gains(d)
    assert L.shape == (size,)
    for ke in (0.0, 5000.0, 20000.0):
        stable = np.all(np.real(imp.closed_loop_poles(d, L, ke)) < 0)
        # the paper's force gain c sits outside the LQR: on a surface four times stiffer than
        # designed for, c k_env destabilises the tool mode (poles +10.9 +- 68j)
        assert stable == (structure == "integral" or ke <= 5000.0), ke
    law = imp.ImpedanceLaw(L, d.K_z, d.D_z, force_gain=imp.force_gain(d, L))
    with pytest.raises(ValueError, match="flange"):
        law.output(0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="compliant-tool plant"):
        imp.simulate_1dof(imp.OneAxisPlant(), d, imp.smooth_ramp(0, 0, 0, 1), 0.1)


def test_compliant_design_model_matches_rigid_limit():
    """A very stiff tool spring: the 5-state model's slow poles approach the rigid model's."""
    d_rigid = imp.ImpedanceControllerParameters()
    d_stiff = replace(d_rigid, tool_mass=12.0, tool_compliance=1e-9, tool_damping=1e3)
    A3, _ = imp.design_model(d_rigid)
    A5, _ = imp.design_model(d_stiff)
    slow5 = np.sort_complex(np.linalg.eigvals(A5))
    slow5 = slow5[np.abs(slow5) < 1e3]
    assert_allclose(np.sort_complex(slow5), np.sort_complex(np.linalg.eigvals(A3)), rtol=1e-2, atol=1e-6)

"""The six-axis plant's compiled kernel (fmus/robot_plant/six_axis_kernels.pyx) against its
numpy oracle (tests/six_axis_reference.py, the readable form it was written from): the right
side, the RK4 trajectory over thousands of steps at several poses with each realism switch on and
off, the outputs (tool pose, velocities, accelerations, sensor point), and bad input.

Round-off budget of a trajectory: the two right sides are the same operations in different
summation orders (numpy's matrix products and LAPACK's solve against the kernel's loops and
Cholesky), measured to differ by up to 1e-13 of the largest component. On a smooth, damped
trajectory RK4 carries these forward without growing them: after N steps about N x 1e-13 of each
state component's scale, 1e-9 after 2000 steps at most with margin (measured 1e-12). Where the
Bouc-Wen element and the friction reverse, the trajectory itself amplifies any round-off: the
same kernel started 1e-13 relative apart ends up to 4.5e-9 apart; there the test measures this
sensitivity in the same run and allows ten times it (:func:`within_round_off`)."""
from __future__ import annotations

import math

import numpy as np
import pytest

import six_axis_reference as ref
from fmus.common import quaternion
from fmus.common.parameters import replace
from fmus.robot_plant.six_axis_model import OUTPUTS, SixAxisParameters, SixAxisPlant, kernels

P = SixAxisParameters()
DT = 1e-3
OFF = dict(foundation_tilt=False, arm_bending=False, hysteresis=False, friction_realism=False,
           ripple_amplitude=(0.0,) * 6, torque_constant_error=(0.0,) * 6, current_bandwidth=0.0)
POSES = [P.q0, (0.5, -0.5, 0.3, 1.0, -1.0, 0.5), (2.0, 0.2, -1.5, -1.5, 0.5, 2.0)]


def _scale(traj: np.ndarray) -> np.ndarray:
    """Each state component's scale over a trajectory: its largest magnitude (each its own:
    passive angles ~1e-5 rad beside arm angles ~1 rad)."""
    return np.maximum(np.abs(traj).max(axis=0), 1e-12)


def _pd(m: SixAxisPlant, x: np.ndarray, k: int, qm_ref: np.ndarray, hold: np.ndarray) -> tuple:
    """A weak motor-side PD around the holding torque with a torque varying step by step, and
    a 10 ms tool blow from step 50: ``(tau_m, wrench or None)`` at step ``k`` and state ``x``."""
    n = m.n
    kp = 2.0 * m.J_m / m.J_m[1]
    tau = hold + kp * (qm_ref - x[n:n + 6]) - 0.05 * kp * x[2 * n + 6:2 * n + 12] \
        + np.array([0.5, 1.0, -1.0, 0.2, 0.2, 0.1]) * math.sin(7 * k * DT)
    return tau, (np.array([400.0, -300.0, 200.0, 5.0, 0.0, -5.0]) if 50 <= k < 60 else None)


def run_both(p: SixAxisParameters, steps: int) -> tuple[float, float, float]:
    """The kernel's and the oracle's trajectories from the plant ``p``'s rest state under
    :func:`_pd`: the largest state difference relative to each component's scale, the arm's
    travel [rad], and the trajectory's own sensitivity to round-off: the largest relative
    difference between the kernel's run and the kernel's again from a start perturbed by 1e-13
    relative (random)."""
    m, again = SixAxisPlant(p), SixAxisPlant(p)
    again.x = again.x * (1.0 + 1e-13 * np.random.default_rng(0).standard_normal(again.size))
    dyn = ref.RigidBodyDynamics(m.tree)
    s = m.substeps_for(DT)
    n = m.n
    x, cur = m.x.copy(), m.current.copy()
    qm_ref, hold = x[n:n + 6].copy(), m.current.copy()
    mine, theirs, perturbed = [], [], []
    for k in range(steps):
        tau, w = _pd(m, m.x, k, qm_ref, hold)
        m.step(tau, w, DT)
        x, cur = ref.step(m, dyn, x, cur, tau, w, DT, s)
        again.step(*_pd(again, again.x, k, qm_ref, hold), DT)
        mine.append(m.x.copy())
        theirs.append(x.copy())
        perturbed.append(again.x.copy())
    a, b, c = np.array(mine), np.array(theirs), np.array(perturbed)
    scale = _scale(b)
    assert np.all(np.isfinite(a))
    return (float((np.abs(a - b) / scale).max()), float(np.abs(b[:, m.act] - b[0, m.act]).max()),
            float((np.abs(c - a) / scale).max()))


def within_round_off(diff: float, sensitivity: float) -> bool:
    """Whether the kernel-oracle difference ``diff`` is round-off: under the plain budget (module
    docstring, 1e-9) or under ten times the trajectory's ``sensitivity`` to a 1e-13 perturbation
    of its start (the Bouc-Wen element's and the friction's reversals make some trajectories
    amplify round-off: measured 4.5e-9 from 1e-13 at the third pose; the oracle's differences
    enter at every step, not once: the factor ten)."""
    return diff < max(1e-9, 10.0 * sensitivity)


def test_the_right_side_equals_the_oracle() -> None:
    """Random states, currents and wrenches, every switch on and all off: the kernel's ``x_dot``
    equals the oracle's to the round-off of the two summation orders (1e-12 of the largest
    component: ~1e3 N m torques through 12 bodies' sums and a solve with M's condition ~1e5,
    each ~1e-16 relative; measured 9e-14)."""
    rng = np.random.default_rng(5)
    worst = 0.0
    for p in (P, replace(P, **OFF), replace(P, locked=(True, False, False, True, False, False))):
        m = SixAxisPlant(p)
        dyn = ref.RigidBodyDynamics(m.tree)
        for _ in range(10):
            x = m.x + rng.normal(0.0, 1e-2, m.size)
            c, w = rng.normal(0.0, 3.0, 6), rng.normal(0.0, 100.0, 6)
            a, b = m.derivatives(x, c, w), ref.derivatives(m, dyn, x, c, w)
            worst = max(worst, np.abs(a - b).max() / np.abs(b).max())
            assert np.abs(a - b).max() < 1e-12 * np.abs(b).max()
    print(f"largest difference {worst:.1e} of the largest component")


@pytest.mark.parametrize("switches", ["all on", "all off"])
def test_the_trajectory_equals_the_oracle(switches) -> None:
    """At ``q0``, 500 steps (a blow, a varying torque), every switch on (the defaults) or all off:
    the kernel's and the oracle's states agree to round-off (:func:`within_round_off`)."""
    p = P if switches == "all on" else replace(P, **OFF)
    diff, travel, sens = run_both(p, 500)
    print(f"{switches}: largest state difference {diff:.1e} of its scale (sensitivity {sens:.1e}), "
          f"travel {travel:.3f} rad")
    assert travel > 1e-3
    assert within_round_off(diff, sens)


SWITCHES = {"defaults": {}, "ideal": dict(ideal=True), "all off": OFF,
            "no tilt": dict(foundation_tilt=False), "no bending": dict(arm_bending=False),
            "no hysteresis": dict(hysteresis=False), "no friction realism": dict(friction_realism=False),
            "no ripple": dict(ripple_amplitude=(0.0,) * 6), "no torque-constant error": dict(torque_constant_error=(0.0,) * 6),
            "no current loop": dict(current_bandwidth=0.0),
            "axes 1, 4-6 locked": dict(locked=(True, False, False, True, True, True))}


@pytest.mark.slow
@pytest.mark.parametrize("pose", range(len(POSES)))
@pytest.mark.parametrize("switch", list(SWITCHES))
def test_the_trajectory_equals_the_oracle_everywhere(pose, switch) -> None:
    """Three poses, each switch off in turn (and all on, all off, ``ideal``, locked axes), 2000
    steps: round-off (:func:`within_round_off`)."""
    diff, travel, sens = run_both(replace(P, q0=POSES[pose], **SWITCHES[switch]), 2000)
    print(f"pose {pose}, {switch}: largest state difference {diff:.1e} of its scale (sensitivity {sens:.1e}), "
          f"travel {travel:.3f} rad")
    assert travel > 1e-3
    assert within_round_off(diff, sens)


def test_the_outputs_are_the_states_kinematics() -> None:
    """Moving, struck, at random states near rest: the kernel's outputs against the oracle's
    kinematics (tool and sensor points 1e-14 m, the quaternion against
    fmus.common.quaternion.from_matrix 1e-15) and against central differences along ``x_dot``
    (velocities from positions, accelerations without gravity from velocities, the angular
    velocity from the rotation: step 1e-6 s, error ~(1e-6 s)^2 x third derivative ~1e4 plus
    round-off 1e-16 / 1e-6: 1e-6 relative); arm and motor angles and rates are the state's, the
    gearbox torque the oracle's."""
    m = SixAxisPlant(P)
    dyn = ref.RigidBodyDynamics(m.tree)
    names = [nm for nm, _ in OUTPUTS]
    at = np.cumsum([0] + [k for _, k in OUTPUTS])
    sensor = np.array([P.sensor_offset[0], 0.0, P.sensor_offset[1]])
    rng = np.random.default_rng(2)
    for _ in range(5):
        x = m.x + rng.normal(0.0, 1e-3, m.size)
        x[m.n + 6:] += rng.normal(0.0, 0.5, m.size - m.n - 6)
        c, w = m.current + rng.normal(0.0, 2.0, 6), rng.normal(0.0, 200.0, 6)
        y = m.outputs(x, c, w)
        out = {nm: y[at[i]:at[i + 1]] for i, nm in enumerate(names)}
        q, qm, dq, dqm, z = m.split(x)
        assert np.array_equal(out["q_m"], qm) and np.array_equal(out["dq_m"], dqm)
        assert np.array_equal(out["q_a"], q[m.act]) and np.array_equal(out["dq_a"], dq[m.act])
        D, Dd = qm / m.r - q[m.act], dqm / m.r - dq[m.act]
        tau_s = m.k_hi * D - m.k_soft * m.delta * np.tanh(D / m.delta) + m.d * Dd + m.k_h * z
        assert np.abs(out["tau_s"] - tau_s).max() < 1e-12 * np.abs(tau_s).max()
        k = dyn.kinematics(q)
        R, o = k["R"][m.tree.tool], k["o"][m.tree.tool]
        assert np.abs(out["p_tool"] - (o + R @ m.tree.tcp)).max() < 1e-14
        assert np.abs(out["p_sensor"] - (o + R @ (m.tree.tcp + sensor))).max() < 1e-14
        assert np.abs(out["quat_tool"] - quaternion.from_matrix(R)).max() < 1e-15
        xd = ref.derivatives(m, dyn, x, c, w)
        h = 1e-6

        def at_(xx):
            return m.outputs(xx, c, w)

        yp, ym = at_(x + h * xd), at_(x - h * xd)
        for pos, vel in (("p_tool", "v_tool"),):
            fd = (yp[at[names.index(pos)]:at[names.index(pos) + 1]] - ym[at[names.index(pos)]:at[names.index(pos) + 1]]) / (2 * h)
            assert np.abs(out[vel] - fd).max() < 1e-6 * max(1.0, np.abs(fd).max())
        for vel, acc in (("v_tool", "a_tool"),):
            # the velocity depends on x only: its rate along x_dot is the acceleration
            fd = (yp[at[names.index(vel)]:at[names.index(vel) + 1]] - ym[at[names.index(vel)]:at[names.index(vel) + 1]]) / (2 * h)
            assert np.abs(out[acc] - fd).max() < 1e-6 * max(1.0, np.abs(fd).max())
        # the sensor point's velocity (from its position), then its acceleration
        i_ps = at[names.index("p_sensor")]

        def v_sensor(xx):
            xdd = ref.derivatives(m, dyn, xx, c, w)
            return (at_(xx + h * xdd)[i_ps:i_ps + 3] - at_(xx - h * xdd)[i_ps:i_ps + 3]) / (2 * h)

        hh = 1e-4                   # nested differences: a larger outer step (error ~1e-8 x 1e4)
        fd = (v_sensor(x + hh * xd) - v_sensor(x - hh * xd)) / (2 * hh)
        assert np.abs(out["a_sensor"] - fd).max() < 1e-4 * max(1.0, np.abs(fd).max())
        # angular velocity: dR/dt R^T = [omega]x
        Rp = dyn.kinematics(m.split(x + h * xd)[0])["R"][m.tree.tool]
        Rm = dyn.kinematics(m.split(x - h * xd)[0])["R"][m.tree.tool]
        W = (Rp - Rm) / (2 * h) @ R.T
        assert np.abs(out["omega_tool"] - [W[2, 1], W[0, 2], W[1, 0]]).max() < 1e-6 * max(1.0, np.abs(W).max())


def test_the_outputs_table_is_the_kernels() -> None:
    """The model's output layout (what the FMU adapter scatters) is the kernel's."""
    assert OUTPUTS == kernels().OUTPUTS


def test_bad_arrays_are_refused() -> None:
    m = SixAxisPlant(P)
    with pytest.raises(ValueError, match="state of 42 values"):
        m.kernel.derivatives(np.zeros(41), np.zeros(6), np.zeros(6), np.zeros(42))
    with pytest.raises(ValueError, match="6 values"):
        m.kernel.step(m.x.copy(), np.zeros(5), np.zeros(6), np.zeros(6), DT, 2)
    with pytest.raises(TypeError, match="missing"):
        kernels().Plant(n=3)

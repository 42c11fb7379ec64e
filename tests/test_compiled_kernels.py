"""The Cython kernels (fmus/**/*_kernels.pyx) against their readable Python forms
(tests/kernel_oracles.py), bit for bit: on states of realistic runs and on random states,
constants and inputs; their argument checks; the sensors' work-array layout named alike on both
sides.

Bit for bit, not to a tolerance: the oracle is the kernel's operations in the same order on
IEEE doubles, and the kernels are compiled without contraction into fused multiply-adds
(fmus/common/cython_kernels.py), so any difference is a changed operation.
"""
from __future__ import annotations

import copy
import struct

import numpy as np
import pytest

import kernel_oracles as oracle
from fmus.common import cython_kernels, dynamics
from fmus.common.robot_params import RobotParameters
from fmus.estimators import rigid_kinematics_model
from fmus.robot_plant import plant_dynamics, sensor_model, tracker_model
from fmus.robot_plant.plant_model import PlantParameters

plant = cython_kernels.load("robot_plant.plant_kernels")
arm = cython_kernels.load("common.dynamics_kernels")
sensors = cython_kernels.load("robot_plant.sensor_kernels")
tracker = cython_kernels.load("robot_plant.tracker_kernels")
rigid = cython_kernels.load("estimators.rigid_kinematics_kernels")


def _bits(value):
    """``value`` (floats, arrays, tuples of them) in a form equal only when bit for bit equal."""
    if isinstance(value, np.ndarray):
        return value.dtype.str, value.shape, value.tobytes()
    if isinstance(value, (tuple, list)):
        return tuple(_bits(v) for v in value)
    if isinstance(value, (float, np.floating)):
        return struct.pack("<d", value)
    return type(value).__name__, value


def _states(start: tuple, step, scale: np.ndarray, rng: np.random.Generator, n_run: int = 40,
            n_random: int = 40) -> list[tuple]:
    """States of a run from ``start`` (``step(s, tau1, tau2)``: the next), then random states
    about its end (``scale``: the spread of each coordinate)."""
    states = [start]
    for _ in range(n_run):
        states.append(step(states[-1], float(rng.normal(3.0, 5.0)), float(rng.normal(1.0, 5.0))))
    end = np.array(states[-1])
    states += [tuple(map(float, end + rng.normal(0.0, 1.0, end.size) * scale)) for _ in range(n_random)]
    return states


@pytest.mark.parametrize("variant", ["default", "substeps3", "perturbed"])
def test_the_plant_chain_is_its_python_form(variant):
    rng = np.random.default_rng(["default", "substeps3", "perturbed"].index(variant))
    p = PlantParameters(**({"substeps": 3} if variant == "substeps3" else {}))
    P = plant_dynamics.PlantChain(p).P
    if variant == "perturbed":
        P = P * rng.uniform(0.7, 1.3, P.size)
    start = tuple(plant_dynamics.plant_model(p).state)
    states = _states(start, lambda s, t1, t2: plant.chain4_step(s, t1, t2, 0.0, 0.0, 1e-3, p.substeps, P),
                     np.r_[0.3 * np.ones(6), 10.0 * np.ones(6)], rng)
    for s in states:
        t1, t2, fx, fz = map(float, rng.normal(0.0, 20.0, 4))
        sub = int(rng.integers(1, 4))
        assert _bits(plant.chain4_arm(s, fx, fz, P)) == _bits(oracle.chain4_arm(s, fx, fz, P))
        assert _bits(plant.chain4_rates(s, t1, t2, fx, fz, P)) == _bits(oracle.chain4_rates(s, t1, t2, fx, fz, P))
        assert (_bits(plant.chain4_step(s, t1, t2, fx, fz, 1e-3, sub, P))
                == _bits(oracle.chain4_step(s, t1, t2, fx, fz, 1e-3, sub, P)))
        assert _bits(plant.chain4_outputs(s, fx, fz, P)) == _bits(oracle.chain4_outputs(s, fx, fz, P))
        at = rng.permutation(40)[:26].astype(np.int64)
        at[rng.random(26) < 0.2] = -1
        out, expected = np.full(40, np.nan), np.full(40, np.nan)
        tau, f = np.array([t1, t2]), np.array([fx, fz])
        assert (_bits(plant.chain4_advance(s, tau, f, 1e-3, sub, P, out, at))
                == _bits(oracle.chain4_advance(s, tau, f, 1e-3, sub, P, expected, at)))
        assert _bits(out) == _bits(expected)
    assert np.ptp(np.array(states)[:, 0]) > 1e-4           # the run moved the arm


@pytest.mark.parametrize("perturbed", [False, True])
def test_the_flexible_joint_model_is_its_python_form(perturbed):
    rng = np.random.default_rng(7 + perturbed)
    K = dynamics.ArmConstants(RobotParameters()).packed
    if perturbed:
        K = K * rng.uniform(0.7, 1.3, K.size)
    start = dynamics.FlexibleRobotModel(RobotParameters(), (0.3, -0.2)).state
    states = _states(start, lambda s, t1, t2: arm.flex_step(s, t1, t2, 0.0, 0.0, 1e-3, 1, K),
                     np.r_[0.3 * np.ones(4), 10.0 * np.ones(4)], rng)
    for s in states:
        t1, t2, fx, fz = map(float, rng.normal(0.0, 20.0, 4))
        sub = int(rng.integers(1, 4))
        assert _bits(arm.flex_rates(s, t1, t2, fx, fz, K)) == _bits(oracle.flex_rates(s, t1, t2, fx, fz, K))
        assert (_bits(arm.flex_step(s, t1, t2, fx, fz, 1e-3, sub, K))
                == _bits(oracle.flex_step(s, t1, t2, fx, fz, 1e-3, sub, K)))
        for i in range(2):
            D = float(rng.normal(0.0, 0.02))
            assert (_bits(arm.spring_scalar(K[9 + i], K[11 + i], K[13 + i], D))
                    == _bits(oracle.spring_scalar(K[9 + i], K[11 + i], K[13 + i], D)))


def _run_channels(kernel, step, n: int, runs: int, kw: dict, rng: np.random.Generator) -> list:
    """A SensorChannels of ``kw`` stepped 300 times (inputs of one run for every run when
    ``runs > 1``) with the kernels ``kernel`` and ``step``: its work array and reading after each."""
    ch = sensor_model.SensorChannels(n, **kw)
    ch._prepare(1e-3)
    size = runs * n
    ch._work = np.concatenate([ch._work[:sensor_model._TABLE + 6 * n], np.zeros(4 * size)])
    ch._rows = np.random.default_rng(1).normal(size=(64, 2 * size))
    out = np.zeros(size)
    x = rng.normal(0.0, 1.0, n)
    kernel(x, ch._work, out, ch._rows, 0, 0, False, True, False)
    seen = [(ch._work.copy(), out.copy())]
    for k in range(300):
        x = x + rng.normal(0.0, 0.1, n)
        if ch._work[sensor_model._ROW] == len(ch._rows):
            ch._work[sensor_model._ROW] = 0.0
        seen.append((step(x, ch._work, out, ch._rows), ch._work.copy(), out.copy()))
    return seen


@pytest.mark.parametrize("trial", range(6))
def test_the_sensor_channels_are_their_python_form(trial):
    rng = np.random.default_rng(100 + trial)
    n, runs = int(rng.integers(1, 4)), (1, 1, 3)[trial % 3]
    kw = dict(noise=rng.uniform(0.0, 0.1, n), bias=rng.normal(0.0, 0.1, n), bias_rw=rng.uniform(0.0, 0.05, n),
              scale=rng.normal(0.0, 0.01, n), resolution=rng.choice([0.0, 1e-3, 0.05], n),
              range=rng.choice([np.inf, 0.5, 3.0], n), sample_rate=(0.0, 250.0, 100.0)[trial % 3],
              cutoff=(0.0, 20.0, 150.0)[trial // 2], filter_order=1 + trial % 2)
    compiled = _run_channels(sensors.channels_kernel, sensors.channels_step, n, runs, kw, np.random.default_rng(trial))
    python = _run_channels(oracle.channels_kernel, oracle.channels_step, n, runs, kw, np.random.default_rng(trial))
    assert _bits(compiled) == _bits(python)
    assert len({c[0] for c in compiled[1:]}) > 1 if kw["sample_rate"] else True   # held and sampled steps


def test_the_imu_reading_is_its_python_form():
    rng = np.random.default_rng(3)
    for _ in range(300):
        a, (phi, omega) = rng.normal(0.0, 10.0, 2), map(float, rng.normal(0.0, 2.0, 2))
        mount = sensor_model.mount_matrix(tuple(rng.normal(0.0, 0.3, 3)))
        got, expected = (np.empty(3), np.empty(3)), (np.empty(3), np.empty(3))
        sensors.imu_reading_into(a, phi, omega, mount, 9.81, *got)
        oracle.imu_reading_into(a, phi, omega, mount, 9.81, *expected)
        assert _bits(got) == _bits(expected)


def test_the_sensor_work_array_has_one_layout():
    """sensor_model's names of the work array's parts, the kernels' and the oracle's: one layout."""
    names = ["COUNT", "PERIOD", "ROW", "STARTED", "ORDER", "N", "COEF", "TABLE", "GAIN", "BIAS", "RW", "NOISE",
             "RES", "LIM", "HELD", "SAMPLED", "USED_UP"]
    assert sensors.LAYOUT == {k: getattr(sensor_model, "_" + k) for k in names}
    assert sensors.LAYOUT == {k: getattr(oracle, "_" + k) for k in names}


def _run_tracker(update, trial: int) -> list:
    """A TrackerModel of trial ``trial``'s settings (positions in 2-D for trials 0-5, in 3-D for
    6-8) updated 400 times at irregular instants through ``update`` (its kernel): the return,
    state, history and sample after each call."""
    rng = np.random.default_rng(200 + trial)
    dims = 2 if trial < 6 else 3
    model = tracker_model.TrackerModel(noise=(0.0, 1e-5, 1e-3)[trial % 3], sample_rate=(1000.0, 300.0, 77.0)[trial % 3],
                                       skew=(0.0, 3.3e-3, 0.02)[trial // 2 % 3], seed=trial, dims=dims)
    seen = []

    def recording(*args):
        done = update(*args)
        seen.append((done, args[3].copy(), args[4].copy(), args[7].copy()))
        return done
    tracker_model.tracker_update, saved = recording, tracker_model.tracker_update
    try:
        t, p = 0.0, np.array([1.0, 0.5, -0.2][:dims])
        model.start(0.0021, p)
        for _ in range(400):
            t += float(rng.choice([1e-3, 5e-4, 2e-3]))
            p = p + rng.normal(0.0, 1e-3, dims)
            model.update(t, p)
    finally:
        tracker_model.tracker_update = saved
    return seen


@pytest.mark.parametrize("trial", range(9))
def test_the_tracker_is_its_python_form(trial):
    compiled, python = _run_tracker(tracker.tracker_update, trial), _run_tracker(oracle.tracker_update, trial)
    assert _bits(compiled) == _bits(python)
    assert len({c[3].tobytes() for c in compiled}) > 10     # samples were taken


def test_the_tracker_state_has_one_layout():
    names = ["ENTRIES", "NEXT", "T_MEAS", "ROW", "DONE", "FULL", "DRAWN"]
    assert tracker.LAYOUT == {k: getattr(tracker_model, "_" + k) for k in names}
    assert tracker.LAYOUT == {k: getattr(oracle, "_TRACKER_" + k) for k in names}


@pytest.mark.parametrize("perturbed", [False, True])
def test_the_spring_inverse_gravity_and_rigid_baseline_are_their_python_forms(perturbed):
    rng = np.random.default_rng(300 + perturbed)
    robot = RobotParameters()
    K = dynamics.ArmConstants(robot).static * (rng.uniform(0.5, 1.5, 8) if perturbed else 1.0)
    for _ in range(300):
        q1, q2 = map(float, rng.uniform(-2.0, 2.0, 2))
        assert _bits(dynamics.gravity_torques(K[0], K[1], q1, q2)) == _bits(oracle.gravity_torques(K[0], K[1], q1, q2))
        tau, D, guess = float(rng.normal(0.0, 300.0)), float(rng.normal(0.0, 0.01)), bool(rng.integers(2))
        assert (_bits(dynamics.spring_inverse(K[2], K[4], K[6], tau, D, guess))
                == _bits(oracle.spring_inverse(K[2], K[4], K[6], tau, D, guess)))
        assert _bits(rigid.compensated(q1, q2, K)) == _bits(oracle.compensated(q1, q2, K))
    consts = rigid_kinematics_model.constants(robot, gravity_compensation=perturbed)
    samples, expected_samples, out, expected = np.zeros(7), np.zeros(7), np.zeros(9), np.zeros(9)
    t, q_m = 0.0, np.array([30.0, -20.0])
    for step in range(300):
        now = step * 1e-3
        if step % int(rng.integers(1, 4)) == 0:                   # a new sample, late or not
            t, q_m = max(t, now - float(rng.choice([0.0, 1e-3, 2e-3]))), q_m + rng.normal(0.0, 0.1, 2)
        first = int(rng.integers(0, 6))
        assert (_bits(rigid.estimate(q_m, t, now, consts, samples, out, first))
                == _bits(oracle.estimate(q_m, t, now, consts, expected_samples, expected, first)))
        assert _bits((samples, out)) == _bits((expected_samples, expected))
    assert rigid.TIME_TOL == oracle.TIME_TOL


def test_wrong_arguments_raise_instead_of_reading_past_an_array():
    P = plant_dynamics.PlantChain(PlantParameters()).P
    s = tuple(plant_dynamics.plant_model(PlantParameters()).state)
    tau, f, out, at = np.zeros(2), np.zeros(2), np.zeros(30), np.arange(26, dtype=np.int64)
    with pytest.raises(ValueError, match="P: at least 51 values are needed, not 50"):
        plant.chain4_step(s, 0.0, 0.0, 0.0, 0.0, 1e-3, 1, P[:50])
    with pytest.raises(ValueError, match="12 floats, not 11"):
        plant.chain4_outputs(s[:11], 0.0, 0.0, P)
    with pytest.raises(TypeError, match="at: a 1-dimensional array of int64"):
        plant.chain4_advance(s, tau, f, 1e-3, 1, P, out, at.astype(float))
    with pytest.raises(IndexError, match="output index 20 beyond the 20 outputs"):
        plant.chain4_advance(s, tau, f, 1e-3, 1, P, out[:20], at + 4)
    with pytest.raises(TypeError, match="out: a C-contiguous writable array"):
        plant.chain4_advance(s, tau, f, 1e-3, 1, P, out[::2], at)
    with pytest.raises(ValueError, match="tau: at least 2 values"):
        plant.chain4_advance(s, tau[:1], f, 1e-3, 1, P, out, at)
    K = dynamics.ArmConstants(RobotParameters()).packed
    with pytest.raises(ValueError, match="K: at least 25 values are needed, not 24"):
        arm.flex_rates((0.0,) * 8, 0.0, 0.0, 0.0, 0.0, K[:24])
    ch = sensor_model.SensorChannels(2, noise=0.1)
    ch.step(np.zeros(2), 1e-3)
    with pytest.raises(IndexError, match="no row 5 of 4 random numbers"):
        work = ch._work.copy()
        work[sensor_model._ROW], work[sensor_model._COUNT] = 5.0, 0.0
        sensors.channels_step(np.zeros(2), work, np.zeros(2), ch._rows[:5])
    with pytest.raises(ValueError, match="work array does not fit"):
        sensors.channels_step(np.zeros(2), ch._work[:-1], np.zeros(2), ch._rows)

"""The ParticleFilter FMU built, validated and exercised through fmpy, against the plain model."""
from __future__ import annotations

from pathlib import Path

import fmpy
import numpy as np
import pytest
from fmpy import read_model_description
from numpy.testing import assert_array_equal

from fmus.common import kinematics
from fmus.common.frames import G
from fmus.common.parameters import validate
from fmus.estimators import particle_filter_model as pm
from fmu_host import Slave
from test_particle_filter_model import signals_from_rest

T = 0.01


@pytest.fixture(scope="session")
def fmu(every_fmu: dict[str, Path]) -> Path:
    return every_fmu["ParticleFilter"]


def _acc3(f: np.ndarray, p: pm.ParticleFilterParameters) -> np.ndarray:
    """Accelerometer (x, z) readings as 3-vectors with x at ``index_x`` and z at ``index_z``."""
    acc = np.full((len(f), 3), 0.123)     # the unused (y) axis holds something
    acc[:, p.index_x - 1], acc[:, p.index_z - 1] = f[:, 0], f[:, 1]
    return acc


def test_model_description(fmu: Path) -> None:
    md = read_model_description(str(fmu), validate=True)
    assert md.coSimulation.modelIdentifier == "ParticleFilter"
    v = {x.name: x for x in md.modelVariables}
    for name, unit in (("q_m_meas[1]", "rad"), ("acc_s[3]", "m/s2"), ("dddq_a_ref[2]", "rad/s3"),
                       ("q_a_hat[1]", "rad"), ("dq_a_hat[2]", "rad/s"), ("ddq_a_hat[1]", "rad/s2"),
                       ("p_tool_hat[2]", "m"), ("trace_P_q", "rad2"), ("ess", "1"), ("n_reinit", "1")):
        assert v[name].unit == unit, name
    for name in ("n_particles", "proposal", "resampling", "ess_threshold", "seed", "bandwidth",
                 "use_accelerometer", "q_jerk", "r_motor", "r_acc", "gear_ratio[1]", "q_a0[1]", "index_x"):
        assert v[name].causality == "parameter", name
    assert v["proposal"].type == "String" and v["n_particles"].type == "Integer"
    deps = {o.variable.name: {d.name for d in o.dependencies} for o in md.outputs}
    meas = {"q_m_meas[1]", "q_m_meas[2]", "acc_s[1]", "acc_s[2]", "acc_s[3]", "t_meas"}
    for name in ("q_a_hat[1]", "ess", "n_reinit", "trace_P_q"):
        assert deps[name] == meas, name


def test_runs_standalone_under_simulate_fmu(fmu: Path) -> None:
    res = fmpy.simulate_fmu(str(fmu), stop_time=0.5, step_size=T, output_interval=T)
    assert len(res) >= 50
    for name in res.dtype.names:
        assert np.all(np.isfinite(res[name])), name
    assert np.all(res["trace_P_q"] > 0) and np.all(res["ess"] >= 1) and np.all(res["ess"] <= 1000)
    assert np.all(res["n_reinit"] == 0)
    # default inputs: motors at zero, the accelerometer at rest at the home pose: the estimate
    # stays near the home pose (within the gravity deflection of the gearboxes)
    assert np.abs(res["q_a_hat[1]"]).max() < 5e-3 and np.abs(res["q_a_hat[2]"]).max() < 5e-3


CASES = [
    dict(),
    dict(proposal="prior", p0_q=1e-5),
    dict(resampling="ess", ess_threshold=0.3, use_bias=True, index_x=3, index_z=1, n_particles=200, seed=9),
    dict(bandwidth=0.0, n_particles=300),
    dict(bandwidth=0.3, proposal="prior", p0_q=1e-5, n_particles=300),
]


@pytest.mark.parametrize("params", CASES, ids=["ekf", "prior", "ess-bias-swapped", "no-kernel", "bandwidth"])
def test_fmu_matches_the_plain_model_bit_for_bit(fmu: Path, params: dict) -> None:
    n = 40
    p = validate(pm.ParticleFilterParameters(q_a0=(0.2, -0.1), **params))
    qm, f, u, x = signals_from_rest(n, p)
    acc = _acc3(f, p)
    s = Slave(fmu, dict(q_a0=(0.2, -0.1), **params))
    s.init()
    pf = pm.ParticleFilterModel(p)
    for k in range(n):
        s.set(q_m_meas=qm[k], acc_s=acc[k], dddq_a_ref=u[k])
        xf = pf.update(pf.measurement_vector(qm[k], f[k]))
        assert_array_equal(s.get("q_a_hat", 2), xf[0:2])
        assert_array_equal(s.get("dq_a_hat", 2), xf[2:4])
        assert_array_equal(s.get("ddq_a_hat", 2), xf[4:6])
        assert_array_equal(s.get("p_tool_hat", 2), kinematics.tool_position(xf[0:2], p))
        assert s.get("trace_P_q") == pf.P[0, 0] + pf.P[1, 1]
        assert s.get("ess") == pf.ess and s.get("n_reinit") == 0.0
        pf.predict(0.5 * ((u[k - 1] if k else 0.0) + u[k]), T)   # mean of the last two jerk inputs
        s.step(T)
    s.close()
    assert np.abs(xf[0:2] - x[-1, 0:2]).max() < 1e-4       # and it estimates the motion


def test_gauss_seidel_inputs_are_fused_after_the_prediction(fmu: Path) -> None:
    """The master sets the measurements of t + T before doStep(t, T) and reads after it; the
    outputs are read twice and the inputs set twice per step (recomputed, same random numbers)."""
    n = 30
    p = validate(pm.ParticleFilterParameters(q_a0=(0.2, -0.1), n_particles=200))
    qm, f, u, x = signals_from_rest(n, p)
    acc = _acc3(f, p)
    s = Slave(fmu, dict(q_a0=(0.2, -0.1), n_particles=200))
    s.set(q_m_meas=qm[0], acc_s=acc[0], dddq_a_ref=u[0])
    s.init()
    pf = pm.ParticleFilterModel(p)
    pf.update(pf.measurement_vector(qm[0], f[0]))
    for k in range(n - 1):
        s.set(q_m_meas=qm[k + 1] + 1e-3, acc_s=acc[k + 1], dddq_a_ref=u[k + 1])
        s.step(T)
        s.get("q_a_hat", 2)                                 # an update from other inputs ...
        s.set(q_m_meas=qm[k + 1])                           # ... replaced before the next step
        pf.predict(0.5 * (u[k] + u[k + 1]), T)
        xf = pf.update(pf.measurement_vector(qm[k + 1], f[k + 1]))
        assert_array_equal(s.get("q_a_hat", 2), xf[0:2])
        assert_array_equal(s.get("dq_a_hat", 2), xf[2:4])
    s.close()


def _run(fmu: Path, params: dict, n: int = 15) -> np.ndarray:
    p = validate(pm.ParticleFilterParameters(q_a0=(0.2, -0.1), **params))
    qm, f, u, x = signals_from_rest(n, p)
    acc = _acc3(f, p)
    s = Slave(fmu, dict(q_a0=(0.2, -0.1), **params))
    s.init()
    out = []
    for k in range(n):
        s.set(q_m_meas=qm[k], acc_s=acc[k], dddq_a_ref=u[k])
        out.append(np.r_[s.get("q_a_hat", 2), s.get("dq_a_hat", 2), s.get("ess")])
        s.step(T)
    s.close()
    return np.array(out)


def test_deterministic_for_a_seed(fmu: Path) -> None:
    a = _run(fmu, dict(n_particles=100, seed=4))
    assert_array_equal(a, _run(fmu, dict(n_particles=100, seed=4)))
    assert not np.array_equal(a, _run(fmu, dict(n_particles=100, seed=5)))


def test_absurd_measurement_reinitialises_with_a_warning(fmu: Path) -> None:
    s = Slave(fmu, dict(n_particles=200))
    s.init()
    s.set(q_m_meas=(0.0, 0.0), acc_s=(0.0, 0.0, G))
    s.step(T)
    s.set(acc_s=(1e200, 0.0, G))      # an absurd (finite) reading: every weight underflows
    assert s.get("n_reinit") == 1.0      # the update at t (not committed yet)
    for name in ("q_a_hat", "dq_a_hat", "ddq_a_hat", "p_tool_hat"):
        assert np.all(np.isfinite(s.get(name, 2))), name
    s.step(T)                            # committed with a warning naming the cause, no error; the
    warnings = [m for m in s.log if "re-initialised" in m]     # reading, still there, is the one at t + T
    assert len(warnings) == 1 and "underflowed" in warnings[0] and "skipped" in warnings[0], s.log
    assert s.get("n_reinit") == 2.0
    s.set(acc_s=(0.0, 0.0, G))
    for _ in range(5):
        s.step(T)
    assert len([m for m in s.log if "re-initialised" in m]) == 2
    assert s.get("n_reinit") == 2.0 and s.get("ess") > 1.0
    assert np.abs(s.get("q_a_hat", 2)).max() < 5e-3          # near the home pose again
    s.close()


def test_nan_input_and_bad_parameter_are_named(fmu: Path) -> None:
    s = Slave(fmu, dict(n_particles=50))
    s.init()
    s.set(acc_s=(np.nan, 0.0, G))
    with pytest.raises(Exception):
        s.step(T)
    assert any("acc_s" in line for line in s.log), s.log
    bad = Slave(fmu, dict(proposal="optimal"))
    with pytest.raises(Exception):
        bad.init()
    assert any("proposal" in line for line in bad.log), bad.log

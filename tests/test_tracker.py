"""The reference measurement system (Tracker): noise, sample-and-hold, time skew, as math and
through its FMU."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import pythonfmu.builder  # noqa: F401 - at collection, before any FMU runs in this process: after
# a run, `pythonfmu` resolves to an FMU's bundled copy, and build_all would then make FMUs
# without binaries (the copy has no resources/binaries)
from numpy.testing import assert_allclose

from fmu_host import Slave
from fmus.robot_plant.tracker_model import TrackerModel
from orchestration.build import validate_fmu

V = np.array([0.2, -0.1])          # m/s: a ramp at 200 mm/s (the ISO path's speed)
P0 = np.array([1.0, 0.6])


def ramp(t: float) -> np.ndarray:
    return P0 + V * t


def drive(model: TrackerModel, dt: float, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Update times, held measurements and their stamps over ``n`` steps of the ramp."""
    model.start(0.0, ramp(0.0))
    ts, ps, ks = [], [], []
    for k in range(1, n + 1):
        t = k * dt
        model.update(t, ramp(t))
        ts.append(t)
        ps.append(model.p_meas.copy())
        ks.append(model.t_meas)
    return np.array(ts), np.array(ps), np.array(ks)


@pytest.mark.parametrize("skew", [0.0, 1e-3, 2.5e-3])
def test_a_ramp_is_measured_exactly_skew_late(skew):
    """Noise off: the sample stamped t_meas is the ramp at t_meas - skew (linear interpolation of
    a ramp is exact), also when the skew is not a multiple of the update step."""
    t, p, stamp = drive(TrackerModel(0.0, 1000.0, skew), 1e-3, 200)
    late = stamp >= skew                      # before that: the position at rest at the start
    assert late.sum() > 150
    assert_allclose(p[late], np.array([ramp(s - skew) for s in stamp[late]]), atol=1e-13)
    assert_allclose(stamp, t, atol=1e-12)     # 1 kHz samples on 1 kHz updates: always fresh
    # the error a metric against this reference sees on the ramp: speed times skew
    assert_allclose(np.linalg.norm(p[late] - np.array([ramp(s) for s in t[late]]), axis=1),
                    np.linalg.norm(V) * skew, atol=1e-12)


def test_sample_and_hold_at_its_own_rate():
    """At 300 Hz on 1 ms updates (a period of 3.33 steps) the output changes only when a
    sample instant k/300 has passed; it holds the newest one and stamps it."""
    t, p, stamp = drive(TrackerModel(0.0, 300.0, 0.0), 1e-3, 100)
    expected = np.floor(t * 300.0 + 1e-9) / 300.0
    assert_allclose(stamp, expected, atol=1e-12)
    assert_allclose(p, np.array([ramp(s) for s in expected]), atol=1e-13)
    changes = np.count_nonzero(np.any(np.diff(p, axis=0) != 0.0, axis=1))
    assert changes == len(np.unique(expected)) - 1


def test_noise_statistics():
    """White, zero-mean, the given standard deviation per axis, independent axes; reproducible."""
    sigma = 2e-5
    model = TrackerModel(sigma, 1000.0, 0.0, seed=3)
    model.start(0.0, P0)
    e = []
    for k in range(1, 20001):
        model.update(k * 1e-3, P0)
        e.append(model.p_meas - P0)
    e = np.array(e)
    n = len(e)
    assert_allclose(e.mean(axis=0), 0.0, atol=4 * sigma / np.sqrt(n))
    assert_allclose(e.std(axis=0), sigma, rtol=4 / np.sqrt(2 * n))
    assert abs(np.corrcoef(e[:, 0], e[:, 1])[0, 1]) < 4 / np.sqrt(n)
    assert abs(np.corrcoef(e[1:, 0], e[:-1, 0])[0, 1]) < 4 / np.sqrt(n)     # white
    again = TrackerModel(sigma, 1000.0, 0.0, seed=3)
    again.start(0.0, P0)
    again.update(1e-3, P0)
    assert_allclose(again.p_meas - P0, e[0], rtol=0, atol=0)


@pytest.mark.parametrize("kwargs, word", [({"sample_rate": 0.0}, "sample_rate"),
                                          ({"skew": -1e-3}, "skew")])
def test_bad_model_arguments(kwargs, word):
    args = {"noise": 0.0, "sample_rate": 1000.0, "skew": 0.0, **kwargs}
    with pytest.raises(ValueError, match=word):
        TrackerModel(**args)


# ---- the FMU -----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def fmu(every_fmu: dict[str, Path]) -> Path:
    return every_fmu["Tracker"]


def test_fmu_validates_with_units(fmu):
    assert validate_fmu(fmu) == []
    s = Slave(fmu)
    try:
        for v in s.md.modelVariables:
            assert v.description, v.name
            if v.type == "Real":
                assert v.unit, v.name
        outputs = [u for u in s.md.outputs if u.variable.name.startswith("p_tool_meas")]
        assert outputs and all(u.dependencies == [] for u in outputs)     # no direct feedthrough
    finally:
        s.close()


def test_fmu_measures_the_ramp_skew_late(fmu):
    """Through FMI, a Gauss-Seidel master's way: the input set before doStep(t, dt) is the
    position at t + dt; the output after the step is the ramp at t_meas - skew, t_meas = t + dt."""
    skew, dt = 2e-3, 1e-3
    s = Slave(fmu, {"noise": 0.0, "skew": skew})
    try:
        s.set(p_tool=ramp(0.0))
        s.init()
        assert_allclose(s.get("p_tool_meas", 2), ramp(0.0))
        for k in range(1, 30):
            s.set(p_tool=ramp(k * dt))
            s.step(dt)
            assert s.get("t_meas") == pytest.approx(k * dt, abs=1e-12)
            if k * dt >= skew:
                assert_allclose(s.get("p_tool_meas", 2), ramp(k * dt - skew), atol=1e-13)
    finally:
        s.close()


@pytest.mark.parametrize("bad, word", [({"noise": -1e-5}, "noise"), ({"sample_rate": 0.0}, "sample_rate"),
                                       ({"skew": -1e-3}, "skew"), ({"skew": 5.0}, "skew")])
def test_fmu_rejects_bad_parameters(fmu, bad, word):
    s = Slave(fmu, bad)
    try:
        with pytest.raises(Exception, match="ExitInitializationMode"):
            s.fmu.exitInitializationMode()
        assert s.log.has("initialisation", f"'{word}"), s.log.messages
    finally:
        s.close()

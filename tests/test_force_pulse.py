"""ForcePulse: half-sine rubber-hammer strikes on the tool (Henriksson et al. 2009, section IV-A),
as math and through its FMU."""
from __future__ import annotations

import math
from pathlib import Path

import fmpy
import numpy as np
import pytest
from numpy.testing import assert_allclose

from fmus.common.parameters import ParameterError, validate
from fmus.robot_plant import force_pulse_model as fp


def test_pulse_shape_and_impulse() -> None:
    times, amps, d = (0.1, 0.3), (500.0, -200.0), 0.008
    assert fp.pulse_force(0.1 + d / 2, times, amps, d) == pytest.approx(500.0)
    assert fp.pulse_force(0.3 + d / 4, times, amps, d) == pytest.approx(-200.0 * math.sin(math.pi / 4))
    assert fp.pulse_force(0.1 - 1e-9, times, amps, d) == 0.0
    assert fp.pulse_force(0.1 + d, times, amps, d) == 0.0
    # the step means deliver the exact impulse for any step, also one longer than the pulse
    for dt in (5e-4, 1e-3, 3e-3, 0.02):
        t = np.arange(0.0, 0.5, dt)
        total = sum(fp.mean_force(tk, dt, times, amps, d) * dt for tk in t)
        assert_allclose(total, fp.impulse(500.0, d) + fp.impulse(-200.0, d), rtol=1e-10)
    # unused slots (t0 <= 0) do nothing
    assert fp.mean_force(0.0, 1.0, (0.0, -1.0), (100.0, 100.0), d) == 0.0


def test_parameters() -> None:
    with pytest.raises(ParameterError, match="direction"):
        validate(fp.ForcePulseParameters(direction=(0.0, 0.0)))
    with pytest.raises(ParameterError, match="duration"):
        validate(fp.ForcePulseParameters(duration=0.0))
    assert_allclose(fp.ForcePulseParameters(direction=(3.0, 4.0)).unit_direction(), [0.6, 0.8])


@pytest.fixture(scope="module")
def fmu(every_fmu: dict[str, Path]) -> Path:
    return every_fmu["ForcePulse"]


def test_fmu_delivers_the_impulse_along_the_direction(fmu) -> None:
    """Through fmpy at 2 kHz: f_ext = f_in + pulse along the unit direction, the step values
    sum to the impulse 2 F d / pi, zero outside the pulses."""
    dt, d = 5e-4, 0.008
    start = {"times[1]": 0.02, "times[2]": 0.06, "amplitudes[1]": 600.0, "amplitudes[2]": -300.0,
             "direction[1]": 3.0, "direction[2]": 4.0, "duration": d, "f_in[1]": 10.0, "f_in[2]": -5.0}
    for i in range(3, 9):
        start[f"times[{i}]"] = 0.0
    res = fmpy.simulate_fmu(str(fmu), stop_time=0.1, step_size=dt, output_interval=dt, start_values=start,
                            output=["f_ext[1]", "f_ext[2]", "f_pulse"])
    t = res["time"]
    fx, fz, f = res["f_ext[1]"] - 10.0, res["f_ext[2]"] + 5.0, res["f_pulse"]
    assert_allclose(fx, 0.6 * f, atol=1e-12)
    assert_allclose(fz, 0.8 * f, atol=1e-12)
    # the value after the step to t is the mean over [t, t + dt]
    assert_allclose(f[1:], [fp.mean_force(tk, dt, (0.02, 0.06), (600.0, -300.0), d) for tk in t[1:]],
                    atol=1e-9)
    first = (t > 0.01) & (t < 0.04)
    assert_allclose(np.sum(f[first]) * dt, fp.impulse(600.0, d), rtol=1e-9)
    assert_allclose(np.sum(f[t >= 0.04]) * dt, fp.impulse(-300.0, d), rtol=1e-9)
    assert np.all(f[t < 0.02 - dt] == 0.0)
    md = fmpy.read_model_description(str(fmu))
    assert {v.name for v in md.modelVariables if v.causality == "output"} == {"f_ext[1]", "f_ext[2]", "f_pulse"}

"""The FMI 2.0 contract of every FlexFusion FMU (issue 13): bad step sizes and non-finite
outputs are errors with a logged cause, errors reach the host's logger even without debug
logging, fixed parameters refuse changes after initialisation, and get/set FMU state restores
the complete internal state bit-exactly (also through serialisation).

With pythonfmu 0.7's native layer an exception of the slave becomes ``fmi2Fatal`` (it has no
path to ``fmi2Error``): the tests accept either error status, never OK or Discard.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description
from fmpy.fmi1 import FMICallException
from numpy.testing import assert_array_equal

from fmu_host import Slave

from fmus.common.frames import G

DISCARD, ERROR, FATAL = 2, 3, 4


def _status(call, *args) -> int:
    try:
        call(*args)
    except FMICallException as exc:
        return exc.status
    return 0


@pytest.mark.parametrize("h", [float("nan"), 0.0, -1e-3, float("inf")])
def test_bad_step_size_is_an_error_logged_without_debug_logging(every_fmu, h) -> None:
    s = Slave(every_fmu["Encoder"], init=True, logging_on=False)
    assert _status(s.fmu.doStep, 0.0, h) in (ERROR, FATAL)
    s.close()
    assert s.log.has("step size must be finite and > 0"), s.log


def test_do_step_before_initialisation_is_an_error(every_fmu) -> None:
    s = Slave(every_fmu["Encoder"], logging_on=False)
    assert _status(s.fmu.doStep, 0.0, 1e-3) in (ERROR, FATAL)
    s.close()
    assert s.log.has("called in the initialization state"), s.log


def test_non_finite_output_is_an_error_naming_it(every_fmu) -> None:
    s = Slave(every_fmu["FlexibleRobot2DOF"], init=True, logging_on=False)
    s.set(tau_m=[1e300, 1e300])            # finite, absurd: the states overflow
    s.step(1e-3)
    vrs = [s.vr[f"q_a[{i}]"] for i in (1, 2)]
    assert _status(s.fmu.getReal, vrs) in (ERROR, FATAL)
    assert s.log.has("output 'q_a[1]' is not finite", "t = 0.001 s"), s.log


def test_non_finite_input_is_an_error_naming_it_until_it_is_finite_again(every_fmu) -> None:
    """The one check per step (issue 16) still names the input, every step it stays bad, and a
    huge but finite input (whose sum overflows) is no error."""
    s = Slave(every_fmu["Encoder"], {"resolution": 0.0}, init=True, logging_on=False)
    s.set(q_m=[1e308, 1e308])
    s.step(1e-3)
    s.set(q_m=[0.1, float("nan")])
    assert _status(s.fmu.doStep, 1e-3, 1e-3) in (DISCARD, ERROR, FATAL)   # the step is refused
    assert s.log.has("input 'q_m' is not finite", "t = 0.001 s"), s.log
    s.close()
    s = Slave(every_fmu["Encoder"], init=True, logging_on=False)
    s.set(q_m=[0.1, float("inf")])
    assert _status(s.fmu.doStep, 0.0, 1e-3) in (DISCARD, ERROR, FATAL)
    assert _status(s.fmu.doStep, 0.0, 1e-3) in (DISCARD, ERROR, FATAL)    # not set again: still bad
    s.set(q_m=[0.1, 0.2])
    s.step(1e-3)
    s.close()


def test_fixed_parameter_refuses_a_change_after_initialisation(every_fmu) -> None:
    s = Slave(every_fmu["Encoder"], {"noise": 1e-5}, init=True, logging_on=False)
    assert _status(s.fmu.setReal, [s.vr["noise"]], [2e-5]) in (ERROR, FATAL)
    assert s.log.has("parameter 'noise' is fixed"), s.log
    assert s.get("noise") == 1e-5
    assert _status(s.fmu.setInteger, [s.vr["seed"]], [7]) in (ERROR, FATAL)
    assert s.log.has("parameter 'seed' is fixed"), s.log
    s.close()
    before = Slave(every_fmu["Encoder"])              # in Initialization Mode it may change
    before.fmu.setReal([before.vr["noise"]], [2e-5])
    before.init()
    assert before.get("noise") == 2e-5
    before.close()


# every sensor with its noise: the tunable `reseed` (fmus/common/noise.py)
NOISY = {"Encoder": ({"noise": 1e-3, "bias_rw": 1e-3}, "q_m_meas", 2),
         "Imu": ({}, "acc_s", 3), "ForceTorqueSensor": ({}, "f_s", 3),
         "Tracker": ({"noise": 1e-3}, "p_tool_meas", 2)}


@pytest.mark.parametrize("name", sorted(NOISY))
def test_tunable_reseed_restarts_the_noise_between_steps(every_fmu, name) -> None:
    params, output, size = NOISY[name]
    md = read_model_description(str(every_fmu[name]))
    assert {v.name: v.variability for v in md.modelVariables}["reseed"] == "tunable"

    def run(reseeds: dict[int, int], at_start: dict | None = None) -> np.ndarray:
        s = Slave(every_fmu[name], {**params, **(at_start or {})}, init=True, logging_on=False)
        rows = []
        for k in range(12):
            if k in reseeds:
                status = _status(s.fmu.setInteger, [s.vr["reseed"]], [reseeds[k]])
                assert status == 0 or (reseeds[k] < -1 and s.log.has("parameter 'reseed'", ">= -1"))
            s.step(1e-3)
            rows.append(s.get(output, size))
        s.close()
        return np.array(rows)
    plain, reseeded, again, refused = run({}), run({5: 7}), run({5: 7}), run({5: 7, 8: -2})
    assert_array_equal(reseeded[:5], plain[:5])          # before the reseed: the seed's numbers
    assert np.mean(reseeded[5:] != plain[5:]) > 0.5      # after: new ones (some quantised alike)
    assert_array_equal(again, reseeded)                  # reproducible
    assert_array_equal(refused, reseeded)                # a bad value: refused, the old one kept
    assert_array_equal(run({}, {"reseed": 7}), run({0: 7}))   # set in Initialization Mode: from the start


def _drive(s: Slave, inputs: list[str], k0: int, n: int, h: float) -> np.ndarray:
    """n steps with smoothly varying inputs (a function of the step number), the outputs after each."""
    outputs = [v.valueReference for v in s.md.modelVariables if v.causality == "output"]
    rows = []
    for k in range(k0, k0 + n):
        if inputs:
            s.fmu.setReal([s.vr[i] for i in inputs],
                          [0.01 * (j + 1) * np.sin(0.3 * k + j) + (G if "acc_s[3]" == i else 0.0)
                           for j, i in enumerate(inputs)])
        s.fmu.doStep(k * h, h)
        rows.append(s.fmu.getReal(outputs))
    return np.array(rows)


def test_every_fmu_declares_and_restores_its_complete_state(every_fmu) -> None:
    h, n1, n2 = 1e-3, 15, 25
    for name, path in every_fmu.items():
        md = read_model_description(str(path))
        assert md.coSimulation.canGetAndSetFMUstate and md.coSimulation.canSerializeFMUstate, name
        inputs = [v.name for v in md.modelVariables if v.causality == "input"]
        s = Slave(path, init=True)
        _drive(s, inputs, 0, n1, h)
        state = s.fmu.getFMUstate()
        data = s.fmu.serializeFMUstate(state)
        reference = _drive(s, inputs, n1, n2, h)
        s.fmu.setFMUstate(state)
        again = _drive(s, inputs, n1, n2, h)
        s.fmu.setFMUstate(state)                        # a state can be restored twice
        twice = _drive(s, inputs, n1, n2, h)
        s.fmu.freeFMUstate(state)
        s.close()
        other = Slave(path, init=True)                  # another instance, from the bytes
        restored = other.fmu.deSerializeFMUstate(data)
        other.fmu.setFMUstate(restored)
        copied = _drive(other, inputs, n1, n2, h)
        other.close()
        assert np.all(np.isfinite(reference)), name
        assert_array_equal(again, reference, err_msg=name)
        assert_array_equal(twice, reference, err_msg=name)
        assert_array_equal(copied, reference, err_msg=name)

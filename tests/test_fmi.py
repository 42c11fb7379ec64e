"""fmus/common/fmi.py directly, in Python (no FMU built): FlexFusionSlave's declarations, its
modelDescription (units, feedthrough dependencies), parameter validation, the step contract,
lazy feedthrough outputs and the FMU state. Through built FMUs: test_every_fmu.py and
test_fmi_*.py."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from fmus.common.fmi import FlexFusionSlave, known_units, nominal_step
from fmus.common.parameters import ParameterError, param

BASE_UNITS = {"kg", "m", "s", "rad"}


@dataclass(frozen=True)
class ToyParameters:
    gain: float = param(2.0, "1", "gain of the feedthrough", low=0.0, high=10.0)
    lag: tuple = param((0.1, 0.2), "s", "per-channel time constant", low=0.0, low_inclusive=False)
    mode: str = param("sum", "1", "how the state integrates", choices=("sum", "hold"))
    seed: int = param(3, "1", "an integer parameter", low=0)


class Toy(FlexFusionSlave):
    """y = gain * u (feedthrough); x[i] integrates u (no feedthrough)."""

    parameters_class = ToyParameters

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.input("u", unit="m", description="input")
        self.input("w", 2, unit="N", description="unused vector input")
        self.output("y", unit="m", description="gain * u", depends_on=["u"])
        self.output("x", 2, unit="m", description="integral of u")
        self.setups = 0

    def setup(self, p: ToyParameters) -> None:
        self.setups += 1
        self.update_outputs()

    def update_outputs(self) -> None:
        self.y = self.params.gain * self.u

    def step(self, t: float, dt: float) -> None:
        if self.params.mode == "sum":
            self.x[:] += self.u * dt
        self.update_outputs()


def toy(log: list | None = None) -> Toy:
    """A Toy whose error messages go to ``log`` (a host logger callback, as a native layer gives)."""
    return Toy(instance_name="toy", logger=None if log is None else lambda status, category, msg: log.append(msg))


def vr(slave: FlexFusionSlave, name: str) -> int:
    return next(r for r, v in slave.vars.items() if v.name == name)


def started(log: list | None = None, **params) -> Toy:
    s = toy(log)
    s.setup_experiment(0.0, None, None)
    s.enter_initialization_mode()
    for k, v in params.items():
        s.set_real([vr(s, k)], [v])
    s.exit_initialization_mode()
    return s


def test_nominal_step_removes_the_hosts_last_bits() -> None:
    assert 0.03 - 0.02 != 0.01                       # what fmpy's simulate_fmu passes
    assert nominal_step(0.03 - 0.02) == 0.01
    assert nominal_step(1e-3) == 1e-3
    assert abs(nominal_step(math.pi) / math.pi - 1) < 5e-13


def test_every_known_unit_is_made_of_si_base_units() -> None:
    from fmus.common.fmi import _UNITS
    assert set(known_units()) == set(_UNITS)
    for unit, exponents in _UNITS.items():
        assert set(exponents) <= BASE_UNITS, unit
        assert all(isinstance(e, int) and e != 0 for e in exponents.values()), unit
    assert _UNITS["N.m/rad"] == {"kg": 1, "m": 2, "s": -2, "rad": -1}


def test_model_description_units_vectors_and_dependencies() -> None:
    root = toy().to_xml()
    variables = list(root.find("ModelVariables"))
    index = {sv.get("name"): i + 1 for i, sv in enumerate(variables)}
    assert {"u", "w[1]", "w[2]", "y", "x[1]", "x[2]", "gain", "lag[1]", "lag[2]", "mode", "seed"} <= set(index)
    units = {sv.get("name"): sv.find("Real").get("unit") for sv in variables if sv.find("Real") is not None}
    assert units["u"] == "m" and units["w[2]"] == "N" and units["lag[1]"] == "s" and units["gain"] == "1"
    defined = {u.get("name") for u in root.find("UnitDefinitions")}
    assert defined == set(units.values())
    tags = [e.tag for e in root]
    assert tags.index("UnitDefinitions") == tags.index("CoSimulation") + 1      # schema order
    deps = {variables[int(u.get("index")) - 1].get("name"): u.get("dependencies")
            for u in root.find("ModelStructure/Outputs")}
    assert deps == {"y": str(index["u"]), "x[1]": "", "x[2]": ""}
    initial = {int(u.get("index")) for u in root.find("ModelStructure/InitialUnknowns")}
    assert initial == {index["y"], index["x[1]"], index["x[2]"]}
    described = {sv.get("name"): sv.get("description") for sv in variables}
    assert described["x[2]"] == "integral of u (2)"
    assert root.find("CoSimulation").get("canGetAndSetFMUstate") == "true"


def test_bad_declarations_are_refused_naming_them() -> None:
    class BadUnit(FlexFusionSlave):
        def __init__(self, **kwargs) -> None:
            super().__init__(**kwargs)
            self.output("y", unit="furlong", description="")

    class BadDependency(FlexFusionSlave):
        def __init__(self, **kwargs) -> None:
            super().__init__(**kwargs)
            self.output("y", unit="m", description="", depends_on=["u"])

    with pytest.raises(ValueError, match="unit 'furlong' of 'y'"):
        BadUnit(instance_name="b")
    with pytest.raises(ValueError, match="depends on 'u', which is not a declared input"):
        BadDependency(instance_name="b")


def test_parameters_are_validated_when_initialisation_ends_naming_the_parameter() -> None:
    s = toy()
    s.enter_initialization_mode()
    s.set_real([vr(s, "lag[2]")], [0.0])
    with pytest.raises(ParameterError, match=r"parameter 'lag\[2\]' = 0.0 \[s\] must be > 0.0"):
        s.exit_initialization_mode()
    s = toy()
    s.enter_initialization_mode()
    s.set_string([vr(s, "mode")], ["spin"])
    with pytest.raises(ParameterError, match="parameter 'mode' = 'spin' is not one of"):
        s.exit_initialization_mode()


def test_feedthrough_output_follows_its_input_without_a_step() -> None:
    s = started(gain=3.0)
    assert s.setups == 1
    s.set_real([vr(s, "u")], [0.5])
    assert s.get_real([vr(s, "y"), vr(s, "x[1]")]) == [1.5, 0.0]
    s.do_step(0.0, 0.1)
    assert_array_equal(s.x, [0.05, 0.05])


def test_outputs_are_valid_in_initialization_mode() -> None:
    s = toy()
    s.enter_initialization_mode()
    s.set_real([vr(s, "u")], [1.0])
    assert s.get_real([vr(s, "y")]) == [2.0]            # built from the defaults so far
    s.set_real([vr(s, "gain")], [5.0])
    assert s.get_real([vr(s, "y")]) == [5.0]            # rebuilt after the parameter changed
    s.exit_initialization_mode()
    assert s.setups == 2


@pytest.mark.parametrize("h", [0.0, -1e-3, math.nan, math.inf])
def test_a_bad_step_size_is_refused(h: float) -> None:
    s = started()
    with pytest.raises(ValueError, match="step size must be finite and > 0"):
        s.do_step(0.0, h)


def test_step_before_initialisation_and_fixed_parameters_after_it_are_refused() -> None:
    s = toy()
    with pytest.raises(ValueError, match="called in the instantiated state"):
        s.do_step(0.0, 1e-3)
    s = started()
    with pytest.raises(ValueError, match="parameter 'gain' is fixed"):
        s.set_real([vr(s, "gain")], [1.0])
    with pytest.raises(ValueError, match="parameter 'seed' is fixed"):
        s.set_integer([vr(s, "seed")], [1])


def test_a_non_finite_input_fails_the_step_and_a_non_finite_output_the_read() -> None:
    log = []
    s = started(log)
    s.set_real([vr(s, "u")], [math.nan])
    assert s.do_step(0.0, 1e-3) is False
    assert len(log) == 1 and "toy: step at t = 0 s: input 'u' is not finite" in log[0], log
    s = started(gain=1.0)
    s.set_real([vr(s, "u")], [math.inf])
    with pytest.raises(FloatingPointError, match="output 'y' is not finite"):
        s.get_real([vr(s, "y")])


def test_fmu_state_restores_bit_exactly_and_survives_serialisation() -> None:
    s = started()
    s.set_real([vr(s, "u")], [0.3])
    s.do_step(0.0, 1e-3)
    state = s._fmu_state_to_bytes(s._get_fmu_state())
    for k in range(5):
        s.do_step((k + 1) * 1e-3, 1e-3)
    after = s.x.copy()
    s._set_fmu_state(s._fmu_state_from_bytes(state))
    assert_array_equal(s.x, [3e-4, 3e-4])
    for k in range(5):
        s.do_step((k + 1) * 1e-3, 1e-3)
    assert_array_equal(s.x, after)
    assert s.get_real([vr(s, "x[1]")]) == [after[0]]      # the getters see the restored array


class _Payload:
    """Unpickling it creates the marker file."""

    def __init__(self, marker) -> None:
        self.marker = marker

    def __reduce__(self):
        return (open, (str(self.marker), "w"))


def test_a_foreign_or_crafted_state_is_an_fmi_error_naming_why_and_runs_nothing(tmp_path) -> None:
    import pickle

    from fmus.common import state_codec
    log: list[str] = []
    s = started(log)
    s.do_step(0.0, 1e-3)
    good = s._fmu_state_to_bytes(s._get_fmu_state())
    marker = tmp_path / "ran"
    crafted = pickle.dumps({"arrays": {}, "attrs": {"x": _Payload(marker)}})
    with pytest.raises(ValueError, match="toy: fmi2DeSerializeFMUstate: state refused: a pickle"):
        s._fmu_state_from_bytes(crafted)
    assert not marker.exists() and "state refused: a pickle" in log[-1]
    with pytest.raises(ValueError, match="truncated"):
        s._fmu_state_from_bytes(good[:-5])
    state = s._get_fmu_state()
    wider = dict(state, arrays=dict(state["arrays"], x=np.zeros(3)))
    with pytest.raises(ValueError, match=r"variable 'x': not an array of shape \(2,\)"):
        s._fmu_state_from_bytes(s._fmu_state_to_bytes(wider))
    odd = dict(state, attrs=dict(state["attrs"], params=np.zeros(2)))    # a kernel would index it
    with pytest.raises(ValueError, match="'params' is float64 of 1 dimensions, this instance holds a ToyParameters"):
        s._fmu_state_from_bytes(s._fmu_state_to_bytes(odd))

    class Other(Toy):
        """Another FMU (its model identifier)."""
    other = Other(instance_name="other")
    with pytest.raises(ValueError, match="the state of another FMU or build .*'model': 'Toy'"):
        other._fmu_state_from_bytes(good)
    s._set_fmu_state(s._fmu_state_from_bytes(good))         # the good one still restores
    assert_array_equal(s.x, [0.0, 0.0])
    assert state_codec.MAGIC == good[:16]


def test_get_real_reads_any_list_of_references_live() -> None:
    """get_real generates the reading of each list of references once (one copy of the span of
    each array): any order, repeats, scalars, inputs and parameters read what each variable's
    getter reads, at every call (the reading holds arrays, not values), and after an FMU state
    is restored."""
    s = started()
    reals = [r for r, v in s.vars.items() if type(v).__name__ == "Real"]
    lists = [reals, reals[::-1], [vr(s, "x[2]"), vr(s, "x[1]"), vr(s, "x[2]")],
             [vr(s, "x[1]"), vr(s, "y"), vr(s, "x[2]"), vr(s, "lag[2]"), vr(s, "w[1]")]]
    saved = s._get_fmu_state()
    for k in range(3):
        s.set_real([vr(s, "u"), vr(s, "w[1]"), vr(s, "w[2]")], [0.1 * k + 0.2, k, -k])
        s.do_step(k * 1e-3, 1e-3)
        for refs in lists:
            assert s.get_real(refs) == [s.vars[r].getter() for r in refs]
    s._set_fmu_state(saved)
    for refs in lists:
        assert s.get_real(refs) == [s.vars[r].getter() for r in refs]
    assert s.get_real([vr(s, "x[1]"), vr(s, "x[2]")]) == [0.0, 0.0]


def test_set_real_writes_any_list_of_inputs_as_each_setter_does() -> None:
    """set_real generates the writing of each list of input references once: any order and
    repeats (the last value wins) set what each variable's setter sets, also after an FMU
    state is restored; a list with a parameter goes through the setters (a fixed one refuses)."""
    s = started()
    u, w1, w2 = vr(s, "u"), vr(s, "w[1]"), vr(s, "w[2]")
    saved = s._get_fmu_state()
    for restored in (False, True):
        for refs, values in (([u, w1, w2], [0.5, 1.0, 2.0]), ([w2, u, w1], [3.0, -0.5, 4.0]),
                             ([w1, w1, u], [5.0, 6.0, 7.0])):
            s.set_real(refs, values)
            expected = dict(zip(refs, values))
            assert [s.vars[r].getter() for r in expected] == list(expected.values())
            assert [s.vars[r].getter() for r in (u, w1, w2)] == [s.u, *s.w]    # what the model reads
            assert isinstance(s.u, float)
        s._set_fmu_state(saved)
        assert [s.u, *s.w] == [0.0, 0.0, 0.0]
    with pytest.raises(ValueError, match="parameter 'gain' is fixed"):
        s.set_real([u, vr(s, "gain")], [1.0, 3.0])


def test_vector_outputs_share_one_buffer_in_declaration_order() -> None:
    s = started()
    span = s.output_span("x", "x")
    s._outputs[span] = (1.5, -2.5)
    assert_array_equal(s.x, [1.5, -2.5])
    with pytest.raises(ValueError, match="'y' is not a vector output"):
        s.output_span("y", "x")


def test_nominal_step_keeps_the_sign_of_zero() -> None:
    assert math.copysign(1.0, nominal_step(-0.0)) == -1.0
    assert math.copysign(1.0, nominal_step(0.0)) == 1.0

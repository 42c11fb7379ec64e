"""fmus/common/parameters.py: declared fields, range checks whose message names the parameter and
its unit, vectors checked element by element, a set's own check(), replace() and as_array()."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from fmus.common.parameters import ParameterError, as_array, fields, param, replace, validate


@dataclasses.dataclass(frozen=True)
class Arm:
    mass: float = param(80.0, "kg", "link mass", low=0.0, low_inclusive=False, source="data sheet")
    ratio: float = param(0.5, "1", "a fraction", low=0.0, high=1.0, high_inclusive=False)
    stiffness: tuple = param([1e5, 2e5], "N.m/rad", "per joint", low=1e3, high=1e7)
    mode: str = param("fast", choices=["fast", "exact"])
    seed: int = param(0, "1", "seed", low=0)
    enabled: bool = param(True)

    def check(self) -> None:
        if self.mode == "exact" and self.ratio > 0.5:
            raise ParameterError("parameter 'ratio' must be <= 0.5 when mode = 'exact'")


def test_declaration_keeps_unit_description_range_and_source() -> None:
    f = {x.name: x for x in fields(Arm)}
    assert list(f) == ["mass", "ratio", "stiffness", "mode", "seed", "enabled"]
    assert f["mass"].metadata["unit"] == "kg"
    assert f["mass"].metadata["source"] == "data sheet"
    assert f["mass"].metadata["low"] == 0.0 and not f["mass"].metadata["low_inclusive"]
    assert Arm().stiffness == (1e5, 2e5)                  # a list default becomes a tuple
    assert f["mode"].metadata["choices"] == ("fast", "exact")
    assert f["mode"].metadata["unit"] == "1"             # dimensionless by default
    assert fields(Arm()) == fields(Arm)


def test_defaults_are_valid_and_validate_returns_the_set() -> None:
    a = Arm()
    assert validate(a) is a


@pytest.mark.parametrize("changes, message", [
    (dict(mass=0.0), r"parameter 'mass' = 0.0 \[kg\] must be > 0.0"),
    (dict(mass=-3), r"parameter 'mass' = -3 \[kg\] must be > 0.0"),
    (dict(ratio=1.0), r"parameter 'ratio' = 1.0 \[1\] must be < 1.0"),
    (dict(ratio=-0.1), r"parameter 'ratio' = -0.1 \[1\] must be >= 0.0"),
    (dict(stiffness=(1e5, 1e8)), r"parameter 'stiffness\[2\]' = 100000000.0 \[N.m/rad\] must be <= 10000000.0"),
    (dict(stiffness=(10.0, 1e5)), r"parameter 'stiffness\[1\]' = 10.0 \[N.m/rad\] must be >= 1000.0"),
    (dict(mass=math.nan), r"parameter 'mass' = nan is not a finite number"),
    (dict(stiffness=(1e5, math.inf)), r"parameter 'stiffness\[2\]' = inf is not a finite number"),
    (dict(mode="slow"), r"parameter 'mode' = 'slow' is not one of \['fast', 'exact'\]"),
    (dict(seed=-1), r"parameter 'seed' = -1 \[1\] must be >= 0"),
    (dict(mode="exact", ratio=0.9), r"parameter 'ratio' must be <= 0.5 when mode = 'exact'"),   # check()
])
def test_a_value_outside_its_range_is_named_with_its_unit(changes: dict, message: str) -> None:
    with pytest.raises(ParameterError, match=message):
        validate(dataclasses.replace(Arm(), **changes))


def test_bounds_are_inclusive_unless_declared_otherwise() -> None:
    validate(Arm(ratio=0.0, stiffness=(1e3, 1e7)))          # both ends of closed ranges
    validate(Arm(mass=1e-300))                               # just above an open lower bound


def test_parameter_error_is_a_value_error() -> None:
    assert issubclass(ParameterError, ValueError)


def test_replace_validates_and_stores_vectors_as_tuples() -> None:
    a = replace(Arm(), stiffness=np.array([3e5, 4e5]), seed=2)
    assert a.stiffness == (3e5, 4e5) and isinstance(a.stiffness, tuple)
    assert replace(Arm(), stiffness=[5e5, 6e5]).stiffness == (5e5, 6e5)
    assert hash(a) == hash(replace(Arm(), stiffness=[3e5, 4e5], seed=2))   # still hashable, frozen
    with pytest.raises(ParameterError, match=r"stiffness\[1\]"):
        replace(Arm(), stiffness=[0.0, 1e5])


def test_as_array_is_a_float_copy() -> None:
    a = Arm()
    x = as_array(a.stiffness)
    assert x.dtype == float
    assert_array_equal(x, [1e5, 2e5])
    x[0] = 0.0
    assert a.stiffness == (1e5, 2e5)

"""Parameter sets: one dataclass per component, each field documented once.

Every physical or tuning parameter of a component is a field of a frozen dataclass declared
with :func:`param`. The field carries its unit, description, admissible range and source, so
that the FMU adapter can declare it as an FMI parameter (vectors become ``name[1]``,
``name[2]``), the orchestration can override it from a scenario, and :func:`validate`
rejects a value outside its physical range with a message naming the parameter.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Any, Sequence

import numpy as np


class ParameterError(ValueError):
    """A parameter value outside its admissible range; the message names the parameter."""


def param(default: Any, unit: str = "1", description: str = "", *, low: float | None = None,
          high: float | None = None, low_inclusive: bool = True, high_inclusive: bool = True,
          choices: Sequence[str] | None = None, source: str = "", tunable: bool = False,
          search: tuple[float, float] | None = None) -> Any:
    """Declare a parameter field.

    Parameters
    ----------
    default
        Default value: float, int, bool, str, or a tuple of floats for a per-joint vector.
    unit
        SI unit string as used in the FMI ``UnitDefinitions`` ("rad", "N.m/rad", "1", ...).
    description
        One sentence for the modelDescription and the docs.
    low, high, low_inclusive, high_inclusive
        Admissible range of every element; ``None`` means unbounded.
    choices
        Admissible values of a string parameter.
    source
        Where the default comes from (paper, data sheet, benchmark).
    tunable
        FMI variability ``tunable`` instead of ``fixed``: the host may change it between steps
        (FMI 2.0, section 2.2.7); the FMU then calls its ``tuned(name)`` (fmus.common.fmi).
    search
        ``(low, high)``: the default search range of the tuner (``flexfusion tune``) for every
        element; the FMU writes it into its modelDescription's vendor annotation
        (docs/fmu_annotation.md). ``None``: not tuned by default.
    """
    if isinstance(default, list):
        default = tuple(default)
    meta = dict(unit=unit, description=description, low=low, high=high,
                low_inclusive=low_inclusive, high_inclusive=high_inclusive,
                choices=tuple(choices) if choices else None, source=source, tunable=tunable,
                search=None if search is None else (float(search[0]), float(search[1])))
    return dataclasses.field(default=default, metadata=meta)


def fields(params_cls: type) -> tuple[dataclasses.Field, ...]:
    """The parameter fields of ``params_cls``, a parameter dataclass (class or instance)."""
    return dataclasses.fields(params_cls)


def _check_scalar(name: str, value: Any, meta: dict) -> None:
    if meta["choices"] is not None:
        if value not in meta["choices"]:
            raise ParameterError(f"parameter '{name}' = {value!r} is not one of {list(meta['choices'])}")
        return
    if isinstance(value, (bool, str)):
        return
    v = float(value)
    if not math.isfinite(v):
        raise ParameterError(f"parameter '{name}' = {value!r} is not a finite number")
    low, high = meta["low"], meta["high"]
    if low is not None and (v < low or (v == low and not meta["low_inclusive"])):
        op = ">=" if meta["low_inclusive"] else ">"
        raise ParameterError(f"parameter '{name}' = {value!r} [{meta['unit']}] must be {op} {low}")
    if high is not None and (v > high or (v == high and not meta["high_inclusive"])):
        op = "<=" if meta["high_inclusive"] else "<"
        raise ParameterError(f"parameter '{name}' = {value!r} [{meta['unit']}] must be {op} {high}")


def validate(params: Any) -> Any:
    """Check every field of ``params`` (a parameter dataclass instance) against its declared
    range, then the set's own ``check()`` if any.

    Returns the parameters unchanged, so that ``p = validate(P(...))`` reads naturally.

    Raises
    ------
    ParameterError
        Naming the first offending parameter (vector elements as ``name[i]``, 1-based).
    """
    for f in fields(params):
        value = getattr(params, f.name)
        if isinstance(value, (tuple, list, np.ndarray)):
            for i, v in enumerate(value):
                _check_scalar(f"{f.name}[{i + 1}]", v, f.metadata)
        else:
            _check_scalar(f.name, value, f.metadata)
    check = getattr(params, "check", None)
    if check is not None:
        check()
    return params


def replace(params: Any, **changes: Any) -> Any:
    """A validated copy of ``params`` with the fields named in ``changes`` (keyword arguments)
    changed; vectors may be given as lists or arrays. Raises :class:`ParameterError` as
    :func:`validate` does."""
    changes = {k: tuple(np.asarray(v, dtype=float).tolist()) if isinstance(v, (list, np.ndarray)) else v
               for k, v in changes.items()}
    return validate(dataclasses.replace(params, **changes))


def as_array(value: Any) -> np.ndarray:
    """``value``, a per-joint parameter tuple, as a float array (a copy, so the frozen defaults
    stay frozen)."""
    return np.array(value, dtype=float)

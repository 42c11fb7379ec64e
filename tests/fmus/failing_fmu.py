"""Toy FMU for the master's tests: fails at ``fail_at`` (an FMI error, or NaN on its output)."""
from __future__ import annotations

from dataclasses import dataclass

from fmus.common.fmi import FlexFusionSlave
from fmus.common.parameters import param


@dataclass(frozen=True)
class FailingParameters:
    fail_at: float = param(0.05, "s", "time from which the FMU fails")
    mode: str = param("error", "1", "error: doStep returns an FMI error; nan: y becomes NaN",
                      choices=("error", "nan"))


class Failing(FlexFusionSlave):
    """y = t until ``fail_at``, then an FMI error or NaN (test toy)."""

    parameters_class = FailingParameters
    nan_outputs = "pass"          # stands for a third-party FMU: the master must catch the NaN
    description = "failing test toy"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.input("u", unit="1", description="unused input")
        self.output("y", unit="1", description="t, or NaN after fail_at in mode nan")

    def setup(self, p):
        self.p = p

    def step(self, t, dt):
        t1 = t + dt
        if t1 > self.p.fail_at + 1e-12:
            if self.p.mode == "error":
                raise ValueError(f"toy failure: the solver diverged at t = {t1:.6g} s")
            self.y = float("nan")
            return
        self.y = t1

"""Toy FMU for the master's tests: ``y = gain * u + offset``, ``yv = gain * uv`` (direct feedthrough)."""
from __future__ import annotations

from dataclasses import dataclass

from fmus.common.fmi import FlexFusionSlave
from fmus.common.parameters import param


@dataclass(frozen=True)
class GainParameters:
    gain: float = param(1.0, "1", "gain")
    offset: float = param(0.0, "1", "offset")


class Gain(FlexFusionSlave):
    """Static gain with direct feedthrough (test toy)."""

    parameters_class = GainParameters
    description = "gain test toy"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.input("u", unit="1", description="input")
        self.input("uv", 2, unit="1", description="vector input")
        self.output("y", unit="1", description="gain * u + offset", depends_on=("u",))
        self.output("yv", 2, unit="1", description="gain * uv", depends_on=("uv",))

    def setup(self, p):
        self.p = p
        self.update_outputs()

    def update_outputs(self):
        self.y = self.p.gain * self.u + self.p.offset
        self.yv[:] = self.p.gain * self.uv

    def step(self, t, dt):
        self.update_outputs()

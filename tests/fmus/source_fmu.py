"""Toy FMU for the master's tests: a clock and a seeded noise source (no inputs).

After a step to ``t``: ``y = slope * t``, ``n`` = number of steps taken, ``ys = (t, 2 t) + offset``,
``noise`` a standard normal draw from a generator seeded by the parameter ``seed``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fmus.common.fmi import FlexFusionSlave
from fmus.common.parameters import param


@dataclass(frozen=True)
class SourceParameters:
    slope: float = param(1.0, "1", "slope of y")
    seed: int = param(0, "1", "noise seed", low=0)
    offset: tuple = param((0.0, 0.0), "1", "offset added to ys")
    enabled: bool = param(True, "1", "when false, noise stays 0")
    label: str = param("src", "1", "a string parameter (unused)")


class Source(FlexFusionSlave):
    """Clock, step counter and seeded noise (test toy)."""

    parameters_class = SourceParameters
    description = "source test toy"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.output("y", unit="1", description="slope * t")
        self.output("n", unit="1", description="number of steps taken")
        self.output("ys", 2, unit="1", description="(t, 2 t)")
        self.output("noise", unit="1", description="seeded standard normal noise")
        self.output("t_s", unit="s", description="time in seconds")

    def setup(self, p):
        self.p = p
        self.rng = np.random.default_rng(p.seed)
        self.count = 0

    def step(self, t, dt):
        t1 = t + dt
        self.count += 1
        self.y = self.p.slope * t1
        self.n = float(self.count)
        self.ys[:] = (t1 + self.p.offset[0], 2 * t1 + self.p.offset[1])
        self.noise = float(self.rng.standard_normal()) if self.p.enabled else 0.0
        self.t_s = t1

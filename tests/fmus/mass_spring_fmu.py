"""Toy FMU for the master's tests: a mass on a spring to the wall, coupled by a second spring
to another mass whose position is the input ``x_other`` (held constant over a step).

``m x'' = -k x - kc (x - x_other) - c x'``, integrated exactly over each step (matrix
exponential), so the only error of a coupled run is the coupling (zero-order hold) error.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

from fmus.common.fmi import FlexFusionSlave
from fmus.common.parameters import param


@dataclass(frozen=True)
class MassSpringParameters:
    m: float = param(1.0, "kg", "mass", low=0.0, low_inclusive=False)
    k: float = param(1.0, "N/m", "spring to the wall", low=0.0)
    kc: float = param(0.0, "N/m", "coupling spring to the other mass", low=0.0)
    c: float = param(0.0, "N.s/m", "damping", low=0.0)
    x0: float = param(0.0, "m", "initial position")
    v0: float = param(0.0, "m/s", "initial velocity")


class MassSpring(FlexFusionSlave):
    """A mass-spring with a coupling spring to another mass (test toy)."""

    parameters_class = MassSpringParameters
    description = "mass-spring test toy"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.input("x_other", unit="m", description="position of the coupled mass")
        self.output("x", unit="m", description="position")
        self.output("v", unit="m/s", description="velocity")

    def setup(self, p):
        self.p = p
        self.state = np.array([p.x0, p.v0])
        self.x, self.v = float(p.x0), float(p.v0)
        self._cache = {}

    def _phi(self, dt):
        if dt not in self._cache:
            p = self.p
            a = np.array([[0.0, 1.0, 0.0],
                          [-(p.k + p.kc) / p.m, -p.c / p.m, p.kc / p.m],
                          [0.0, 0.0, 0.0]])
            self._cache[dt] = expm(a * dt)
        return self._cache[dt]

    def step(self, t, dt):
        z = self._phi(dt) @ np.array([self.state[0], self.state[1], self.x_other])
        self.state = z[:2]
        self.x, self.v = float(z[0]), float(z[1])

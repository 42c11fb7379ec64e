"""Short force pulses on the tool: the rubber-hammer excitation of Henriksson et al. (2009),
section IV-A ("the tool is also hit a couple of times by a rubber hammer in both paths").

A strike at ``t0`` with peak ``F`` along the unit direction ``n`` (world x, z) is a half-sine

.. math::

    f(t) = F\\, n \\sin\\left(\\pi \\frac{t - t_0}{d}\\right), \\qquad t_0 \\le t < t_0 + d,

of duration ``d`` (a rubber hammer on a steel tool: a few milliseconds) and impulse
``2 F d / pi``. A master holds the force over each communication step (zero-order hold), so the
FMU outputs the *mean* of the pulse over the coming step (:func:`mean_force`): the impulse
delivered is exact for any step, even one longer than the pulse.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from fmus.common.parameters import ParameterError, param

PAPER = "Henriksson et al. 2009, section IV-A"
MAX_PULSES = 8


@dataclass(frozen=True)
class ForcePulseParameters:
    """Parameters of the ForcePulse FMU."""

    times: tuple = param((1.5, 4.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0), "s", "start times of up to "
                         f"{MAX_PULSES} strikes (<= 0: unused)", source=f"{PAPER}: a couple of strikes per path")
    amplitudes: tuple = param((400.0,) * MAX_PULSES, "N", "peak force of each strike (signed: "
                              "negative strikes push against the direction)", low=-1e5, high=1e5,
                              source="assumed: a rubber-hammer blow of a few 100 N")
    direction: tuple = param((1.0, 0.0), "1", "direction of the force ON the tool, world x and z "
                             "(normalised; must not be zero)")
    duration: float = param(0.008, "s", "duration of a half-sine pulse", low=0.0, low_inclusive=False,
                            high=1.0, source="assumed: rubber hammer on a steel tool, 5-10 ms")

    def check(self) -> None:
        """Checks across fields: a non-zero direction, one amplitude per time."""
        if math.hypot(*self.direction) < 1e-9:
            raise ParameterError(f"parameter 'direction' = {self.direction} must not be zero")
        if len(self.times) != len(self.amplitudes):
            raise ParameterError("parameters 'times' and 'amplitudes' must have the same length "
                                 f"({len(self.times)} and {len(self.amplitudes)})")

    def unit_direction(self) -> np.ndarray:
        """``direction`` normalised."""
        n = np.asarray(self.direction, float)
        return n / np.hypot(*n)


def pulse_force(t: float, times: Sequence[float], amplitudes: Sequence[float], duration: float) -> float:
    """Sum of the half-sine pulses at time ``t`` (scalar, along the direction, N): pulse ``i``
    starts at ``times[i]`` (s, 0 = unused), has peak ``amplitudes[i]`` (N) and lasts
    ``duration`` (s)."""
    f = 0.0
    for t0, a in zip(times, amplitudes):
        t0 = float(t0)
        if t0 > 0.0 and t0 <= t < t0 + duration:
            f += float(a) * math.sin(math.pi * (t - t0) / duration)
    return f


def _integral(t: float, t0: float, duration: float) -> float:
    """``int_{t0}^{t} sin(pi (s - t0) / d) ds`` with ``t`` clipped to the pulse."""
    s = min(max(t - t0, 0.0), duration)
    return duration / math.pi * (1.0 - math.cos(math.pi * s / duration))


def mean_force(t: float, dt: float, times: Sequence[float], amplitudes: Sequence[float],
               duration: float) -> float:
    """Mean of :func:`pulse_force` (pulses at ``times`` with peaks ``amplitudes``, each lasting
    ``duration``) over ``[t, t + dt]`` (``dt = 0``: the value at ``t``)."""
    if dt <= 0.0:
        return pulse_force(t, times, amplitudes, duration)
    total = 0.0
    for t0, a in zip(times, amplitudes):
        t0 = float(t0)
        if t0 > 0.0 and t + dt > t0 and t < t0 + duration:
            total += float(a) * (_integral(t + dt, t0, duration) - _integral(t, t0, duration))
    return total / dt


def impulse(amplitude: float, duration: float) -> float:
    """Impulse ``2 F d / pi`` (N s) of one half-sine strike of peak ``amplitude`` ``F`` (N) and
    ``duration`` ``d`` (s)."""
    return 2.0 * amplitude * duration / math.pi


__all__ = ["ForcePulseParameters", "pulse_force", "mean_force", "impulse", "MAX_PULSES"]

"""The reference measurement system of the papers (a laser tracker): plain math behind the
Tracker FMU (no FMI here).

The papers judge their estimators against a Leica laser tracker, not against the truth:

* Axelsson, Karlsson, Norrlöf (2012), section 5.1: "accuracy of 0.01 mm per meter and a sample
  rate of 1 kHz"; "the measured tool position is however not synchronized with the other
  measured signals, i.e., a manual synchronization is therefore needed, which can introduce
  small errors";
* Henriksson et al. (2009), section IV: Leica tracker, "1 kHz with an accuracy of 0.01 mm";
* the IMU paper, section 3.3: Leica LTD840, "accuracy on the order of 0.1 mm", 1 kHz.

:class:`TrackerModel` reproduces those three properties: white measurement noise, its own sample
rate with sample-and-hold, and a clock that runs ``skew`` behind the controller's (a sample
stamped ``t_k`` is the position at ``t_k - skew``, interpolated linearly from a short history of
the true position).
"""
from __future__ import annotations

from collections import deque
from itertools import islice
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from fmus.common.noise import BlockNormals, make_rng, reseed_param, reseeded_rng
from fmus.common.parameters import param


class TrackerModel:
    """Measured tool position: ``p_meas_k = p(t_k - skew) + e_k``, ``e_k ~ N(0, noise^2 I)``.

    The sample instants are ``t_k = t0 + k / sample_rate`` (``k = 0, 1, ...``) on the
    controller's clock; the output holds the newest sample ``t_k <= t`` and its stamp ``t_k``.
    The true position is known at the instants given to :meth:`update` and linearly
    interpolated in between (before the first instant it is the first position: the robot is at
    rest when the measurement starts). Sample instants need not fall on update instants.

    Parameters
    ----------
    noise
        White-noise standard deviation per axis and sample (m).
    sample_rate
        Sample rate (Hz), > 0.
    skew
        How far the tracker's clock lags the controller's (s), >= 0.
    seed, stream
        Seed and stream name of the noise (:func:`fmus.common.noise.make_rng`).
    """

    def __init__(self, noise: float, sample_rate: float, skew: float, seed: int = 0,
                 stream: str = "tracker") -> None:
        if not sample_rate > 0.0:
            raise ValueError(f"sample_rate must be > 0, got {sample_rate!r}")
        if not skew >= 0.0:
            raise ValueError(f"skew must be >= 0, got {skew!r}")
        self.noise, self.period, self.skew = float(noise), 1.0 / float(sample_rate), float(skew)
        self.stream = stream
        self._rng = BlockNormals(make_rng(seed, stream), 2)
        self._history: deque[tuple[float, float, float]] = deque()      # (t, x, z)
        self._t0 = 0.0
        self._k = 0                          # index of the next sample instant
        self.p_meas = np.zeros(2)
        self.t_meas = 0.0

    def reseed(self, seed: int) -> None:
        """Draw the noise from now on from ``seed``'s reseeded stream
        (:func:`fmus.common.noise.reseeded_rng`)."""
        self._rng = BlockNormals(reseeded_rng(seed, self.stream), 2)

    def _position(self, t: float) -> tuple[float, float]:
        """True position at ``t`` by linear interpolation in the history (held before it)."""
        h = self._history
        if t <= h[0][0]:
            return h[0][1], h[0][2]
        for (ta, xa, za), (tb, xb, zb) in zip(h, islice(h, 1, None)):
            if t <= tb:
                w = (t - ta) / (tb - ta) if tb > ta else 1.0
                return xa + w * (xb - xa), za + w * (zb - za)
        return h[-1][1], h[-1][2]

    def start(self, t0: float, p: Sequence[float]) -> None:
        """Begin at ``t0`` with the true position ``p``: the first sample, stamped ``t0``."""
        self._history.clear()
        self._t0, self._k = float(t0), 0
        self.update(t0, p)

    def update(self, t: float, p: Sequence[float]) -> None:
        """The true position is ``p`` at ``t`` (non-decreasing); take every sample due by ``t``."""
        self._history.append((float(t), float(p[0]), float(p[1])))
        while True:
            t_k = self._t0 + self._k * self.period
            if t_k > t + 1e-9 * self.period:
                break
            x, z = self._position(t_k - self.skew)
            e = self._rng.standard_normal(2)          # white noise: drawn even when noise = 0
            self.p_meas = np.array([x + self.noise * e[0], z + self.noise * e[1]])
            self.t_meas = t_k
            self._k += 1
        # keep what the next sample can need: back to one entry at or before (next t_k - skew)
        oldest = self._t0 + self._k * self.period - self.skew
        while len(self._history) > 1 and self._history[1][0] <= oldest:
            self._history.popleft()


LEICA = ("Axelsson et al. 2012, section 5.1 and Henriksson et al. 2009, section IV: Leica laser "
         "tracker, 1 kHz, accuracy 0.01 mm per metre of range")


@dataclass(frozen=True)
class TrackerParameters:
    """Parameters of the Tracker FMU."""

    noise: float = param(2e-5, "m", "white measurement noise std per axis and sample (0 = off)",
                         low=0.0, source=f"{LEICA}: 0.02 mm at the robot's 1.5-2 m range (the IMU "
                         "paper's LTD840: about 0.1 mm)")
    sample_rate: float = param(1000.0, "Hz", "sample rate; the output holds the newest sample",
                               low=0.0, low_inclusive=False, source=LEICA)
    skew: float = param(1e-3, "s", "how far the tracker's clock lags the controller's: a sample "
                        "stamped t_meas is the position at t_meas - skew (0 = synchronised)",
                        low=0.0, high=1.0, source="Axelsson et al. 2012, section 5.1: the tracker is "
                        "not synchronised with the robot's signals; assumed one 1 kHz sample")
    seed: int = param(4, "1", "seed of the noise stream", low=0)
    reseed: int = reseed_param()


__all__ = ["TrackerModel", "TrackerParameters"]

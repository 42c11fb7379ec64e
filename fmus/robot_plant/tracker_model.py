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

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from fmus.common import cython_kernels
from fmus.common.noise import make_rng, normal_rows, reseed_param, reseeded_rng
from fmus.common.parameters import param


# TrackerModel's state (a float array the kernel keeps): history entries, index of the next
# sample instant, the held sample's stamp, the next row of the drawn random numbers
_ENTRIES, _NEXT, _T_MEAS, _ROW = range(4)
_DONE, _FULL, _DRAWN = 0, 1, 2           # what tracker_update returns
_FLOAT = np.dtype(float)


# compiled (robot_plant/tracker_kernels.pyx: its names of the state's parts and of what it
# returns are these; tests/test_compiled_kernels.py holds them equal)
tracker_update = cython_kernels.load("robot_plant.tracker_kernels").tracker_update


class TrackerModel:
    """Measured tool position: ``p_meas_k = p(t_k - skew) + e_k``, ``e_k ~ N(0, noise^2 I)``.

    The sample instants are ``t_k = t0 + k / sample_rate`` (``k = 0, 1, ...``) on the
    controller's clock; the output holds the newest sample ``t_k <= t`` and its stamp ``t_k``.
    The true position is known at the instants given to :meth:`update` and linearly
    interpolated in between (before the first instant it is the first position: the robot is at
    rest when the measurement starts). Sample instants need not fall on update instants.
    One compiled call per update (:func:`tracker_update`).

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
    out
        Float array of ``dims`` the samples :attr:`p_meas` are written into (an FMU's output), or None.
    dims
        Coordinates of a position: 2 (world x, z; the planar arm) or 3 (x, y, z; the six-axis arm).
    """

    BLOCK = 256       # samples per draw of the random numbers

    def __init__(self, noise: float, sample_rate: float, skew: float, seed: int = 0,
                 stream: str = "tracker", out: np.ndarray | None = None, dims: int = 2) -> None:
        if not sample_rate > 0.0:
            raise ValueError(f"sample_rate must be > 0, got {sample_rate!r}")
        if not skew >= 0.0:
            raise ValueError(f"skew must be >= 0, got {skew!r}")
        self.noise, self.period, self.skew = float(noise), 1.0 / float(sample_rate), float(skew)
        self.stream = stream
        self._consts = np.array([0.0, self.period, self.skew, self.noise])
        self.dims = int(dims)
        self._hist = np.zeros((8, 1 + self.dims))   # (t, x, z) entries, grown when full
        self._state = np.zeros(4)
        self.p_meas = np.zeros(self.dims) if out is None else out
        self._rng = make_rng(seed, stream)
        self._draw()

    @property
    def t_meas(self) -> float:
        """The held sample's stamp (s, controller clock)."""
        return float(self._state[_T_MEAS])

    def _draw(self) -> None:
        self._rows = normal_rows(self._rng, self.dims, self.BLOCK)
        self._state[_ROW] = 0

    def reseed(self, seed: int) -> None:
        """Draw the noise from now on from ``seed``'s reseeded stream
        (:func:`fmus.common.noise.reseeded_rng`)."""
        self._rng = reseeded_rng(seed, self.stream)
        self._draw()

    def start(self, t0: float, p: Sequence[float]) -> None:
        """Begin at ``t0`` with the true position ``p``: the first sample, stamped ``t0``."""
        self._state[_ENTRIES] = self._state[_NEXT] = 0.0
        self._consts[0] = float(t0)
        self.update(t0, p)

    def update(self, t: float, p: Sequence[float]) -> None:
        """The true position is ``p`` (x, z) at ``t`` (non-decreasing); take every sample due by
        ``t``."""
        if type(p) is not np.ndarray or p.dtype is not _FLOAT:
            p = np.asarray(p, dtype=float)
        append = True
        while (done := tracker_update(t, p, append, self._hist, self._state, self._consts, self._rows,
                                      self.p_meas)) != _DONE:
            if done == _FULL:
                self._hist = np.concatenate([self._hist, np.zeros_like(self._hist)])
            else:
                self._draw()
                append = False


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

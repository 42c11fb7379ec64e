"""Seeded, reproducible noise for the sensor models.

Every random quantity in FlexFusion comes from a :class:`numpy.random.Generator` made by
:func:`make_rng` from an integer ``seed`` (an FMU parameter) and a stream name. Different stream
names give statistically independent generators for the same seed, so that e.g. the white noise
and the bias random walk of a sensor, or the accelerometer and the gyro of an IMU, never share
random numbers, and changing one noise level does not shift the random numbers of another
(common random numbers across a Monte Carlo or tuning study).

**Reseeding** (issue 17: a Monte Carlo after a common warm-up, orchestration/fork.py). A sensor
FMU has, besides its fixed ``seed``, a tunable parameter ``reseed`` (:func:`reseed_param`):
``-1`` (default) never reseeds; setting it to ``s >= 0`` restarts every noise stream of the
sensor at the current time from :func:`reseeded_rng` ``(s, stream)`` (set before initialisation
ends, from the start). Its streams are not those of any ``seed`` (the stream name gets
``"/reseed"``), so a fork never replays the numbers a run drew from its start, and the state the
streams had (bias walk, filters, held sample) carries on: only the random numbers to come change.
A run that never sets ``reseed`` draws exactly what it drew before the parameter existed.
"""
from __future__ import annotations

import zlib
from typing import Any

import numpy as np

from .parameters import param


def stream_key(stream: str) -> int:
    """A stable 32-bit hash of a stream name (CRC-32; unlike ``hash()`` it is not salted)."""
    return zlib.crc32(stream.encode("utf-8")) & 0xFFFFFFFF


def make_rng(seed: int, stream: str = "") -> np.random.Generator:
    """A deterministic generator for ``(seed, stream)``.

    Parameters
    ----------
    seed
        Non-negative integer seed (the ``seed`` parameter of an FMU or a scenario).
    stream
        Name of the random stream; different names give independent generators.

    Returns
    -------
    numpy.random.Generator
        PCG64 generator seeded with ``SeedSequence([seed, crc32(stream)])``.

    Raises
    ------
    ValueError
        If ``seed`` is negative or not an integer.
    """
    if isinstance(seed, bool) or int(seed) != seed or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence([int(seed), stream_key(stream)])))


def reseeded_rng(seed: int, stream: str = "") -> np.random.Generator:
    """The generator of ``stream`` after a reseed to ``seed`` (module docstring): independent of
    ``make_rng(s, stream)`` for every ``s``."""
    return make_rng(seed, f"{stream}/reseed")


def reseed_param() -> Any:
    """The tunable ``reseed`` parameter of a sensor (module docstring)."""
    return param(-1, "1", "restart the noise streams from this seed when set, also between steps "
                 "(tunable; -1 = never): a fork's new noise after a common warm-up", low=-1,
                 tunable=True, source="issue 17: a Monte Carlo after a common warm-up")


def white_noise(rng: np.random.Generator, sigma: float | np.ndarray, n: int) -> np.ndarray:
    """``n`` zero-mean Gaussian samples with standard deviation ``sigma`` (scalar or per channel).

    ``rng`` is the stream's generator (:func:`make_rng`); ``sigma`` is in the unit of the signal
    the noise is added to. The ``n`` standard normal numbers are always drawn, even when
    ``sigma`` is zero, so that the stream position does not depend on the noise level.
    """
    return np.asarray(sigma, dtype=float) * rng.standard_normal(n)


def random_walk_increment(rng: np.random.Generator, sigma_per_sqrt_s: float | np.ndarray,
                          dt: float, n: int) -> np.ndarray:
    """Increments of a Wiener process with intensity ``sigma_per_sqrt_s`` over ``dt`` seconds.

    ``rng`` is the stream's generator (:func:`make_rng`); ``sigma_per_sqrt_s`` is in the signal's
    unit per sqrt(s) (scalar or per channel); ``n`` increments (one per channel) are drawn. After a
    time ``t`` the walk has standard deviation ``sigma_per_sqrt_s * sqrt(t)``.
    """
    return np.asarray(sigma_per_sqrt_s, dtype=float) * np.sqrt(dt) * rng.standard_normal(n)


def normal_rows(rng: np.random.Generator, n: int, rows: int) -> np.ndarray:
    """The next ``rows`` draws of ``n`` standard normal numbers of the stream's generator
    ``rng`` (:func:`make_rng`), one draw per row: numpy's Generator keeps no state between draws
    but the bit generator's, so the rows of one ``standard_normal((rows, n))`` are the numbers
    of ``rows`` calls of ``standard_normal(n)``, in order. A compiled sensor takes them row by
    row (no call, about 1.5 us, per sample), and draws the same stream.
    """
    return rng.standard_normal((rows, n))


__all__ = ["normal_rows", "make_rng", "reseeded_rng", "reseed_param", "stream_key", "white_noise", "random_walk_increment"]

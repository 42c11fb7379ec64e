"""Error metrics of an estimate against the truth (pure numpy/scipy, no FMI).

* :func:`rmse` -- root mean square of the Euclidean error, eq. (27) of the 2012 paper
  (Axelsson, Karlsson, Gunnarsson, "Bayesian state estimation of a flexible industrial robot").
* :func:`bandpass_errors` -- max and mean of the error norm after a 3–30 Hz band-pass, as in
  Table I of the 2009 paper (Karlsson & Norrlöf / Henriksson et al., tool position estimation).
* :func:`max_error` -- largest Euclidean error.

A scenario's "truth" may be the plant's truth or a reference system's measurement (the papers'
laser tracker, with its own noise, rate and time skew): :func:`entries` records which.
"""
from __future__ import annotations

from typing import Any

import numpy as np
from scipy.signal import butter, filtfilt


def _error(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    e = np.asarray(estimate, dtype=float) - np.asarray(truth, dtype=float)
    if e.ndim == 1:
        e = e[:, None]
    return e


def rmse(estimate: np.ndarray, truth: np.ndarray) -> float:
    """Root mean square of the Euclidean error (2012 paper, eq. 27).

    Parameters
    ----------
    estimate, truth
        Arrays of shape (n,) or (n, d): one row per time.

    Returns
    -------
    float
        ``sqrt(1/n sum_k ||estimate_k - truth_k||^2)``.
    """
    e = _error(estimate, truth)
    if len(e) == 0:
        return float("nan")
    return float(np.sqrt(np.mean(np.sum(e * e, axis=1))))


def max_error(estimate: np.ndarray, truth: np.ndarray) -> float:
    """Largest Euclidean error ``max_k ||estimate_k - truth_k||`` of ``estimate`` against
    ``truth`` (rows are samples)."""
    e = _error(estimate, truth)
    if len(e) == 0:
        return float("nan")
    return float(np.max(np.linalg.norm(e, axis=1)))


def bandpass_errors(estimate: np.ndarray, truth: np.ndarray, fs: float, low: float = 3.0,
                    high: float = 30.0, order: int = 4, keep: np.ndarray | None = None) -> tuple[float, float]:
    """Max and mean of the error norm after a zero-phase band-pass (2009 paper, Table I: 3–30 Hz).

    Each error component is filtered with a Butterworth band-pass of the given ``order``
    applied forwards and backwards (``scipy.signal.filtfilt``, odd padding of three periods of
    ``low`` at each end); then ``|e_k|`` (Euclidean norm)
    is taken per sample.

    Parameters
    ----------
    estimate, truth
        (n,) or (n, d) arrays sampled at ``fs`` Hz.
    fs
        Sampling frequency (Hz).
    low, high
        Pass band (Hz), ``0 < low < high < fs/2``.
    keep
        Optional boolean mask of the samples that enter max and mean (the whole record is
        filtered first, so the filter's start-up does not fall into the kept part).

    Returns
    -------
    (float, float)
        ``max_k |e_k|`` and ``mean_k |e_k|`` of the band-passed error.
    """
    if not 0 < low < high < fs / 2:
        raise ValueError(f"band-pass needs 0 < low < high < fs/2, got low={low}, high={high}, fs={fs}")
    e = _error(estimate, truth)
    b, a = butter(order, [low, high], btype="bandpass", fs=fs)
    minimum = 3 * max(len(a), len(b))
    if len(e) <= minimum:
        raise ValueError(f"band-pass needs more than {minimum} samples, got {len(e)}")
    # odd padding of about three periods of the low corner: scipy's default (27 samples) leaves
    # a start-up transient of the high-pass part of up to 30 % inside the record
    padlen = min(len(e) - 1, max(minimum, int(np.ceil(3 * fs / low))))
    ef = filtfilt(b, a, e, axis=0, padlen=padlen)
    norm = np.linalg.norm(ef, axis=1)
    if keep is not None:
        norm = norm[np.asarray(keep, dtype=bool)]
    if len(norm) == 0:
        return float("nan"), float("nan")
    return float(np.max(norm)), float(np.mean(norm))


def at_sample_times(time: np.ndarray, estimate: np.ndarray, truth: np.ndarray, truth_time: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The fresh samples of a held, time-stamped truth (a reference system's measurement) and
    the estimate linearly interpolated to their stamps: ``(stamps, estimate, truth)``.

    A sample is fresh where ``truth_time`` changes (and the first row); held repeats are
    dropped, so the hold does not count as an error and the comparison is at the time the
    measurement says it belongs to."""
    time, truth_time = np.asarray(time, dtype=float), np.asarray(truth_time, dtype=float).reshape(-1)
    fresh = np.r_[True, np.diff(truth_time) != 0.0]
    stamps = truth_time[fresh]
    est = np.asarray(estimate, dtype=float)
    est = est.reshape(len(est), -1)
    interp = np.column_stack([np.interp(stamps, time, est[:, j]) for j in range(est.shape[1])])
    truth = np.asarray(truth, dtype=float)
    return stamps, interp.reshape((len(stamps),) + np.shape(estimate)[1:]), truth[fresh]


def compute(spec: Any, time: np.ndarray, estimate: np.ndarray, truth: np.ndarray,
            truth_time: np.ndarray | None = None) -> dict[str, float]:
    """Evaluate one scenario metric ``spec`` (:class:`orchestration.scenario.MetricSpec`) of
    ``estimate`` against ``truth``, rows sampled at ``time``.

    Returns ``{name: value}`` for ``rmse`` and ``max``, ``{name_max: .., name_mean: ..}`` for
    ``bandpass``. Samples with ``time < spec.after`` are left out. With ``truth_time`` (the
    truth's sample time stamps) only its fresh samples count (:func:`at_sample_times`).
    """
    if truth_time is not None:
        time, estimate, truth = at_sample_times(time, estimate, truth, truth_time)
    time = np.asarray(time, dtype=float)
    keep = time >= spec.after - 1e-12
    if spec.kind == "rmse":
        return {spec.name: rmse(estimate[keep], truth[keep])}
    if spec.kind == "max":
        return {spec.name: max_error(estimate[keep], truth[keep])}
    if spec.kind == "bandpass":
        fs = 1.0 / float(np.median(np.diff(time)))
        mx, mean = bandpass_errors(estimate, truth, fs, spec.low, spec.high, spec.order, keep=keep)
        return {f"{spec.name}_max": mx, f"{spec.name}_mean": mean}
    raise ValueError(f"unknown metric kind {spec.kind!r}")


def entries(spec: Any, values: dict[str, float]) -> dict[str, dict[str, Any]]:
    """The ``metrics.json`` entries of one spec's :func:`compute` values: each value with what
    it compares (``estimate``, ``truth``) and whether that ``truth`` is the plant's truth or a
    reference system's measurement (``against``: ``"truth"`` | ``"reference"`` | another role,
    :func:`orchestration.roles.against`)."""
    extra = {"truth_time": spec.truth_time} if spec.truth_time else {}
    return {name: {"value": v, "kind": spec.kind, "estimate": spec.estimate, "truth": spec.truth,
                   "against": spec.against, **extra} for name, v in values.items()}


__all__ = ["rmse", "max_error", "bandpass_errors", "at_sample_times", "compute", "entries"]

"""Error metrics of an estimate against the truth (pure numpy/scipy, no FMI).

* :func:`rmse` -- root mean square of the Euclidean error, eq. (27) of the 2012 paper
  (Axelsson, Karlsson, Gunnarsson, "Bayesian state estimation of a flexible industrial robot")
  over the samples of one run; :func:`rmse_over_runs` -- eq. (27) as the paper uses it, per
  time over Monte Carlo runs.
* :func:`bandpass_errors` -- max and mean of the error norm after a 3–30 Hz band-pass, as in
  Table I of the 2009 paper (Karlsson & Norrlöf / Henriksson et al., tool position estimation).
* :func:`max_error` -- largest Euclidean error.
* :func:`nees`, :func:`nis` -- consistency of a filter: the normalised estimation error squared
  against the truth with the filter's own covariance, and the normalised innovation squared
  (Bar-Shalom, Li, Kirubarajan 2001, "Estimation with applications to tracking and
  navigation", section 5.4). For a consistent filter each is chi-square distributed with as
  many degrees of freedom as states (measurements); :func:`chi2_band` gives the two-sided 95 %
  band, and :func:`monte_carlo_consistency` the average over N runs (ANEES, ANIS) with its band
  ``chi2(N dof) / N`` (ibid., eqs. 5.4.2-4 to 5.4.2-6).

A scenario's "truth" may be the plant's truth or a reference system's measurement (the papers'
laser tracker, with its own noise, rate and time skew): :func:`entries` records which.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from fmus.common import cython_kernels, disk_cache


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
        Arrays of shape (n,) or (n, d): one row per time (``truth = 0.0`` gives the RMS of
        ``estimate``).

    Returns
    -------
    float
        ``sqrt(1/n sum_k ||estimate_k - truth_k||^2)``.
    """
    e = _error(estimate, truth)
    if len(e) == 0:
        return float("nan")
    return float(np.sqrt(np.mean(np.sum(e * e, axis=1))))


def rmse_over_runs(error: np.ndarray) -> np.ndarray:
    """RMSE per time over Monte Carlo runs (2012 paper, eq. 27):
    ``sqrt(1/N_MC sum_j ||x_t - xhat_t^(j)||^2)`` (the paper applies it to each group of states
    apart: angular positions, velocities, accelerations).

    Parameters
    ----------
    error
        Estimate minus truth, (runs, times, d): run ``j``'s error at each time.

    Returns
    -------
    np.ndarray
        (times,).
    """
    e = np.asarray(error, dtype=float)
    return np.sqrt(np.mean(np.sum(e * e, axis=2), axis=0))


def max_error(estimate: np.ndarray, truth: np.ndarray) -> float:
    """Largest Euclidean error ``max_k ||estimate_k - truth_k||`` of ``estimate`` against
    ``truth`` (rows are samples)."""
    e = _error(estimate, truth)
    if len(e) == 0:
        return float("nan")
    return float(np.max(np.linalg.norm(e, axis=1)))


def bandpass_design(fs: float, low: float = 3.0, high: float = 30.0, order: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """The Butterworth band-pass of :func:`bandpass` as second-order sections and their
    steady-state initial conditions: ``(sos, zi)``, ``scipy.signal.butter(..., output="sos")``
    and ``scipy.signal.sosfilt_zi`` of it, shapes ``(order, 6)`` and ``(order, 2)``.

    Kept in the cache (:func:`fmus.common.disk_cache.cached_array`, by the four numbers), so
    that ``scipy.signal`` (0.9 s of CPU to import, 40 % of a flagship run) is imported only the
    first time a design is needed.

    Parameters
    ----------
    fs
        Sampling frequency (Hz).
    low, high
        Pass band (Hz).
    order
        Order of the Butterworth prototype.
    """
    def compute() -> np.ndarray:
        from scipy.signal import butter, sosfilt_zi
        sos = butter(order, [low, high], btype="bandpass", fs=fs, output="sos")
        return np.hstack([sos, sosfilt_zi(sos)])

    key = disk_cache.content_key("butter-bandpass-sos", float(fs), float(low), float(high), int(order))
    both = disk_cache.cached_array("bandpass", key, (order, 8), compute, keep=64)
    return np.ascontiguousarray(both[:, :6]), np.ascontiguousarray(both[:, 6:])


def bandpass(x: np.ndarray, fs: float, low: float = 3.0, high: float = 30.0, order: int = 4) -> np.ndarray:
    """``x`` through a zero-phase Butterworth band-pass along its first axis (2009 paper,
    Table I: 3–30 Hz): ``scipy.signal.sosfiltfilt`` with odd padding of three periods of
    ``low`` at each end (scipy's default of 27 samples leaves a start-up transient of the
    high-pass part of up to 30 % inside the record).

    Computed as scipy computes it, bit for bit (tests/test_metrics.py), from the cached design
    (:func:`bandpass_design`) and the compiled section cascade
    (``fmus/common/signal_kernels.pyx``), without importing ``scipy.signal``.

    The filter runs as second-order sections: at 1 kHz the 3 Hz corner puts the poles close to
    the unit circle, where the transfer-function form ``(b, a)`` of the same filter is
    ill-conditioned (its gain off by up to 5e-5 relative, and a last-bit change of the input
    moving the output by 5e-6; as sections: 1e-13).

    Parameters
    ----------
    x
        (n,) or (n, d) array sampled at ``fs`` Hz.
    fs
        Sampling frequency (Hz).
    low, high
        Pass band (Hz), ``0 < low < high < fs/2``.
    order
        Order of the Butterworth prototype (the band-pass has twice as many poles).

    Returns
    -------
    numpy.ndarray
        The filtered ``x``, same shape.
    """
    if not 0 < low < high < fs / 2:
        raise ValueError(f"band-pass needs 0 < low < high < fs/2, got low={low}, high={high}, fs={fs}")
    x = np.asarray(x, dtype=float)
    minimum = 3 * (2 * order + 1)           # scipy's own default padding: 3 (filter length)
    if len(x) <= minimum:
        raise ValueError(f"band-pass needs more than {minimum} samples, got {len(x)}")
    sos, zi = bandpass_design(fs, low, high, order)
    n = min(len(x) - 1, max(minimum, int(np.ceil(3 * fs / low))))
    rows = x.reshape(len(x), -1).T                                     # (signals, samples)
    ext = np.concatenate((2 * rows[:, :1] - rows[:, n:0:-1], rows,       # scipy's odd extension
                          2 * rows[:, -1:] - rows[:, -2:-(n + 2):-1]), axis=1)
    sosfilt = cython_kernels.load("common.signal_kernels").sosfilt
    y = np.ascontiguousarray(ext)
    sosfilt(sos, y, np.ascontiguousarray(zi[None] * y[:, :1, None]))
    y = np.ascontiguousarray(y[:, ::-1])
    sosfilt(sos, y, np.ascontiguousarray(zi[None] * y[:, :1, None]))
    return y[:, ::-1][:, n:-n].T.reshape(x.shape)


def bandpass_errors(estimate: np.ndarray, truth: np.ndarray, fs: float, low: float = 3.0,
                    high: float = 30.0, order: int = 4, keep: np.ndarray | None = None) -> tuple[float, float]:
    """Max and mean of the error norm after a zero-phase band-pass (2009 paper, Table I: 3–30 Hz).

    Each error component is filtered with a Butterworth band-pass of the given ``order``
    applied forwards and backwards (:func:`bandpass`); then ``|e_k|`` (Euclidean norm) is
    taken per sample.

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
    error = _error(estimate, truth)
    error = error.reshape(len(error), -1)
    squares = np.zeros(len(error))
    for j in range(error.shape[1]):       # a column at a time: the filter's temporaries (padded,
        filtered = bandpass(error[:, j], fs, low, high, order)   # reversed copies) of one column
        squares += filtered * filtered   # only; the same sums as np.linalg.norm(.., axis=1)
    norm = np.sqrt(squares)
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


def autocorrelation(x: np.ndarray, lags: int) -> np.ndarray:
    """Normalised sample autocorrelation of a series at lags ``1..lags``:
    ``rho_l = sum_k <d_k, d_{k+l}> / sum_k <d_k, d_k>`` with ``d = x - mean(x)`` (rows are
    times; a (K, m) series sums over its components). For a white series ``rho_l`` is about
    ``N(0, 1/K)`` (Mehra 1970, "On the identification of variances and adaptive Kalman
    filtering", IEEE Trans. Automatic Control 15(2): its whiteness test, 95 % band
    ``1.96 / sqrt(K)``).

    Raises
    ------
    ValueError
        Fewer than ``lags + 2`` samples, ``lags < 1``, or a constant series.
    """
    d = np.asarray(x, dtype=float)
    d = d.reshape(len(d), -1)
    if lags < 1 or len(d) < lags + 2:
        raise ValueError(f"an autocorrelation at {lags} lags needs at least {lags + 2} samples, got {len(d)}")
    d = d - d.mean(axis=0)
    c0 = float(np.sum(d * d))
    if not c0 > 0.0:
        raise ValueError("the series is constant: no autocorrelation")
    return np.array([float(np.sum(d[:-l] * d[l:])) / c0 for l in range(1, lags + 1)])


#: Lags of :func:`innovation_criterion`'s whiteness term.
WHITENESS_LAGS = 10


def innovation_criterion(statistic: np.ndarray, dof: int, squared: bool = True,
                         lags: int = WHITENESS_LAGS) -> dict[str, Any]:
    """A tuning criterion for a Kalman filter's Q and R that needs no truth: the consistency of
    its innovations (Bar-Shalom, Li, Kirubarajan 2001, "Estimation with applications to
    tracking and navigation", section 5.4.2: the NIS ``nu_k^T S_k^-1 nu_k`` of a consistent
    filter is chi-square with ``dof`` = measurement dimension degrees of freedom, eq. 5.4.2-7)
    and their whiteness (Mehra 1970: the innovations of the optimal filter are white; a wrong
    Q or R colours them).

    ``cost = ln(ANIS / dof)^2 + sum_{l=1..lags} rho_l^2``

    with ANIS the time average of the NIS and ``rho_l`` the normalised autocorrelation
    (:func:`autocorrelation`) of the NIS series. Both terms are zero for a consistent filter
    (up to sampling error: ``ANIS`` within :func:`chi2_band` (dof, K) for independent
    samples, ``K sum rho_l^2`` about chi-square(``lags``), the Box-Pierce statistic); Q too small
    makes the NIS too large and its sequence correlated (the filter lags: runs of large
    innovations), Q too large makes it too small.

    The whiteness term is on the NIS, the scalar every estimator of the contract gives
    (``nis`` or ``innovation_norm``), not on the innovation vector Mehra tests: for Gaussian
    innovations of unit variance ``corr(e_k^2, e_{k+l}^2) = rho_l^2`` (Isserlis), so it is
    zero exactly when the innovations are uncorrelated at that lag, and less sensitive near
    zero. A held statistic (a row that repeats the last update's value exactly: the filter did
    not update) is dropped, so the hold does not count as correlation.

    Parameters
    ----------
    statistic
        (K,) the filter's NIS per update, or its square root (``squared=False``).
    dof
        Degrees of freedom: the dimension of the measurement fused at each update.
    lags
        Lags of the whiteness term.

    Returns
    -------
    dict
        ``cost``, ``anis``, ``anis_band_95`` (:func:`chi2_band` (dof, K)), ``rho`` (list),
        ``box_pierce`` (``K sum rho_l^2``), ``box_pierce_95`` (its chi-square(lags) 95 %
        quantile) and ``samples`` K.

    Raises
    ------
    ValueError
        Too few samples, a non-positive ANIS or dof.
    """
    s = nis(statistic, squared=squared)
    s = s[np.r_[True, np.diff(s) != 0.0]]            # held repeats are not updates
    if dof < 1:
        raise ValueError(f"dof must be >= 1, got {dof}")
    anis = float(np.mean(s)) if len(s) else float("nan")
    if not anis > 0.0:
        raise ValueError(f"the average NIS must be positive, got {anis}")
    rho = autocorrelation(s, lags)
    from scipy.stats import chi2
    return {"cost": float(np.log(anis / dof) ** 2 + np.sum(rho * rho)), "anis": anis,
            "anis_band_95": list(chi2_band(dof, len(s))), "rho": rho.tolist(),
            "box_pierce": float(len(s) * np.sum(rho * rho)), "box_pierce_95": float(chi2.ppf(0.95, lags)),
            "samples": len(s), "dof": dof}


def packed_dimension(m: int) -> int | None:
    """``n`` of a covariance packed as its lower triangle in ``m = n (n + 1) / 2`` elements
    (None when ``m`` is no such number)."""
    n = int(round((np.sqrt(8 * m + 1) - 1) / 2))
    return n if n * (n + 1) // 2 == m else None


def unpack_covariance(packed: np.ndarray) -> np.ndarray:
    """Covariances (K, n, n) from their lower triangles packed row by row (K, n (n + 1) / 2),
    ``numpy.tril_indices(n)`` order (the estimator contract's ``P_x``)."""
    packed = np.atleast_2d(np.asarray(packed, dtype=float))
    m = packed.shape[1]
    n = packed_dimension(m)
    if n is None:
        raise ValueError(f"a packed covariance has n (n + 1) / 2 elements, got {m}")
    rows, cols = np.tril_indices(n)
    P = np.zeros((packed.shape[0], n, n))
    P[:, rows, cols] = packed
    P[:, cols, rows] = packed
    return P


def nees(error: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """Normalised estimation error squared ``e_k^T P_k^-1 e_k`` per time (Bar-Shalom et al.
    2001, eq. 5.4.2-1).

    Parameters
    ----------
    error
        (K, d) estimate minus truth.
    covariance
        (K, n (n + 1) / 2) the filter's covariances packed (:func:`unpack_covariance`), n >= d:
        the error's d states are the covariance's first d (their marginal covariance).
    """
    e = np.asarray(error, dtype=float)
    e = e[:, None] if e.ndim == 1 else e
    P = unpack_covariance(covariance)
    d = e.shape[1]
    if P.shape[1] < d:
        raise ValueError(f"the covariance is {P.shape[1]}x{P.shape[1]}, the error has {d} states")
    return np.einsum("ki,ki->k", e, np.linalg.solve(P[:, :d, :d], e[:, :, None])[:, :, 0])


def nis(statistic: np.ndarray, squared: bool = True) -> np.ndarray:
    """Normalised innovation squared ``nu_k^T S_k^-1 nu_k`` per time (Bar-Shalom et al. 2001,
    eq. 5.4.2-7), from the filter's output ``statistic``: the NIS itself (``squared``) or its
    square root, the normalised innovation norm (``innovation_norm`` of the estimator contract)."""
    s = np.asarray(statistic, dtype=float).reshape(-1)
    return s if squared else s * s


def chi2_band(dof: int, n_runs: int = 1, level: float = 0.95) -> tuple[float, float]:
    """Two-sided ``level`` band of the average of ``n_runs`` independent chi-square(``dof``)
    values: ``chi2.ppf((1 -+ level) / 2, n_runs dof) / n_runs`` (Bar-Shalom et al. 2001,
    eq. 5.4.2-5)."""
    a = (1.0 - level) / 2.0
    from scipy.stats import chi2                 # here, as scipy.signal: start-up cost
    lo, hi = chi2.ppf([a, 1.0 - a], dof * n_runs) / n_runs
    return float(lo), float(hi)


def monte_carlo_consistency(statistic: np.ndarray, dof: int, level: float = 0.95) -> dict[str, Any]:
    """The Monte Carlo average of a consistency statistic (NEES or NIS) over runs.

    Parameters
    ----------
    statistic
        (N, K): the statistic of N independent runs at K common times.
    dof
        Its degrees of freedom (states for NEES, measurements for NIS).

    Returns
    -------
    dict
        ``average`` (K,) the average over the runs per time (ANEES / ANIS), ``band`` its
        two-sided ``level`` band :func:`chi2_band` (dof, N), ``mean`` its time average and
        ``fraction_in_band`` the fraction of times inside the band (about ``level`` for a
        consistent filter).
    """
    s = np.atleast_2d(np.asarray(statistic, dtype=float))
    average = s.mean(axis=0)
    lo, hi = chi2_band(dof, s.shape[0], level)
    return {"average": average, "band": (lo, hi), "mean": float(average.mean()),
            "fraction_in_band": float(np.mean((average >= lo) & (average <= hi))),
            "runs": s.shape[0], "dof": dof}


def _rows(keep: np.ndarray) -> slice | np.ndarray:
    """The rows of the mask ``keep``: a slice where they are the last rows (the recorded time
    increases, so ``time >= after`` is), which indexes without copying the columns, else
    the mask itself."""
    start = int(np.argmax(keep)) if keep.any() else len(keep)
    return slice(start, None) if keep[start:].all() else keep


def compute(spec: Any, time: np.ndarray, estimate: np.ndarray, truth: np.ndarray | None,
            truth_time: np.ndarray | None = None, covariance: np.ndarray | None = None) -> dict[str, float]:
    """Evaluate one scenario metric ``spec`` (:class:`orchestration.scenario.MetricSpec`) of
    ``estimate`` against ``truth`` (and ``covariance`` for NEES), rows sampled at ``time``.

    Returns ``{name: value}`` for ``rmse`` and ``max``, ``{name_max: .., name_mean: ..}`` for
    ``bandpass``, ``{name: time average, name_in_band: fraction of samples inside the two-sided
    95 % chi-square band of one sample}`` for ``nees`` (with ``covariance``) and ``nis`` (the
    estimate is the filter's ``nis`` output or its ``innovation_norm``; no truth). Samples with
    ``time < spec.after`` are left out. With ``truth_time`` (the truth's sample time stamps)
    only its fresh samples count (:func:`at_sample_times`).
    """
    if spec.kind in ("nees", "nis"):
        keep = np.asarray(time, dtype=float) >= spec.after - 1e-12
        if spec.kind == "nees":
            stat = nees(_error(estimate, truth)[keep], np.asarray(covariance)[keep])
        else:
            stat = nis(np.asarray(estimate)[keep], squared=not spec.estimate.endswith("innovation_norm"))
        lo, hi = chi2_band(spec.dof)
        return {spec.name: float(np.mean(stat)) if len(stat) else float("nan"),
                f"{spec.name}_in_band": float(np.mean((stat >= lo) & (stat <= hi))) if len(stat) else float("nan")}
    if truth_time is not None:
        time, estimate, truth = at_sample_times(time, estimate, truth, truth_time)
    time = np.asarray(time, dtype=float)
    keep = time >= spec.after - 1e-12
    if spec.kind == "rmse":
        return {spec.name: rmse(estimate[_rows(keep)], truth[_rows(keep)])}
    if spec.kind == "max":
        return {spec.name: max_error(estimate[_rows(keep)], truth[_rows(keep)])}
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
    if spec.kind in ("nees", "nis"):
        extra.update(dof=spec.dof, band_95=list(chi2_band(spec.dof)),
                     **({"covariance": spec.covariance} if spec.covariance else {}))
    return {name: {"value": v, "kind": spec.kind, "estimate": spec.estimate, "truth": spec.truth,
                   "against": spec.against, **extra} for name, v in values.items()}


__all__ = ["rmse", "max_error", "bandpass", "bandpass_errors", "at_sample_times", "packed_dimension",
           "unpack_covariance", "nees", "nis", "autocorrelation", "innovation_criterion", "WHITENESS_LAGS",
           "chi2_band", "monte_carlo_consistency", "compute", "entries"]

"""The FMU adapter base of every estimator: each measurement fused at the time it was taken, the
update held pending until the next step, the last good estimate held after a divergence.

The sensors publish ``t_meas``, the time their held sample was taken; a filter takes it as an
optional input of the same name (:mod:`fmus.common.sample_time`). Design: the filter's state
stays anchored at the last fused measurement. For a measurement stamped ``t_meas``, newer than
that, the filter advances from the anchor to ``t_meas`` with it (predict, then update), and
outputs the prediction from there to the current time. A measurement that arrives late (a
Jacobi master such as libcosim hands it over one or two steps after it was taken) is so fused
exactly as if it had come on time, with no history to keep or re-filter: each sensor's stamps
only grow, so nothing ever arrives out of sequence. A held sample (the stamp of the last fused
one: a sensor slower than the filter) is not fused again, and one stamped after the current time
waits for the step that reaches it. A prediction over several filter periods runs period by
period (the filters' models and noise are per sample).

The update for the newest measurement stays pending until the next step: inputs set between
steps (time ``t``) replace one another, and ``do_step(t, T)`` commits the last one computed before
it, so that the measurements a Gauss-Seidel master (ours) sets before ``do_step(t, T)``, its
producers' values of ``t + T``, are fused after the prediction to ``t + T``. With ``t_meas``
unconnected the inputs are the measurement at the current time, which gives exactly that; the
sensors' stamps under our master say the same, so wiring them changes no result.

A filter with direct feedthrough (``feedthrough = True``: the Kalman and particle filters of
the 2012 and 2009 papers) fuses the inputs as soon as they are set, and its outputs at ``t`` are
the estimate with the measurement of ``t``. One without (the complementary filter, the IMU EKF,
the acceleration observer) fuses only in ``do_step``: its initial inputs start the filter
(``setup``), and are not fused again.
"""
from __future__ import annotations

import copy
import math
from typing import Any

from fmus.common.fmi import FlexFusionSlave
from fmus.common.kalman import FilterDivergence
from fmus.common.sample_time import (T_MEAS_DESCRIPTION, TIME_TOL, UNSTAMPED, intervals,
                                     measurement_time)


class FusionSchedule:
    """The fusion schedule of the module docstring, without FMI: the committed estimate and its
    time, the pending update and the stamp last fused. :class:`FilterAdapter` runs it for one
    filter in an FMU; the batched engine's EKF over runs
    (``fmus/estimators/ekf_accelerometer_batched.py``) runs the same code, so the two cannot
    drift apart. A user sets ``_est``, ``_t_state``, ``_t_fused``, ``_pending``, ``_step`` and
    the input ``t_meas``, and implements ``_predicted``, ``_fused`` (or ``_advanced``) and
    ``_show``, or ``_advanced_and_shown`` and ``_show_at`` (see :class:`FilterAdapter`)."""

    def _advanced(self, est: Any, t0: float, t1: float) -> Any:
        return self._fused(self._predicted_to(est, t0, t1))

    def _advanced_and_shown(self, est: Any, t0: float, t1: float, now: float) -> Any:
        new = self._advanced(est, t0, t1)
        self._show_at(new, t1, now)
        return new

    def _show_at(self, est: Any, t: float, now: float) -> None:
        self._show(self._predicted_to(est, t, now))

    def _committed(self, est: Any, t: float) -> None:
        pass

    def _predicted_to(self, est: Any, t0: float, t1: float) -> Any:
        if t1 <= t0 + TIME_TOL:
            return est
        n, T = intervals(t0, t1, self._step)
        for _ in range(n):
            est = self._predicted(est, T)
        return est

    def _commit(self) -> None:
        (self._t_state, self._est), self._pending = self._pending, None
        self._t_fused = self._t_state
        self._committed(self._est, self._t_state)

    def _fuse_and_show(self, t_m: float, now: float) -> None:
        """Fuse the measurement inputs stamped ``t_m`` (pending until the next step) and show
        the estimate at ``now``."""
        if t_m <= now + TIME_TOL:
            if self._pending is not None and t_m > self._pending[0] + TIME_TOL:
                self._commit()                          # a newer sample: the pending one is final
            if t_m > self._t_fused + TIME_TOL:          # not fused yet
                self._pending = (t_m, self._advanced_and_shown(self._est, self._t_state, t_m, now))
                return
        t, est = self._pending if self._pending is not None else (self._t_state, self._est)
        self._show_at(est, t, now)


class FilterAdapter(FusionSchedule, FlexFusionSlave):
    """Base of an estimator FMU (module docstring).

    A subclass declares its inputs and outputs (with :meth:`declare_t_meas`), calls
    :meth:`start_fusion` with the initial estimate at the end of its ``setup`` and implements:

    ``_predicted(est, T)``
        the estimate ``est`` predicted over ``T`` without a measurement (a new value: estimates
        are never changed); by default a shallow copy of ``est`` after its ``predict(T)``, for a
        model object that replaces its arrays rather than changing them;
    ``_fused(prior)``
        the measurement update of ``prior`` with the measurement inputs (a new value), or,
        instead, ``_advanced(est, T)``: ``est`` carried over ``T`` to the measurement inputs'
        time and updated with them (a filter whose prediction uses the measurement, e.g. an
        IMU's rates); ``T`` is 0 for the initial inputs of a filter with feedthrough;
    ``_show(est)``
        set the outputs from an estimate;
    ``_advanced_and_shown(est, t0, t1, now)`` and ``_show_at(est, t, now)`` (optional)
        instead of the three above, for a filter that does a fusion in one call: ``est`` (of
        time ``t0``) carried to the measurement inputs' time ``t1`` and updated with them (the
        result), and the result predicted on to ``now`` shown; ``est`` (of time ``t``)
        predicted to ``now`` and shown (by default from the three above);
    ``_before_step()`` (optional)
        read the inputs a step uses besides the measurements (e.g. the model's input);
    ``_committed(est, t)`` (optional)
        act on an update that became final (e.g. log a re-initialisation).

    ``divergence`` is the filter's exception for a non-finite or indefinite estimate: it ends the
    step with an FMI error naming the cause, as does every later step; the outputs keep the last
    good estimate (never NaN) and stay readable.
    """

    divergence: type[Exception] = FilterDivergence
    feedthrough = True

    def declare_t_meas(self) -> None:
        """Declare the optional input ``t_meas`` [s], the measurement inputs' stamp (start value
        :data:`~fmus.common.sample_time.UNSTAMPED`: unconnected)."""
        self.input("t_meas", unit="s", start=UNSTAMPED, description=T_MEAS_DESCRIPTION)

    def start_fusion(self, initial: Any) -> None:
        """Begin at the start time with the estimate ``initial``; fuse the initial inputs (with
        feedthrough) or count them as the measurement ``initial`` started from (without)."""
        self._est, self._t_state = initial, self._time   # the committed estimate and its time
        self._t_fused = -math.inf if self.feedthrough else self._time   # the stamp last committed
        self._pending: tuple | None = None  # (t_meas, estimate) fused, not committed
        self._diverged = ""
        if self.feedthrough:
            self._refresh(self._time)
        else:
            self._show(initial)

    def _predicted(self, est: Any, T: float) -> Any:
        est = copy.copy(est)
        est.predict(T)
        return est

    def _fused(self, prior: Any) -> Any:
        raise NotImplementedError

    def _show(self, est: Any) -> None:
        raise NotImplementedError

    def _before_step(self) -> None:
        pass

    def _refresh(self, now: float) -> None:
        """Fuse the measurement inputs at their time (pending until the next step) and set the
        outputs to the estimate at ``now``."""
        if self._diverged:
            return                                      # hold the last good estimate
        t_m = measurement_time(self.t_meas, now)
        try:
            self._fuse_and_show(t_m, now)
        except self.divergence as exc:
            self._diverged = f"{exc} (measurements of t = {t_m:.6g} s)"
            self._pending = None

    def update_outputs(self) -> None:
        """With feedthrough, fuse the inputs just set and show the estimate at the current time."""
        if self.feedthrough:
            self._refresh(self._time)

    def step(self, t: float, dt: float) -> None:
        """Advance from ``t`` to ``t + dt`` [s]: commit the update computed before this step,
        fuse the inputs at their stamp and show the estimate at ``t + dt``; a divergence raises
        ``divergence`` (this step and every later one)."""
        if self._pending is None and not self._diverged and self.feedthrough:
            self._refresh(t)
        if self._diverged:
            raise self.divergence(f"{self._diverged}; the outputs hold the last good estimate")
        if self._pending is not None:
            self._commit()             # the update computed before this step (see the module)
        self._before_step()
        self._refresh(t + dt)
        if self._diverged:
            raise self.divergence(self._diverged)


__all__ = ["FilterAdapter", "FusionSchedule"]

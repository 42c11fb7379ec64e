"""The FMU base of the filters that fuse each measurement at the time it was taken.

The sensors publish ``t_meas``, the time their held sample was taken; a filter takes it as an
optional input of the same name (:mod:`fmus.common.sample_time`). Design: the filter's state
stays anchored at the last fused measurement. For a measurement stamped ``t_meas``, newer than
that, the filter predicts from the anchor to ``t_meas``, updates, and outputs the prediction from
there to the current time. A measurement that arrives late (a Jacobi master such as libcosim
hands it over one or two steps after it was taken) is so fused exactly as if it had come on
time, with no history to keep or re-filter: each sensor's stamps only grow, so nothing ever
arrives out of sequence. A held sample (the stamp of the last fused one: a sensor slower than the
filter) is not fused again, and one stamped after the current time waits for the step that
reaches it. A prediction over several filter periods runs period by period (the filters' models
and noise are per sample).

The update for the newest measurement stays pending until the next step: inputs set between
steps (time ``t``) replace one another, and ``do_step(t, T)`` commits the last one computed before
it, so that the measurements a Gauss-Seidel master (ours) sets before ``do_step(t, T)``, its
producers' values of ``t + T``, are fused after the prediction to ``t + T``. With ``t_meas``
unconnected the inputs are the measurement at the current time, which gives exactly that; the
sensors' stamps under our master say the same, so wiring them changes no result.
"""
from __future__ import annotations

import math
from typing import Any

from fmus.common.fmi import FlexFusionSlave
from fmus.common.sample_time import (T_MEAS_DESCRIPTION, TIME_TOL, UNSTAMPED, intervals,
                                         measurement_time)


class StampedEstimator(FlexFusionSlave):
    """Base of a filter FMU with sample-time fusion (module docstring).

    A subclass declares its inputs and outputs (with :meth:`declare_t_meas`), calls
    :meth:`start_fusion` with the initial estimate at the end of its ``setup`` and implements:

    ``_predicted(est, T)``
        the estimate ``est`` predicted over ``T`` (a new value: estimates are never changed);
    ``_fused(prior)``
        the measurement update of ``prior`` with the measurement inputs (a new value);
    ``_show(est)``
        set the outputs from an estimate;
    ``_before_step()`` (optional)
        read the inputs a step uses besides the measurements (e.g. the model's input).

    ``divergence`` is the filter's exception for a non-finite or indefinite estimate: it ends the
    step with an FMI error naming the cause, as does every later step; the outputs keep the last
    good estimate (never NaN) and stay readable.
    """

    divergence: type[Exception] = FloatingPointError

    def declare_t_meas(self) -> None:
        self.input("t_meas", unit="s", start=UNSTAMPED, description=T_MEAS_DESCRIPTION)

    def start_fusion(self, initial: Any) -> None:
        """Begin at the start time with the estimate ``initial`` and fuse the initial inputs."""
        self._est, self._t_state = initial, self._time   # the committed estimate and its time
        self._t_fused = -math.inf          # the stamp of the last committed measurement
        self._pending: tuple | None = None  # (t_meas, estimate) fused, not committed
        self._diverged = ""
        self._refresh(self._time)

    def _predicted(self, est: Any, T: float) -> Any:
        raise NotImplementedError

    def _fused(self, prior: Any) -> Any:
        raise NotImplementedError

    def _show(self, est: Any) -> None:
        raise NotImplementedError

    def _before_step(self) -> None:
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

    def _refresh(self, now: float) -> None:
        """Fuse the measurement inputs at their time (pending until the next step) and set the
        outputs to the estimate at ``now``."""
        if self._diverged:
            return                                      # hold the last good estimate
        t_m = measurement_time(self.t_meas, now)
        try:
            if t_m <= now + TIME_TOL:
                if self._pending is not None and t_m > self._pending[0] + TIME_TOL:
                    self._commit()                      # a newer sample: the pending one is final
                if t_m > self._t_fused + TIME_TOL:      # not fused yet
                    prior = self._predicted_to(self._est, self._t_state, t_m)
                    self._pending = (t_m, self._fused(prior))
            t, est = self._pending if self._pending is not None else (self._t_state, self._est)
            self._show(self._predicted_to(est, t, now))
        except self.divergence as exc:
            self._diverged = f"{exc} (measurements of t = {t_m:.6g} s)"
            self._pending = None

    def update_outputs(self) -> None:
        self._refresh(self._time)

    def step(self, t: float, dt: float) -> None:
        if self._pending is None and not self._diverged:
            self._refresh(t)
        if self._diverged:
            raise self.divergence(f"{self._diverged}; the outputs hold the last good estimate")
        if self._pending is not None:
            self._commit()             # the update computed before this step (see the module)
        self._before_step()
        self._refresh(t + dt)
        if self._diverged:
            raise self.divergence(self._diverged)


__all__ = ["StampedEstimator"]

"""Sample times: the one convention by which sensors stamp their samples and estimators fuse
each measurement at the time it was taken, whatever the master's coupling scheme (plain
functions and constants, shared by both sides).

The sensors publish ``t_meas``, the time their held sample was taken
(:func:`fmus.robot_plant.sensor_model.input_time`); an estimator takes it as an optional input
of the same name. Unconnected, the input keeps its start value :data:`UNSTAMPED` and the
measurement inputs count as the measurement at the estimator's current time (the sensors'
convention under a Gauss-Seidel master, ours).
"""
from __future__ import annotations

from fmus.common.fmi import nominal_step

UNSTAMPED = -1.0     # start value of a stamp input (a sensor's t_truth, an estimator's t_meas): unconnected
TIME_TOL = 1e-9      # s: two times closer than this are one instant (hosts round times)
T_MEAS_DESCRIPTION = ("time the measurement inputs were sampled (the sensors' t_meas); "
                      "unconnected (negative): they count as the measurement at the end of the step")


def measurement_time(t_meas: float, now: float) -> float:
    """The time [s] of the measurement inputs: their stamp ``t_meas``, or ``now`` (the
    estimator's current time) when unstamped (negative, :data:`UNSTAMPED`)."""
    return t_meas if t_meas >= 0.0 else now


def span(t0: float, t1: float) -> float:
    """The length of the interval from ``t0`` to ``t1``, rounded as
    :func:`fmus.common.fmi.nominal_step` rounds the host's step (so that the interval of one
    communication step has the same bits as the step itself)."""
    return nominal_step(t1 - t0)


def intervals(t0: float, t1: float, step: float) -> tuple[int, float]:
    """The prediction from ``t0`` to ``t1`` as ``n`` equal intervals of about ``step`` (the
    estimator's sample period: its discrete model and noise are per sample), ``(n, length)``.

    The length is rounded as :func:`span` rounds.
    """
    length = t1 - t0
    n = max(1, round(length / step)) if step > 0.0 else 1     # NaN before the first step: 1
    return n, nominal_step(length / n)


__all__ = ["UNSTAMPED", "TIME_TOL", "T_MEAS_DESCRIPTION", "measurement_time", "span", "intervals"]

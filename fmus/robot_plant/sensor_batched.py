"""The Encoder and Imu FMUs' math for many runs at once (a leading run axis), for the batched
study engine (:mod:`orchestration.batched`). No FMI here.

Every run has its own seed; everything else is shared. :class:`RunSensorChannels` is
:class:`~fmus.robot_plant.sensor_model.SensorChannels` itself, elementwise on ``(runs, n)``
arrays, with each run's random numbers drawn from that run's own streams
(:func:`fmus.common.noise.make_rng` of its seed and the stream name), so run ``r`` gets exactly
the numbers the FMU with seed ``seeds[r]`` draws. :class:`BatchedEncoder` and
:class:`BatchedImu` follow the adapters (``encoder_fmu.py``, ``imu_fmu.py``) line by line: the
same calls, in the same order, on arrays with a run axis.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from fmus.common.noise import make_rng, normal_rows
from fmus.common.sample_time import UNSTAMPED
from fmus.robot_plant.sensor_model import SensorChannels, imu_reading, input_time


class RunStreams:
    """The standard normal numbers of one named stream for many seeds, served as one
    ``(runs, n)`` block per call, as :meth:`numpy.random.Generator.standard_normal` would
    give each seed's own generator call by call.

    Drawn ahead in blocks of ``block`` calls per generator (a generator's numbers do not depend
    on how the draws are split: ``standard_normal((k, n))`` is ``k`` calls of ``n``).
    """

    def __init__(self, seeds: Sequence[int], stream: str, block: int = 1000) -> None:
        self._rngs = [make_rng(int(s), stream) for s in seeds]
        self._block = int(block)
        self._buf: np.ndarray | None = None
        self._next = 0

    def rows(self, n: int) -> np.ndarray:
        """The numbers of the next ``block`` calls of ``n`` at once, ``(block, runs * n)``: one
        row per call, run after run."""
        return np.stack([normal_rows(g, n, self._block) for g in self._rngs], axis=1).reshape(self._block, -1)

    def standard_normal(self, n: int) -> np.ndarray:
        buf = self._buf
        if buf is None or self._next == buf.shape[0]:
            buf = self._buf = self.rows(n).reshape(self._block, len(self._rngs), n)
            self._next = 0
        if buf.shape[2] != n:
            raise ValueError(f"a run stream serves blocks of {buf.shape[2]} numbers, not {n}")
        self._next += 1
        return buf[self._next - 1]


class _Zeros:
    def __init__(self, runs: int, block: int) -> None:
        self.runs, self.block = runs, block

    def rows(self, n: int) -> np.ndarray:
        return np.zeros((self.block, self.runs * n))


class RunSensorChannels(SensorChannels):
    """:class:`SensorChannels` for ``len(seeds)`` runs: inputs, outputs and states are
    ``(runs, n)`` arrays, and run ``r`` draws from the streams of ``seeds[r]``."""

    BLOCK = 1000      # samples per draw of the run streams

    def __init__(self, n: int, seeds: Sequence[int], *, stream: str = "", **kwargs) -> None:
        super().__init__(n, seed=0, stream=stream, **kwargs)
        runs = len(seeds)
        self._rng_noise = RunStreams(seeds, f"{stream}/noise", self.BLOCK)
        # without a random walk its increments are zeros whatever is drawn: draw none
        self._rng_rw = (RunStreams(seeds, f"{stream}/bias_rw", self.BLOCK) if np.any(self.bias_rw)
                        else _Zeros(runs, self.BLOCK))
        self._allocate((runs, n))

    def _draws(self) -> tuple[np.ndarray, np.ndarray]:
        return self._rng_rw.rows(self.n), self._rng_noise.rows(self.n)


class BatchedEncoder:
    """The Encoder FMU (``encoder_fmu.py``) for many seeds: ``q_m`` ``(runs, 2)`` in,
    ``q_m_meas`` ``(runs, 2)`` out; the sample stamps ``t_truth`` / ``t_meas`` are shared
    (one time for every run)."""

    def __init__(self, p, seeds: Sequence[int]) -> None:
        self.channels = RunSensorChannels(
            2, seeds, stream="encoder", noise=p.noise, bias=p.bias, bias_rw=p.bias_rw,
            scale=p.scale, resolution=p.resolution, sample_rate=p.sample_rate, cutoff=p.cutoff,
            filter_order=p.filter_order)

    def initial(self, q_m: np.ndarray, t0: float, t_truth: float = UNSTAMPED) -> np.ndarray:
        q = self.channels.initial(q_m, input_time(t0, 0.0, t_truth))
        return np.broadcast_to(q, self.channels.output.shape).copy()

    def step(self, q_m: np.ndarray, t: float, dt: float, t_truth: float = UNSTAMPED) -> np.ndarray:
        return self.channels.step(q_m, dt, input_time(t, dt, t_truth))

    @property
    def t_meas(self) -> float:
        return self.channels.t_meas


class BatchedImu:
    """The Imu FMU (``imu_fmu.py``) for many seeds. The true kinematics (``a_sensor``,
    ``phi_tool``, ``omega_tool``) are the same in every run when the noise does not enter the
    closed loop (one row): then the ideal reading is computed once by the FMU's own
    :func:`imu_reading`; else run by run. ``gyro = False``: the gyro (its own noise streams)
    is not simulated and its reading is None."""

    def __init__(self, p, seeds: Sequence[int], gyro: bool = True) -> None:
        self.p = p
        self.runs = len(seeds)
        self.with_gyro = gyro
        self.acc = RunSensorChannels(
            3, seeds, stream="imu/acc", noise=p.acc_noise, bias=p.acc_bias, bias_rw=p.acc_bias_rw,
            scale=p.acc_scale, resolution=p.acc_resolution, range=p.acc_range, sample_rate=p.sample_rate,
            cutoff=p.acc_cutoff, filter_order=p.filter_order, names={"cutoff": "acc_cutoff"})
        self.gyro = RunSensorChannels(
            3, seeds, stream="imu/gyro", noise=p.gyro_noise, bias=p.gyro_bias,
            bias_rw=p.gyro_bias_rw, scale=p.gyro_scale, resolution=p.gyro_resolution,
            range=p.gyro_range, sample_rate=p.sample_rate, cutoff=p.gyro_cutoff,
            filter_order=p.filter_order, names={"cutoff": "gyro_cutoff"})

    def _ideal(self, a_sensor: np.ndarray, phi: np.ndarray, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        a_sensor = np.atleast_2d(a_sensor)
        phi, omega = np.ravel(phi), np.ravel(omega)
        rows = [imu_reading(a_sensor[i], float(phi[i]), float(omega[i]), self.p.mount_rpy, self.p.g)
                for i in range(a_sensor.shape[0])]
        return np.array([r[0] for r in rows]), np.array([r[1] for r in rows])

    def initial(self, a_sensor, phi, omega, t0: float, t_truth: float = UNSTAMPED) -> tuple[np.ndarray, np.ndarray]:
        acc, gyro = self._ideal(a_sensor, phi, omega)
        t = input_time(t0, 0.0, t_truth)
        shape = (self.runs, 3)
        return (np.broadcast_to(self.acc.initial(acc, t), shape).copy(),
                np.broadcast_to(self.gyro.initial(gyro, t), shape).copy() if self.with_gyro else None)

    def step(self, a_sensor, phi, omega, t: float, dt: float, t_truth: float = UNSTAMPED
             ) -> tuple[np.ndarray, np.ndarray]:
        acc, gyro = self._ideal(a_sensor, phi, omega)
        t_in = input_time(t, dt, t_truth)
        return self.acc.step(acc, dt, t_in), self.gyro.step(gyro, dt, t_in) if self.with_gyro else None

    @property
    def t_meas(self) -> float:
        return self.acc.t_meas


__all__ = ["RunStreams", "RunSensorChannels", "BatchedEncoder", "BatchedImu"]

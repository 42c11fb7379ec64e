"""FMU adapter of the wrist force/torque sensor between the robot and the tool (force part;
math in :mod:`fmus.robot_plant.sensor_model`; the impedance paper's eq. 1)."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from fmus.common.fmi import FlexFusionSlave
from fmus.common.parameters import param
from fmus.common.frames import G
from fmus.robot_plant.sensor_model import SensorChannels, force_sensor_reading

PAPER = "García, Robertsson, Gómez Ortega, Johansson (impedance paper)"
JR3 = "JR3 6-DOF wrist sensor class (the impedance paper's sensor): +-660 N, 16-bit output"


@dataclass(frozen=True)
class ForceTorqueSensorParameters:
    """Parameters of the ForceTorqueSensor FMU."""

    m_tool: float = param(12.0, "kg", "tool mass between the sensor and the tool tip", low=0.0,
                          low_inclusive=False, source=f"{PAPER}, section III (12 kg grinding tool)")
    mount_rpy: tuple = param((0.002, 0.003, -0.002), "rad", "mounting roll, pitch, yaw of the sensor "
                             "on the tool (R_mount = Rz(yaw) Ry(pitch) Rx(roll), sensor to tool); the "
                             "default is a mounting error nobody compensates (0 = ideal)",
                             low=-math.pi, high=math.pi,
                             source="assumed: flange and adapter-plate tolerances of about 0.1-0.2 deg")
    noise: float = param(0.5, "N", "white noise std per sample", low=0.0,
                         source="assumed, strain-gauge sensor of this range (about 0.1 % of range)")
    bias: tuple = param((0.0, 0.0, 0.0), "N", "constant offset per axis (after taring: 0)",
                        low=-660.0, high=660.0)
    bias_rw: float = param(0.01, "N/s0.5", "bias random-walk intensity per sqrt(s) (thermal drift)",
                           low=0.0, source="assumed: about 0.1 N drift over 100 s")
    scale: tuple = param((0.008, -0.005, 0.01), "1", "scale-factor error per axis (0 = ideal)",
                         low=-0.5, high=0.5, source="assumed within the calibration accuracy of "
                         "strain-gauge F/T sensors, about 1 % (JR3 / ATI data sheets)")
    resolution: float = param(2.0 * 660.0 / 2 ** 16, "N", "quantisation step (16 bit over +-660 N; "
                              "0 = off)", low=0.0, source=JR3)
    f_range: float = param(660.0, "N", "measuring range: readings saturate at it and set 'saturated'",
                           low=0.0, low_inclusive=False, source=JR3)
    cutoff: float = param(0.0, "Hz", "anti-aliasing low-pass cut-off (0 = off); must be below the "
                          "Nyquist frequency of the communication step", low=0.0)
    filter_order: int = param(2, "1", "anti-aliasing filter order (1 or 2, Butterworth)", low=1, high=2)
    sample_rate: float = param(0.0, "Hz", "sample rate with sample-and-hold (0 = every communication "
                               "step). Its period must be an integer multiple of the communication step",
                               low=0.0)
    g: float = param(G, "m/s2", "gravity", low=0.0)
    seed: int = param(3, "1", "seed of the noise streams", low=0)


def sensor_channels(p: ForceTorqueSensorParameters) -> SensorChannels:
    """The sensor's imperfections (noise, bias, scale, quantisation, range, rate, filter)."""
    return SensorChannels(
        3, seed=p.seed, stream="force_sensor", noise=p.noise, bias=p.bias, bias_rw=p.bias_rw,
        scale=p.scale, resolution=p.resolution, range=p.f_range, sample_rate=p.sample_rate,
        cutoff=p.cutoff, filter_order=p.filter_order)


def calibration_readings(p: ForceTorqueSensorParameters, phis: Sequence[float], n_samples: int = 500,
                         dt: float = 1e-3) -> np.ndarray:
    """Mean readings of this sensor at rest, free of contact, ``n_samples`` samples of ``dt`` in
    each tool angle of ``phis``: the data of :func:`fmus.robot_plant.sensor_model.calibrate_tool`.
    Returns (len(phis), 3)."""
    channels = sensor_channels(p)
    out = []
    for phi in phis:
        ideal = force_sensor_reading((0.0, 0.0), (0.0, 0.0), float(phi), p.m_tool, p.mount_rpy, p.g)
        out.append(np.mean([channels.step(ideal, dt) for _ in range(n_samples)], axis=0))
    return np.array(out)


class ForceTorqueSensor(FlexFusionSlave):
    """Wrist force in the sensor frame ``f_s = R_s^T (m_tool (a_tool - g_vec) - f_ext)`` with the
    sensor imperfections; ``saturated`` is 1 when a component is at or beyond ``f_range``.

    No direct feedthrough: the reading at ``t + dt`` is the sample of the inputs held over
    ``[t, t + dt)``. Right after initialisation the output is the noise-free reading of the
    initial inputs (at rest in free space: ``m_tool g`` on sensor z). The sample-period and
    cut-off checks need the communication step and so happen at the first ``doStep``.
    """

    parameters_class = ForceTorqueSensorParameters
    description = "Wrist force sensor: contact force + tool inertia + tool weight, sensor frame"

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.input("f_ext", 2, unit="N", description="contact force ON the tool, world x and z")
        self.input("a_tool", 2, unit="m/s2", description="tool acceleration, world x and z")
        self.input("phi_tool", unit="rad", description="tool angle about world y")
        self.output("f_s", 3, unit="N", description="measured wrist force, sensor frame",
                    start=(0.0, 0.0, 12.0 * G))
        self.output("saturated", unit="1", description="1 when a force component is at or beyond "
                    "the range f_range, else 0 (diagnostic)")
        self.channels: SensorChannels | None = None

    def _ideal(self):
        p = self.params
        return force_sensor_reading(self.f_ext, self.a_tool, self.phi_tool, p.m_tool, p.mount_rpy, p.g)

    def setup(self, p: ForceTorqueSensorParameters) -> None:
        self.channels = sensor_channels(p)
        self.f_s[:] = self.channels.initial(self._ideal())
        self.saturated = float(self.channels.saturated.any())

    def step(self, t: float, dt: float) -> None:
        self.f_s[:] = self.channels.step(self._ideal(), dt)
        self.saturated = float(self.channels.saturated.any())

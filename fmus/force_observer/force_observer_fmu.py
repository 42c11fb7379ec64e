"""FMU adapter of the contact-force observers (impedance paper, eqs. 1, 8-10, 11-19, 27-35).

The math is in :mod:`fmus.force_observer.force_observer_math`; this file declares the
variables, checks each reading and holds the state.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pythonfmu.enums import Fmi2Status

from fmus.common.frames import G
from fmus.common.fmi import FlexFusionSlave
from fmus.common.parameters import ParameterError, param
from fmus.force_observer import force_observer_math as fom

PAPER = "García, Robertsson, Gómez Ortega, Johansson (impedance paper)"


@dataclass(frozen=True)
class ForceObserverParameters:
    """Parameters of the ForceObserver FMU."""

    observer: str = param("lowpass", "1", "which observer: static (eqs. 8-10), kalman (eqs. 11-19) "
                          "or lowpass (eqs. 27-35)", choices=fom.OBSERVER_KINDS)
    m_tool: float = param(12.0, "kg", "tool mass between the force sensor and the tool tip, as the "
                          "observer knows it: from a tool calibration (fmus.robot_plant.sensor_model."
                          "calibrate_tool), not the true mass", low=0.0, low_inclusive=False,
                          source=f"{PAPER}, section III (12 kg grinding tool); the contact scenarios "
                          "use the calibrated 12.10 kg")
    k11: float = param(8.8, "Hz", "low-pass observer gain k11 (position innovation -> position), 1/s; "
                       "with k21 it sets the error dynamics s^2 + k11 s + k21 (eq. 28)", low=0.0,
                       low_inclusive=False, source=f"1 Hz, damping 0.7 (the paper's section V has 0.38)")
    k13: float = param(-0.0073, "s", "low-pass observer gain k13 (acceleration innovation -> position), s",
                       source=f"{PAPER}, section V")
    k21: float = param(39.5, "1", "low-pass observer gain k21 (position innovation -> velocity), 1/s^2",
                       low=0.0, low_inclusive=False, source=f"1 Hz, damping 0.7 (the paper's section V has 9.05)")
    k23: float = param(1.0, "1", "low-pass observer gain k23 (acceleration innovation -> velocity); "
                       "1 makes the estimate Newton's law (eq. 35)", low=0.0, high=1.0,
                       source=f"{PAPER}, eq. 35")
    sigma_f: float = param(20.0, "N", "Kalman observer: std of the unknown force per sample (process noise)",
                           low=0.0, low_inclusive=False)
    sigma_x: float = param(1e-4, "m", "Kalman observer: std of the tool position input", low=0.0,
                           low_inclusive=False)
    sigma_a: float = param(0.05, "m/s2", "Kalman observer: std of the accelerometer", low=0.0,
                           low_inclusive=False)
    f_range: float = param(660.0, "N", "force sensor range: a component at or beyond it is flagged "
                           "as saturated", low=0.0, low_inclusive=False, source="JR3 wrist sensor class")
    acc_range: float = param(156.9, "m/s2", "accelerometer range (16 g): at or beyond it is saturated",
                             low=0.0, low_inclusive=False)
    index_x: int = param(1, "1", "index (1-based) of the sensor-frame x component in f_s and acc_s",
                         low=1, high=3)
    index_z: int = param(3, "1", "index (1-based) of the sensor-frame z component in f_s and acc_s",
                         low=1, high=3)
    g: float = param(G, "m/s2", "gravity", low=0.0)

    def check(self) -> None:
        if self.index_x == self.index_z:
            raise ParameterError(f"parameters 'index_x' and 'index_z' must differ (both {self.index_x})")

    def config(self) -> fom.ObserverConfig:
        """The math module's configuration."""
        return fom.ObserverConfig(kind=self.observer, m=self.m_tool, k11=self.k11, k13=self.k13,
                                  k21=self.k21, k23=self.k23, sigma_f=self.sigma_f,
                                  sigma_x=self.sigma_x, sigma_a=self.sigma_a)


class ForceObserver(FlexFusionSlave):
    """Contact force from the wrist force sensor, the tool accelerometer and the tool position.

    Output ``f_contact_hat`` is the force the tool exerts ON the environment, world x and z
    (``= -f_ext`` of the ContactEnvironment; zero in free space, positive along the direction
    in which the tool pushes). ``f_raw`` is the raw reading in the same frame and sign with
    gravity removed (``F + m a``, eq. 1) for comparison.

    Bad input: a non-finite input or a saturated force/acceleration reading sets ``fault``
    (1 saturated, 2 not finite), counts it in ``n_faults``, logs a warning when a fault episode
    begins (or its kind changes), holds the last good estimate and freezes the observer state. No NaN ever leaves.
    """

    parameters_class = ForceObserverParameters
    nan_inputs = "pass"
    description = "Contact-force observer: static, Kalman or low-pass (force + acceleration fusion)"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.input("f_s", 3, unit="N", description="wrist force sensor reading, sensor frame")
        self.input("acc_s", 3, unit="m/s2", description="tool accelerometer specific force, sensor frame")
        self.input("p_tool", 2, unit="m", description="tool position (true or estimated), world x and z",
                   start=(1.2, 0.9))
        self.input("phi_tool", unit="rad", description="tool angle about world y (sensor to world rotation)")
        deps = ("f_s", "acc_s", "p_tool", "phi_tool")
        self.output("f_contact_hat", 2, unit="N", depends_on=deps,
                    description="estimated force of the tool on the environment, world x and z")
        self.output("f_raw", 2, unit="N", depends_on=deps,
                    description="raw force reading in the world, gravity removed (contact + inertia)")
        self.output("a_meas", 2, unit="m/s2", depends_on=deps,
                    description="tool acceleration from the accelerometer, world x and z")
        self.output("fault", unit="1", depends_on=deps,
                    description="reading fault: 0 none, 1 saturated, 2 not finite")
        self.output("n_faults", unit="1", description="number of steps with a faulty reading")

    def setup(self, params: ForceObserverParameters) -> None:
        self.core = fom.ForceObserverCore(params.config())
        self._ix, self._iz = params.index_x - 1, params.index_z - 1
        self._last_good = np.zeros(2)
        self._in_fault = 0             # fault code of the episode being flagged
        self._current: tuple | None = None
        self.update_outputs()

    def _readings(self) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
        p = self.params
        fault = fom.reading_fault(self.f_s, self.acc_s, p.f_range, p.acc_range)
        if not (np.all(np.isfinite(self.p_tool)) and np.isfinite(self.phi_tool)):
            fault = fom.FAULT_NOT_FINITE
        if fault == fom.FAULT_NOT_FINITE:
            return fault, self._last_good, np.zeros(2), np.zeros(2)
        f_xz = np.array([self.f_s[self._ix], self.f_s[self._iz]])
        a_xz = np.array([self.acc_s[self._ix], self.acc_s[self._iz]])
        u, a = fom.world_readings(f_xz, a_xz, float(self.phi_tool), p.m_tool, p.g)
        return fault, u, a, np.array(self.p_tool, dtype=float)

    def update_outputs(self) -> None:
        fault, u, a, x = self._readings()
        if fault == fom.FAULT_NONE:
            est = self.core.output(u, a, x)
            self.f_contact_hat[:] = est
            self.f_raw[:] = u
            self.a_meas[:] = a
            self._last_good = self.f_contact_hat.copy()    # what a fault holds: the last output
        else:
            self.f_contact_hat[:] = self._last_good        # hold; never a NaN
            if fault == fom.FAULT_SATURATED:
                self.f_raw[:] = u
                self.a_meas[:] = a
        self.fault = float(fault)
        self._current = (fault, u, a, x)

    def step(self, t: float, dt: float) -> None:
        if self._inputs_dirty or self._current is None:   # else the outputs are current
            self.update_outputs()
        fault, u, a, x = self._current
        if fault == fom.FAULT_NONE:
            self.core.advance(u, a, x, dt)
            self._in_fault = 0
        else:
            self.n_faults += 1.0
            if fault != self._in_fault:     # a new episode, or another kind of fault
                what = "saturated" if fault == fom.FAULT_SATURATED else "not finite"
                self.log(f"{self.instance_name}: force/acceleration reading {what} at t = {t:.6g} s "
                         f"(f_s = {list(self.f_s)}, acc_s = {list(self.acc_s)}); holding the last "
                         f"estimate {list(self._last_good)} N", Fmi2Status.warning)
            self._in_fault = fault
        self.update_outputs()

"""FMU adapter of the contact-force observers (impedance paper, eqs. 1, 8-10, 11-19, 27-35).

The math is in :mod:`fmus.force_observer.force_observer_math`; this file declares the
variables, checks each reading and holds the state.
"""
from __future__ import annotations

import numpy as np
from pythonfmu.enums import Fmi2Status

from fmus.common.fmi import FlexFusionSlave
from fmus.force_observer import force_observer_math as fom


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

    parameters_class = fom.ForceObserverParameters
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

    def setup(self, params: fom.ForceObserverParameters) -> None:
        self.core = fom.ForceObserverCore(params)
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

"""Ground truth for the 2009 EKF tests: the plant (:class:`dynamics.FlexibleRobotModel`) under the
motion controller on path P1 at 2 kHz, with rubber-hammer pulses on the tool, and the ideal (or
noisy) motor-angle and accelerometer samples the filters read.

Sample convention (the FMUs' timing): sample ``k`` at ``t_k = k T`` holds the state ``x_k``, the
measurements taken from it and the torque ``tau_k`` the controller computes from them, which the
plant then holds over ``[t_k, t_k + T)``.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from fmus.common import dynamics, kinematics
from fmus.common.robot_params import RobotParameters
from fmus.robot_plant import motion_control_model as mcm
from fmus.robot_plant.sensor_model import hammer_force

T = 5e-4                                   # 2 kHz, as in the paper
HAMMER_TIMES = (0.3, 1.45, 2.6)            # s
HAMMER_FORCE = (400.0, -250.0)             # N (world x, z), half-sine pulses
HAMMER_DURATION = 0.01                     # s


@lru_cache(maxsize=4)
def simulate(duration: float = 3.0, path: str = "p1", noise: bool = False, seed: int = 0) -> dict:
    """Closed-loop truth and the filters' inputs, as read-only arrays (cached)."""
    p = RobotParameters()
    ctrl = mcm.build_controller(mcm.MotionControllerParameters(path=path))
    plant = dynamics.FlexibleRobotModel(p, ctrl.model.q_a_ref0, substeps=1)
    n = int(round(duration / T)) + 1
    out = {k: np.zeros((n, m)) for k, m in (("x", 8), ("tau", 2), ("q_m", 2), ("acc_s", 3),
                                            ("p_tool", 2), ("v_sensor", 2))}
    rng = np.random.default_rng(seed)
    zero = np.zeros(2)
    for k in range(n):
        t = k * T
        x = plant.x
        f_ext = hammer_force(t, HAMMER_TIMES, HAMMER_FORCE, HAMMER_DURATION)
        ddq = plant.arm_acceleration(*f_ext)
        q_m = x[2:4].copy()
        f = kinematics.specific_force(x[0:2], x[4:6], ddq, p)
        if noise:
            q_m += rng.normal(0.0, 2e-5, 2)
            f = f + rng.normal(0.0, 0.02, 2)
        tau = ctrl.evaluate(t, q_m, x[6:8], zero).copy()
        ctrl.advance(T)
        out["x"][k] = x
        out["tau"][k] = tau
        out["q_m"][k] = q_m
        out["acc_s"][k] = (f[0], 0.0, f[1])
        out["p_tool"][k] = kinematics.tool_position(x[0:2], p)
        out["v_sensor"][k] = kinematics.velocity(x[0:2], x[4:6], p, "sensor")
        plant.step(tau, f_ext, T)
    out["t"] = np.arange(n) * T
    out["q_a0"] = tuple(float(v) for v in ctrl.model.q_a_ref0)
    for v in out.values():
        if isinstance(v, np.ndarray):
            v.flags.writeable = False
    return out


def run_filter(ekf, data: dict, n: int | None = None) -> dict:
    """Run an :class:`EkfFlexibleModel` over ``data``; filtered estimates per sample."""
    n = len(data["t"]) if n is None else n
    xs = np.zeros((n, 8))
    p_hat = np.zeros((n, 2))
    nu = np.zeros(n)
    for k in range(n):
        xf = ekf.update(data["q_m"][k], data["acc_s"][k], data["tau"][k])
        xs[k] = xf
        p_hat[k] = ekf.tool_position(xf)
        nu[k] = ekf.innovation_norm
        ekf.predict(T)
    return {"x": xs, "p_tool": p_hat, "innovation_norm": nu}


def bandpass(e: np.ndarray, lo: float = 3.0, hi: float = 30.0) -> np.ndarray:
    """Zero-phase 3-30 Hz band-pass (2nd-order Butterworth, forward-backward) along axis 0."""
    from scipy.signal import butter, sosfiltfilt
    sos = butter(2, (lo, hi), btype="bandpass", fs=1.0 / T, output="sos")
    return sosfiltfilt(sos, e, axis=0)

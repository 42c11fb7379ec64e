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
    xs = np.zeros((n, ekf.n))
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


def errors(p_hat: np.ndarray, data: dict) -> dict:
    """Max and mean tool-position error [m] of ``p_hat`` against the truth, over all
    frequencies and after the 3-30 Hz band-pass (the paper's Table I columns)."""
    e = np.linalg.norm(p_hat - data["p_tool"], axis=1)
    eb = np.linalg.norm(bandpass(p_hat - data["p_tool"]), axis=1)
    return dict(max=float(e.max()), mean=float(e.mean()), bp_max=float(eb.max()), bp_mean=float(eb.mean()))


def rigid_tool_position(data: dict) -> np.ndarray:
    """Rigid kinematics: the tool position from the motor angles over the gear ratios."""
    p = RobotParameters()
    r = np.asarray(p.gear_ratio)
    return np.array([kinematics.tool_position(q / r, p) for q in data["q_m"]])


def drift_table(noise: bool = False, corrections=("off", "tilt", "tilt_stiffness"),
                scales=(1.0, 0.5), **params) -> list[tuple]:
    """EKF Integrated with each drift correction, nominal and with the filter's stiffness scaled
    (0.5: the paper's 50 % error), beside rigid kinematics: rows ``(name, stiffness_scale,
    errors dict)``."""
    from fmus.estimators import ekf_flexible_model as em
    d = simulate(noise=noise)
    rows = [("rigid kinematics", s, errors(rigid_tool_position(d), d)) for s in scales[:1]]
    for corr in corrections:
        for s in scales:
            ekf = em.make_filter("integrated", q_a0=d["q_a0"], stiffness_scale=s,
                                 drift_correction=corr, **params)
            rows.append((f"EKF Integrated, {corr}", s, errors(run_filter(ekf, d)["p_tool"], d)))
    return rows


def main(argv=None) -> int:
    """Print :func:`drift_table` (``python tests/ekf_flexible_truth.py [--noise]``)."""
    import argparse
    ap = argparse.ArgumentParser(description="EKF Integrated's drift corrections on P1 (3 s, 2 kHz, "
                                 "three hammer strikes): tool-position errors in mm")
    ap.add_argument("--noise", action="store_true", help="sensor noise (encoder 2e-5 rad, accelerometer 0.02 m/s2)")
    ap.add_argument("--substeps", type=int, default=1, help="the filters' Euler steps per sample")
    args = ap.parse_args(argv)
    print(f"P1, {'noisy' if args.noise else 'noiseless'} sensors, {args.substeps} Euler step(s) per sample; "
          "tool-position error [mm]")
    print(f"{'estimator':<32} {'stiffness':>9} {'all max':>8} {'all mean':>9} {'3-30 max':>9} {'3-30 mean':>10}")
    for name, s, e in drift_table(noise=args.noise, substeps=args.substeps):
        print(f"{name:<32} {('x%.1f' % s) if 'EKF' in name else 'exact':>9} {e['max'] * 1e3:8.3f} "
              f"{e['mean'] * 1e3:9.3f} {e['bp_max'] * 1e3:9.4f} {e['bp_mean'] * 1e3:10.4f}", flush=True)
    return 0


if __name__ == "__main__":
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
    raise SystemExit(main())

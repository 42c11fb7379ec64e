"""Speed of the 2009 paper's observers through their FMUs (Henriksson et al. 2009, section IV-D).

Seconds of computation (wall clock; the CPU time of the process beside it, which is what counts
on a loaded machine) per second of 2 kHz data for each observer, driven through fmpy's
``FMU2Slave`` the way the master drives it (one batched ``setReal`` of the inputs, ``doStep``,
one batched ``getReal`` of the outputs per step), beside the paper's figures (MATLAB, 2009):
EKF Complete 4.9 s, EKF Integrated 2.6 s, EKF Motor 2.1 s, deterministic observer 0.17 s.

Add an observer by appending a :class:`Case` to :func:`cases` (FMU model identifier, the
inputs per step as a function of the step index, the outputs to read, and the paper's figure).

Run: ``.venv/bin/python benchmarks/observers_2009.py [--seconds S] [--only NAME ...]``.
"""
from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

REPO = Path(__file__).resolve().parent.parent
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from fmus.common import dynamics, kinematics                  # noqa: E402
from fmus.common.robot_params import RobotParameters          # noqa: E402

RATE = 2000.0                     # Hz, the paper's sample rate
T = 1.0 / RATE
Q_A0 = (0.1, -0.2)                # rad, a pose inside the workspace


@dataclass
class Case:
    """One observer to time.

    ``inputs(k)`` returns ``{input name: value or vector}`` for step ``k``; ``outputs`` are read
    after every step; ``paper_s_per_s`` is the paper's computation time per second of data.
    """

    name: str
    fmu: str
    inputs: Callable[[int], dict]
    outputs: tuple = ("p_tool_hat",)
    params: dict = field(default_factory=dict)
    paper_s_per_s: float | None = None


def _measurements() -> Callable[[int], dict]:
    """A consistent input stream: the robot swinging gently about ``Q_A0`` (motor angles from
    the static deflection, accelerometer from the kinematics, gravity-holding torque)."""
    p = RobotParameters()
    x0 = dynamics.static_equilibrium(Q_A0, p)
    r = np.asarray(p.gear_ratio)
    tau0 = dynamics.gravity_torque(Q_A0, p) / r

    def inputs(k: int) -> dict:
        t = k * T
        w = 2 * math.pi * 1.5
        q = np.asarray(Q_A0) + 0.02 * math.sin(w * t)
        dq = np.full(2, 0.02 * w * math.cos(w * t))
        ddq = np.full(2, -0.02 * w * w * math.sin(w * t))
        f = kinematics.specific_force(q, dq, ddq, p)
        q_m = r * (q + (x0[2:4] / r - x0[0:2]))
        return {"tau_m": tau0, "q_m_meas": q_m, "acc_s": (f[0], 0.0, f[1])}
    return inputs


def cases() -> list[Case]:
    """The observers to time (name, FMU, inputs, outputs, the paper's figure)."""
    meas = _measurements()
    no_acc = lambda k: {key: v for key, v in meas(k).items() if key != "acc_s"}   # noqa: E731
    params = {"q_a0": Q_A0}
    return [
        Case("EKF Complete", "EkfComplete", meas, ("p_tool_hat", "trace_P_p"), params, 4.9),
        Case("EKF Motor", "EkfMotor", no_acc, ("p_tool_hat", "trace_P_p"), params, 2.1),
        Case("EKF Integrated", "EkfIntegrated", meas, ("p_tool_hat", "trace_P_p"), params, 2.6),
        Case("Det. Observer", "AccelerationObserver", meas, ("p_tool_hat", "q_a_hat"), params, 0.17),
        Case("Det. Obs. + fusion", "AccelerationObserver", meas, ("p_tool_hat", "q_a_hat"),
             {**params, "drift_crossover": 1.0}, None),
    ]


def _vector_refs(vr: dict, name: str) -> list[int]:
    if name in vr:
        return [vr[name]]
    refs, i = [], 1
    while f"{name}[{i}]" in vr:
        refs.append(vr[f"{name}[{i}]"])
        i += 1
    if not refs:
        raise KeyError(f"no variable {name!r}")
    return refs


def time_case(case: Case, fmu_dir: Path, seconds: float = 2.0) -> dict:
    """Run ``case`` for ``seconds`` of 2 kHz data; returns timing figures."""
    from orchestration.fmu_host import Slave

    s = Slave(fmu_dir / f"{case.fmu}.fmu", case.params)
    n = int(round(seconds * RATE))
    first = case.inputs(0)
    in_refs = [r for k in first for r in _vector_refs(s.vr, k)]
    out_refs = [r for k in case.outputs for r in _vector_refs(s.vr, k)]
    values = [[float(v) for k in first for v in np.atleast_1d(case.inputs(j)[k])] for j in range(n + 1)]
    fmu = s.fmu
    fmu.setReal(in_refs, values[0])       # the samples at t = 0, as the master sets them
    s.init()
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        for j in range(n):
            fmu.setReal(in_refs, values[j + 1])      # Gauss-Seidel: the samples of t + T
            fmu.doStep(currentCommunicationPoint=j * T, communicationStepSize=T)
            fmu.getReal(out_refs)
    except Exception as exc:
        raise RuntimeError(f"{case.name} failed at step {j}: {exc}; log: {' | '.join(s.log[-3:])}") from None
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    s.close()
    return {"name": case.name, "us_per_step": wall / n * 1e6, "s_per_s": wall / seconds,
            "cpu_us_per_step": cpu / n * 1e6, "paper_s_per_s": case.paper_s_per_s}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=2.0, help="seconds of 2 kHz data per observer")
    ap.add_argument("--only", nargs="*", help="observer names or FMU identifiers")
    ap.add_argument("--fmu-dir", type=Path, help="built FMUs (default: build them into a temp dir)")
    args = ap.parse_args(argv)
    selected = [c for c in cases() if not args.only or c.name in args.only or c.fmu in args.only]
    with tempfile.TemporaryDirectory(prefix="observers_2009_") as tmp:
        fmu_dir = args.fmu_dir
        if fmu_dir is None:
            from orchestration.build import build_all
            fmu_dir = Path(tmp)
            build_all(fmu_dir, only=sorted({c.fmu for c in selected}), quiet=True)
        print(f"{'observer':<16} {'us/step':>8} {'CPU us/step':>12} {'s per s of 2 kHz data':>22} {'paper':>7}")
        for c in selected:
            r = time_case(c, fmu_dir, args.seconds)
            paper = "" if r["paper_s_per_s"] is None else f"{r['paper_s_per_s']:.2f}"
            print(f"{r['name']:<16} {r['us_per_step']:8.1f} {r['cpu_us_per_step']:12.1f} {r['s_per_s']:22.3f} "
                  f"{paper:>7}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

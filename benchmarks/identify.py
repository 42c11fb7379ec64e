"""Identification study: cost of one residual evaluation and the whole study's wall time.

Prints
* the cost of one closed-loop simulation of an experiment (the unit of the fit: a residual
  evaluation is one per experiment, a Jacobian one per experiment and parameter) and of the
  model's RK4 step inside it;
* the wall time of ``flexfusion study identify`` with its defaults (three experiments of 2.4 s)
  on ``--workers`` local processes (default 2), split into the FMU experiments and the fit,
  with the number of residual evaluations and the largest relative error against the plant.

Aim: the whole study under 2 minutes on 2 workers.

Run: ``.venv/bin/python benchmarks/identify.py [--workers K] [--skip-study]``.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from fmus.common import dynamics, kinematics  # noqa: E402
from fmus.common.robot_params import RobotParameters  # noqa: E402
from fmus.robot_plant.motion_control_model import MotionControllerParameters  # noqa: E402
from orchestration import identification as ident  # noqa: E402
from orchestration import study_identify  # noqa: E402

CSV = Path(study_identify.SCENARIOS) / "paths" / "identify_moves.csv"


def residual_cost(duration: float = 2.4, repeat: int = 5) -> tuple[float, float]:
    """Seconds per closed-loop simulation of one experiment, and per simulated step."""
    p = RobotParameters()
    n = int(round(duration / 1e-3))
    point = study_identify.WORKING_POINTS[0]
    ctrl = MotionControllerParameters(path="csv", csv_file=str(CSV), path_start=point,
                                      excitation_amplitude=(0.5, 0.5))
    x0 = dynamics.static_equilibrium(kinematics.inverse_kinematics(np.array(point), p), p)
    exp = ident.Experiment("bench", np.arange(n + 1) * 1e-3, np.zeros((n + 1, 2)), np.tile(x0[2:4], (n + 1, 1)),
                           np.zeros((n + 1, 3)), ctrl)
    theta = np.log(ident.parameter_values(p))
    ident.experiment_residual(theta, exp, p, ident.NoiseLevels())           # builds the reference table
    t0 = time.perf_counter()
    for _ in range(repeat):
        ident.experiment_residual(theta, exp, p, ident.NoiseLevels())
    per = (time.perf_counter() - t0) / repeat
    return per, per / n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--skip-study", action="store_true", help="only the residual cost")
    args = ap.parse_args()
    per, per_step = residual_cost()
    n_par = len(ident.NAMES)
    n_exp = len(study_identify.WORKING_POINTS)
    print(f"one experiment's residual (2.4 s at 1 kHz): {per * 1e3:.0f} ms = {per_step * 1e6:.1f} us per step")
    print(f"one residual evaluation ({n_exp} experiments): {n_exp * per:.2f} s serial; "
          f"one Jacobian ({n_par} columns): {n_exp * n_par * per:.1f} s serial")
    if args.skip_study:
        return
    from orchestration.study import open_executor
    with tempfile.TemporaryDirectory() as tmp, open_executor(args.workers) as ex:
        t0 = time.perf_counter()
        rep = study_identify.identify(study_identify.DEFAULT_SCENARIO, Path(tmp), ex, progress=False)
        wall = time.perf_counter() - t0
    worst = max(abs(p["relative_error"]) for p in rep["parameters"].values())
    t_exp = rep["experiments"]["wall_time_experiments"]
    print(f"study identify on {args.workers} workers: {wall:.1f} s (experiments {t_exp:.1f} s, "
          f"fit {wall - t_exp:.1f} s), "
          f"{rep['fit']['nfev']} residual evaluations, s^2 = {rep['fit']['s2']:.3g}, "
          f"largest relative error {worst:.2e}, biased: {', '.join(rep['biased']) or 'none'}")


if __name__ == "__main__":
    main()

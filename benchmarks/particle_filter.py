"""Speed of the 2012 particle filter with 10,000 particles (issue 16): this tree's filter
against a baseline commit's, interleaved in one process.

Prints the CPU time per filter step (``update`` + ``predict``, plain model, no FMI) at the
paper's 100 Hz with the EKF proposal (eq. 30) and the bootstrap proposal (eq. 28, the prior),
always resampling, on the smooth motion of :mod:`benchmarks.estimators_2012`: with the default
regularisation (``bandwidth`` 1: 60,000 more normal draws and a move per step) and, for the
bootstrap, also as plain Algorithm 1 (``bandwidth`` 0, the scenario's ``pf_alg1``); the
real-time factor (goals, one core: EKF proposal 1.5x, bootstrap 3x) and the speed-up over the
baseline. The baseline's filter module and its estimation model are loaded from git (the rest
from this tree); both filters see the same measurements and seed, and the estimates they end
with are printed side by side: equal to round-off until a round-off difference flips a
resampling decision (the weights are compared at 1e-12 in tests/test_particle_filter_model.py;
over runs the filters agree statistically, see docs/figures.md). The first measurement of numba on
the likelihood alone (``particle_filter_numba.py``, 1.1-1.2x) is retired: the filter's sampling,
weighting and resampling are compiled kernels now (:mod:`fmus.estimators.axelsson2012_batched`,
``particle_filter_model.propose_and_weigh``).

Run: ``.venv/bin/python benchmarks/particle_filter.py [--baseline REV] [--steps 40]``.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))

from estimators_2012 import Q0, signals  # noqa: E402
from flagship import old_modules  # noqa: E402

from fmus.estimators import particle_filter_model as pm  # noqa: E402

BASELINE = "f04d4a7"     # main before the compiled particle filter
T = 1e-2


def cpu_per_step(model, y, u, k0: int, k1: int) -> float:
    t0 = time.process_time()
    for k in range(k0, k1):
        model.update(y[k])
        model.predict(u[k], T)
    return (time.process_time() - t0) / (k1 - k0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", default=BASELINE, help="commit to compare with (default %(default)s)")
    ap.add_argument("--steps", type=int, default=40, help="timed filter steps per proposal")
    ap.add_argument("--particles", type=int, default=10000)
    args = ap.parse_args()
    old = old_modules(args.baseline, ["fmus/estimators/axelsson2012_model.py",
                                      "fmus/estimators/particle_filter_model.py"])[-1]
    print(f"particle filter, N = {args.particles}, T = {T * 1e3:.0f} ms, CPU ms per step "
          f"(update + predict), baseline {args.baseline} vs this tree")
    print(f"  {'proposal':9s} {'bandwidth':>9s} {'baseline':>9s} {'this tree':>9s} {'speed-up':>9s} {'RTF':>6s}"
          f" {'goal':>5s}   final q_a estimate (baseline / this tree)")
    for proposal, bandwidth, goal in (("ekf", 1.0, 1.5), ("prior", 1.0, 3.0), ("prior", 0.0, 3.0)):
        kw = dict(q_a0=Q0, proposal=proposal, n_particles=args.particles, bandwidth=bandwidth)
        models = [m.ParticleFilterModel(m.ParticleFilterParameters(**kw)) for m in (old, pm)]
        n = 10 + 2 * args.steps
        _, _, u, y = signals(n, T, pm.ParticleFilterParameters(**kw))
        cost = [0.0, 0.0]
        for f in models:                                      # warm-up
            cpu_per_step(f, y, u, 0, 10)
        for k in range(10, n, 2):                             # interleaved: the same load for both
            for i, f in enumerate(models):
                cost[i] += cpu_per_step(f, y, u, k, k + 2) / args.steps
        est = " / ".join(np.array2string(f.x[0:2], precision=12) for f in models)
        print(f"  {proposal:9s} {bandwidth:9.0f} {cost[0] * 1e3:9.2f} {cost[1] * 1e3:9.2f} {cost[0] / cost[1]:8.2f}x "
              f"{T / cost[1]:5.2f}x {goal:4.1f}x   {est}")


if __name__ == "__main__":
    main()

"""Per-step cost of the 2012 EKF's FMU adapter (``EkfAccelerometer``, issue 16): this tree against
a baseline commit, in one run.

The FMU class runs in this process, driven as our master drives it at 1 kHz (``set_real`` of the
measurements, jerk reference and stamp, then ``do_step`` and ``get_real`` of the flagship's
recorded outputs), on a smooth arm motion: its motor angles and accelerometer readings through
the model (eqs. 15-19) with noise, stamped on time. Timed: ``do_step`` plus ``get_real`` (the
step's adapter and filter, what ``benchmarks/flagship.py`` splits as ``step ekf`` plus the
output read), the median over the steps of a run (wall clock: a step the scheduler interrupted
is an outlier), the best of ``--repeat`` runs of each tree, interleaved (the machine is
shared: compare the ratio, not figures of different runs). No FMU is built: the baseline's
sources are exported with ``git archive``.

Run: ``.venv/bin/python benchmarks/ekf_step.py [--baseline REV] [--steps 2000] [--repeat 5]``
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
INPUTS = ("q_m_meas[1]", "q_m_meas[2]", "acc_s[1]", "acc_s[2]", "acc_s[3]", "t_meas", "dddq_a_ref[1]",
          "dddq_a_ref[2]")
OUTPUTS = ("p_tool_hat[1]", "p_tool_hat[2]", "q_a_hat[1]", "q_a_hat[2]", "dq_a_hat[1]", "dq_a_hat[2]")
H = 1e-3


def inputs(steps: int):
    """Rows of :data:`INPUTS` for ``steps + 1`` instants ``k H``: a smooth motion of both arm
    angles, its motor angles and accelerometer x, z readings (eqs. 15-19) with noise, its jerk."""
    import numpy as np

    from fmus.estimators import axelsson2012_model as am
    p = am.EkfAccelerometerParameters()
    t = np.arange(steps + 1) * H
    q0, amp, w = np.array(p.initial_angles()), np.array([0.05, 0.03]), np.array([3.0, 5.0])
    wt = np.outer(t, w)
    x = np.column_stack([q0 + amp * np.sin(wt), amp * w * np.cos(wt), -amp * w ** 2 * np.sin(wt)])
    model = am.MeasurementModel(p.robot(), am.Layout(True, False))
    y = np.array([model.h(xk) for xk in x]) + np.random.default_rng(1).normal(0.0, [3e-5, 3e-5, 2e-2, 2e-2],
                                                                             (len(t), 4))
    return np.column_stack([y[:, 0:2], y[:, 2], np.zeros(len(t)), y[:, 3], t, -amp * w ** 3 * np.cos(wt)])


def measure(path: str) -> float:
    """us per step (do_step + get_real) of the FMU class of the tree on the path, with the
    inputs saved at ``path``."""
    import numpy as np

    from fmus.estimators.ekf_accelerometer_fmu import EkfAccelerometer
    rows = np.load(path).tolist()
    s = EkfAccelerometer(instance_name="ekf")
    vr = {v.name: k for k, v in s.vars.items()}
    s.setup_experiment(0.0, None, None)
    s.enter_initialization_mode()
    in_vr, out_vr = [vr[n] for n in INPUTS], [vr[n] for n in OUTPUTS]
    s.set_real(in_vr, rows[0])
    s.get_real(out_vr)
    s.exit_initialization_mode()
    set_real, do_step, get_real, clock = s.set_real, s.do_step, s.get_real, time.perf_counter_ns
    spent = []
    for k in range(len(rows) - 1):
        set_real(in_vr, rows[k + 1])
        t0 = clock()
        ok = do_step(k * H, H)
        get_real(out_vr)
        spent.append(clock() - t0)
        if not ok:
            raise RuntimeError(f"the step at t = {k * H:.3f} s failed")
    return float(np.median(spent)) / 1000.0      # the median: a step the scheduler interrupted is an outlier


def _in_tree(tree: Path, path: str) -> float:
    env = dict(os.environ, PYTHONPATH=str(tree))
    out = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--measure", path], cwd=tree, env=env,
                         check=True, capture_output=True, text=True).stdout
    return float(out.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", default="c530927", help="commit to compare with (default %(default)s: "
                    "the adapter with one kernel per prediction and per update)")
    ap.add_argument("--steps", type=int, default=2000, help="steps of one run (1 kHz)")
    ap.add_argument("--repeat", type=int, default=5, help="runs of each tree, interleaved; the best counts")
    ap.add_argument("--measure", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.measure:
        measure(args.measure)                   # the first run compiles or loads the kernels
        print(measure(args.measure))
        return
    sys.path.insert(0, str(REPO))
    import numpy as np
    with tempfile.TemporaryDirectory(prefix="ff_ekf_step_") as tmp:
        archive = subprocess.run(["git", "archive", args.baseline], cwd=REPO, check=True, capture_output=True).stdout
        base = Path(tmp) / "baseline"
        base.mkdir()
        subprocess.run(["tar", "-x", "-C", str(base)], input=archive, check=True)
        path = str(Path(tmp) / "inputs.npy")
        np.save(path, inputs(args.steps))
        runs = [(_in_tree(base, path), _in_tree(REPO, path)) for _ in range(args.repeat)]
    old, new = (min(r[i] for r in runs) for i in (0, 1))
    print(f"EkfAccelerometer FMU class, do_step + get_real per 1 ms step, best of {args.repeat} "
          f"(baseline {args.baseline} vs this tree)")
    print(f"  baseline   {old:6.2f} us   (runs: {' '.join(f'{r[0]:.1f}' for r in runs)})")
    print(f"  this tree  {new:6.2f} us   (runs: {' '.join(f'{r[1]:.1f}' for r in runs)})   {old / new:.2f}x faster")


if __name__ == "__main__":
    main()

"""The flagship scenario in our master and, exported as SSP, in libcosim: the EKF's tool-position
RMS error (after 0.5 s) under each master.

Usage: ``python benchmarks/fmi_libcosim_flagship.py [STOP_TIME]`` (default 11 s, about 1.5 min;
the FMUs of ``dist/fmus`` or ``$FLEXFUSION_FMU_DIR``). libcosim runs in a subprocess
(``tests/cosim_runner.py``): pythonfmu FMUs run in the host's interpreter.

Measured (issue 13, 11 s): our master 0.108 mm, libcosim 0.384 mm (ratio 3.6; 42.6 mm before
the initialisation fix): libcosim hands the EKF its measurements two steps late. With the
measurements fused at their stamps (``t_meas``): our master 0.1078 mm (results bit-identical),
libcosim 0.211 mm (ratio 1.95; goal 1.25 not reached). The rest is one step of the sensors'
stamps: they say t + T (the value our Gauss-Seidel master sets before ``doStep(t, T)``) while
libcosim sets the value of t. Stamped t instead (an experiment), libcosim gives 0.0178 mm over
3 s against our 0.0171 mm, and our master would then be a step off: a sensor cannot know which
its host does; the producer (the plant) would have to stamp its outputs.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from orchestration.cli import export_ssp  # noqa: E402
from orchestration.fmpy_compat import exit_without_finalizers  # noqa: E402
from orchestration.master import run  # noqa: E402
from orchestration.metrics import rmse  # noqa: E402

STEP = 1e-3      # the flagship's base step
COLUMNS = ["plant.p_tool[1]", "plant.p_tool[2]", "ekf.p_tool_hat[1]", "ekf.p_tool_hat[2]"]


def main(stop: float) -> None:
    with tempfile.TemporaryDirectory(prefix="flexfusion_libcosim_") as tmp:
        compare(stop, Path(tmp))


def compare(stop: float, out: Path) -> None:
    scenario = REPO / "orchestration" / "scenarios" / "flagship.toml"
    overrides = [f"scenario.stop_time={stop}"]
    ssp = export_ssp(scenario, out / "flagship.ssp", overrides)
    t0 = time.perf_counter()
    ours = run(scenario, overrides, out_dir=out / "ours")
    keep = ours.time >= 0.5 - 1e-12
    e_ours = rmse(ours["ekf.p_tool_hat"][keep], ours["plant.p_tool"][keep])
    print(f"our master: EKF tool RMS error {e_ours * 1e3:.4f} mm ({time.perf_counter() - t0:.0f} s)")
    t0 = time.perf_counter()
    subprocess.run([sys.executable, str(REPO / "tests" / "cosim_runner.py"), str(ssp),
                    str(int(round(STEP * 1e9))), str(int(round(stop / STEP))), str(out / "cosim.json"),
                    *COLUMNS], cwd=REPO, env=dict(os.environ, PYTHONPATH=str(REPO)), check=False)
    data = json.loads((out / "cosim.json").read_text())
    if "error" in data:
        raise SystemExit(data["error"])
    v = {c: np.array(data["values"][c]) for c in COLUMNS}
    keep = np.array(data["time"]) >= 0.5 - 1e-12
    p = np.column_stack([v[c] for c in COLUMNS[:2]])[keep]
    p_hat = np.column_stack([v[c] for c in COLUMNS[2:]])[keep]
    e_cosim = rmse(p_hat, p)
    print(f"libcosim:   EKF tool RMS error {e_cosim * 1e3:.4f} mm ({time.perf_counter() - t0:.0f} s); "
          f"ratio {e_cosim / e_ours:.2f} (goal: within 1.25)")


if __name__ == "__main__":
    main(float(sys.argv[1]) if len(sys.argv) > 1 else 11.0)
    exit_without_finalizers(0)

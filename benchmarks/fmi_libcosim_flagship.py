"""The flagship scenario in our master and, exported as SSP, in libcosim: the EKF's tool-position
RMS error (after 0.5 s) under each master, for the flagship as shipped and for a host
comparison on the ideal plant with the nominal model (where the realistic plant's static errors,
about 0.35 mm, do not hide a timing error).

Usage: ``python benchmarks/fmi_libcosim_flagship.py [STOP_TIME]`` (default 11 s, about 3 min
for both cases; the FMUs of ``dist/fmus`` or ``$FLEXFUSION_FMU_DIR``). libcosim runs in a
subprocess (``orchestration/cosim_runner.py``): pythonfmu FMUs run in the host's interpreter.

Measured, issue 13, ideal plant and nominal model, 11 s: our master 0.108 mm throughout;
libcosim 42.6 mm while outputs read as zero in Initialization Mode, 0.384 mm with that fixed
(the measurements reached the EKF two steps late and were fused as current), 0.211 mm with
each fused at its sensor's stamp (``encoder.t_meas -> ekf.t_meas``; the sensors stamped the
time their inputs stand for under our master, t + T, while libcosim sets the plant's values of
t), and now, with the plant stamping its outputs (``plant.t_state -> *.t_truth``): 0.1100 mm
against 0.1078 mm (ratio 1.02; goal 1.25). The flagship as shipped: 0.3506 mm against 0.3497
(ratio 1.00; 0.3860 mm, ratio 1.10, without the plant's stamp). Our master's results are bit
for bit those without the plant's stamp. What is left (ideal, 3 s: 0.0178 against 0.0171 mm)
is not in the stamps. Replaying the EKF's model on our master's measurements (ideal, 3 s;
0.017070 mm, bit for bit the FMU's): the jerk reference one step late, as libcosim hands it
over, gives 0.017073 mm (it does not matter); the output predicted two steps from the last
sample, as under libcosim, 0.017204 mm (+0.8 %). The rest is most likely the motion itself: under
libcosim the controller's motor-angle feedback is one step older, and the true tool paths of
the two hosts differ by 0.20 mm RMS.
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
from orchestration.cosim_runner import RUNNER  # noqa: E402
from orchestration.master import run  # noqa: E402
from orchestration.metrics import rmse  # noqa: E402

STEP = 1e-3      # the flagship's base step
COLUMNS = ["plant.p_tool[1]", "plant.p_tool[2]", "ekf.p_tool_hat[1]", "ekf.p_tool_hat[2]"]


#: the ideal plant and the estimators' nominal model: a host comparison, where the realistic
#: plant's static errors (about 0.35 mm) would hide a one-step shift (tests/test_fmi_libcosim.py)
IDEAL = ["plant.ideal=true", "parameter_sets.identified_robot={}"]


def main(stop: float) -> None:
    with tempfile.TemporaryDirectory(prefix="flexfusion_libcosim_") as tmp:
        for label, extra in (("flagship as shipped", []), ("ideal plant, nominal model", IDEAL)):
            print(f"-- {label}, {stop:g} s")
            folder = Path(tmp) / ("ideal" if extra else "shipped")
            compare(stop, folder, extra)


def compare(stop: float, out: Path, extra: list[str]) -> None:
    scenario = REPO / "orchestration" / "scenarios" / "flagship.toml"
    overrides = [f"scenario.stop_time={stop}", *extra]
    out.mkdir(parents=True)
    ssp = export_ssp(scenario, out / "flagship.ssp", overrides)
    t0 = time.perf_counter()
    ours = run(scenario, overrides, out_dir=out / "ours")
    keep = ours.time >= 0.5 - 1e-12
    e_ours = rmse(ours["ekf.p_tool_hat"][keep], ours["plant.p_tool"][keep])
    print(f"our master: EKF tool RMS error {e_ours * 1e3:.4f} mm ({time.perf_counter() - t0:.0f} s)")
    t0 = time.perf_counter()
    subprocess.run([sys.executable, str(RUNNER), str(ssp),
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

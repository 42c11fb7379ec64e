"""The flagship scenario exported as SSP and run in libcosim (a standard master that reads
outputs in Initialization Mode and couples Jacobi-like) against our master.

Issue 13, the EKF's tool error over the 11 s flagship on the ideal plant with the nominal model
(``python benchmarks/fmi_libcosim_flagship.py``), under libcosim against our master's 0.108 mm:
42.6 mm while outputs read as zero in Initialization Mode (the EKF started from the zero pose);
0.384 mm with the initialisation fixed (the measurements reached the EKF two steps late, fused as
current); 0.211 mm with each fused at its sensor's stamp (``encoder.t_meas -> ekf.t_meas``), the
sensors stamping the time their inputs stand for under our master (t + T) while libcosim hands
them the plant's values of t; 0.110 mm (ratio 1.02) now that the plant stamps its outputs
(``plant.t_state -> encoder/imu/tracker.t_truth``). Here 1 s: 0.0360 against 0.0343 mm (ratio 1.05).
"""
from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("libcosimpy")

REPO = Path(__file__).resolve().parent.parent


def test_flagship_in_libcosim_starts_from_the_right_pose(tmp_path, fmu_env) -> None:
    from orchestration.cli import export_ssp
    from orchestration.master import run
    from orchestration.metrics import rmse
    from test_ssp import cosim

    scenario = REPO / "orchestration" / "scenarios" / "flagship.toml"
    # the ideal plant and the nominal model: a host comparison, not a model-error study (the
    # realistic plant's static errors would hide a one-step shift)
    overrides = ["scenario.stop_time=1.0", "plant.ideal=true", "parameter_sets.identified_robot={}"]
    ssp = export_ssp(scenario, tmp_path / "flagship.ssp", overrides)
    # the package carries the time stamps: the plant's to the sensors, the sensors' to the EKF
    ssd = zipfile.ZipFile(ssp).read("SystemStructure.ssd").decode()
    for sensor in ("encoder", "imu"):
        assert (f'startElement="plant" startConnector="t_state" endElement="{sensor}" '
                'endConnector="t_truth"' in ssd)
    assert ('startElement="encoder" startConnector="t_meas" endElement="ekf" endConnector="t_meas"'
            in ssd)
    ours = run(scenario, overrides, out_dir=tmp_path / "ours")
    cols = ["plant.p_tool[1]", "plant.p_tool[2]", "ekf.p_tool_hat[1]", "ekf.p_tool_hat[2]"]
    theirs = cosim(ssp, 1e-3, 1000, cols)
    p = np.column_stack([theirs[c] for c in cols[:2]])
    p_hat = np.column_stack([theirs[c] for c in cols[2:]])
    # the first step: the EKF was initialised from the measured pose, not from zero
    assert np.linalg.norm(p_hat[0] - p[0]) < 1e-3
    keep = theirs["time"] >= 0.5 - 1e-12
    error_libcosim = rmse(p_hat[keep], p[keep])
    k = ours.time >= 0.5 - 1e-12
    error_ours = rmse(ours["ekf.p_tool_hat"][k], ours["plant.p_tool"][k])
    assert error_ours < 1e-4
    # stamped by the plant, the sensors' samples carry their true time under both masters, and
    # the EKF's error is the same to within the 25 % goal (without the plant's stamp 5.4 times
    # ours, 0.186 mm against 0.034 mm; without any stamp 11 times)
    assert error_libcosim < 1.25 * error_ours, (error_libcosim, error_ours)

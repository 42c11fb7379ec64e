"""End to end: the flagship scenario (make demo) through the master, shortened."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from orchestration import CouplingWarning, run

FLAGSHIP = Path(__file__).resolve().parent.parent / "orchestration" / "scenarios" / "flagship.toml"


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    out = tmp_path_factory.mktemp("flagship")
    with pytest.warns(CouplingWarning):        # the control loop's sampled-data edge
        return run(FLAGSHIP, ["scenario.stop_time=2.5"], out_dir=out)


def test_flagship_runs_and_writes_results(result) -> None:
    out = Path(result.out_dir)
    for name in ("results.csv", "metrics.json", "run.json"):
        assert (out / name).stat().st_size > 0
    assert result.time[-1] == pytest.approx(2.5)
    assert np.isfinite(result["plant.p_tool"]).all()


def test_robot_follows_the_path_and_bends(result) -> None:
    """The tool tracks the reference to under a millimetre, yet differs from the rigid
    kinematics of the motor angles by more than 0.1 mm at the first corners: there is
    something for the estimators to recover."""
    tracking = np.hypot(*(result["plant.p_tool"] - result["controller.p_ref"]).T)
    deviation = np.hypot(*(result["rigid.p_tool_hat"] - result["plant.p_tool"]).T)
    assert tracking.max() < 1e-3
    assert deviation.max() > 0.1e-3
    assert result.metrics["rigid_position_rmse"] == pytest.approx(np.sqrt((deviation[result.time >= 0.5] ** 2).mean()))


def test_imu_at_the_start_reads_gravity(result) -> None:
    acc = result["imu.acc_s"][:200]
    assert np.allclose(np.linalg.norm(acc, axis=1), 9.81, atol=0.2)


def test_ekf_with_accelerometer_beats_rigid_kinematics_and_is_on_time(result) -> None:
    """The 2012 paper's EKF tracks the bending tool better than the motor angles alone, and its
    estimate belongs to the same time as the truth (no one-step offset: at 200 mm/s one step
    is 0.2 mm)."""
    after = result.time >= 0.5
    truth = result["plant.p_tool"]
    err = {n: np.hypot(*(result[f"{n}.p_tool_hat"] - truth).T)[after] for n in ("ekf", "rigid")}
    rms = {n: float(np.sqrt((e ** 2).mean())) for n, e in err.items()}
    assert rms["ekf"] < 0.5 * rms["rigid"], rms
    ekf = result["ekf.p_tool_hat"][after]
    shifted = np.hypot(*(ekf[1:] - truth[after][:-1]).T)     # estimate vs the truth a step earlier
    assert err["ekf"].mean() < 0.5 * shifted.mean()

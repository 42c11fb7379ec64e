"""The six-axis controller and sensors in a co-simulation (issue 23): MotionController6 on an
Encoder6, Imu3D with ArmPlaneImu, Tracker3D, around a stand-in of the six-axis plant FMU
(tests/fmus/six_axis: the numpy reference model behind the agreed interface) until
FlexibleRobot6DOF lands. Slow (the stand-in costs a few ms per step): ``make test-slow``."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import pythonfmu.builder  # noqa: F401 - before any FMU runs in this process (test_honest_signals.py)

from fmus.common import irb4600
from fmus.common.frames import G
from orchestration import run
from toys import TOYS

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def fmu_folder(every_fmu, tmp_path_factory) -> Path:
    """Every FlexFusion FMU and the stand-in plant in one folder."""
    from orchestration.build import build_all
    folder = tmp_path_factory.mktemp("six_axis_fmus")
    build_all(folder, quiet=True, scripts=[TOYS / "six_axis" / "six_axis_standin_fmu.py"])
    for name, fmu in every_fmu.items():
        (folder / fmu.name).symlink_to(fmu)
    return folder


def doc(q0, stop_time: float) -> dict:
    return {
        "connections": [
            "controller.tau_m -> plant.tau_m", "encoder.q_m_meas -> controller.q_m", "plant.q_m -> encoder.q_m",
            "plant.a_sensor -> imu.a_sensor", "plant.quat_tool -> imu.quat_tool",
            "plant.omega_tool -> imu.omega_tool", "plant.t_state -> encoder.t_truth",
            "plant.t_state -> imu.t_truth", "imu.acc_s -> plane.acc_s", "imu.gyro_s -> plane.gyro_s",
            "encoder.q_m_meas -> plane.q_m", "plant.p_tool -> tracker.p_tool",
            "plant.t_state -> tracker.t_truth",
        ],
        "delays": ["controller.tau_m -> plant.tau_m"],
        "scenario": {"name": "six_axis", "stop_time": stop_time, "base_step": 0.001, "seed": 1},
        "components": {
            "controller": {"fmu": "MotionController6", "parameters": {"path": "p1"}},
            "plant": {"fmu": "SixAxisStandIn", "parameters": {"q0": list(q0)}},
            "encoder": {"fmu": "Encoder6"},
            "imu": {"fmu": "Imu3D", "parameters": {"mount_rpy": [0.0, 0.0, 0.0]}},
            "plane": {"fmu": "ArmPlaneImu"},
            "tracker": {"fmu": "Tracker3D", "parameters": {"noise": 0.0}},
        },
        "record": {"variables": ["controller.p_ref", "plant.p_tool", "plant.q_a", "imu.acc_s", "plane.acc_arm",
                                 "tracker.p_tool_meas"]},
    }


def test_p1_through_the_encoders_and_the_3d_sensors(fmu_folder, monkeypatch, tmp_path) -> None:
    """1.1 s of P1 (0.6 s of motion) on the ideal stand-in: the drives on their quantised,
    noisy encoders track within 0.1 mm, as on the true motor angles (0.053 mm,
    tests/test_motion_control6.py: the feed-forward's 1 ms hold; the encoder's 1e-4 rad steps
    over the gear ratio 200 are 0.5 um of arm angle, about 1 um at the tool, and through the
    PID 5e-4 N m); at rest the IMU reads g's magnitude and
    its arm-plane reading has no component out of the plane of axes 2-3; the tracker follows
    in x, y, z with its 1 ms skew (1 m/s at most: 1 mm)."""
    monkeypatch.setenv("FLEXFUSION_FMU_DIR", str(fmu_folder))
    from fmus.robot_plant.trajectory6 import make_reference
    q0 = make_reference("p1").q0
    res = run(doc(q0, 1.1), out_dir=tmp_path)
    t = res.time
    err = np.linalg.norm(res["plant.p_tool"] - res["controller.p_ref"], axis=1)
    print(f"P1 tracking on the encoders: {err.max() * 1e3:.4f} mm at most")
    assert err.max() <= 1e-4
    start = irb4600.tool_pose(q0)[0]
    assert np.abs(res["plant.p_tool"][0] - start).max() <= 1e-5        # the stand-in's static sag
    rest = t < 0.4
    acc = res["imu.acc_s"][rest]
    assert np.all(np.abs(np.linalg.norm(acc, axis=1) - G) <= 0.15)        # noise 0.02 m/s2, 16-bit steps
    assert np.abs(res["plane.acc_arm"][rest][:, 1]).max() <= 0.1           # y: out of the plane
    lag = np.abs(res["tracker.p_tool_meas"] - res["plant.p_tool"]).max()
    assert lag <= 1.1e-3

"""Encoder, Imu, ForceTorqueSensor and ContactEnvironment built and exercised through fmpy."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description, simulate_fmu
from numpy.testing import assert_allclose, assert_array_equal

from fmu_host import Slave
from orchestration.build import validate_fmu

from fmus.common.frames import G

NAMES = ["Encoder", "Imu", "ForceTorqueSensor", "ContactEnvironment"]
STOP, DT = 0.05, 1e-3
N_ROWS = int(round(STOP / DT)) + 1
# the sensors' default calibration errors switched off (ideal mounting and scale)
IDEAL_IMU = {f"{v}[{i}]": 0.0 for v in ("mount_rpy", "acc_scale", "gyro_scale") for i in (1, 2, 3)}
IDEAL_FTS = {f"{v}[{i}]": 0.0 for v in ("mount_rpy", "scale") for i in (1, 2, 3)}


def sim(fmu_dir: Path, name: str, logger=None, **start_values) -> np.ndarray:
    return simulate_fmu(str(fmu_dir / f"{name}.fmu"), stop_time=STOP, output_interval=DT,
                        start_values=start_values, logger=logger, debug_logging=logger is not None)


def columns(result: np.ndarray, prefix: str) -> np.ndarray:
    """The columns ``prefix[1..n]`` of a result as an array (rows = time)."""
    names = [n for n in result.dtype.names if n.startswith(prefix + "[")]
    return np.column_stack([result[n] for n in names])


@pytest.mark.parametrize("name", NAMES)
def test_validates_and_declares_units_and_descriptions(fmu_dir, name):
    assert validate_fmu(fmu_dir / f"{name}.fmu") == []
    md = read_model_description(str(fmu_dir / f"{name}.fmu"))
    for v in md.modelVariables:
        assert v.description, f"{name}.{v.name} has no description"
        if v.type == "Real":
            assert v.unit, f"{name}.{v.name} has no unit"
    assert any(v.name == "seed" for v in md.modelVariables) or name == "ContactEnvironment"


@pytest.mark.parametrize("name", NAMES)
def test_runs_standalone_with_default_inputs(fmu_dir, name):
    r = sim(fmu_dir, name)
    assert len(r) == N_ROWS
    for col in r.dtype.names:
        assert np.all(np.isfinite(r[col])), f"{name}.{col} not finite"


def test_ideal_readings_at_rest(fmu_dir):
    imu = sim(fmu_dir, "Imu", **IDEAL_IMU)
    acc, gyro = columns(imu, "acc_s"), columns(imu, "gyro_s")
    assert_array_equal(acc[0], [0.0, 0.0, G])                    # valid right after initialisation
    # white noise 0.02 m/s2 plus a 200 Hz filter: 6 sigma of the unfiltered noise bounds it
    assert np.max(np.abs(acc - [0.0, 0.0, G])) < 6 * 0.02
    assert np.max(np.abs(gyro)) < 6 * 0.005
    ft = sim(fmu_dir, "ForceTorqueSensor", **IDEAL_FTS)
    f = columns(ft, "f_s")
    res = 2 * 660.0 / 2 ** 16
    assert_allclose(f[0], [0.0, 0.0, 12.0 * G], atol=res / 2)
    assert np.max(np.abs(f - [0.0, 0.0, 12.0 * G])) < 6 * 0.5 + res
    assert np.all(ft["saturated"] == 0.0)
    enc = columns(sim(fmu_dir, "Encoder"), "q_m_meas")
    lsb = 2 * math.pi / 2 ** 16
    assert_allclose(enc / lsb, np.round(enc / lsb), atol=1e-9)   # whole counts
    env = sim(fmu_dir, "ContactEnvironment")
    assert np.all(columns(env, "f_ext") == 0.0) and np.all(env["penetration"] == 0.0)


def test_default_calibration_errors_at_rest(fmu_dir):
    """By default the IMU and the force sensor are mounted slightly misaligned and have
    scale-factor errors: at rest they read (1 + scale) R_mount^T (0, 0, g) (times m_tool)."""
    from fmus.robot_plant.sensor_model import ForceTorqueSensorParameters
    from fmus.robot_plant.sensor_model import ImuParameters
    from fmus.common.frames import rot_rpy
    ip, fp = ImuParameters(), ForceTorqueSensorParameters()
    quiet = dict(acc_noise=0.0, acc_bias_rw=0.0, acc_resolution=0.0, gyro_noise=0.0, gyro_bias_rw=0.0)
    acc = columns(sim(fmu_dir, "Imu", **quiet), "acc_s")
    expected = (1 + np.array(ip.acc_scale)) * (rot_rpy(ip.mount_rpy).T @ [0.0, 0.0, G])
    assert_allclose(acc, np.tile(expected, (N_ROWS, 1)), atol=1e-12)
    assert 0.01 < np.hypot(acc[0, 0], acc[0, 1]) < 0.1          # 0.1-0.3 deg of tilt: a few cm/s2
    f = columns(sim(fmu_dir, "ForceTorqueSensor", noise=0.0, bias_rw=0.0, resolution=0.0), "f_s")
    expected = (1 + np.array(fp.scale)) * (rot_rpy(fp.mount_rpy).T @ [0.0, 0.0, fp.m_tool * G])
    assert_allclose(f, np.tile(expected, (N_ROWS, 1)), atol=1e-9)


def test_imu_rotated_mount_noise_free(fmu_dir):
    quiet = dict(acc_noise=0.0, acc_bias_rw=0.0, gyro_noise=0.0, gyro_bias_rw=0.0)
    r = sim(fmu_dir, "Imu", **quiet, **{**IDEAL_IMU, "mount_rpy[1]": math.pi / 2})
    assert_allclose(columns(r, "acc_s"), np.tile([0.0, G, 0.0], (N_ROWS, 1)), atol=1e-12)


@pytest.mark.parametrize("name, extra", [("Encoder", {"noise": 1e-3}), ("Imu", {}),
                                         ("ForceTorqueSensor", {})])
def test_seed_reproducible_and_distinct(fmu_dir, name, extra):
    a = sim(fmu_dir, name, seed=11, **extra)
    b = sim(fmu_dir, name, seed=11, **extra)
    c = sim(fmu_dir, name, seed=12, **extra)
    out = [n for n in a.dtype.names if n not in ("time", "saturated")]
    A, B, C = (np.column_stack([x[n] for n in out]) for x in (a, b, c))
    assert_array_equal(A, B)
    assert np.mean(A[1:] != C[1:]) > 0.5


@pytest.mark.parametrize("name, bad, word", [
    ("Encoder", {"noise": -1e-5}, "noise"),
    ("Imu", {"acc_noise": -0.01}, "acc_noise"),
    ("Imu", {"gyro_range": 0.0}, "gyro_range"),
    ("ForceTorqueSensor", {"m_tool": 0.0}, "m_tool"),
    ("ForceTorqueSensor", {"m_tool": -3.0}, "m_tool"),
    ("ContactEnvironment", {"stiffness": 0.0}, "stiffness"),
    ("ContactEnvironment", {"wall_normal[1]": 0.0, "wall_normal[2]": 0.0}, "wall_normal"),
])
def test_bad_parameter_rejected_at_initialisation(fmu_dir, name, bad, word):
    s = Slave(fmu_dir / f"{name}.fmu", bad)
    try:
        with pytest.raises(Exception, match="ExitInitializationMode"):
            s.fmu.exitInitializationMode()
        assert s.log.has("initialisation", f"'{word}"), s.log.messages
    finally:
        s.close()


@pytest.mark.parametrize("name", ["Encoder", "Imu", "ForceTorqueSensor"])
def test_sample_rate_not_dividing_the_step_fails(fmu_dir, name):
    s = Slave(fmu_dir / f"{name}.fmu", {"sample_rate": 300.0}, init=True)   # period 3.33 ms vs step 1 ms
    try:
        with pytest.raises(Exception, match="DoStep"):
            s.fmu.doStep(0.0, DT)
        assert s.log.has("'sample_rate'", "not an integer multiple"), s.log.messages
    finally:
        s.close()


def test_sample_rate_holds_between_samples(fmu_dir):
    # 250 Hz at a 1 ms step: a new noisy reading every 4 steps, held in between
    r = sim(fmu_dir, "ForceTorqueSensor", sample_rate=250.0)
    f = columns(r, "f_s")[1:]
    assert_array_equal(f[0::4][:12], f[1::4][:12])
    assert_array_equal(f[0::4][:12], f[3::4][:12])
    assert np.all(f[0::4][:11] != f[4::4][:11])


def test_hammer_pulse_through_fmu(fmu_dir):
    r = sim(fmu_dir, "ContactEnvironment", enabled=False, **{"hammer_times[1]": 0.01})
    t, f = r["time"], columns(r, "f_ext")
    expected = np.where((t >= 0.01) & (t < 0.015), 300.0 * np.sin(np.pi * (t - 0.01) / 0.005), 0.0)
    assert_allclose(f[:, 0], expected, atol=1e-9)
    assert_allclose(f[:, 1], 0.0)
    assert f[:, 0].max() > 250.0





def test_contact_environment_feedthrough(fmu_dir):
    s = Slave(fmu_dir / "ContactEnvironment.fmu", {"damping": 100.0}, init=True)
    try:
        assert_allclose(s.get("f_ext", 2), 0.0)
        s.set(p_tool=[1.302, 0.4])                           # 2 mm into the default wall
        assert_allclose(s.get("f_ext", 2), [-5000.0 * 0.002, 0.0], rtol=1e-12)
        assert s.get("penetration") == pytest.approx(0.002, rel=1e-12)
        s.set(v_tool=[0.05, 0.0])                            # moving in: damping adds
        assert_allclose(s.get("f_ext", 2), [-(10.0 + 5.0), 0.0], rtol=1e-12)
        s.set(v_tool=[-0.5, 0.0])                            # retracting fast: never pulls
        assert_allclose(s.get("f_ext", 2), 0.0)
        s.fmu.doStep(0.0, DT)
        s.set(p_tool=[1.2, 0.0])
        assert_allclose(s.get("f_ext", 2), 0.0)
        assert s.get("penetration") == 0.0
    finally:
        s.close()


def test_model_structure_dependencies(fmu_dir):
    md = read_model_description(str(fmu_dir / "ContactEnvironment.fmu"))
    deps = {u.variable.name: sorted(d.name for d in u.dependencies) for u in md.outputs}
    assert deps["f_ext[1]"] == ["p_tool[1]", "p_tool[2]", "v_tool[1]", "v_tool[2]"]
    for name in ["Encoder", "Imu", "ForceTorqueSensor"]:           # sampled: no feedthrough
        md = read_model_description(str(fmu_dir / f"{name}.fmu"))
        assert all(u.dependencies == [] for u in md.outputs), name


def test_force_sensor_saturation_flag(fmu_dir):
    # the 12 kg tool weighs 117.7 N: a 50 N range saturates sensor z and sets the flag
    r = sim(fmu_dir, "ForceTorqueSensor", f_range=50.0, noise=0.0, bias_rw=0.0, **IDEAL_FTS)
    f = columns(r, "f_s")
    res = 2 * 660.0 / 2 ** 16
    assert np.all(r["saturated"] == 1.0)
    assert np.all(f[:, 2] <= 50.0) and np.all(f[:, 2] > 50.0 - res)
    assert_allclose(f[:, :2], 0.0)

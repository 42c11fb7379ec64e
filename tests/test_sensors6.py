"""The six-axis robot's sensor math (fmus/robot_plant/sensor_model.py, tracker_model.py): the 3-D
IMU's readings, the arm-plane readings of the axis-2/3 estimators, the tracker in x, y, z. Well
under a second."""
from __future__ import annotations

import numpy as np

from fmus.common import irb4600, quaternion
from fmus.common.frames import G, rot_rpy
from fmus.robot_plant.sensor_model import arm_plane_reading, imu_reading, imu_reading_3d, mount_matrix
from fmus.robot_plant.tracker_model import TrackerModel

ARM = irb4600.arm()
RNG = np.random.default_rng(7)
POSES = RNG.uniform(-1.0, 1.0, (6, 6))


def test_a_static_tilted_imu_reads_minus_r_transpose_g() -> None:
    g_vec = np.array([0.0, 0.0, -G])
    mount = rot_rpy((0.02, -0.03, 0.05))
    for q in POSES:
        quat = irb4600.tool_pose(q, ARM)[1]
        R = quaternion.to_matrix(quat) @ mount
        acc, gyro = imu_reading_3d(np.zeros(3), quat, np.zeros(3), mount)
        assert np.abs(acc - (-R.T @ g_vec)).max() <= 1e-14 * G     # a rotation of g: round-off
        assert abs(np.linalg.norm(acc) - G) <= 1e-13
        assert not gyro.any()


def test_in_the_plane_the_3d_imu_is_the_planar_one() -> None:
    mount = (0.004, 0.003, -0.003)
    for phi, omega, a in ((0.3, 1.2, (2.0, -1.0)), (-1.1, -0.4, (0.5, 3.0))):
        acc, gyro = imu_reading_3d((a[0], 0.0, a[1]), quaternion.from_angle_y(phi), (0.0, omega, 0.0),
                                   mount_matrix(mount))
        acc2, gyro2 = imu_reading(a, phi, omega, mount)
        assert np.abs(acc - acc2).max() <= 1e-14 * G and np.abs(gyro - gyro2).max() <= 1e-15


def test_the_arm_plane_readings_are_the_forearms() -> None:
    """Turned by the wrist's angles, the reading of an IMU on the tool is that of the same IMU
    on a tool with the wrist at zero: gravity at rest lies in the plane of axes 2-3 (y = 0)."""
    mount = rot_rpy((0.01, 0.02, -0.01))
    for q in POSES:
        quat = irb4600.tool_pose(q, ARM)[1]
        omega = RNG.normal(size=3)
        acc, gyro = imu_reading_3d(np.zeros(3), quat, omega, mount)
        plane_acc, plane_gyro = arm_plane_reading(acc, gyro, q[3:], mount)
        R3 = irb4600.link_frames(q, ARM)[0][2] @ mount
        assert np.abs(plane_acc - R3.T @ np.array([0.0, 0.0, G])).max() <= 1e-13
        assert np.abs(plane_gyro - R3.T @ omega).max() <= 1e-14
    acc, gyro = imu_reading_3d(np.zeros(3), irb4600.tool_pose(POSES[0], ARM)[1], np.zeros(3), np.eye(3))
    assert abs(arm_plane_reading(acc, gyro, POSES[0][3:], np.eye(3))[0][1]) <= 1e-13


def test_the_tracker_in_3d_samples_the_skewed_position() -> None:
    tr = TrackerModel(0.0, 1000.0, 1e-3, dims=3)
    path = lambda t: np.array([1.0 + 0.1 * t, -0.2 * t, 0.9 + 0.05 * t * t])   # noqa: E731
    tr.start(0.0, path(0.0))
    for k in range(1, 50):
        tr.update(k * 2e-3, path(k * 2e-3))        # every other sample instant
        t_k = tr.t_meas
        assert abs(t_k - k * 2e-3) <= 1e-12
        # linear interpolation of the 2 ms history at t_k - skew: the quadratic z errs by
        # 0.05 (1 ms)^2 = 5e-8 m at most
        assert np.abs(tr.p_meas - path(t_k - 1e-3)).max() <= 5e-8 + 1e-15
    noisy = TrackerModel(2e-5, 1000.0, 0.0, seed=3, dims=3)
    noisy.start(0.0, path(0.0))
    samples = []
    for k in range(1, 400):
        noisy.update(k * 1e-3, path(0.0))
        samples.append(noisy.p_meas.copy())
    s = np.std(np.array(samples), axis=0)
    assert np.all(np.abs(s - 2e-5) <= 0.2e-5)        # 399 samples: the std's 3.5 % standard error, 5 sigma

"""Frames of the planar arm and its sensors (plain math, no FMI): gravity, rotations, the rigid
sensor mount and the planar tool pose in 3-D.

World frame (DESIGN.md): x forward, z up, origin at joint 2; the arm moves in the x-z plane and
the tool frame is the world frame rotated by the tool angle ``phi`` about +y, ``Ry(phi)``. A
sensor's frame is rotated from the tool frame by its mounting rotation (roll, pitch, yaw).
Quaternions follow :mod:`fmus.common.quaternion` (Hamilton, scalar first, body to world).
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from fmus.common.quaternion import conjugate, from_angle_y, from_matrix, multiply, normalise, rotate

G = 9.81  #: standard gravity [m/s^2], the one value every model uses


def rot_y(phi: float) -> np.ndarray:
    """``Ry(phi)``: tool frame to world (rotation about +y)."""
    c, s = math.cos(phi), math.sin(phi)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_rpy(rpy: Sequence[float]) -> np.ndarray:
    """Mounting rotation from ``rpy`` = (roll, pitch, yaw) [rad] (``Rz(yaw) @ Ry(pitch) @ Rx(roll)``),
    sensor to tool."""
    r, p, y = (float(v) for v in rpy)
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    return rz @ ry @ rx


def sensor_rotation(phi: float, mount_rpy: Sequence[float]) -> np.ndarray:
    """``R_s = Ry(phi) @ R_mount``: sensor frame to world, for the tool angle ``phi`` [rad] and
    the mounting rotation ``mount_rpy`` (roll, pitch, yaw [rad], :func:`rot_rpy`)."""
    return rot_y(phi) @ rot_rpy(mount_rpy)


class RigidMount:
    """A sensor rigidly mounted on the tool: its point at ``lever_arm`` (tool frame) and its frame
    rotated by ``mount_matrix`` (sensor to tool) from the tool's."""

    def __init__(self, lever_arm: Sequence[float], mount_matrix: np.ndarray) -> None:
        self.lever = np.array(lever_arm, dtype=float)
        self.q_mount = from_matrix(mount_matrix)

    def sensor_pose(self, p_tool, q_tool) -> tuple[np.ndarray, np.ndarray]:
        """The sensor point [m] and frame (quaternion, sensor to world) of a tool pose: the tool
        point ``p_tool`` [m, world] and orientation ``q_tool`` (quaternion, tool to world)."""
        return (np.asarray(p_tool, float) + rotate(q_tool, self.lever), multiply(q_tool, self.q_mount))

    def tool_pose(self, p_sensor, q_sensor) -> tuple[np.ndarray, np.ndarray]:
        """The tool point [m] and orientation (tool to world) of a sensor pose: the sensor point
        ``p_sensor`` [m, world] and frame ``q_sensor`` (quaternion, sensor to world)."""
        q_tool = normalise(multiply(q_sensor, conjugate(self.q_mount)))
        return np.asarray(p_sensor, float) - rotate(q_tool, self.lever), q_tool


def planar_pose(p_xz, phi: float) -> tuple[np.ndarray, np.ndarray]:
    """3-D pose of a planar tool pose, the point ``p_xz`` = (x, z) [m] and the tool angle ``phi``
    [rad]: position ``(x, 0, z)`` and ``Ry(phi)`` as a quaternion."""
    return np.array([float(p_xz[0]), 0.0, float(p_xz[1])]), from_angle_y(phi)


__all__ = ["G", "rot_y", "rot_rpy", "sensor_rotation", "RigidMount", "planar_pose"]

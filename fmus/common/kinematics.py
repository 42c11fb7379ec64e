"""Planar forward kinematics of the two-axis arm: positions, Jacobians, accelerations.

World frame x forward, z up, origin at axis 2; rotations are about +y. With the arm angles
``q = (q1, q2)`` and the tool angle ``phi = q1 + q2``,

* elbow ``p_e = l1 (sin q1, cos q1)``,
* tool point ``p_tool = p_e + l2 (cos phi, -sin phi)``,
* a point fixed to the tool at ``o = (o_x, o_z)`` in the tool frame:
  ``p = p_tool + R(phi) o`` with ``R(phi) = [[cos, sin], [-sin, cos]]`` (tool frame to world).

The accelerometer model of Axelsson et al. (2012), eqs. 17-19, is :func:`specific_force`:
the sensor measures ``R_s^T (p_ddot - g_vec)`` with ``g_vec = (0, -g)``.
"""
from __future__ import annotations

import math

import numpy as np

from fmus.common.jit import kernel

POINTS = ("tool", "sensor", "elbow")


def rotation(phi: float) -> np.ndarray:
    """``R(phi)``: tool frame (x, z) to world (x, z), a rotation by ``phi`` about +y."""
    c, s = math.cos(phi), math.sin(phi)
    return np.array([[c, s], [-s, c]])


def _offset(point: str, p) -> tuple[float, float]:
    """The point's offset from the tool point, in the tool frame."""
    if point == "tool":
        return 0.0, 0.0
    if point == "sensor":
        return float(p.sensor_offset[0]), float(p.sensor_offset[1])
    raise ValueError(f"unknown point {point!r}; expected one of {POINTS}")


def _geometry(q, p, point: str) -> tuple[float, float, float, float]:
    """Lever arms of joints 1 and 2 to the point: ``r1 = p - 0`` and ``r2 = p - p_e`` (x, z each)."""
    q1, phi = float(q[0]), float(q[0]) + float(q[1])
    s1, c1, sp, cp = math.sin(q1), math.cos(q1), math.sin(phi), math.cos(phi)
    if point == "elbow":
        return p.l1 * s1, p.l1 * c1, 0.0, 0.0
    ox, oz = _offset(point, p)
    # forearm part in world: l2 (cos, -sin) + R(phi) o
    r2x = p.l2 * cp + cp * ox + sp * oz
    r2z = -p.l2 * sp - sp * ox + cp * oz
    return p.l1 * s1 + r2x, p.l1 * c1 + r2z, r2x, r2z


def position(q, p, point: str = "tool") -> np.ndarray:
    """World position (x, z) [m] of ``point`` ("tool", "sensor" or "elbow") at the arm angles
    ``q`` [rad], for the robot ``p`` (:class:`~fmus.common.robot_params.RobotParameters`: links
    ``l1``, ``l2`` and the ``sensor_offset`` in the tool frame)."""
    x, z, _, _ = _geometry(q, p, point)
    return np.array([x, z])


def tool_position(q, p) -> np.ndarray:
    """Tool point position (world x, z) [m] at the arm angles ``q`` [rad] of the robot ``p``:
    the rigid forward kinematics."""
    return position(q, p, "tool")


@kernel
def tool_point(q1: float, q2: float, l1: float, l2: float) -> tuple[float, float]:
    """:func:`tool_position` on floats (compiled, for the numba kernels of the controller and the
    2012 EKF; the Cython kernels have it from common/planar_arm.pxd, held equal by
    tests/test_compiled_kernels.py until these move too): world x, z [m] of the tool at the arm
    angles ``q1``, ``q2`` [rad] of links ``l1``, ``l2`` [m]."""
    phi = q1 + q2
    return l1 * math.sin(q1) + l2 * math.cos(phi), l1 * math.cos(q1) - l2 * math.sin(phi)


@kernel
def tool_jacobian(q1: float, q2: float, l1: float, l2: float) -> tuple[float, float, float, float]:
    """:func:`jacobian` of the tool on floats (compiled), row-major ``(J00, J01, J10, J11)``
    [m/rad], at the arm angles ``q1``, ``q2`` [rad] of links ``l1``, ``l2`` [m]."""
    s1, c1 = math.sin(q1), math.cos(q1)
    s12, c12 = math.sin(q1 + q2), math.cos(q1 + q2)
    return l1 * c1 - l2 * s12, -l2 * s12, -l1 * s1 - l2 * c12, -l2 * c12


def sensor_position(q, p) -> np.ndarray:
    """Accelerometer mount position (world x, z) [m] at the arm angles ``q`` [rad] of the robot
    ``p`` (its ``sensor_offset``)."""
    return position(q, p, "sensor")


def jacobian(q, p, point: str = "tool") -> np.ndarray:
    """``J(q) = dp/dq`` [m/rad] of ``point`` (as in :func:`position`) at the arm angles ``q``
    [rad] of the robot ``p``; a rotation about +y maps ``r`` to ``(r_z, -r_x)``."""
    rx, rz, r2x, r2z = _geometry(q, p, point)
    elbow_x, elbow_z = rx - r2x, rz - r2z
    # joint 1 turns the whole chain about the origin; joint 2 the forearm about the elbow
    return np.array([[rz, r2z], [-rx, -r2x]]) if point != "elbow" else np.array([[elbow_z, 0.0], [-elbow_x, 0.0]])


def jacobian_dot(q, dq, p, point: str = "tool") -> np.ndarray:
    """Time derivative of :func:`jacobian` of ``point`` at the arm angles ``q`` [rad] along the
    arm velocities ``dq`` [rad/s], for the robot ``p``.

    Each column is ``omega_k x r_k``-type: ``d/dt (r_z, -r_x) = (v_z, -v_x)`` of the lever arm.
    """
    rx, rz, r2x, r2z = _geometry(q, p, point)
    w1, w12 = float(dq[0]), float(dq[0]) + float(dq[1])
    # velocity of the lever arms: r1 = e + r2 with e turning at w1 and r2 at w12
    ex, ez = rx - r2x, rz - r2z
    v2x, v2z = w12 * r2z, -w12 * r2x
    if point == "elbow":
        v2x = v2z = 0.0
    v1x, v1z = w1 * ez + v2x, -w1 * ex + v2z
    if point == "elbow":
        return np.array([[v1z, 0.0], [-v1x, 0.0]])
    return np.array([[v1z, v2z], [-v1x, -v2x]])


def point_motion(q, dq, ddq, p, point: str = "tool") -> tuple[float, float, float, float, float, float]:
    """Position, velocity and acceleration ``(x, z, vx, vz, ax, az)`` of ``point``, in plain floats
    (m, m/s, m/s^2), at the arm angles ``q`` [rad], velocities ``dq`` [rad/s] and accelerations
    ``ddq`` [rad/s^2] of the robot ``p``.

    ``v = J dq``, ``a = J ddq + J_dot dq`` (2012 paper, eq. 19: eq. 18 differentiated twice),
    with ``J`` and ``J_dot`` written
    out (the plant evaluates this every step: no numpy arrays on the hot path).
    """
    rx, rz, r2x, r2z = _geometry(q, p, point)
    w1, w2 = float(dq[0]), float(dq[1])
    a1, a2 = float(ddq[0]), float(ddq[1])
    if point == "elbow":
        r2x = r2z = 0.0
        w2 = a2 = 0.0
    w12 = w1 + w2
    ex, ez = rx - r2x, rz - r2z
    v2x, v2z = w12 * r2z, -w12 * r2x                # forearm lever turning at w1 + w2
    vx, vz = w1 * ez + v2x, -w1 * ex + v2z          # the point
    # J ddq + J_dot dq, J = [[rz, r2z], [-rx, -r2x]], J_dot = [[vz, v2z], [-vx, -v2x]]
    ax = rz * a1 + r2z * a2 + vz * w1 + v2z * w2
    az = -rx * a1 - r2x * a2 - vx * w1 - v2x * w2
    return rx, rz, vx, vz, ax, az


def velocity(q, dq, p, point: str = "tool") -> np.ndarray:
    """World velocity ``J(q) dq`` [m/s] of ``point`` at the arm angles ``q`` [rad] and
    velocities ``dq`` [rad/s] of the robot ``p``."""
    return jacobian(q, p, point) @ np.asarray(dq, float)


def point_acceleration(q, dq, ddq, p, point: str = "tool") -> np.ndarray:
    """World acceleration ``J(q) ddq + J_dot(q, dq) dq`` [m/s^2] of ``point`` (2012 paper,
    eq. 19) at the arm angles ``q`` [rad], velocities ``dq`` [rad/s] and accelerations ``ddq``
    [rad/s^2] of the robot ``p``."""
    return np.array(point_motion(q, dq, ddq, p, point)[4:6])


def specific_force(q, dq, ddq, p) -> np.ndarray:
    """Noise-free accelerometer reading [m/s^2] in the sensor frame (x, z): Axelsson 2012,
    eqs. 17-19, at the arm angles ``q`` [rad], velocities ``dq`` [rad/s] and accelerations
    ``ddq`` [rad/s^2] of the robot ``p`` (its links, ``sensor_offset`` and gravity ``g``).

    ``rho_s = R(phi)^T (p_ddot_s - g_vec)``, ``g_vec = (0, -g)``; at rest it reads ``+g`` along
    the world's up direction.
    """
    a = point_acceleration(q, dq, ddq, p, "sensor")
    return rotation(float(q[0]) + float(q[1])).T @ (a - np.array([0.0, -p.g]))


def inverse_kinematics(p_tool, p) -> np.ndarray:
    """Arm angles putting the tool at ``p_tool``, on the branch of the home pose (``|q2| <= pi/2``).

    ``|p|^2 = l1^2 + l2^2 - 2 l1 l2 sin q2`` gives ``q2``; with ``A = l1 - l2 sin q2`` and
    ``B = l2 cos q2``, ``q1 = atan2(x, z) - atan2(B, A)``.

    Raises
    ------
    ValueError
        If the point is out of reach.
    """
    x, z = float(p_tool[0]), float(p_tool[1])
    s2 = (p.l1 ** 2 + p.l2 ** 2 - (x * x + z * z)) / (2 * p.l1 * p.l2)
    if not -1.0 <= s2 <= 1.0:
        raise ValueError(f"point ({x:g}, {z:g}) m is out of reach of links {p.l1:g} m and {p.l2:g} m")
    q2 = math.asin(s2)
    q1 = math.atan2(x, z) - math.atan2(p.l2 * math.cos(q2), p.l1 - p.l2 * s2)
    return np.array([q1, q2])


# ---- vectorised over many poses (trajectory tables), links given as floats ------------------
def tool_position_many(q: np.ndarray, l1: float, l2: float) -> np.ndarray:
    """Tool position of the planar arm (:func:`tool_position`), vectorised over the leading axes
    of ``q`` (..., 2), for the links ``l1``, ``l2``.

    ``p = l1 (sin q1, cos q1) + l2 (cos(q1 + q2), -sin(q1 + q2))`` (project convention).
    """
    q1, q12 = q[..., 0], q[..., 0] + q[..., 1]
    return np.stack([l1 * np.sin(q1) + l2 * np.cos(q12), l1 * np.cos(q1) - l2 * np.sin(q12)], axis=-1)


def inverse_kinematics_many(p: np.ndarray, l1: float, l2: float) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form IK (:func:`inverse_kinematics`) of many points ``p`` (n, 2), on the branch of
    the home pose (``|q2| <= pi/2``), for the links ``l1``, ``l2``; no error for unreachable points.

    ``|p|^2 = l1^2 + l2^2 - 2 l1 l2 sin q2`` gives ``q2``; with ``A = l1 - l2 sin q2`` and
    ``B = l2 cos q2``, ``x = A sin q1 + B cos q1``, ``z = A cos q1 - B sin q1`` give
    ``q1 = atan2(x, z) - atan2(B, A)``.

    Returns
    -------
    q
        (n, 2) arm angles [rad] (NaN where unreachable).
    sin_q2
        (n,) the value of ``sin q2`` before clipping (|.| > 1: out of reach).
    """
    x, z = p[:, 0], p[:, 1]
    s2 = (l1 * l1 + l2 * l2 - (x * x + z * z)) / (2.0 * l1 * l2)
    with np.errstate(invalid="ignore"):
        q2 = np.arcsin(s2)
    a = l1 - l2 * np.sin(q2)
    b = l2 * np.cos(q2)
    q1 = np.arctan2(x, z) - np.arctan2(b, a)
    return np.stack([q1, q2], axis=1), s2


def jacobian_many(q: np.ndarray, l1: float, l2: float) -> np.ndarray:
    """Tool Jacobian ``dp/dq`` (:func:`jacobian` of the tool) of many arm angles ``q`` (n, 2),
    (n, 2, 2), for the links ``l1``, ``l2``."""
    q1, q12 = q[:, 0], q[:, 0] + q[:, 1]
    jac = np.empty((q.shape[0], 2, 2))
    jac[:, 0, 0] = l1 * np.cos(q1) - l2 * np.sin(q12)
    jac[:, 0, 1] = -l2 * np.sin(q12)
    jac[:, 1, 0] = -l1 * np.sin(q1) - l2 * np.cos(q12)
    jac[:, 1, 1] = -l2 * np.cos(q12)
    return jac

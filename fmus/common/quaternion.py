"""Unit quaternions for 3-D orientation (plain math, no FMI).

Convention: Hamilton product, scalar first, ``q = (w, x, y, z)``. A quaternion ``q`` describes
the orientation of a body frame B in the world frame W: it maps body vectors to world vectors,
``v_W = q ⊗ (0, v_B) ⊗ q*`` = ``to_matrix(q) @ v_B``. A rotation by the angle ``|r|`` about the
unit axis ``r / |r|`` is ``exp(r) = (cos(|r|/2), sin(|r|/2) r/|r|)`` (:func:`from_rotation_vector`).

In the planar FlexFusion conventions the tool frame is the world frame rotated by ``phi`` about
+y, ``Ry(phi)``; its quaternion is ``(cos(phi/2), 0, sin(phi/2), 0)`` (:func:`from_angle_y`).

The functions work on plain floats internally (they run every step of a filter) and return
``numpy`` arrays.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


def multiply(q: Sequence[float], r: Sequence[float]) -> np.ndarray:
    """Hamilton product ``q ⊗ r`` (apply ``r`` first, then ``q``, to body vectors)."""
    w1, x1, y1, z1 = float(q[0]), float(q[1]), float(q[2]), float(q[3])
    w2, x2, y2, z2 = float(r[0]), float(r[1]), float(r[2]), float(r[3])
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
                     w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                     w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def conjugate(q: Sequence[float]) -> np.ndarray:
    """``q* = (w, -x, -y, -z)``: the inverse of a unit quaternion."""
    return np.array([float(q[0]), -float(q[1]), -float(q[2]), -float(q[3])])


def norm(q: Sequence[float]) -> float:
    """Euclidean norm of the four components of ``q``."""
    return math.sqrt(sum(float(c) * float(c) for c in q))


def normalise(q: Sequence[float]) -> np.ndarray:
    """``q / |q|`` with the sign chosen so that ``w >= 0`` (the same rotation).

    Raises
    ------
    ValueError
        If ``q`` is zero or not finite.
    """
    n = norm(q)
    if not (n > 0.0 and math.isfinite(n)):
        raise ValueError(f"cannot normalise the quaternion {tuple(q)}")
    s = 1.0 / n if float(q[0]) >= 0.0 else -1.0 / n
    return np.array([float(c) * s for c in q])


def to_matrix(q: Sequence[float]) -> np.ndarray:
    """Rotation matrix of the unit quaternion ``q`` (body to world)."""
    w, x, y, z = float(q[0]), float(q[1]), float(q[2]), float(q[3])
    return np.array([[1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
                     [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
                     [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)]])


def rotate(q: Sequence[float], v: Sequence[float]) -> np.ndarray:
    """``q ⊗ (0, v) ⊗ q*``: the body vector ``v`` in the world frame (``to_matrix(q) @ v``).

    Uses ``v + 2 w (u × v) + 2 u × (u × v)`` with ``u = (x, y, z)``.
    """
    w, x, y, z = float(q[0]), float(q[1]), float(q[2]), float(q[3])
    vx, vy, vz = float(v[0]), float(v[1]), float(v[2])
    tx, ty, tz = 2.0 * (y * vz - z * vy), 2.0 * (z * vx - x * vz), 2.0 * (x * vy - y * vx)
    return np.array([vx + w * tx + (y * tz - z * ty),
                     vy + w * ty + (z * tx - x * tz),
                     vz + w * tz + (x * ty - y * tx)])


def rotate_inverse(q: Sequence[float], v: Sequence[float]) -> np.ndarray:
    """``q* ⊗ (0, v) ⊗ q``: the world vector ``v`` in the body frame (``to_matrix(q).T @ v``)."""
    return rotate(conjugate(q), v)


def from_rotation_vector(r: Sequence[float]) -> np.ndarray:
    """The exponential map: rotation by ``|r|`` rad about ``r / |r|`` (exact, any angle)."""
    rx, ry, rz = float(r[0]), float(r[1]), float(r[2])
    angle = math.sqrt(rx * rx + ry * ry + rz * rz)
    half = 0.5 * angle
    if angle < 1e-8:                     # sin(h)/angle = 1/2 - h^2/12 + ... (error < 1e-17)
        k = 0.5 - half * half / 12.0
    else:
        k = math.sin(half) / angle
    return np.array([math.cos(half), k * rx, k * ry, k * rz])


def to_rotation_vector(q: Sequence[float]) -> np.ndarray:
    """The logarithm map of the unit quaternion ``q``, inverse of :func:`from_rotation_vector`:
    a rotation vector [rad] with angle in [0, pi]."""
    w, x, y, z = float(q[0]), float(q[1]), float(q[2]), float(q[3])
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    s = math.sqrt(x * x + y * y + z * z)
    if s < 1e-8:
        k = 2.0 / w * (1.0 - s * s / (3.0 * w * w)) if w > 0.0 else 2.0
    else:
        k = 2.0 * math.atan2(s, w) / s
    return np.array([k * x, k * y, k * z])


def propagate(q: Sequence[float], omega_body: Sequence[float], dt: float) -> np.ndarray:
    """Exact propagation over ``dt`` at a constant body-frame angular velocity ``omega_body``.

    ``dq/dt = 1/2 q ⊗ (0, omega)`` has for constant ``omega`` the solution
    ``q(t + dt) = q(t) ⊗ exp(omega dt)``; the result is renormalised (rounding only).
    """
    w = omega_body
    return normalise(multiply(q, from_rotation_vector((float(w[0]) * dt, float(w[1]) * dt,
                                                       float(w[2]) * dt))))


def from_angle_y(phi: float) -> np.ndarray:
    """Quaternion of ``Ry(phi)``, the planar tool orientation (rotation by ``phi`` about +y)."""
    return np.array([math.cos(0.5 * phi), 0.0, math.sin(0.5 * phi), 0.0])


def angle_y(q: Sequence[float]) -> float:
    """The angle [rad] about +y of ``q``, a rotation about +y (the inverse of :func:`from_angle_y`).

    For a general rotation it is ``atan2(R[0,2], R[2,2])``: the direction of the body z axis
    projected on the world x-z plane.
    """
    w, x, y, z = float(q[0]), float(q[1]), float(q[2]), float(q[3])
    return math.atan2(2.0 * (x * z + w * y), 1.0 - 2.0 * (x * x + y * y))


def from_matrix(m: np.ndarray) -> np.ndarray:
    """Unit quaternion (``w >= 0``) of the 3x3 rotation matrix ``m`` (Shepperd's method,
    Shepperd 1978)."""
    m = np.asarray(m, dtype=float)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0.0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q = (0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s)
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = ((m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s)
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = ((m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = ((m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s)
    return normalise(q)


def skew(v: Sequence[float]) -> np.ndarray:
    """``[v]×``, the matrix of the cross product ``v × (.)``."""
    x, y, z = float(v[0]), float(v[1]), float(v[2])
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


__all__ = ["IDENTITY", "multiply", "conjugate", "norm", "normalise", "to_matrix", "rotate",
           "rotate_inverse", "from_rotation_vector", "to_rotation_vector", "propagate",
           "from_angle_y", "angle_y", "from_matrix", "skew"]

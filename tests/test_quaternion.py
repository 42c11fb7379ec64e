"""Quaternion helpers: algebra, exact constant-rate propagation, unit norm."""
import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from fmus.common import quaternion as qt
from fmus.common.frames import rot_rpy, rot_y

RNG = np.random.default_rng(7)


def random_unit(n=1):
    q = RNG.standard_normal((n, 4))
    return [qt.normalise(x) for x in q]


def test_matrix_and_rotate_agree_and_are_orthonormal():
    for q in random_unit(20):
        m = qt.to_matrix(q)
        assert_allclose(m @ m.T, np.eye(3), atol=1e-14)
        assert_allclose(np.linalg.det(m), 1.0, atol=1e-14)
        v = RNG.standard_normal(3)
        assert_allclose(qt.rotate(q, v), m @ v, atol=1e-14)
        assert_allclose(qt.rotate_inverse(q, v), m.T @ v, atol=1e-14)


def test_product_composes_rotations():
    for q, r in zip(random_unit(10), random_unit(10)):
        assert_allclose(qt.to_matrix(qt.multiply(q, r)), qt.to_matrix(q) @ qt.to_matrix(r), atol=1e-14)
        assert_allclose(qt.multiply(q, qt.conjugate(q)), qt.IDENTITY, atol=1e-15)


def test_from_angle_y_is_the_project_convention():
    for phi in (-2.0, -0.3, 0.0, 0.7, 3.0):
        assert_allclose(qt.to_matrix(qt.from_angle_y(phi)), rot_y(phi), atol=1e-15)
        assert_allclose(qt.angle_y(qt.from_angle_y(phi)), phi, atol=1e-14)


def test_from_matrix_inverts_to_matrix():
    for q in random_unit(30):
        q = q if q[0] >= 0 else -q
        assert_allclose(qt.from_matrix(qt.to_matrix(q)), q, atol=1e-14)
    m = rot_rpy((0.3, -1.2, 2.5))
    assert_allclose(qt.to_matrix(qt.from_matrix(m)), m, atol=1e-14)


@pytest.mark.parametrize("angle", [0.0, 1e-12, 1e-6, 0.5, 3.0])
def test_exp_log_round_trip(angle):
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    r = angle * axis
    q = qt.from_rotation_vector(r)
    assert_allclose(qt.norm(q), 1.0, atol=1e-15)
    assert_allclose(qt.to_rotation_vector(q), r, atol=1e-15, rtol=1e-13)
    # Rodrigues' formula
    k = qt.skew(axis)
    rod = np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k
    assert_allclose(qt.to_matrix(q), rod, atol=1e-15)


def test_constant_rate_propagation_is_exact_and_unit():
    """10 000 steps at a constant body rate: the analytic rotation exp(w t), unit norm."""
    w = np.array([0.4, -1.1, 2.3])
    dt = 1e-3
    q0 = qt.normalise([0.9, 0.1, -0.3, 0.2])
    q = q0
    norms = []
    for _ in range(10_000):
        q = qt.propagate(q, w, dt)
        norms.append(qt.norm(q))
    t = 10_000 * dt
    expected = qt.multiply(q0, qt.from_rotation_vector(w * t))
    expected = expected if expected[0] >= 0 else -expected
    assert_allclose(q, expected, atol=1e-11)
    assert_allclose(norms, 1.0, atol=1e-15)


def test_normalise_rejects_zero():
    with pytest.raises(ValueError, match="cannot normalise"):
        qt.normalise([0.0, 0.0, 0.0, 0.0])

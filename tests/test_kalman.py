"""The Kalman toolkit (fmus/common/kalman.py): the one definiteness test and estimate check."""
from __future__ import annotations

import numpy as np
import pytest

from fmus.common.kalman import FilterDivergence, check_estimate, cholesky_lower, is_positive_definite, solve


def test_positive_definiteness_agrees_with_the_eigenvalues() -> None:
    """Random symmetric matrices: positive definite exactly when the smallest eigenvalue is > 0."""
    rng = np.random.default_rng(4)
    for _ in range(200):
        A = rng.normal(size=(5, 5))
        P = A @ A.T + rng.uniform(-2.0, 2.0) * np.eye(5)
        ev = np.linalg.eigvalsh(P).min()
        if abs(ev) > 1e-9:
            assert is_positive_definite(P) == (ev > 0.0)


def test_check_estimate_names_the_cause_and_the_place() -> None:
    x, P = np.zeros(3), np.eye(3)
    check_estimate(x, P, "here")
    with pytest.raises(FilterDivergence, match="^here: non-finite"):
        check_estimate(np.array([0.0, np.nan, 0.0]), P, "here")
    with pytest.raises(FilterDivergence, match="^there: non-finite"):
        check_estimate(x, np.full((3, 3), np.inf), "there")
    indefinite = np.diag([1.0, -1e-3, 1.0])
    with pytest.raises(FilterDivergence, match=r"not positive definite \(smallest eigenvalue -0.001\)"):
        check_estimate(x, indefinite, "here")
    check_estimate(x, indefinite, "here", definite=False)      # only finiteness asked


def test_cholesky_and_solve_are_numpys_to_the_bit() -> None:
    """The direct LAPACK calls of the filters' hot path give np.linalg's bits, transposed (strided)
    operands and vector right-hand sides included; an indefinite matrix has no factor,
    as np.linalg.cholesky raises for it."""
    rng = np.random.default_rng(5)
    for n, m in ((4, 6), (2, 10), (6, 1)):
        A = rng.normal(size=(n, n))
        S = A @ A.T + 0.1 * np.eye(n)
        L = cholesky_lower(S)
        assert np.array_equal(L, np.linalg.cholesky(S))
        B, b = rng.normal(size=(n, m)), rng.normal(size=n)
        assert np.array_equal(solve(L.T, B), np.linalg.solve(L.T, B))
        assert np.array_equal(solve(L, b), np.linalg.solve(L, b))
        assert cholesky_lower(S - 2 * np.linalg.eigvalsh(S).max() * np.eye(n)) is None
        for bad in (np.nan, np.inf):         # numpy returns a non-finite factor (caught later)
            S[0, 0] = bad
            assert np.array_equal(cholesky_lower(S), np.linalg.cholesky(S), equal_nan=True)

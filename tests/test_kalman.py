"""The Kalman toolkit (fmus/common/kalman.py): the one definiteness test and estimate check."""
from __future__ import annotations

import numpy as np
import pytest

from fmus.common.kalman import FilterDivergence, check_estimate, is_positive_definite


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

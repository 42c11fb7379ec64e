"""The 2012 measurement model over many states (fmus/estimators/axelsson2012_batched.py, the
particle filter's and the batched engine's): the scalar model's bits, finite differences, and
the numpy code it replaced."""
from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from fmus.estimators import axelsson2012_batched as ab
from fmus.estimators import axelsson2012_model as am
from fmus.estimators import particle_filter_model as pm
from pf_numpy_reference import NumpyMeasurement

LAYOUTS = [(True, False), (True, True), (False, False), (False, True)]


def _model(acc: bool, bias: bool) -> am.MeasurementModel:
    return am.MeasurementModel(am.EkfAccelerometerParameters().robot(), am.Layout(acc, bias))


def _states(n_states: int, n: int = 400, seed: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, n_states)) * np.r_[0.8, 0.8, 1.0, 1.0, 5.0, 5.0, [1e-3] * (n_states - 6)]
    X[:3, 4:6] *= 1e-5        # some states in the soft zone of the gearbox (tiny torque) ...
    X[:3, 0:2] = [0.0, math.pi / 2]   # ... where gravity is zero
    return X


def _evaluate(meas: am.MeasurementModel, X: np.ndarray, bound_stop: bool, D0=None):
    N, L = len(X), meas.layout
    Y, H, D = np.empty((N, L.m)), np.zeros((N, L.m, L.n)), np.empty((N, 2))
    D0 = np.full((N, 2), np.nan) if D0 is None else D0
    ab.measure_many(X, meas.constants, *meas.switches, bound_stop, D0, Y, H, D)
    return Y, H, D


@pytest.mark.parametrize("acc,bias", LAYOUTS)
def test_each_row_is_the_scalar_model_bit_for_bit(acc: bool, bias: bool) -> None:
    """Every row's h and H are the single EKF's, to the bit (the same kernels), and its
    deflections the scalar spring solve's."""
    meas = _model(acc, bias)
    X = _states(meas.layout.n)
    B = ab.BatchedMeasurement(meas)
    Y, H = B.h_and_jacobian(X)
    assert Y.shape == (len(X), meas.layout.m) and H.shape == (len(X), meas.layout.m, meas.layout.n)
    for i, x in enumerate(X):
        y, h = meas.h_and_jacobian(x)
        assert_array_equal(Y[i], y)
        assert_array_equal(H[i], h)
    assert_array_equal(B.h(X), Y)
    assert_array_equal(B.deflection(X), [am.deflections_kernel(am.motion(x), meas.constants, np.nan, np.nan, False)
                                         for x in X])


@pytest.mark.parametrize("acc,bias", LAYOUTS)
def test_jacobian_equals_finite_differences(acc: bool, bias: bool) -> None:
    meas = _model(acc, bias)
    B = ab.BatchedMeasurement(meas)
    X = _states(meas.layout.n, n=25)[3:]    # away from the soft zone's curvature
    H = B.h_and_jacobian(X)[1]
    eps = 1e-6
    Hfd = np.empty_like(H)
    for j in range(meas.layout.n):
        dX = np.zeros_like(X)
        dX[:, j] = eps
        Hfd[:, :, j] = (B.h(X + dX) - B.h(X - dX)) / (2 * eps)
    # central differences: truncation O(eps^2 h''') and rounding about 1e-16 |h| / eps
    assert_allclose(H, Hfd, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("acc,bias", LAYOUTS)
def test_the_particle_filters_rounding_and_warm_start_agree_with_the_numpy_code(acc: bool, bias: bool) -> None:
    """With the particle filter's stopping rule (Newton's error bound) and with the Newton
    iteration started from nearby deflections, h and H are the former numpy code's to 1e-12."""
    meas = _model(acc, bias)
    X = _states(meas.layout.n)
    ref = NumpyMeasurement(meas)
    Y, H, D = _evaluate(meas, X, bound_stop=True)
    assert_allclose(Y, ref.h(X), rtol=1e-12, atol=0)
    assert_allclose(H, ref.jacobian(X), rtol=1e-12, atol=1e-12 * np.abs(H).max())
    assert_allclose(Y, _evaluate(meas, X, bound_stop=False)[0], rtol=1e-14, atol=0)
    near = X * (1 + 1e-3 * np.random.default_rng(1).normal(size=X.shape))
    Yw, _, Dw = _evaluate(meas, near, bound_stop=True, D0=D)            # Newton from X's deflections
    assert_allclose(Yw, ref.h(near), rtol=1e-12, atol=0)
    assert_allclose(Dw, ref.deflection(near), rtol=1e-12, atol=0)


def test_shapes_that_do_not_fit_the_layout_are_refused() -> None:
    """The kernels do not check indices: ``measure_many`` refuses arrays that do not fit
    (an empty Jacobian instead of None, a state without the bias states)."""
    meas = _model(True, True)
    X = _states(meas.layout.n, n=5)
    Y, D = np.empty((5, 4)), np.full((5, 2), np.nan)
    for bad in (dict(H=np.zeros((5, 0, 0))), dict(X=X[:, :6]), dict(Y=np.empty((5, 2)))):
        args = dict(X=X, Y=Y, H=None) | bad
        with pytest.raises(ValueError, match="do not fit"):
            ab.measure_many(args["X"], meas.constants, *meas.switches, False, D, args["Y"], args["H"], D)

"""tests/references.py: the comparisons with stored numbers fail on a real difference and hold
on round-off of a value's own scale, its column's or its series'."""
from __future__ import annotations

import numpy as np
import pytest

from references import KERNEL_RTOL, REFERENCES, STUDY_RTOL, assert_near, assert_same_document, column_scale


def test_every_reference_file_has_an_entry_and_a_recorder() -> None:
    import importlib

    from references import DATA
    stored = {p.name for p in DATA.glob("*_reference.*")}
    named = {f"{name}_reference.npz" for name in REFERENCES} | {f"{name}_main_reference.json" for name in REFERENCES}
    assert stored <= named, stored - named
    assert len(stored) == len(REFERENCES)
    for module, what in REFERENCES.values():
        assert callable(importlib.import_module(module).save) and what


def test_assert_near_scales_by_column_and_group() -> None:
    stored = np.array([[1.0, 0.0, 500.0], [2.0, 1e-18, 510.0]])
    assert_near(stored * (1 + 1e-14), stored, KERNEL_RTOL)
    with pytest.raises(AssertionError, match="1 of 6 elements differ"):
        assert_near(stored + [[0.0, 0.0, 1e-6], [0.0, 0.0, 0.0]], stored, KERNEL_RTOL)
    # a column that cancels to zero: judged by its group's scale (one matrix), not by its own
    now = stored.copy()
    now[:, 1] = [6e-18, 0.0]
    with pytest.raises(AssertionError):
        assert_near(now, stored, KERNEL_RTOL)
    assert_near(now, stored, KERNEL_RTOL, groups=(slice(0, 2),))
    assert column_scale(stored, (slice(0, 2),)).tolist() == [[2.0, 2.0, 510.0]]
    with pytest.raises(AssertionError):                     # flags and stamps exactly
        assert_near(np.array([True, False]), np.array([True, True]), KERNEL_RTOL)


def test_assert_same_document_rules() -> None:
    ref = {"name": "x", "columns": {"all_max": 3e-3, "band_max": 2e-5}, "series": [1e-2, 0.0, 2e-2], "n": 3}
    got = {"name": "x", "columns": {"all_max": 3e-3 * (1 + 1e-13), "band_max": 2e-5 + 1e-15},
           "series": [1e-2, 1e-16, 2e-2], "n": 3}
    assert_same_document(got, ref, STUDY_RTOL, {"band_max": "all_max"})
    with pytest.raises(AssertionError, match="band_max"):    # without its unfiltered error's scale
        assert_same_document(got, ref, STUDY_RTOL)
    for key, value in (("n", 4), ("name", "y")):
        with pytest.raises(AssertionError):
            assert_same_document(dict(got, **{key: value}), ref, STUDY_RTOL, {"band_max": "all_max"})
    moved = dict(got, columns={"all_max": 3e-3 * (1 + 1e-9), "band_max": 2e-5})
    with pytest.raises(AssertionError, match="all_max"):
        assert_same_document(moved, ref, STUDY_RTOL, {"band_max": "all_max"})
    with pytest.raises(AssertionError):
        assert_same_document(dict(got, extra=1), ref, STUDY_RTOL)

"""The stored numeric references of the tests (``tests/data``): what each guards, how it is
compared on a machine other than the one that recorded it, and the one command that re-records
them from the working tree (HEAD)::

    .venv/bin/python tests/references.py                  # every reference
    .venv/bin/python tests/references.py plant_kernel     # some (names below)

A reference is a regression guard: it holds today's numbers so that a change which moves them
is seen. It is not bit for bit across machines: CPU features (numpy's SIMD loops), the C
library's elementary functions (glibc picks FMA variants of ``sin``/``exp``/... on CPUs that
have them) and BLAS differ, and each moves the last bits of a result. So every stored float is
compared with :func:`assert_near`: to ``rtol`` of the scale of its own column (its largest
magnitude), so a quantity that cancels to zero (a Jacobian inverse's entry at a path's corner,
a velocity at a stop) carries round-off of its column's size, not of its own.
``tests/test_other_machine.py`` runs the reference tests as another machine would (numpy's
baseline SIMD, glibc's non-FMA functions) so that a test pinned to one machine's bits fails
here first. Bit-for-bit checks remain only where both sides run in the same process.
"""
from __future__ import annotations

import importlib
import sys
from pathlib import Path

import numpy as np

DATA = Path(__file__).parent / "data"

#: name -> (test module that records and checks it, what it guards)
REFERENCES: dict[str, tuple[str, str]] = {
    "plant_kernel": ("test_plant_kernel", "the realistic plant's compiled chain (states, outputs, applied torques)"),
    "motion_control": ("test_motion_control_kernel", "the motion controller's compiled law, references and integral"),
    "rigid_kinematics": ("test_rigid_kinematics_kernel", "rigid kinematics' arm angles and tool positions"),
    "sensor_channels": ("test_sensor_kernel", "the sensor channels' readings with every imperfection on"),
    "tracker": ("test_tracker_scalar", "the tracker's sampled, skewed, noisy positions"),
    "ekf_step": ("test_ekf_accelerometer_step", "the 2012 EKF FMU's outputs under five fusion schedules"),
    "montecarlo": ("test_study_montecarlo", "study.json of the 2012 Monte Carlo study at 0.5 s"),
    "robustness": ("test_study_robustness", "table.json of the 2009 robustness study at 0.3 s"),
}

#: the references whose recording runs co-simulations (they need the FMUs built)
NEEDS_FMUS = {"montecarlo", "robustness"}

#: Kernels' references (80-400 steps of one model): measured with tests/test_other_machine.py's
#: settings, their results move by at most 3.3e-14 of a column's scale (the plant); 30x margin.
KERNEL_RTOL = 1e-12
#: Studies' references (0.3-0.5 s closed-loop co-simulations with filters): with the same settings
#: their numbers move by at most 3.7e-13 of their size (an EKF's largest error in the 2009 table:
#: a last-bit change amplified about 1700-fold); between the machine that recorded them first and
#: another, by 1.7e-13 (a 3-30 Hz band error, of its unfiltered error's size: ``scales``). 1e-11
#: leaves a 27x margin, while a change of the models or of the study moves them far more (the
#: band-pass as second-order sections: 1e-3).
STUDY_RTOL = 1e-11


def column_scale(stored: np.ndarray, groups: tuple[slice, ...] = ()) -> np.ndarray:
    """The largest magnitude of each column of ``stored`` (of the whole array if 1-D), broadcast
    against it: the scale of the round-off its entries carry. The columns of each slice in
    ``groups`` share one scale (the entries of one matrix: a column of it may be zero)."""
    a = np.abs(np.asarray(stored, float))
    if a.ndim == 1:
        return np.full_like(a, a.max() if a.size else 0.0)
    scale = a.max(axis=0, keepdims=True)
    for group in groups:
        scale[:, group] = scale[:, group].max()
    return scale


def assert_near(now: np.ndarray, stored: np.ndarray, rtol: float, err_msg: str = "",
                groups: tuple[slice, ...] = ()) -> None:
    """``now`` equals ``stored`` to ``rtol`` of each element and, where an element is near
    zero, to ``rtol`` of its column's scale (:func:`column_scale`, with ``groups``); non-float
    arrays exactly."""
    now, stored = np.asarray(now), np.asarray(stored)
    assert now.shape == stored.shape, (err_msg, now.shape, stored.shape)
    if stored.dtype.kind != "f":
        np.testing.assert_array_equal(now, stored, err_msg=err_msg)
        return
    bound = rtol * np.maximum(np.abs(stored), column_scale(stored, groups))
    bad = ~(np.abs(now - stored) <= bound)
    if bad.any():
        idx = [tuple(map(int, i)) for i in np.argwhere(bad)[:5]]
        raise AssertionError(f"{err_msg}: {int(bad.sum())} of {stored.size} elements differ beyond {rtol:g} "
                             f"of their column's scale; first at {idx}: now {[float(now[i]) for i in idx]}, "
                             f"stored {[float(stored[i]) for i in idx]}")


def assert_same_document(got, ref, rtol: float, scales: dict[str, str] | None = None, path: str = "",
                         scale: float = 0.0) -> None:
    """Every key of ``ref`` (a JSON document) in ``got`` and no other, equal strings and flags,
    numbers to ``rtol`` of their size; the numbers of a list (a series of one quantity) to
    ``rtol`` of the list's largest magnitude, and a number under a key of ``scales`` to ``rtol``
    of its sibling named there too (a band-limited error carries the round-off of the unfiltered
    error it is computed from: ``{"band_max": "all_max"}``)."""
    scales = scales or {}
    if isinstance(ref, dict):
        assert isinstance(got, dict) and set(got) == set(ref), (path, set(got) ^ set(ref))
        for k in ref:
            sibling = abs(ref[scales[k]]) if k in scales and scales[k] in ref else 0.0
            assert_same_document(got[k], ref[k], rtol, scales, f"{path}.{k}", sibling)
    elif isinstance(ref, list):
        assert isinstance(got, list) and len(got) == len(ref), path
        series = max((abs(r) for r in ref if isinstance(r, float)), default=0.0)
        for i, (g, r) in enumerate(zip(got, ref)):
            assert_same_document(g, r, rtol, scales, f"{path}[{i}]", series)
    elif isinstance(ref, float):
        assert isinstance(got, (int, float)) and abs(got - ref) <= rtol * max(abs(ref), scale), \
            f"{path}: {got!r} differs from the stored {ref!r} by more than {rtol:g} of {max(abs(ref), scale):g}"
    else:
        assert got == ref, path


def save_cases(path: Path, cases, record_case, **stored: np.ndarray) -> None:
    """Write ``record_case(name)``'s arrays of every case in ``cases`` to ``path`` (npz, keys
    ``<case>/<array>``), beside ``stored`` (arrays kept as they are, e.g. recorded inputs)."""
    for name in cases:
        stored.update({f"{name}/{key}": v for key, v in record_case(name).items()})
    np.savez_compressed(path, **stored)


def record(names: list[str]) -> None:
    """Re-record the references ``names`` (all if empty) from the working tree."""
    unknown = [n for n in names if n not in REFERENCES]
    if unknown:
        raise SystemExit(f"error: unknown reference(s) {', '.join(unknown)}; known: {', '.join(REFERENCES)}")
    names = names or list(REFERENCES)
    sys.path.insert(0, str(Path(__file__).parent))
    if NEEDS_FMUS & set(names):
        import os
        import tempfile

        from orchestration.build import build_all
        folder = Path(tempfile.mkdtemp(prefix="flexfusion-references-"))
        build_all(folder, quiet=True)
        os.environ["FLEXFUSION_FMU_DIR"] = str(folder)
    for name in names:
        module, what = REFERENCES[name]
        importlib.import_module(module).save()
        print(f"recorded {name}: {what}")


if __name__ == "__main__":
    record(sys.argv[1:])

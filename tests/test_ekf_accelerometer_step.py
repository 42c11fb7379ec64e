"""The EkfAccelerometer FMU's step in one compiled call (issue 16) against its stored
behaviour (first recorded from the adapter before it, one kernel per prediction, one per update,
the outputs set in Python, commit c530927; equal to it bit for bit on that machine): every output
after initialisation, after each output update and after each step, under the fusion schedules
of :mod:`fmus.common.filter_adapter` (stamps on time, one step late, a slower sensor's held
samples, unstamped at 100 Hz), for the filter with and without the accelerometer and with bias
states, and a divergence (its messages and the outputs it holds). With bias states (10) ``P_x``
is the lower triangle of ``P[0:6, 0:6]``, as the plain model's (checked in the same run).

The inputs are the flagship's (``orchestration/scenarios/flagship.toml``, seed 1: encoder,
IMU, jerk reference and stamps of its first 0.375 s; the filter has the flagship's noise
settings on the nominal robot model), stored with the outputs in
``tests/data/ekf_step_reference.npz``; the outputs are re-recorded from the working tree by
``python tests/references.py ekf_step`` (tests/references.py), the inputs kept. Outputs to
1e-12 of each column's scale, not bit for bit: the measurement model's sines and cosines differ
in their last bits between machines (measured: 4e-16 of a column's scale with glibc's non-FMA
functions); flags and the log exactly.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from fmus.estimators import axelsson2012_model as am
from fmus.estimators import ekf_accelerometer_model as em
from fmus.estimators.ekf_accelerometer_fmu import EkfAccelerometer
from references import KERNEL_RTOL, assert_near, save_cases
from toys import InProcess

REFERENCE = Path(__file__).parent / "data" / "ekf_step_reference.npz"
H = 1e-3
STEPS = 150
P_X = slice(10, 31)        # the columns of P_x among the outputs (after the vectors and two scalars)
#: The recorded inputs' columns in the flagship's results.
COLUMNS = ("encoder.q_m_meas[1]", "encoder.q_m_meas[2]", "imu.acc_s[1]", "imu.acc_s[2]", "imu.acc_s[3]",
           "encoder.t_meas", "controller.dddq_a_ref[1]", "controller.dddq_a_ref[2]")
FLAGSHIP = dict(p_tool0=(1.0, 0.6), r_motor=1.2e-9, r_acc=4e-4)
#: name: (parameters, schedule, filter step in base steps)
CASES = {
    "on_time": (FLAGSHIP, "on_time", 1),
    "late": (FLAGSHIP, "late", 1),
    "held_4ms": (FLAGSHIP, "held", 1),
    "unstamped_10ms": (FLAGSHIP, "unstamped", 10),
    "motor_only": (dict(FLAGSHIP, use_accelerometer=False), "on_time", 1),
    "bias_swapped_axes": (dict(FLAGSHIP, use_bias=True, index_x=3, index_z=1), "on_time", 1),
    "diverged": (FLAGSHIP, "diverge", 1),
}


def _outputs(s: InProcess) -> list[str]:
    return [v.name for v in s.s.vars.values() if v.causality.name == "output"]


def record(name: str, inputs: np.ndarray) -> dict[str, np.ndarray]:
    """Every output of the FMU class driven through its FMI methods (as a master does) with the
    recorded ``inputs`` (rows of :data:`COLUMNS`, one per base step) under the schedule of case
    ``name``: after initialisation, then per step (and, one step late, before each step too)."""
    params, schedule, ratio = CASES[name]
    s = InProcess(EkfAccelerometer, **params)
    out_vr = [s.vr[n] for n in _outputs(s)]
    in_vr = [s.vr[n] for n in ("q_m_meas[1]", "q_m_meas[2]", "acc_s[1]", "acc_s[2]", "acc_s[3]", "t_meas",
                               "dddq_a_ref[1]", "dddq_a_ref[2]")]
    if params.get("index_x") == 3:
        inputs = inputs[:, [0, 1, 4, 3, 2, 5, 6, 7]]        # the sensor's x and z axes swapped

    def set_row(j: int, t: float, stamped: bool = True, acc_x: float | None = None) -> None:
        row = inputs[j].copy()
        row[5] = t if stamped else -1.0
        if acc_x is not None:
            row[2 if params.get("index_x", 1) == 1 else 4] = acc_x
        s.s.set_real(in_vr if stamped else in_vr[:5] + in_vr[6:],
                     list(row) if stamped else list(row[:5]) + list(row[6:]))

    rows, ok = [], []
    set_row(0, 0.0, schedule != "unstamped")
    rows.append(s.s.get_real(out_vr))               # in Initialization Mode
    s.init()
    step = ratio * H
    for k in range(STEPS if schedule != "unstamped" else STEPS // 4):
        t = k * step
        if schedule == "late":
            set_row(k, t)                           # the sample of t, one step late
            rows.append(s.s.get_real(out_vr))       # the output update between steps
        elif schedule == "held":
            j = k - k % 4 + 1                       # a 250 Hz sensor: samples at 1, 5, 9 ... ms
            set_row(j, j * H)
        elif schedule == "diverge" and k >= STEPS - 3:
            set_row(k + 1, t + step, acc_x=1e200)   # an absurd (finite) reading
        else:
            set_row((k + 1) * ratio, t + step, schedule != "unstamped")
        ok.append(s.s.do_step(t, step))
        rows.append(s.s.get_real(out_vr))
    log = "\n".join(m.msg for m in s.s.log_queue)
    return {"outputs": np.array(rows), "ok": np.array(ok), "log": np.array(log)}


def save(results_csv: str | None = None) -> None:
    """Record every case into :data:`REFERENCE`, with the stored inputs, or with those of a
    flagship run's ``results_csv`` (recording :data:`COLUMNS`)."""
    if results_csv is None:
        inputs = np.load(REFERENCE)["inputs"]
    else:
        head = np.genfromtxt(results_csv, delimiter=",", max_rows=1, dtype=str)
        head = [h.strip('"') for h in head]
        data = np.loadtxt(results_csv, delimiter=",", skiprows=1, max_rows=10 * STEPS // 4 + 1)
        inputs = data[:, [head.index(c) for c in COLUMNS]]
    save_cases(REFERENCE, CASES, lambda name: record(name, inputs), inputs=inputs)


def _plain_covariances(name: str, inputs: np.ndarray) -> np.ndarray:
    """``P_x`` of the plain model (:class:`~fmus.estimators.ekf_accelerometer_model.EkfAccelerometerModel`)
    fed as the FMU is on time (case ``name``): after the initial update, then per step."""
    params, schedule, ratio = CASES[name]
    assert schedule == "on_time" and ratio == 1
    p = am.EkfAccelerometerParameters(**params)
    ekf = em.EkfAccelerometerModel(p)
    rows = []
    for k in range(STEPS + 1):
        row = inputs[k]
        acc = row[2:5] if p.index_x == 1 else row[[4, 3, 2]]     # the swapped axes of record()
        if k:
            ekf.predict(0.5 * (inputs[k - 1, 6:8] + row[6:8]), H)
        ekf.update(ekf.measurement_vector(row[0:2], (acc[p.index_x - 1], acc[p.index_z - 1])))
        rows.append(ekf.P[np.tril_indices(6)])
    return np.array(rows)


@pytest.mark.parametrize("name", sorted(CASES))
def test_ekf_step_is_its_reference(name: str) -> None:
    stored = np.load(REFERENCE)
    now = record(name, stored["inputs"])
    assert_array_equal(now["ok"], stored[f"{name}/ok"])
    if CASES[name][0].get("use_bias"):
        # with the bias states (10) P_x is the lower triangle of P[0:6, 0:6], as the plain
        # model's (the adapter before took it from the wrong rows of P); same process: bit for bit
        assert_array_equal(now["outputs"][:, P_X], _plain_covariances(name, stored["inputs"]))
    assert_near(now["outputs"], stored[f"{name}/outputs"], rtol=KERNEL_RTOL)
    assert str(now["log"]) == str(stored[f"{name}/log"])
    # the cases test what they say: the filter moved, and only the divergence failed
    assert np.ptp(now["outputs"][:, 0]) > 1e-5
    assert now["ok"].all() != (name == "diverged")
    if name == "diverged":
        assert "EKF diverged" in str(now["log"])

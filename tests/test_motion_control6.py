"""The six-axis motion controller's math (fmus/robot_plant/motion_control6_model.py): the
feed-forward's gearbox inversion, the drive's speed estimate, and tracking P1 on the six-axis
plant with the controller's model (six_axis_model's ideal plant: elastic joints, the nominal
spring, damping and friction), its motor angles as the encoders. About 10 s."""
from __future__ import annotations

import copy
import math
from dataclasses import replace

import numpy as np
import pytest

from fmus.common.parameters import ParameterError
from fmus.robot_plant import motion_control6_model as C
from fmus.robot_plant import six_axis_model as S

P = C.MotionController6Parameters(path="p1")


@pytest.fixture(scope="module")
def model() -> C.MotionControl6Model:
    return C.MotionControl6Model(P)


def _col(rows: np.ndarray, name: str) -> np.ndarray:
    return rows[:, C._AT[name]]


def test_the_motor_reference_carries_the_arm_torque_through_the_nominal_gearbox(model) -> None:
    arm, tab, dt = model.arm, model.table, model.dt
    r = arm.gear_ratio
    D = _col(tab, "q_m") / r - _col(tab, "q")
    dD = _col(tab, "dq_m") / r - _col(tab, "dq")
    spring = arm.k_hi * D - (arm.k_hi - arm.k_lo) * arm.delta * np.tanh(D / arm.delta)
    # the gearbox law holds along the reference: dD/dt is the law's (round-off of the motor
    # angles r (q + D), about 1e-13 rad in D, times k_hi / d: 1e-8 of the torque)
    tau = _col(tab, "tau_arm")
    assert np.abs(spring + arm.d * dD - tau).max() <= 1e-7 * np.abs(tau).max()
    # and that rate is the deflection's derivative, against central differences on the 1 ms
    # grid: they err by h^2 / 6 |D'''| where the lag (time constants 1-2 ms on the wrist, about
    # the grid's step) answers the kinks of the jerk, measured up to 1.1e-2 of an axis's largest
    # rate (axis 4); a wrong rate (sign, factor, the table's other column) errs by order 1
    diff = np.gradient(D, dt, axis=0)[1:-1]
    rel = np.abs(diff - dD[1:-1]).max(axis=0) / np.abs(dD).max(axis=0)
    print("deflection rate against its differences, per axis:", np.array2string(rel, precision=4))
    assert np.all(rel <= 3e-2)
    # at rest the motor torque holds gravity alone (friction of a zero speed is zero)
    assert np.allclose(_col(tab, "tau_ff")[0], tau[0] / r, rtol=0, atol=1e-12)


def test_the_drive_forms_its_speed_from_its_encoder(model) -> None:
    ctrl = C.MotionController6(model, P.kp, P.kd, P.ti, P.tau_max, 0.0)      # raw backward difference
    q = np.arange(6.0)
    ctrl.start(0.0, q)
    ctrl.step(0.0, 1e-3, q + 2e-3 * np.arange(1, 7))
    assert np.allclose(ctrl.velocity, 2.0 * np.arange(1, 7), rtol=1e-12)
    f = C.MotionController6(model, P.kp, P.kd, P.ti, P.tau_max, 250.0)
    f.start(0.0, q)
    f.step(0.0, 1e-3, q + 2e-3 * np.arange(1, 7))
    assert np.allclose(f.velocity, (1 - math.exp(-2 * math.pi * 250 * 1e-3)) * 2.0 * np.arange(1, 7), rtol=1e-12)


def _without_feed_forward(model: C.MotionControl6Model) -> C.MotionControl6Model:
    """``model`` with the start's gravity torque held as the feed-forward and the motor
    reference ``r q`` plus the start's deflection: no acceleration, speed or deflection change."""
    bare = copy.copy(model)
    bare.table = tab = model.table.copy()
    r, rest = model.arm.gear_ratio, model.table[0]
    tab[:, C._AT["tau_ff"]] = rest[C._AT["tau_ff"]]
    tab[:, C._AT["q_m"]] = r * tab[:, C._AT["q"]] + (rest[C._AT["q_m"]] - r * rest[C._AT["q"]])
    return bare


def _track(model: C.MotionControl6Model, seconds: float) -> np.ndarray:
    """Tool error [m] (n, 3) of ``model``'s path on the ideal six-axis plant started at rest at
    the path's start pose, the drives on the plant's motor angles."""
    ctrl = C.MotionController6(model, P.kp, P.kd, P.ti, P.tau_max, P.velocity_cutoff)
    plant = S.SixAxisPlant(S.SixAxisParameters(q0=tuple(model.table[0, C._AT["q"]]), ideal=True))
    ctrl.start(0.0, plant.split(plant.x)[1])
    err = []
    for k in range(int(round(seconds / 1e-3))):
        plant.step(ctrl.tau, None, 1e-3)
        ctrl.step(k * 1e-3, 1e-3, plant.split(plant.x)[1])
        err.append(plant.tool_position(plant.x) - ctrl.row[C._AT["p"]])
    return np.array(err)


def test_the_controller_tracks_p1_on_its_own_model(model) -> None:
    """The first 0.6 s of P1's motion (0.5-1.1 s: the first side, 1 m/s) on the plant the
    controller's model describes: the feed-forward leaves the PID the 1 ms zero-order hold's
    error, the tool within 0.1 mm; the same drives without it (gravity held, no acceleration or
    deflection feed-forward) err more than ten times as much."""
    with_ff = np.linalg.norm(_track(model, 1.1), axis=1)
    without = np.linalg.norm(_track(_without_feed_forward(model), 1.1), axis=1)
    print(f"P1 tool error with feed-forward {with_ff.max() * 1e3:.4f} mm, without {without.max() * 1e3:.3f} mm")
    assert with_ff.max() <= 1e-4
    assert without.max() >= 10 * with_ff.max()


def test_a_path_the_arm_cannot_follow_names_the_parameter_and_time() -> None:
    with pytest.raises(ParameterError, match=r"parameter 'path' = 'p1': path 'p1 \(axes 1, 4-6 held\)': "
                                             r"at t = 0.130 s axis 2 is faster"):
        C.MotionControl6Model(replace(P, speed_scale=5.0))
    with pytest.raises(ParameterError, match="parameter 'kp' needs 6 values, got 2"):
        C.MotionControl6Model(replace(P, kp=(1.0, 2.0)))

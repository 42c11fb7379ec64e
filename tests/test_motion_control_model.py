"""Tests of fmus.robot_plant.motion_control_model: arm reference, feed-forward, closed loop."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.signal import butter, filtfilt

from fmus.common import dynamics, kinematics
from fmus.common.parameters import ParameterError, replace
from fmus.common.robot_params import RobotParameters
from fmus.robot_plant import motion_control_model as mcm
from fmus.robot_plant.trajectory import PathBuilder, make_path

DT = 1e-3   # controller period in the closed-loop tests [s]


@pytest.fixture(scope="module")
def robot() -> RobotParameters:
    return RobotParameters()


@pytest.fixture(scope="module")
def params() -> mcm.MotionControllerParameters:
    return mcm.MotionControllerParameters()


def _gains(p: mcm.MotionControllerParameters) -> mcm.PidGains:
    return mcm.PidGains.from_values(p.kp, p.kd, p.ti, p.tau_max)


# ---- arm reference (kinematics only) -----------------------------------------------------------
@pytest.fixture(scope="module")
def iso_samples():
    tr = make_path("iso9283")
    t = np.linspace(0.0, tr.duration, 3001)
    return tr, t


def test_ik_reference_reproduces_the_path_through_forward_kinematics(iso_samples, robot) -> None:
    tr, t = iso_samples
    p, v, a, j = tr.evaluate_many(t)
    q, dq, _, _ = mcm.arm_reference(p, v, a, j, robot.l1, robot.l2)
    for k in range(0, t.size, 150):
        assert_allclose(kinematics.tool_position(q[k], robot), p[k], atol=1e-12)
        assert_allclose(kinematics.jacobian(q[k], robot, "tool") @ dq[k], v[k], atol=1e-12)
    assert_allclose(kinematics.tool_position_many(q, robot.l1, robot.l2), p, atol=1e-12)
    # the branch of the home pose: the tool at (l2, l1) is q = 0
    q0, _ = kinematics.inverse_kinematics_many(np.array([[robot.l2, robot.l1]]), robot.l1, robot.l2)
    assert_allclose(q0[0], 0.0, atol=1e-12)


def test_arm_reference_derivatives_are_consistent(iso_samples, robot) -> None:
    """dq, ddq, dddq against central differences of the exact IK of the path."""
    tr, t = iso_samples
    h = 1e-5

    def ref(tt: np.ndarray):
        return mcm.arm_reference(*tr.evaluate_many(tt), robot.l1, robot.l2)

    r0, rp, rm = ref(t), ref(t + h), ref(t - h)
    for k in range(3):
        fd = (rp[k] - rm[k]) / (2 * h)
        scale = max(np.abs(r0[k + 1]).max(), 1.0)
        tol = 1e-6 if k < 2 else 1e-3    # jerk from differences of ddq: the snap may jump
        assert_allclose(fd, r0[k + 1], atol=tol * scale)
    # the arm acceleration reproduces the tool acceleration (2012 paper, eq. 19)
    p, v, a, j = tr.evaluate_many(t[::100])
    q, dq, ddq, _ = mcm.arm_reference(p, v, a, j, robot.l1, robot.l2)
    for k in range(q.shape[0]):
        assert_allclose(kinematics.point_acceleration(q[k], dq[k], ddq[k], robot, "tool"), a[k], atol=1e-9)


def test_jacobian_matches_the_shared_kinematics(robot) -> None:
    q = np.array([[0.3, -0.2], [-0.1, 0.5]])
    jac = kinematics.jacobian_many(q, robot.l1, robot.l2)
    for k in range(2):
        assert_allclose(jac[k], kinematics.jacobian(q[k], robot, "tool"), atol=1e-12)


# ---- the reference table and the feed-forward ----------------------------------------------------
@pytest.fixture(scope="module")
def square_model(params) -> mcm.MotionControlModel:
    return mcm.MotionControlModel(make_path("square"), params.robot(), _gains(params))


def test_table_interpolation_is_consistent(square_model) -> None:
    m = square_model
    t = np.array([0.0, 0.7003, 1.2345, 2.0, m.trajectory.duration + 10.0])
    p, v, a, j = m.trajectory.evaluate_many(t)
    for k, tk in enumerate(t):
        row = m.sample(float(tk))
        assert_allclose(row[mcm.COLUMNS["p_ref"]], p[k], atol=1e-9)
        assert_allclose(row[mcm.COLUMNS["v_ref"]], v[k], atol=1e-6)
        q = row[mcm.COLUMNS["q_a_ref"]]
        assert_allclose(kinematics.tool_position_many(q, m.l1, m.l2), p[k], atol=1e-9)
    # derivative columns are the derivatives of the tabulated quantities; where the next
    # derivative jumps (the snap, at a ramp's end) a central difference is off by up to half
    # of one grid step's change of the derivative
    tab, dt = m.table, m.dt
    for a_col, b_col in (("q_a_ref", "dq_a_ref"), ("dq_a_ref", "ddq_a_ref"), ("ddq_a_ref", "dddq_a_ref"),
                         ("q_m_ref", "dq_m_ref")):
        fd = np.gradient(tab[:, mcm.COLUMNS[a_col]], dt, axis=0)
        ref = tab[:, mcm.COLUMNS[b_col]]
        step = np.abs(np.diff(ref, axis=0)).max()
        assert_allclose(fd, ref, atol=1e-3 * np.abs(ref).max() + 0.5 * step)


def test_motor_reference_holds_the_deflection_for_the_arm_torque(square_model, robot) -> None:
    """q_m_ref / r - q_a_ref is the gearbox deflection whose spring torque carries the arm (eq. 11)."""
    m = square_model
    r = np.asarray(robot.gear_ratio, float)
    for tk in (0.0, 0.9, 1.6):
        row = m.sample(tk)
        q = row[mcm.COLUMNS["q_a_ref"]]
        qm = row[mcm.COLUMNS["q_m_ref"]]
        tau_arm = row[mcm.COLUMNS["tau_arm"]]
        assert_allclose(tau_arm, dynamics.inverse_dynamics_rigid(q, row[mcm.COLUMNS["dq_a_ref"]],
                                                                row[mcm.COLUMNS["ddq_a_ref"]], robot), rtol=1e-9)
        dq = row[mcm.COLUMNS["dq_a_ref"]]
        dqm = row[mcm.COLUMNS["dq_m_ref"]]
        spring = dynamics.spring_torque(q, qm, robot)
        damping = np.asarray(robot.d, float) * (dqm / r - dq)
        assert_allclose(spring + damping, tau_arm, rtol=1e-3, atol=1e-3 * np.abs(tau_arm).max())
    # at rest the motor reference is the static equilibrium under gravity
    row = m.sample(0.0)
    q = row[mcm.COLUMNS["q_a_ref"]]
    assert_allclose(dynamics.spring_torque(q, row[mcm.COLUMNS["q_m_ref"]], robot),
                    dynamics.gravity_torque(q, robot), rtol=1e-9)
    assert np.all(np.abs(row[mcm.COLUMNS["q_m_ref"]] / r - q) > 1e-5)   # a real deflection


def test_model_error_changes_the_feed_forward(params) -> None:
    soft = replace(params, k_lo=tuple(0.5 * np.asarray(params.k_lo)), k_hi=tuple(0.5 * np.asarray(params.k_hi)))
    a = mcm.MotionControlModel(make_path("square"), params.robot(), _gains(params))
    b = mcm.MotionControlModel(make_path("square"), soft.robot(), _gains(params))
    qa = mcm.COLUMNS["q_a_ref"]
    qm = mcm.COLUMNS["q_m_ref"]
    assert_allclose(a.table[:, qa], b.table[:, qa], atol=1e-15)
    r = np.asarray(params.gear_ratio)
    da = a.table[:, qm] / r - a.table[:, qa]
    db = b.table[:, qm] / r - b.table[:, qa]
    assert np.abs(db).max() > 1.5 * np.abs(da).max()


def test_the_table_is_cached_by_everything_it_is_built_from(params, tmp_path, monkeypatch) -> None:
    """The disk cache gives back the table bit for bit, for the same path, robot model and grid
    only: a changed robot parameter, path start or speed, or grid is built anew; the gains,
    which the table does not depend on, share it."""
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(tmp_path))
    builds = []
    build = mcm.MotionControlModel._build_table
    monkeypatch.setattr(mcm.MotionControlModel, "_build_table", lambda self, t: builds.append(1) or build(self, t))

    def model(path=make_path("square"), robot=params.robot(), gains=_gains(params), **kw):
        return mcm.MotionControlModel(path, robot, gains, **kw)

    first = model()
    assert len(builds) == 1 and len(list((tmp_path / "tables").glob("*.npy"))) == 1
    again = model(gains=mcm.PidGains.from_values((1.0, 1.0), (0.1, 0.1), (0.0, 0.0), (50.0, 50.0)))
    assert len(builds) == 1
    assert again.table.tobytes() == first.table.tobytes() == build(first, first.t_grid).tobytes()
    k_hi = np.asarray(params.k_hi)
    for other in (dict(robot=replace(params, k_hi=(k_hi[0], np.nextafter(k_hi[1], 0.0))).robot()),
                  dict(path=make_path("square").scaled(1.01)),
                  dict(path=make_path("square", start=(1.0, 0.61))),
                  dict(dt_grid=4e-4)):
        n = len(builds)
        changed = model(**other)
        assert len(builds) == n + 1
        assert changed.table.shape != first.table.shape or not np.array_equal(changed.table, first.table)


def test_cartesian_offset_moves_the_arm_reference(square_model) -> None:
    m = square_model
    ctrl = mcm.MotionController(m)
    zero = np.zeros(2)
    for dp in (np.array([1e-5, -2e-5]), np.array([0.01, 0.02]), np.array([-0.03, 0.0])):
        ctrl.evaluate(1.1, zero, zero, dp)
        p_nominal = m.sample(1.1)[mcm.COLUMNS["p_ref"]]
        assert_allclose(ctrl.p_ref, p_nominal + dp, atol=1e-15)
        tol = 1e-9 if np.hypot(*dp) > 1e-4 else 1e-12
        assert_allclose(kinematics.tool_position_many(ctrl.q_a_ref, m.l1, m.l2), p_nominal + dp, atol=tol)
        dq = ctrl.q_a_ref - m.sample(1.1)[mcm.COLUMNS["q_a_ref"]]
        assert_allclose(ctrl.q_m_ref - m.sample(1.1)[mcm.COLUMNS["q_m_ref"]], m.r * dq, rtol=1e-12)


def test_pid_law_and_anti_windup(square_model) -> None:
    m = square_model
    ctrl = mcm.MotionController(m)
    g = m.gains
    row = m.sample(0.0)
    qm_ref, tau_ff = row[mcm.COLUMNS["q_m_ref"]], row[mcm.COLUMNS["tau_ff"]]
    e = np.array([1e-3, -2e-3])
    w = np.array([0.1, 0.2])
    tau = ctrl.evaluate(0.0, qm_ref - e, -w, np.zeros(2))
    assert_allclose(tau, tau_ff + g.kp * e + g.kd * w, rtol=1e-12)
    ctrl.advance(0.01)
    assert_allclose(ctrl.integral, 0.01 * e)
    tau = ctrl.evaluate(0.0, qm_ref - e, -w, np.zeros(2))
    assert_allclose(tau, tau_ff + g.kp * (e + 0.01 * e / g.ti) + g.kd * w, rtol=1e-12)
    # saturated: the torque is limited and the integral does not grow further
    ctrl.reset()
    big = np.array([1e3, -1e3])
    tau = ctrl.evaluate(0.0, qm_ref - big, np.zeros(2), np.zeros(2))
    assert_allclose(np.abs(tau), g.tau_max)
    ctrl.advance(0.01)
    assert_allclose(ctrl.integral, 0.0)


# ---- errors ----------------------------------------------------------------------------------------
def test_unreachable_waypoint_is_named(params) -> None:
    tr = PathBuilder((1.2, 0.9), speed=0.2, accel=2.0).line_to((1.6, 0.9)).line_to((1.9, 1.2), label="far corner").build()
    with pytest.raises(mcm.ReachError, match="far corner at \\(1.9, 1.2\\) m is out of reach"):
        mcm.MotionControlModel(tr, params.robot(), _gains(params))
    # a path point out of reach between reachable waypoints: a circle that leaves the workspace
    tr = PathBuilder((1.6, 0.9), speed=0.2, accel=2.0).circle((1.8, 0.9), label="round trip").build()
    with pytest.raises(mcm.ReachError, match="on the move to round trip is out of reach"):
        mcm.MotionControlModel(tr, params.robot(), _gains(params))


def test_bad_parameters_name_the_parameter(params, tmp_path: Path) -> None:
    with pytest.raises(ParameterError, match="'path_start'"):
        mcm.build_controller(replace(params, path="p1", path_start=(2.5, 1.0)))
    with pytest.raises(ParameterError, match="parameter 'csv_file' must name"):
        replace(params, path="csv")
    bad = tmp_path / "bad.csv"
    bad.write_text("x,z\n1.2,0.9\n1.3,oops\n")
    with pytest.raises(ParameterError, match=f"parameter 'csv_file' = '{bad}'.*line 3"):
        mcm.build_controller(replace(params, path="csv", csv_file=str(bad)))
    with pytest.raises(ParameterError, match="parameter 'path' = 'p9' is not one of"):
        replace(params, path="p9")
    slow = tmp_path / "slow.csv"          # 1e11 s of path: refused before its table is allocated
    slow.write_text("x,z,speed\n1.2,0.9,\n1.3,0.9,1e-12\n")
    with pytest.raises(ParameterError, match=r"path 'csv:slow.csv' lasts 1e\+11 s, longer than the 1200 s"):
        mcm.build_controller(replace(params, path="csv", csv_file=str(slow)))
    with pytest.raises(ParameterError, match="kp\\[2\\]"):
        replace(params, kp=(1.0, -1.0))


# ---- closed loop with the flexible plant ------------------------------------------------------------
def _closed_loop(traj, ctrl_params: mcm.MotionControllerParameters, plant: RobotParameters,
                 t_end: float | None = None, encoder=None) -> dict[str, np.ndarray]:
    """Controller at 1 kHz (torque held over each period) around dynamics.FlexibleRobotModel.
    ``encoder``: None, the law on the true motor angle and speed; else a function of the true
    angle giving the reading, from which the drive forms its speed (MotionController.measure)."""
    model = mcm.MotionControlModel(traj, ctrl_params.robot(), _gains(ctrl_params))
    ctrl = mcm.MotionController(model, velocity_cutoff=ctrl_params.velocity_cutoff)
    robot = dynamics.FlexibleRobotModel(plant, model.q_a_ref0)
    n = int(round(((t_end if t_end is not None else traj.duration + 0.3)) / DT))
    r = np.asarray(plant.gear_ratio, float)
    zero = np.zeros(2)
    out = {k: np.empty((n + 1, 2)) for k in ("p_tool", "p_rigid", "p_ref", "e_m", "tau")}
    out["t"] = np.arange(n + 1) * DT
    for k in range(n + 1):
        x = robot.x
        q, qm, dqm = x[0:2], x[2:4], x[6:8]
        if encoder is not None:
            qm = encoder(qm)
            ctrl.measure(k * DT, qm)
            dqm = ctrl.law_speed(k * DT)
        tau = ctrl.evaluate(k * DT, qm, dqm, zero)
        out["p_tool"][k] = kinematics.tool_position(q, plant)
        out["p_rigid"][k] = kinematics.tool_position(qm / r, plant)
        out["p_ref"][k] = ctrl.p_ref
        out["e_m"][k] = ctrl.error
        out["tau"][k] = tau
        if k < n:
            ctrl.advance(DT)
            robot.step(tau, zero, DT)
    return out


def _corner_path() -> "object":
    """A run of 90-degree corners at 200 mm/s as in the ISO path (accel 3 m/s^2, blended)."""
    b = PathBuilder((1.2, 0.8), speed=0.2, accel=3.0, blend=1.0, hold=0.1, name="corners")
    for _ in range(3):
        b.line_by((-0.04, 0.0)).line_by((0.0, -0.03))
    return b.build()


def _figures(out: dict[str, np.ndarray]) -> dict[str, float]:
    """Tool vs rigid kinematics of q_m/r (all frequencies, and 3-30 Hz as in the 2009 paper's
    Table I), tool tracking error vs p_ref, motor-side error."""
    dev = out["p_tool"] - out["p_rigid"]
    b, a = butter(2, [3.0, 30.0], btype="band", fs=1.0 / DT)
    band = filtfilt(b, a, dev, axis=0)
    trk = np.hypot(*(out["p_tool"] - out["p_ref"]).T)
    dn = np.hypot(*dev.T)
    db = np.hypot(*band.T)
    return dict(dev_peak=dn.max(), dev_rms=math.sqrt((dn ** 2).mean()),
                band_peak=db.max(), band_mean=db.mean(),
                trk_peak=trk.max(), trk_rms=math.sqrt((trk ** 2).mean()),
                em_peak=np.abs(out["e_m"]).max())


def test_the_drives_speed_is_the_filtered_backward_difference() -> None:
    """measure(): the first reading primes (speed 0); a ramp's difference is its slope, which
    the first-order low-pass reaches as 1 - exp(-2 pi f_c t) at the sample times; cut-off 0 is
    the raw difference; a reading at the last one's time changes nothing. The reference speed
    is formed the same way from the reference angles: a drive reading exactly its reference
    has equal speeds, and the law's derivative term is zero (law_speed is dq_m_ref)."""
    model = mcm.MotionControlModel(make_path("square"), mcm.MotionControllerParameters().robot(),
                                   _gains(mcm.MotionControllerParameters()))
    w, h, fc = np.array([3.0, -7.0]), 1e-3, 250.0
    ctrl = mcm.MotionController(model, velocity_cutoff=fc)
    ctrl.measure(0.0, np.array([0.1, 0.2]))
    assert_allclose(ctrl.velocity, 0.0, atol=0)
    for k in range(1, 6):
        ctrl.measure(k * h, np.array([0.1, 0.2]) + w * k * h)
        assert_allclose(ctrl.velocity, w * (1.0 - math.exp(-2.0 * math.pi * fc * k * h)), rtol=1e-12)
    v = ctrl.velocity.copy()
    ctrl.measure(5 * h, np.array([9.0, 9.0]))
    assert_allclose(ctrl.velocity, v, rtol=0)
    raw = mcm.MotionController(model, velocity_cutoff=0.0)
    raw.measure(0.0, np.zeros(2))
    raw.measure(2e-3, np.array([1e-3, -4e-3]))
    assert_allclose(raw.velocity, [0.5, -2.0], rtol=1e-12)
    on_path = mcm.MotionController(model, velocity_cutoff=fc)
    for t in np.arange(0.4, 0.9, h):                                     # the square path moves
        on_path.measure(t, model.sample(t)[mcm.COLUMNS["q_m_ref"]])
    assert np.abs(on_path.velocity).min() > 1.0
    assert_allclose(on_path.velocity, on_path.velocity_ref, rtol=0, atol=0)
    assert_allclose(on_path.law_speed(t), model.sample(t)[mcm.COLUMNS["dq_m_ref"]], rtol=1e-15)
    assert mcm.MotionControllerParameters().velocity_cutoff == mcm.DEFAULT_VELOCITY_CUTOFF == 250.0


def _resolver(seed: int = 0):
    """The Encoder's defaults as a function: 2e-5 rad white noise, then 16-bit quantisation."""
    rng = np.random.default_rng(seed)
    lsb = 2.0 * math.pi / 2 ** 16
    return lambda qm: np.round((qm + rng.normal(0.0, 2e-5, 2)) / lsb) * lsb


def test_the_drive_on_its_encoder_stays_well_behaved(params, robot) -> None:
    """Speed from the default encoder (quantised, noisy, differenced, 250 Hz low-pass) instead
    of the true speed: the loop stays stable and tracks the corners as well. Measured: tool
    tracking RMS 1.01x the ideal drive's, torque increments RMS 0.93x (with the exact
    dq_m_ref in the derivative term instead of the filtered reference: 3.7x, the lag)."""
    path = _corner_path()
    ideal = _closed_loop(path, params, robot)
    drive = _closed_loop(path, params, robot, encoder=_resolver())
    fi, fd = _figures(ideal), _figures(drive)
    assert np.all(np.isfinite(drive["tau"]))
    assert fd["em_peak"] < 0.01 and fd["trk_peak"] < 0.5e-3          # the bounds of the ideal drive
    assert fd["trk_rms"] < 1.05 * fi["trk_rms"]                         # measured 1.01x
    steps = [math.sqrt((np.diff(o["tau"], axis=0) ** 2).mean()) for o in (ideal, drive)]
    assert steps[1] < 1.1 * steps[0]                                    # no ringing, no noise pumping


def test_closed_loop_tracks_corners_and_the_tool_deflects(params, robot) -> None:
    out = _closed_loop(_corner_path(), params, robot)
    f = _figures(out)
    assert np.all(np.isfinite(out["tau"]))
    # motor-side tracking: small (motor side 0.01 rad = 50 urad arm side) ...
    assert f["em_peak"] < 0.01
    # ... the tool follows the path to well under a millimetre ...
    assert f["trk_peak"] < 0.5e-3
    # ... and deviates from the rigid kinematics of the motor angles by > 0.1 mm in the
    # 3-30 Hz band, i.e. dynamically (not only the static gravity deflection)
    assert f["band_peak"] > 0.1e-3
    # stable: at rest after the path the motion decays
    tail = out["t"] > out["t"][-1] - 0.1
    assert np.abs(np.diff(out["p_tool"][tail], axis=0)).max() < 1e-6


@pytest.mark.slow
def test_closed_loop_iso_path(params, robot) -> None:
    out = _closed_loop(make_path("iso9283"), params, robot)
    f = _figures(out)
    print("ISO 9283 closed loop: " + ", ".join(f"{k} = {v * 1e3:.3f} mm" if k != "em_peak" else
                                                  f"{k} = {v:.4f} rad" for k, v in f.items()))
    assert f["em_peak"] < 0.02 and f["trk_peak"] < 1e-3 and f["band_peak"] > 0.1e-3


def test_closed_loop_is_stable_and_damped(params, robot) -> None:
    """Linearised closed loop at the home pose: every pole in the left half plane, damped.

    Without Coulomb friction: its smooth zero-speed part would add a large, misleading
    viscous damping to the linearisation at rest (Coulomb friction only removes energy).
    """
    robot = replace(robot, f_c=(0.0, 0.0))
    model = mcm.MotionControlModel(make_path("square"), params.robot(), _gains(params))
    ctrl = mcm.MotionController(model)
    row = model.sample(0.0)
    q0, qm0 = row[mcm.COLUMNS["q_a_ref"]], row[mcm.COLUMNS["q_m_ref"]]
    x0 = np.concatenate([q0, qm0, np.zeros(4), np.zeros(2)])   # + integral states
    g = model.gains

    def f(z: np.ndarray) -> np.ndarray:
        x, integ = z[:8], z[8:]
        e = qm0 - x[2:4]
        tau = row[mcm.COLUMNS["tau_ff"]] + g.kp * (e + integ / g.ti) - g.kd * x[6:8]
        return np.concatenate([dynamics.derivatives(x, tau, np.zeros(2), robot), e])

    h = 1e-7
    a = np.column_stack([(f(x0 + h * e) - f(x0 - h * e)) / (2 * h) for e in np.eye(10)])
    lam = np.linalg.eigvals(a)
    assert np.all(lam.real < 0)
    zeta = -lam.real / np.abs(lam)
    freq = np.abs(lam) / (2 * np.pi)
    # the rigid-body (servo) poles are well damped and well below the gearbox resonances ...
    servo = freq < 6.0
    assert servo.sum() >= 4 and zeta[servo].min() > 0.5
    # ... which stay lightly damped, between 8 and 30 Hz (the plant's own structural damping)
    flex = ~servo & (zeta < 0.5)
    assert flex.sum() == 4 and np.all((freq[flex] > 8.0) & (freq[flex] < 30.0)) and zeta[flex].min() > 0.02


def test_identification_multisine_excitation(params) -> None:
    """RMS = amplitude per joint, every line inside the band on the period's grid, independent
    phases per joint, added to the PID torque (and nothing when the amplitude is zero)."""
    ex = mcm.Multisine((0.5, 2.0), (3.0, 12.0), 1.0, seed=4)
    t = np.arange(4000) / 4000.0                       # one period
    u = np.array([ex(tk) for tk in t])
    assert_allclose(np.sqrt(np.mean(u ** 2, axis=0)), [0.5, 2.0], rtol=1e-9)
    spec = np.abs(np.fft.rfft(u, axis=0))
    lines = np.flatnonzero(spec[:, 0] > 1e-6 * spec[:, 0].max())
    assert lines.tolist() == list(range(3, 13))
    assert abs(np.corrcoef(u[:, 0], u[:, 1])[0, 1]) < 0.3
    with pytest.raises(ParameterError, match="excitation_band"):
        mcm.Multisine((1.0, 1.0), (0.2, 0.4), 1.0, seed=0)
    with pytest.raises(ParameterError, match="excitation_band"):
        replace(params, excitation_band=(5.0, 2.0))
    assert params.excitation() is None
    excited = replace(params, excitation_amplitude=(0.5, 2.0), excitation_band=(3.0, 12.0), excitation_seed=4)
    a, b = mcm.build_controller(params), mcm.build_controller(excited)
    row = a.model.sample(0.37)
    qm, dqm = row[mcm.COLUMNS["q_m_ref"]], row[mcm.COLUMNS["dq_m_ref"]]     # on the path: no saturation
    assert_allclose(b.evaluate(0.37, qm, dqm, np.zeros(2)) - a.evaluate(0.37, qm, dqm, np.zeros(2)),
                    ex(0.37), atol=1e-12)

"""The six-axis paths (fmus/robot_plant/trajectory6.py): the IK round trip along each path, the
joint derivatives against differences of the IK, the planar paths on axes 2-3, the bad paths
named. About 10 s (the ISO cube's 18 000-point IK dominates)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from fmus.common import irb4600, kinematics, quaternion
from fmus.common.robot_params import RobotParameters
from fmus.robot_plant import trajectory6 as T
from fmus.robot_plant.motion_control_model import arm_reference
from fmus.robot_plant.trajectory import PathBuilder, make_path

ARM = irb4600.arm()


@pytest.fixture(scope="module")
def refs() -> dict[str, T.JointReference]:
    return {name: T.make_reference(name, ARM) for name in T.PATHS6}


def test_jacobians_are_irb4600s() -> None:
    q = np.random.default_rng(1).uniform(-2.0, 2.0, (30, 6))
    J = T.jacobians(q, ARM)
    # the same products in the same order, vectorised: equal but for the summation order's round-off
    assert max(np.abs(J[k] - irb4600.jacobian(q[k], ARM)).max() for k in range(30)) <= 1e-14


@pytest.mark.parametrize("name", T.PATHS6)
def test_ik_round_trip_along_each_path(refs, name) -> None:
    r = refs[name]
    assert r.t[0] == 0.0 and r.t[-1] >= r.duration + T.T_MARGIN
    for k in range(0, r.t.shape[0], 97):
        p, quat = irb4600.tool_pose(r.q[k], ARM)
        assert np.abs(p - r.p[k]).max() <= 1e-12                       # p is the FK of q
        back = irb4600.inverse_kinematics(p, quat, r.q[k], ARM)
        assert np.abs(back - r.q[k]).max() <= 1e-9, (name, r.t[k])      # IK's closed form, round-off
        assert np.all((r.q[k] >= ARM.q_min) & (r.q[k] <= ARM.q_max))


@pytest.mark.parametrize("name", ["iso_cube", "square"])
def test_the_tool_paths_keep_the_tool_down_and_follow_their_points(refs, name) -> None:
    r = refs[name]
    traj = T.iso_cube_path() if name == "iso_cube" else T.square_path()
    p = traj.evaluate_many(r.t)[0]
    assert np.abs(r.p - p).max() <= 1e-12
    for k in range(0, r.t.shape[0], 301):
        quat = irb4600.tool_pose(r.q[k], ARM)[1]
        assert min(np.abs(quat - T.TOOL_DOWN).max(), np.abs(quat + T.TOOL_DOWN).max()) <= 1e-12


def test_the_iso_cube_is_iso_9283s() -> None:
    P = T.cube_corners()
    diag = np.linalg.norm(P["C7"] - P["C1"])
    assert math.isclose(np.linalg.norm(P["P2"] - P["C1"]), 0.1 * diag)      # 10 % of the diagonal
    assert math.isclose(np.linalg.norm(P["P4"] - P["C7"]), 0.1 * diag)
    normal = np.cross(P["C2"] - P["C1"], P["C8"] - P["C1"])
    for k in ("P1", "P2", "P3", "P4", "P5", "C7"):                          # all in the test plane
        assert abs(normal @ (P[k] - P["C1"])) <= 1e-15
    traj = T.iso_cube_path()
    v = np.linalg.norm(traj.evaluate_many(np.arange(0.0, traj.duration, 1e-3))[1], axis=1)
    assert math.isclose(v.max(), 0.2, rel_tol=1e-9)                        # cruises at 200 mm/s


@pytest.mark.parametrize("name, times", [("iso_cube", (1.2345, 4.567, 8.91, 13.3, 16.02)),
                                         ("square", (0.71, 1.83, 3.3))])
def test_the_joint_derivatives_are_the_iks(name, times) -> None:
    """Central differences of the exact IK at +-d against the Jacobian's derivatives: the
    differences' truncation error d^2 / 6 |f'''| is below 1e-7 of each derivative's scale."""
    traj = T.iso_cube_path() if name == "iso_cube" else T.square_path()
    d = 1e-5
    for tk in times:
        t = tk + d * np.arange(-2, 3)
        r = T.cartesian_reference(traj, T.TOOL_DOWN, T.Q_TOOL_DOWN, ARM, t=t)
        for lo, hi in ((r.q, r.dq), (r.dq, r.ddq), (r.ddq, r.dddq)):
            diff = (lo[3] - lo[1]) / (2 * d)
            assert np.abs(diff - hi[2]).max() <= 1e-6 * max(1.0, np.abs(hi[2]).max()), (name, tk)


@pytest.mark.parametrize("name", ["p1", "p2", "p1_moving", "p2_moving"])
def test_p1_p2_move_axes_2_3_as_the_planar_path(refs, name) -> None:
    r = refs[name]
    rp = RobotParameters()
    p, v, a, j = make_path(name[:2]).evaluate_many(r.t)
    planar = arm_reference(p, v, a, j, rp.l1, rp.l2)
    for got, want in zip((r.q, r.dq, r.ddq, r.dddq), planar):
        assert np.array_equal(got[:, 1:3], want)
    for k in range(0, r.t.shape[0], 199):
        assert np.abs(np.array(kinematics.tool_point(r.q[k, 1], r.q[k, 2], rp.l1, rp.l2)) - p[k]).max() <= 1e-12
    other = r.q[:, [0, 3, 4, 5]]
    if name.endswith("_moving"):
        assert np.ptp(other, axis=0).min() >= 0.29                  # each moves its amplitude
        want = T.axes_moving(r.duration).evaluate_many(r.t)
        for got, w in zip((r.q, r.dq, r.ddq, r.dddq), want):
            assert np.array_equal(got[:, [0, 3, 4, 5]], w)
    else:
        assert np.array_equal(other, np.broadcast_to(T.HOLD, other.shape))
        assert not r.dq[:, [0, 3, 4, 5]].any()


def test_a_path_point_out_of_reach_is_named_with_its_time() -> None:
    with pytest.raises(ValueError, match=r"path 'iso_cube': P1 at \(2.3, 0, 0.9\) m \(t = 0.000 s\): "
                                         r"tool pose .* is out of reach"):
        T.iso_cube(ARM, centre=(2.3, 0.0, 0.9))
    with pytest.raises(ValueError, match=r"P4 at \(1.6, 0.2, 1.6\) m \(t = 7.248 s\): .* out of reach"):
        T.iso_cube(ARM, centre=(1.4, 0.0, 1.4))
    behind = PathBuilder((-1.2, 0.3, 0.9), speed=0.2, accel=2.0, blend=0.0, name="behind").line_to(
        (-1.2, -0.3, 0.9), label="B").build()
    with pytest.raises(ValueError, match=r"path 'behind': the point \(-1.2, -5e-05, 0.9\) m at t = 1.594 s "
                                         r"on the move to B needs axis 1 to leap"):
        T.cartesian_reference(behind, T.TOOL_DOWN, (2.9, 0.3, -0.2, 0.0, 1.47, 0.0), ARM)
    with pytest.raises(ValueError, match=r"at t = 0.130 s axis 2 is faster than its data-sheet speed"):
        T.make_reference("p1", ARM, speed_scale=5.0)
    with pytest.raises(ValueError, match="unknown six-axis path 'cube'"):
        T.make_reference("cube", ARM)

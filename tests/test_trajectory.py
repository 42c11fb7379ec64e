"""Tests of fmus.robot_plant.trajectory: smooth Cartesian paths and the CSV waypoint format."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from fmus.robot_plant import trajectory as tj

REPO = Path(__file__).resolve().parent.parent
EXAMPLE_CSV = REPO / "orchestration" / "scenarios" / "paths" / "example_waypoints.csv"
SHIPPED = ["p1", "p2", "iso9283", "square"]


def _boundaries(tr: tj.Trajectory) -> np.ndarray:
    """Every time where a move's time law changes piece (start, end of ramp, end of cruise, end)."""
    out = []
    for m in tr.moves:
        out += [m.t0, m.t0 + m.ramp, m.t0 + m.ramp + m.cruise, m.t_end]
    return np.array(out) / tr.time_scale


@pytest.fixture(scope="module", params=SHIPPED + ["csv"])
def traj(request: pytest.FixtureRequest) -> tj.Trajectory:
    return tj.make_path(request.param, csv_file=EXAMPLE_CSV)


def test_derivatives_match_finite_differences(traj: tj.Trajectory) -> None:
    rng = np.random.default_rng(0)
    t = rng.uniform(0.0, traj.duration + 0.2, 400)
    h = 1e-5
    p, v, a, j = traj.evaluate_many(t)
    pp, vp, ap, _ = traj.evaluate_many(t + h)
    pm, vm, am, _ = traj.evaluate_many(t - h)
    # truncation error of a central difference is h^2/6 times the next derivative
    assert_allclose((pp - pm) / (2 * h), v, atol=1e-7)
    assert_allclose((vp - vm) / (2 * h), a, atol=1e-5 * max(1.0, np.abs(a).max()))
    # jerk: the snap (4th derivative) may jump at a ramp end, so allow its O(h) effect
    assert_allclose((ap - am) / (2 * h), j, atol=1e-3 * np.abs(j).max())


def test_continuous_up_to_jerk_at_every_boundary(traj: tj.Trajectory) -> None:
    """The time law is analytic between boundaries; across each, nothing up to jerk jumps."""
    tb = _boundaries(traj)
    eps = 1e-9   # over 2 ns a continuous signal with derivative < 1e5 changes by < 2e-4
    lo = traj.evaluate_many(tb - eps)
    hi = traj.evaluate_many(tb + eps)
    for name, a, b in zip("pvaj", lo, hi):
        jump = np.abs(b - a).max()
        assert jump < 2e-4, f"{name} jumps by {jump:g} at a move boundary"


def test_scalar_evaluation_equals_vectorised(traj: tj.Trajectory) -> None:
    t = np.linspace(0.0, traj.duration + 0.3, 37)
    many = traj.evaluate_many(t)
    for i, ti in enumerate(t):
        one = traj.evaluate(float(ti))
        for k in range(4):
            assert one[k].shape == (2,)
            assert_allclose(one[k], many[k][i], rtol=0, atol=1e-15)


def test_a_sorted_grid_evaluates_bit_for_bit_as_any_order(traj: tj.Trajectory) -> None:
    """Sorted times take the slices of each move, other orders the masks: the same numbers,
    also at the moves' own start and end times (each move counts on t0 < t < t_end only)."""
    tb = _boundaries(traj) * traj.time_scale
    t = np.sort(np.concatenate([np.linspace(-0.1, traj.duration + 0.2, 2001), tb, tb, np.nextafter(tb, 0)]))
    shuffled = np.random.default_rng(1).permutation(t.size)
    grid, scattered = traj.evaluate_many(t), traj.evaluate_many(t[shuffled])
    for k in range(4):
        np.testing.assert_array_equal(grid[k][shuffled], scattered[k])


def test_rest_at_start_and_end(traj: tj.Trajectory) -> None:
    p, v, a, j = traj.evaluate_many(np.array([0.0, traj.duration, traj.duration + 5.0]))
    assert_allclose(p[0], traj.start, atol=1e-15)
    assert_allclose(p[1:], np.array([traj.end, traj.end]), atol=1e-12)
    for x in (v, a, j):
        assert_allclose(x, 0.0, atol=1e-12)


def test_paths_stay_in_the_reachable_annulus(traj: tj.Trajectory) -> None:
    """Reachable by the default arm (l1 = 0.9 m, l2 = 1.2 m): 0.3 m < |p| < 2.1 m with margin."""
    p = traj.evaluate_many(np.linspace(0.0, traj.duration, 3000))[0]
    r = np.hypot(p[:, 0], p[:, 1])
    assert r.min() > 0.3 + 0.3 and r.max() < 2.1 - 0.3


def test_iso_speed_is_200_mm_per_s_on_straight_segments() -> None:
    tr = tj.iso9283()
    intervals = tr.move_intervals()
    checked = 0.0
    for k, (t0, t1, m) in enumerate(intervals):
        if m.kind != "line" or m.cruise <= 0:
            continue
        # cruise part not overlapped by the neighbouring moves
        c0 = max(t0 + m.ramp, intervals[k - 1][1] if k else -np.inf)
        c1 = min(t0 + m.ramp + m.cruise, intervals[k + 1][0] if k + 1 < len(intervals) else np.inf)
        if c1 <= c0:
            continue
        t = np.linspace(c0, c1, 50)
        _, v, a, _ = tr.evaluate_many(t)
        assert_allclose(np.hypot(v[:, 0], v[:, 1]), 0.2, rtol=1e-12)
        assert_allclose(a, 0.0, atol=1e-12)
        checked += c1 - c0
    assert checked > 3.0  # seconds of straight-line cruise at 200 mm/s
    # the circles too run at 200 mm/s
    arcs = [(t0, t1, m) for t0, t1, m in intervals if m.kind == "arc"]
    assert len(arcs) == 2
    for t0, t1, m in arcs:
        _, v, _, _ = tr.evaluate_many(np.array([0.5 * (t0 + t1)]))
        assert_allclose(np.hypot(*v[0]), 0.2, rtol=1e-12)


def test_iso_has_a_run_of_90_degree_corners_and_two_circles() -> None:
    tr = tj.iso9283()
    lines = [m for m in tr.moves if m.kind == "line"]
    dirs = np.array([m.geometry.d for m in lines])
    stairs = dirs[-20:]
    assert_allclose(np.einsum("ij,ij->i", stairs[1:], stairs[:-1]), 0.0, atol=1e-12)
    radii = sorted(m.geometry.rho for m in tr.moves if m.kind == "arc")
    assert_allclose(radii, [0.015, 0.075])
    # the path is closed
    assert_allclose(tr.end, tr.start, atol=1e-12)


def test_square_stops_at_the_corners() -> None:
    tr = tj.square()
    side = 0.03
    corners = tr.start + side * np.array([[1, 0], [1, 1], [0, 1], [0, 0]])
    for k, (t0, t1, m) in enumerate(tr.move_intervals()):
        assert m.kind == "line"
        assert_allclose(m.geometry.length, side, rtol=1e-12)
        t_stop = np.linspace(t1, t1 + 0.1, 5)   # the 0.1 s stop
        p, v, a, j = tr.evaluate_many(t_stop)
        assert_allclose(p, np.tile(corners[k % 4], (5, 1)), atol=1e-12)
        assert_allclose(np.hstack([v, a, j]), 0.0, atol=1e-12)
        # and it does reach 80 mm/s along the side
        _, vm, _, _ = tr.evaluate_many(np.array([0.5 * (t0 + t1)]))
        assert_allclose(np.hypot(*vm[0]), 0.08, rtol=1e-12)


def test_p1_triangle_size_and_speed() -> None:
    tr = tj.triangle_p1()
    sides = [m.geometry.length for m in tr.moves[:3]]
    assert all(0.15 <= s <= 0.2 + 1e-12 for s in sides)
    assert 6.0 <= tr.duration <= 8.0
    t = np.arange(0, tr.duration, 1e-3)
    _, v, a, _ = tr.evaluate_many(t)
    speed, acc = np.hypot(*v.T), np.hypot(*a.T)
    assert 0.5 <= speed.max() <= 1.0 and 3.0 <= acc.max() <= 6.0 + 1e-9


def test_p2_is_smaller_and_elsewhere() -> None:
    p1, p2 = tj.triangle_p1(), tj.path_p2()
    ext = lambda tr: np.ptp(tr.evaluate_many(np.linspace(0, tr.duration, 2000))[0], axis=0)
    assert np.all(ext(p2) < ext(p1))
    assert np.hypot(*(p2.start - p1.start)) > 0.2


def test_start_point_translates_and_speed_scale_rescales_time() -> None:
    base = tj.iso9283()
    moved = tj.iso9283(start=(1.1, 0.7))
    t = np.linspace(0, base.duration, 101)
    assert_allclose(moved.evaluate_many(t)[0] - base.evaluate_many(t)[0],
                    np.tile([0.1, 0.1], (101, 1)), atol=1e-12)
    fast = tj.make_path("iso9283", speed_scale=2.0)
    assert_allclose(fast.duration, base.duration / 2, rtol=1e-12)
    pf, vf, af, jf = fast.evaluate_many(t / 2)
    pb, vb, ab, jb = base.evaluate_many(t)
    assert_allclose(pf, pb, atol=1e-14)
    assert_allclose(vf, 2 * vb, atol=1e-12)
    assert_allclose(af, 4 * ab, atol=1e-10)
    assert_allclose(jf, 8 * jb, atol=1e-8)
    with pytest.raises(ValueError, match="speed scale"):
        tj.make_path("p1", speed_scale=0.0)


def test_unknown_path_name() -> None:
    with pytest.raises(ValueError, match="unknown path 'p3'"):
        tj.make_path("p3")
    with pytest.raises(ValueError, match="csv_file is empty"):
        tj.make_path("csv")


# ---- CSV -------------------------------------------------------------------------------------
def test_example_csv_follows_its_waypoints() -> None:
    tr = tj.from_csv(EXAMPLE_CSV)
    expected = np.array([[1.2, 0.9], [1.35, 0.9], [1.35, 1.0], [1.25, 1.05], [1.2, 0.9]])
    assert_allclose(tr.waypoints, expected)
    assert "line 8" in tr.waypoint_labels[2]
    # 0.5 s rest at the start, a stop of 0.2 s at the third waypoint
    assert_allclose(tr.moves[0].t0, 0.5)
    stop = tr.moves[1].t_end
    p, v, _, _ = tr.evaluate_many(np.array([stop, stop + 0.1, stop + 0.2]))
    assert_allclose(p, np.tile(expected[2], (3, 1)), atol=1e-12)
    assert_allclose(v, 0.0, atol=1e-12)
    assert_allclose(tr.moves[0].speed, 0.25)


def test_timed_csv_arrives_on_time(tmp_path: Path) -> None:
    f = tmp_path / "timed.csv"
    f.write_text("t,x,z\n0.2,1.2,0.9\n1.0,1.3,0.9\n1.5,1.3,0.9\n2.5,1.3,1.0\n")
    tr = tj.from_csv(f)
    p, v, _, _ = tr.evaluate_many(np.array([0.2, 1.0, 1.5, 2.5]))
    assert_allclose(p, [[1.2, 0.9], [1.3, 0.9], [1.3, 0.9], [1.3, 1.0]], atol=1e-12)
    assert_allclose(v, 0.0, atol=1e-12)
    assert_allclose(tr.duration, 2.5, rtol=1e-12)


def test_csv_start_parameter_translates(tmp_path: Path) -> None:
    tr = tj.from_csv(EXAMPLE_CSV, start=(1.0, 1.0))
    assert_allclose(tr.start, [1.0, 1.0])
    assert_allclose(tr.waypoints[1], [1.15, 1.0])


@pytest.mark.parametrize("content, line, fragment", [
    ("x,z\n1.2,0.9\n1.3,abc\n", 3, "column 'z' is not a number"),
    ("x,z,speed\n1.2,0.9,\n1.3,0.9\n", 3, "2 values, the header has 3"),
    ("x,y\n1.2,0.9\n", 1, "field 2 of the header is no known column"),
    ("speed,dwell\n0.1,0\n", 1, "must name columns 'x' and 'z'"),
    ("# c\n\nx,z,speed\n1.2,0.9,\n1.3,0.9,-1\n", 5, "speed must be > 0"),
    ("x,z,dwell\n1.2,0.9,0\n1.3,0.9,-0.1\n", 3, "dwell must be >= 0"),
    ("t,x,z\n0,1.2,0.9\n1,1.3,0.9\n1,1.3,1.0\n", 4, "must be larger than"),
    ("t,x,z,speed\n0,1.2,0.9,1\n", 1, "cannot be combined"),
    ("x,z\n1.2,0.9\n1.3,nan\n", 3, "is not finite"),
    ("x,z\n1.2,0.9\n,0.9\n", 3, "column 'x' is empty"),
])
def test_csv_errors_name_file_and_line(tmp_path: Path, content: str, line: int, fragment: str) -> None:
    f = tmp_path / "bad.csv"
    f.write_text(content)
    with pytest.raises(ValueError) as err:
        tj.from_csv(f)
    msg = str(err.value)
    assert f"{f}, line {line}:" in msg and fragment in msg


def test_csv_errors_never_quote_the_file(tmp_path: Path) -> None:
    """A scenario may point a ``*_file`` parameter at any file: the message locates the problem
    (file, line, field) without showing what the file holds."""
    f = tmp_path / "passwd"
    f.write_text("root:x:0:0:root:/root:/bin/bash\n")
    with pytest.raises(ValueError) as err:
        tj.from_csv(f)
    assert "root" not in str(err.value).replace(str(f), "")
    f.write_text("x,z\n1.2,0.9\n1.3,secret\n")
    with pytest.raises(ValueError) as err:
        tj.from_csv(f)
    assert "secret" not in str(err.value)


def test_csv_file_level_errors(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="cannot be read"):
        tj.from_csv(tmp_path / "missing.csv")
    f = tmp_path / "one.csv"
    f.write_text("x,z\n1.2,0.9\n")
    with pytest.raises(ValueError, match="at least two waypoints"):
        tj.from_csv(f)
    f.write_text("# only a comment\n")
    with pytest.raises(ValueError, match="no header"):
        tj.from_csv(f)


def test_builder_rejects_bad_values() -> None:
    with pytest.raises(ValueError, match="speed must be a positive"):
        tj.PathBuilder((1, 1), speed=0, accel=1)
    with pytest.raises(ValueError, match="blend must be in"):
        tj.PathBuilder((1, 1), speed=1, accel=1, blend=2)
    with pytest.raises(ValueError, match="only a closed path"):
        tj.PathBuilder((1, 1), speed=1, accel=1).line_to((1.1, 1)).repeat(2)
    with pytest.raises(ValueError, match="degenerate arc"):
        tj.PathBuilder((1, 1), speed=1, accel=1).arc((1, 1), math.pi)


def test_short_move_and_arc_speed_limits() -> None:
    """A short move gets a triangular profile; an arc keeps v^2/rho <= accel."""
    tr = tj.PathBuilder((1.2, 0.9), speed=1.0, accel=2.0, blend=0.0).line_by((0.01, 0)).build()
    m = tr.moves[0]
    assert m.cruise == 0.0 and m.speed < 1.0
    t = np.linspace(m.t0, m.t_end, 2001)
    _, v, a, _ = tr.evaluate_many(t)
    assert_allclose(np.abs(a).max(), 2.0, rtol=1e-5)
    assert_allclose(np.abs(v).max(), m.speed, rtol=1e-6)
    tr = tj.PathBuilder((1.2, 0.9), speed=1.0, accel=2.0).circle((1.2, 0.95)).build()
    assert_allclose(tr.moves[0].speed, math.sqrt(2.0 * 0.05))

"""Path types (engine.paths): sampled poses continuous, velocities continuous where promised and
equal to the poses' derivatives, per-step twists integrating exactly to the sampled poses, the
raster's sensor aimed along the patch normal at the stand-off, the geometry of each type,
uniform retiming, and the checks that name the offending field."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from engine import CartesianTask, make_inverse, plan, plan_batch, tune
from engine.errors import ParameterError
from engine.paths import ArcPath, LinePath, RasterPath, SpeedLimits, WaypointPath, make_path
from engine.paths.base import displacement_twists
from engine.paths.raster import minimal_rotation
from engine.spatial import axis_angle_rotation, exp_so3, log_so3, rotation_angle
from engine.trajectory import PAPER_Q0_DEG, start_pose

Q0 = np.radians(PAPER_Q0_DEG)


def _rot(axis, deg):
    return axis_angle_rotation(np.array(axis, dtype=float), np.radians(deg))


@pytest.fixture(scope="module")
def start(robot):
    return start_pose(robot, Q0)


RASTER = {
    "corner": [1.35, -0.15, 0.0],
    "scan_edge": [0.2, 0.0, 0.0],
    "step_edge": [0.0, 0.3, 0.0],
    "line_spacing": 0.05,
    "standoff": 0.15,
    "scan_speed": 0.02,
}


def _waypoints(A0):
    return {
        "positions": np.array([[1.30, 0.10, 0.45], [1.50, 0.10, 0.30], [1.50, -0.10, 0.15]]),
        "attitudes": np.array([_rot([0, 0, 1], 15) @ A0, _rot([0, 1, 0], 10) @ A0, _rot([0, 1, 0], 10) @ A0]),
        "limits": SpeedLimits(0.03, math.radians(3.0), 0.01, math.radians(1.0)),
    }


@pytest.fixture(scope="module")
def paths(start):
    p0, A0 = start
    return {
        "line": LinePath(p0, A0, [1.5, 0.0, -0.2], _rot([1, 0, 0], 20) @ A0, 15.0, 1.5, "trapezoidal"),
        "line-quintic": LinePath(p0, A0, [1.5, 0.0, -0.2], _rot([1, 0, 0], 20) @ A0, 15.0, 0.0, "quintic"),
        "waypoints": make_path("waypoints", p0, A0, **_waypoints(A0)),
        "arc": make_path("arc", p0, A0, centre=[1.30, -0.05, 0.5], axis=[0.0, 0.3, 1.0], angle=math.radians(120.0)),
        "arc-3-points-fixed": make_path(
            "arc", p0, A0, via_position=[1.45, 0.0, 0.55], end_position=[1.40, 0.10, 0.40], attitude="fixed", profile="quintic"
        ),
        "raster": make_path("raster", p0, A0, **RASTER),
        "raster-tight-turns": make_path("raster", p0, A0, **{**RASTER, "turn_radius": 0.01, "sensor_axis": [1.0, 0.0, 0.0]}),
        "raster-pass": make_path("raster", p0, A0, **RASTER, pass_index=3),
    }


NAMES = ["line", "line-quintic", "waypoints", "arc", "arc-3-points-fixed", "raster", "raster-tight-turns", "raster-pass"]


@pytest.mark.parametrize("name", NAMES)
def test_poses_and_velocities_are_continuous_and_consistent(paths, name):
    """On a fine grid the poses move by at most the peak speed times the step (continuous),
    the twist is the derivative of the poses (central differences, O(h^2)) and changes by at
    most a bounded acceleration times the step (velocity continuous)."""
    path = paths[name]
    h = 1e-3
    t = np.arange(0.0, path.duration + h / 2, h)
    p, A = path.pose(t)
    twist = path.twist(t)
    speed = np.linalg.norm(twist[:, :3], axis=1).max()
    spin = np.linalg.norm(twist[:, 3:], axis=1).max()
    assert np.linalg.norm(np.diff(p, axis=0), axis=1).max() <= speed * h * (1 + 1e-6) + 1e-15
    assert rotation_angle(A[1:] @ np.swapaxes(A[:-1], -1, -2)).max() <= spin * h * (1 + 1e-6) + 1e-15
    # the twist is the poses' derivative (world axes): central differences inside, O(h^2), and
    # O(h) where the acceleration jumps (the ends of the ramps)
    inner = slice(1, -1)
    v_fd = (p[2:] - p[:-2]) / (2 * h)
    w_fd = log_so3(A[2:] @ np.swapaxes(A[:-2], -1, -2)) / (2 * h)
    np.testing.assert_allclose(v_fd, twist[inner, :3], atol=1e-3 * speed)
    np.testing.assert_allclose(w_fd, twist[inner, 3:], atol=1e-3 * spin + 1e-12)
    assert np.median(np.abs(v_fd - twist[inner, :3])) < 1e-9
    # velocity continuous: no jump larger than a bounded acceleration (0.5 m/s^2, rad/s^2) allows
    jumps = np.abs(np.diff(twist, axis=0)).max()
    assert jumps <= 0.5 * h, f"velocity jumps by {jumps:g} in {h:g} s"
    # at rest at both ends and after the end (the pose is held)
    np.testing.assert_allclose(path.twist(np.array([0.0, path.duration, path.duration + 5.0])), 0.0, atol=1e-12)
    p_end, A_end = path.pose(np.array([path.duration, path.duration + 5.0]))
    assert np.array_equal(p_end[0], p_end[1]) and np.array_equal(A_end[0], A_end[1])


@pytest.mark.parametrize("name", NAMES)
def test_step_twists_integrate_exactly_to_the_sampled_poses(robot, paths, name):
    path = paths[name]
    task = CartesianTask.following(path, Q0, dt=0.25)
    s = task.samples
    assert s.t.shape == (task.n_steps + 1,) and s.t[-1] >= path.duration
    dt = task.dt
    np.testing.assert_allclose(s.p_des[:-1] + s.twists[:-1, :3] * dt, s.p_des[1:], rtol=0, atol=1e-14)
    stepped = exp_so3(s.twists[:-1, 3:] * dt) @ s.A_des[:-1]
    np.testing.assert_allclose(stepped, s.A_des[1:], rtol=0, atol=1e-14)
    assert np.all(s.twists[-1] == 0.0)
    np.testing.assert_array_equal(s.twist_des, path.twist(s.t))
    # the samples start at the end-effector pose of q0 and end at the task's target
    p0, A0 = start_pose(robot, Q0)
    np.testing.assert_allclose(s.p_des[0], p0, atol=1e-12)
    np.testing.assert_allclose(s.A_des[0], A0, atol=1e-12)
    np.testing.assert_allclose(s.p_des[-1], task.target_position, atol=1e-12)


def test_line_path_is_the_classic_task_bit_for_bit(task):
    """The paper's task (from_q0) and the same line as an explicit LinePath sample alike."""
    given = task.path
    line = LinePath(given.start_position, given.start_attitude, given.target_position, given.target_attitude, 15.0, 1.5)
    explicit = CartesianTask.following(line, task.q0, dt=task.dt)
    assert task.kind == explicit.kind == "line"
    for a, b in zip(task.samples, explicit.samples, strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("name", ["raster", "raster-tight-turns"])
def test_raster_sensor_points_along_the_normal_at_the_standoff(paths, name):
    path: RasterPath = paths[name]
    n = path.normal
    np.testing.assert_allclose(n, [0.0, 0.0, 1.0], atol=1e-15)
    t = np.linspace(path.approach_duration, path.duration, 4001)
    p, A = path.pose(t)
    sensor = A @ path.sensor_axis
    assert np.abs(sensor - (-n)).max() < 1e-9
    corner = np.array(RASTER["corner"])
    assert np.abs((p - corner) @ n - RASTER["standoff"]).max() < 1e-9
    # in the patch along the step edge; along the scan edge at most a turn radius outside it
    x, y = (p - corner) @ [1.0, 0.0, 0.0], (p - corner) @ [0.0, 1.0, 0.0]
    assert x.min() >= -path.turn_radius - 1e-12 and x.max() <= 0.2 + path.turn_radius + 1e-12
    assert y.min() >= -1e-12 and y.max() <= 0.3 + 1e-12
    assert path.passes == 7
    # passes at the line spacing, run at the scan speed between the ramps
    speed = np.linalg.norm(path.twist(t)[:, :3], axis=1)
    ramp = RASTER["scan_speed"] / 0.01
    cruise = (t > path.approach_duration + ramp + 1e-9) & (t < path.duration - ramp - 1e-9)
    np.testing.assert_allclose(speed[cruise], RASTER["scan_speed"], rtol=1e-9)
    on_pass = np.abs(x - 0.1) < 0.09
    assert set(np.round(y[on_pass] / 0.05, 9)) == {0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0}
    # the scan length: 7 passes of 0.2 m and 6 turns of a half circle (or two quarters and a straight)
    r = path.turn_radius
    expected = 7 * 0.2 + 6 * (math.pi * r + (0.05 - 2 * r))
    assert path.summary()["scan_length"] == pytest.approx(expected, rel=1e-12)


def test_raster_pass_and_pass_paths(paths):
    whole: RasterPath = paths["raster"]
    one: RasterPath = paths["raster-pass"]
    passes = whole.pass_paths()
    assert len(passes) == whole.passes == 7
    t = np.linspace(0.0, one.duration, 101)
    for a, b in zip(passes[3].pose(t), one.pose(t), strict=True):
        np.testing.assert_array_equal(a, b)
    p, _ = one.pose(np.linspace(one.approach_duration, one.duration, 101))
    np.testing.assert_allclose(p[:, 1], -0.15 + 3 * 0.05, atol=1e-12)  # y of pass 3
    np.testing.assert_allclose(p[0, 0], 1.35 + 0.2, atol=1e-12)  # odd passes run back along the scan edge
    np.testing.assert_allclose(p[-1, 0], 1.35, atol=1e-12)


def test_waypoints_pass_through_every_pose_at_rest(paths, start):
    path: WaypointPath = paths["waypoints"]
    spec = _waypoints(start[1])
    times = path.segment_times
    p, A = path.pose(times)
    np.testing.assert_allclose(p, spec["positions"], atol=1e-12)
    np.testing.assert_allclose(A, spec["attitudes"], atol=1e-12)
    np.testing.assert_allclose(path.twist(times), 0.0, atol=1e-12)
    # each segment within its limits, and one of them binding
    limits = spec["limits"]
    t = np.linspace(0.0, path.duration, 20001)
    tw = path.twist(t)
    # quintic segments: the acceleration is continuous too (zero at each waypoint)
    h = t[1] - t[0]
    acceleration = np.diff(tw, axis=0) / h
    assert np.abs(np.diff(acceleration, axis=0)).max() < 0.01 * np.abs(acceleration).max()
    assert np.linalg.norm(tw[:, :3], axis=1).max() <= limits.speed * (1 + 1e-9)
    assert np.linalg.norm(tw[:, 3:], axis=1).max() <= limits.angular_speed * (1 + 1e-9)
    # along a segment: a straight line and the SO(3) geodesic between its two poses
    mid = times[0] + 0.37 * (times[1] - times[0])
    pm, Am = path.pose(np.array([mid]))
    a, b = spec["positions"][0], spec["positions"][1]
    assert np.linalg.norm(np.cross(pm[0] - a, b - a)) < 1e-12
    s = np.linalg.norm(pm[0] - a) / np.linalg.norm(b - a)
    phi = log_so3(spec["attitudes"][1] @ spec["attitudes"][0].T)
    np.testing.assert_allclose(Am[0], exp_so3(s * phi) @ spec["attitudes"][0], atol=1e-12)
    # given durations replace the limits
    timed = dataclasses.replace(path, segment_durations=np.array([10.0, 20.0, 5.0]))
    np.testing.assert_allclose(timed.segment_times, [10.0, 30.0, 35.0])


def test_arcs(paths, start):
    p0, A0 = start
    arc: ArcPath = paths["arc"]
    t = np.linspace(0.0, arc.duration, 501)
    p, A = arc.pose(t)
    rel = p - arc.centre
    radial = rel - (rel @ arc.axis)[:, None] * arc.axis
    np.testing.assert_allclose(np.linalg.norm(radial, axis=1), arc.radius, rtol=1e-12)
    np.testing.assert_allclose(rel @ arc.axis, (p0 - arc.centre) @ arc.axis, atol=1e-12)
    # the tangent attitude turns with the arc: A_d A_start^T is the arc's rotation
    np.testing.assert_allclose(A[-1] @ A0.T, axis_angle_rotation(arc.axis, arc.angle), atol=1e-12)
    three: ArcPath = paths["arc-3-points-fixed"]
    p3, A3 = three.pose(np.linspace(0.0, three.duration, 20001))
    assert np.linalg.norm(p3 - [1.45, 0.0, 0.55], axis=1).min() < 1e-4  # passes through the via point
    np.testing.assert_allclose(p3[-1], [1.40, 0.10, 0.40], atol=1e-12)
    np.testing.assert_allclose(A3, np.broadcast_to(A0, A3.shape), atol=0)  # held fixed
    np.testing.assert_allclose(np.linalg.norm(p3 - three.centre, axis=1), three.radius, rtol=1e-12)


@pytest.mark.parametrize("name", NAMES)
def test_retiming_keeps_the_geometry(paths, name):
    path = paths[name]
    slow = path.retimed(2.5 * path.duration)
    assert slow.duration == pytest.approx(2.5 * path.duration, rel=1e-12)
    t = np.linspace(0.0, path.duration, 97)
    p, A = path.pose(t)
    ps, As = slow.pose(2.5 * t)
    np.testing.assert_allclose(ps, p, atol=1e-12)
    np.testing.assert_allclose(As, A, atol=1e-12)
    np.testing.assert_allclose(slow.twist(2.5 * t), path.twist(t) / 2.5, atol=1e-12)
    task = CartesianTask.following(path, Q0)
    assert task.with_duration(2.5 * path.duration).path.duration == pytest.approx(slow.duration, rel=1e-12)


def test_minimal_rotation():
    rng = np.random.default_rng(3)
    for a, b in [*(rng.normal(size=(2, 3)) for _ in range(20)), ([0, 0, 1.0], [0, 0, -1.0]), ([1.0, 0, 0], [1.0, 0, 0])]:
        a, b = np.asarray(a) / np.linalg.norm(a), np.asarray(b) / np.linalg.norm(b)
        R = minimal_rotation(a, b)
        np.testing.assert_allclose(R @ a, b, atol=1e-12)
        assert rotation_angle(R) == pytest.approx(math.acos(np.clip(a @ b, -1, 1)), abs=1e-9)


def test_displacement_twists_of_a_known_motion():
    t = np.arange(5) * 0.5
    w = np.array([0.1, -0.2, 0.3])
    p = t[:, None] * [1.0, 2.0, 3.0]
    A = exp_so3(t[:, None] * w)
    tw = displacement_twists(p, A, 0.5)
    np.testing.assert_allclose(tw[:-1], np.tile([1.0, 2.0, 3.0, *w], (4, 1)), atol=1e-14)
    assert np.all(tw[-1] == 0.0)


@pytest.mark.parametrize(
    ("kind", "changes", "field"),
    [
        ("waypoints", {"positions": np.zeros((0, 3)), "attitudes": np.zeros((0, 3, 3))}, "waypoints"),
        ("waypoints", {"positions": np.zeros((101, 3)), "attitudes": np.tile(np.eye(3), (101, 1, 1))}, "waypoints"),
        ("waypoints", "duplicate", r"waypoints\[1\]"),
        ("waypoints", "start", r"waypoints\[0\]"),
        ("waypoints", {"segment_durations": np.array([1.0, 2.0])}, "segment_durations"),
        ("waypoints", {"segment_durations": np.array([1.0, 0.0, 2.0])}, r"segment_durations\[1\]"),
        ("waypoints", {"positions": np.array([[np.nan, 0, 0], [1, 0, 0], [2, 0, 0]])}, r"waypoints\[0\]\.position"),
        ("waypoints", {"attitudes": np.tile(2 * np.eye(3), (3, 1, 1))}, r"waypoints\[0\]\.attitude"),
        ("waypoints", {"duration_override": -1.0}, "duration"),
        ("arc", {"angle": 0.0}, "angle"),
        ("arc", {"angle": 7.0}, "angle"),
        ("arc", {"axis": [0.0, 0.0, 0.0]}, "axis"),
        ("arc", {"attitude": "radial"}, "attitude"),
        ("arc", {"ramp_time": 9.0}, "ramp_time"),
        ("arc", "on-axis", "centre"),
        ("arc", "collinear", "via_position"),
        ("raster", {"line_spacing": 0.31}, "line_spacing"),
        ("raster", {"line_spacing": 1e-4}, "line_spacing"),
        ("raster", {"line_spacing": 0.0}, "line_spacing"),
        ("raster", {"standoff": 0.0}, "standoff"),
        ("raster", {"standoff": -0.1}, "standoff"),
        ("raster", {"scan_speed": 0.0}, "scan_speed"),
        ("raster", {"scan_acceleration": -1.0}, "scan_acceleration"),
        ("raster", {"turn_radius": 0.03}, "turn_radius"),
        ("raster", {"step_edge": [0.1, 0.3, 0.0]}, "step_edge"),
        ("raster", {"scan_edge": [0.0, 0.0, 0.0]}, "scan_edge"),
        ("raster", {"sensor_axis": [0.0, 0.0, 0.0]}, "sensor_axis"),
        ("raster", {"pass_index": 7}, "pass_index"),
        ("line", {"profile": "cubic"}, "profile"),
    ],
)
def test_invalid_paths_name_the_field(start, kind, changes, field):
    p0, A0 = start
    specs = {
        "waypoints": _waypoints(A0),
        "arc": {"centre": [1.30, -0.05, 0.5], "axis": [0.0, 0.3, 1.0], "angle": 1.0},
        "raster": dict(RASTER),
        "line": {"target_position": [1.5, 0, -0.2], "target_attitude": A0},
    }
    spec = specs[kind]
    if changes == "duplicate":
        spec["positions"][1], spec["attitudes"][1] = spec["positions"][0], spec["attitudes"][0]
    elif changes == "start":
        spec["positions"][0], spec["attitudes"][0] = p0, A0
    elif changes == "on-axis":
        spec["centre"], spec["axis"] = p0 - [0.0, 0.0, 0.3], [0.0, 0.0, 1.0]
    elif changes == "collinear":
        spec = {"via_position": p0 + [0.1, 0, 0], "end_position": p0 + [0.2, 0, 0]}
    else:
        spec.update(changes)
    with pytest.raises(ParameterError, match=field):
        make_path(kind, p0, A0, **spec)


def test_a_task_takes_its_duration_and_ends_from_its_path(paths, task):
    path = paths["waypoints"]
    good = CartesianTask.following(path, Q0)
    p, A = path.pose(np.array([0.0, path.duration]))
    assert good.duration == path.duration
    np.testing.assert_array_equal(good.start_position, p[0])
    np.testing.assert_array_equal(good.target_attitude, A[1])
    with pytest.raises(ParameterError, match="dt"):
        dataclasses.replace(good, dt=path.duration / 30_000)
    with pytest.raises(ParameterError, match="type"):
        make_path("spiral", task.start_position, task.start_attitude)


@pytest.mark.parametrize("method", ["inverse", "dls", "adaptive", "wdls", "sdls", "svf"])
def test_every_method_plans_every_path_type(robot, paths, method):
    """Each path type planned by every inverse, with and without feedback: damped methods stay
    finite; a plan succeeds exactly when its message says ok."""
    for name in ("waypoints", "arc", "raster-pass"):
        task = CartesianTask.following(paths[name], Q0, dt=0.25)
        for gain in (0.0, 1.0):
            result = plan(robot, task, make_inverse(method), feedback_gain=gain)
            assert result.t.shape == (task.n_steps + 1,)
            assert result.success == (result.message == "ok")
            if method != "inverse":
                assert result.metrics.finite
            np.testing.assert_array_equal(result.ee_position_desired, task.samples.p_des)


def test_tuning_over_the_passes_of_a_scan(robot, paths):
    """Robust tuning: one GA over the tasks of the scan's passes (worst case)."""
    tasks = [CartesianTask.following(p, Q0) for p in paths["raster"].pass_paths()[:3]]
    result = tune(robot, tasks, "adaptive", population=6, generations=2, seed=5, task_aggregation="max")
    assert result.success and len(result.best_metrics) == 3
    worst = max(plan_batch(robot, t, "adaptive", {k: [v] for k, v in result.best_params.items()}).objective_b[0] for t in tasks)
    assert result.best_objective_b == worst


@pytest.mark.parametrize("name", ["waypoints", "arc-3-points-fixed", "raster-pass"])
def test_compiled_planner_matches_the_numpy_oracle_on_paths(robot, paths, name):
    """The kernels consume any path's samples: the numpy oracle (which reads the task's
    ``desired_pose`` and ``step_twists``) plans the same joint motion."""
    from oracle import inverses as oracle_inverses
    from oracle import planner as oracle_planner

    task = CartesianTask.following(paths[name], Q0, dt=0.25)
    for gain in (0.0, 2.0):
        ours = plan(robot, task, make_inverse("adaptive"), feedback_gain=gain)
        theirs = oracle_planner.plan(robot, task, oracle_inverses.make_inverse("adaptive"), feedback_gain=gain)
        np.testing.assert_allclose(ours.q, theirs.q, atol=1e-9)
        np.testing.assert_allclose(ours.ee_position, theirs.ee_position, atol=1e-9)
        assert ours.success == theirs.success

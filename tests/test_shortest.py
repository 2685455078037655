"""The shortest feasible duration (engine.shortest): the duration found is feasible, 1% faster
is not and 1% slower is (the boundary within 1%); the search's edge cases; and the message of a
failed plan says where (time and desired pose) it failed."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from engine import CartesianTask, PlanSetup, make_inverse, plan, shortest_duration
from engine.errors import ParameterError
from engine.paths import SpeedLimits
from engine.spatial import axis_angle_rotation
from engine.trajectory import PAPER_Q0_DEG, start_pose

Q0 = np.radians(PAPER_Q0_DEG)


def _check_boundary(robot, task, inverse, found):
    assert found.success, found.message
    assert found.plan.success and found.plan.task.duration == pytest.approx(found.duration, rel=1e-12)
    assert 0.0 < found.relative_gap <= 0.002
    assert found.infeasible_duration < found.duration
    assert found.speed_margin >= 0.0
    assert not plan(robot, task.with_duration(0.99 * found.duration), inverse).success
    assert plan(robot, task.with_duration(1.01 * found.duration), inverse).success


def test_paper_line_shortest_duration(robot, task):
    inverse = make_inverse("adaptive", lambda_max=0.06, epsilon=0.12)
    found = shortest_duration(PlanSetup(robot, task), inverse)
    _check_boundary(robot, task, inverse, found)
    assert "joint speed limit broken" in found.limiting  # the speed limit binds on this line
    assert found.duration < task.duration  # 15 s has room to spare
    # one candidate per round (plain bisection) finds the same boundary
    single = shortest_duration(PlanSetup(robot, task), inverse, candidates=1, relative_tolerance=0.001)
    assert single.duration == pytest.approx(found.duration, rel=0.003)
    assert single.rounds > found.rounds


def test_waypoint_path_shortest_duration(robot):
    _, A0 = start_pose(robot, Q0)
    turn = axis_angle_rotation(np.array([0.0, 1.0, 0.0]), math.radians(10.0))
    task = CartesianTask.along(
        robot,
        Q0,
        "waypoints",
        positions=np.array([[1.30, 0.10, 0.45], [1.50, 0.10, 0.30], [1.50, -0.10, 0.15], [1.35, -0.10, 0.05]]),
        attitudes=np.array([A0, turn @ A0, turn @ A0, A0]),
        limits=SpeedLimits(0.03, math.radians(3.0), 0.01, math.radians(1.0)),
    )
    inverse = make_inverse("adaptive", lambda_max=0.02753, epsilon=0.1736)
    found = shortest_duration(PlanSetup(robot, task), inverse, candidates=3)
    _check_boundary(robot, task, inverse, found)
    assert found.evaluations <= 3 * found.rounds


def test_no_feasible_duration_is_a_failed_result(robot, task):
    found = shortest_duration(PlanSetup(robot, task), make_inverse("adaptive", lambda_max=0.06, epsilon=0.12), max_duration=5.0)
    assert not found.success and found.duration == 5.0
    assert "no feasible duration up to 5 s" in found.message and not found.plan.success
    assert math.isnan(found.relative_gap)


def test_a_motionless_task_is_feasible_in_one_step(robot, task):
    still = CartesianTask.from_q0(robot, task.q0, task.start_position, task.start_attitude)
    found = shortest_duration(PlanSetup(robot, still), make_inverse("dls"))
    assert found.success and found.duration == still.dt and math.isnan(found.infeasible_duration)
    assert "one step" in found.message


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"relative_tolerance": 0.0}, "relative_tolerance"),
        ({"relative_tolerance": 0.5}, "relative_tolerance"),
        ({"candidates": 0}, "candidates"),
        ({"max_duration": 0.1}, "max_duration"),
    ],
)
def test_search_settings_are_checked(robot, task, kwargs, field):
    with pytest.raises(ParameterError, match=field):
        shortest_duration(PlanSetup(robot, task), make_inverse("dls"), **kwargs)


def test_an_unreachable_path_fails_saying_where(robot):
    """A raster of a patch beyond the arm's reach: the plan is a result with success false and a
    message naming the time and the desired pose where it first failed."""
    task = CartesianTask.along(
        robot,
        Q0,
        "raster",
        corner=[2.6, -0.15, 0.0],
        scan_edge=[0.2, 0.0, 0.0],
        step_edge=[0.0, 0.3, 0.0],
        line_spacing=0.1,
        standoff=0.15,
        scan_speed=0.02,
    )
    result = plan(robot, task, make_inverse("adaptive", lambda_max=0.02038, epsilon=0.12))
    assert not result.success
    match = re.search(r"first failed at t = ([0-9.e+-]+) s \(.*\), desired pose: position \[(.*)\] m", result.message)
    assert match, result.message
    t = float(match.group(1))
    k = int(np.flatnonzero(result.t == t)[0])
    assert 0 < k < task.n_steps
    position = [float(x) for x in match.group(2).split(",")]
    np.testing.assert_allclose(position, result.ee_position_desired[k], atol=1e-3)
    bad = (result.position_error > 0.05) | (result.attitude_error > math.radians(5.0))
    bad |= np.abs(result.qd).max(axis=1) > task.joint_speed_limit
    assert k == int(np.argmax(bad))  # the first failing sample


def test_path_not_tracked_fails_even_if_the_target_is_reached(robot):
    """Success needs the whole path tracked, not just the final pose: out to a waypoint beyond
    the arm's reach and back, with feedback the end effector ends on the target anyway."""
    p0, A0 = start_pose(robot, Q0)
    task = CartesianTask.along(
        robot,
        Q0,
        "waypoints",
        positions=np.array([[2.2, -0.08, 0.64], p0 + [0.05, 0.0, -0.05]]),
        attitudes=np.array([A0, A0]),
        joint_speed_limit=math.radians(1000.0),
    )
    result = plan(robot, task, make_inverse("adaptive"), feedback_gain=1.0)
    m = result.metrics
    assert m.position_error_final < 1e-3 and m.joint_speed_limit_respected
    assert m.position_error_max > 0.05
    assert not result.success and result.message.startswith("path not tracked")
    first = float(re.search(r"first failed at t = ([0-9.]+) s", result.message).group(1))
    assert 0.0 < first < task.path.segment_times[0]  # on the way out

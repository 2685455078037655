import dataclasses

import numpy as np
import pytest

from engine import make_inverse, plan, replay


@pytest.fixture(scope="module")
def planned(robot, task):
    return plan(robot, task, make_inverse("adaptive"))


def test_replay_agrees_with_the_plan(robot, planned):
    r = replay(robot, planned)
    assert r.success
    assert r.linear_momentum_residual_max < 1e-8
    assert r.angular_momentum_residual_max < 1e-8
    assert r.com_drift_max < 1e-8
    assert r.plan_gap_position_max < 2e-3
    assert r.plan_gap_attitude_max < 2e-3
    # The achieved path tracks the line about as well as planned.
    assert abs(r.path_position_error_max - planned.metrics.position_error_max) < 2e-3


def test_discretisation_gap_shrinks_with_dt(robot, task):
    gaps = []
    for dt in (0.25, 0.125):
        t = dataclasses.replace(task, dt=dt)
        gaps.append(replay(robot, plan(robot, t, make_inverse("dls", **{"lambda": 0.05}))).base_attitude_gap_max)
    # Explicit Euler on the base attitude: first order in dt.
    assert gaps[1] < 0.7 * gaps[0]


def test_replay_of_a_diverged_plan_is_a_failure(robot, planned):
    broken = dataclasses.replace(planned, qd=np.full_like(planned.qd, np.nan))
    r = replay(robot, broken)
    assert not r.success

"""Objective landscapes against the planner itself: every cell is the plan of its parameters."""

from __future__ import annotations

import math

import numpy as np
import pytest

from engine import axis_values, landscape, make_inverse, plan
from engine.errors import ParameterError


def test_cells_are_the_plans_of_their_parameters(robot, task):
    xs = axis_values(0.005, 0.2, 5)
    ys = axis_values(0.01, 1.0, 4, "log")
    land = landscape(robot, task, "adaptive", ("lambda_max", xs), ("epsilon", ys))
    assert land.objective_b.shape == land.feasible.shape == land.max_joint_speed.shape == (5, 4)
    assert land.evaluations == 20
    for i, j in [(0, 0), (2, 1), (4, 3), (1, 2)]:
        single = plan(robot, task, make_inverse("adaptive", lambda_max=xs[i], epsilon=ys[j])).metrics
        feasible = single.finite and single.joint_speed_limit_respected
        assert land.feasible[i, j] == feasible
        if feasible:
            assert land.objective_b[i, j] == pytest.approx(single.objective_b, rel=1e-12)
            assert land.max_joint_speed[i, j] == pytest.approx(single.max_joint_speed, rel=1e-12)
        else:
            assert math.isinf(land.objective_b[i, j])
    i, j = np.unravel_index(np.argmin(land.objective_b), land.objective_b.shape)
    assert land.best_params == {"lambda_max": xs[i], "epsilon": ys[j]}
    assert land.best_objective_b == land.objective_b[i, j]
    assert np.isin(np.isfinite(land.objective_b), [True, False]).all() and land.feasible.any() and not land.feasible.all()


def test_several_tasks_and_a_fixed_parameter(robot, task):
    import dataclasses

    slower = dataclasses.replace(task, path=dataclasses.replace(task.path, duration=20.0, ramp_time=2.0))
    xs, ys = axis_values(0.01, 0.2, 3), axis_values(0.1, 1.0, 3)
    one = landscape(robot, task, "adaptive", ("lambda_max", xs), ("epsilon", ys))
    other = landscape(robot, slower, "adaptive", ("lambda_max", xs), ("epsilon", ys))
    both = landscape(robot, [task, slower], "adaptive", ("lambda_max", xs), ("epsilon", ys))
    worst = landscape(robot, [task, slower], "adaptive", ("lambda_max", xs), ("epsilon", ys), task_aggregation="max")
    ok = both.feasible
    np.testing.assert_allclose(both.objective_b[ok], ((one.objective_b + other.objective_b) / 2)[ok], rtol=1e-12)
    np.testing.assert_allclose(worst.objective_b[ok], np.maximum(one.objective_b, other.objective_b)[ok], rtol=1e-12)
    assert (ok == (one.feasible & other.feasible)).all()
    # svf: sigma0 x nu with nothing fixed; then nu x sigma0 is its transpose
    a = landscape(robot, task, "svf", ("sigma0", [0.01, 0.05]), ("nu", [5.0, 20.0]))
    b = landscape(robot, task, "svf", ("nu", [5.0, 20.0]), ("sigma0", [0.01, 0.05]))
    np.testing.assert_array_equal(a.objective_b, b.objective_b.T)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"method": "dls", "x": ("lambda", [0.1, 0.2]), "y": ("lambda", [0.1, 0.2])}, "method"),
        ({"x": ("lam", [0.1, 0.2])}, "x.name"),
        ({"y": ("lambda_max", [0.1, 0.2])}, "y.name"),
        ({"x": ("lambda_max", [-1.0, 0.2])}, "x"),
        ({"y": ("epsilon", [0.0, 0.2])}, "y"),
        ({"fixed": {"nu": 3.0}}, "fixed.nu"),
        ({"task_aggregation": "median"}, "task_aggregation"),
    ],
)
def test_validation_names_the_argument(robot, task, kwargs, field):
    args = {"method": "adaptive", "x": ("lambda_max", [0.01, 0.1]), "y": ("epsilon", [0.1, 0.5]), **kwargs}
    method, x, y = args.pop("method"), args.pop("x"), args.pop("y")
    with pytest.raises(ParameterError) as info:
        landscape(robot, task, method, x, y, **args)
    assert info.value.field == field


def test_an_axis_beyond_the_range_names_its_first_bad_value(robot, task):
    """Not the whole axis (up to 128 values), nor numpy's repr of a value."""
    with pytest.raises(ParameterError) as info:
        landscape(robot, task, "adaptive", ("lambda_max", [0.05, 20.0, 30.0]), ("epsilon", [0.1, 0.5]))
    assert info.value.field == "x" and info.value.reason == "must be in [0.0, 10.0], got 20.0 and 1 more of 3"


def test_axis_values():
    np.testing.assert_allclose(axis_values(0.0, 1.0, 5), [0.0, 0.25, 0.5, 0.75, 1.0])
    np.testing.assert_allclose(axis_values(0.001, 1.0, 4, "log"), [0.001, 0.01, 0.1, 1.0])
    for args, field in [
        ((0.0, 1.0, 1), "steps"),
        ((0.0, 1.0, 129), "steps"),
        ((1.0, 1.0, 3), "max"),
        ((0.0, 1.0, 3, "log"), "min"),
    ]:
        with pytest.raises(ParameterError) as info:
            axis_values(*args)
        assert info.value.field == field

import copy
import dataclasses

import numpy as np
import pytest

from engine import RobotModel, table1_robot


def test_table1_numbers(robot):
    assert robot.n_joints == 6
    assert robot.base.mass == 450.0
    np.testing.assert_allclose(robot.base.b, [0.5, 0.0, 0.751])
    np.testing.assert_allclose([link.mass for link in robot.links], [1.5, 9.6, 1.5, 9.0, 1.5, 10.5])
    np.testing.assert_allclose(robot.links[1].a, [-0.4925, 0.054, 0.0])
    np.testing.assert_allclose(robot.links[3].inertia[1, 2], -0.01)
    np.testing.assert_allclose(robot.links[5].b, [-0.164, 0.0, 0.0])
    np.testing.assert_allclose(robot.total_mass, 483.6)


def test_round_trip(robot):
    again = RobotModel.from_dict(robot.to_dict())
    assert again.to_dict() == robot.to_dict()


def test_immutable(robot):
    with pytest.raises(dataclasses.FrozenInstanceError):
        robot.name = "x"
    with pytest.raises(ValueError):
        robot.links[0].a[0] = 1.0


def test_axis_is_normalised():
    d = table1_robot().to_dict()
    d["links"][0]["joint_axis"] = [0.0, 0.0, 5.0]
    np.testing.assert_allclose(RobotModel.from_dict(d).links[0].joint_axis, [0, 0, 1])


def _broken(path, value):
    d = table1_robot().to_dict()
    target = d
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = value
    return d


@pytest.mark.parametrize(
    ("path", "value", "field"),
    [
        (("base", "mass"), 0.0, "base.mass"),
        (("base", "mass"), float("nan"), "base.mass"),
        (("links", 2, "mass"), -1.0, "links[2].mass"),
        (("links", 1, "a"), [0.0, float("inf"), 0.0], "links[1].a"),
        (("links", 0, "joint_axis"), [0.0, 0.0, 0.0], "links[0].joint_axis"),
        (("links", 3, "inertia"), [[1, 0.5, 0], [0, 1, 0], [0, 0, 1]], "links[3].inertia"),
        (("links", 3, "inertia"), [[1, 0, 0], [0, -1, 0], [0, 0, 1]], "links[3].inertia"),
        (("links", 4, "inertia"), [[1, 0, 0], [0, 1, 0], [0, 0, 3]], "links[4].inertia"),
        (("base", "inertia"), [[1, 0], [0, 1]], "base.inertia"),
        (("end_effector", "C_e"), [[1, 0, 0], [0, 1, 0], [0, 0, -1]], "end_effector.C_e"),
        (("base", "b"), [1.0, 2.0], "base.b"),
        (("links", 1, "torque_limit_n_m"), -1.0, "links[1].torque_limit_n_m"),
        (("links", 1, "torque_limit_n_m"), 0.0, "links[1].torque_limit_n_m"),
        (("links", 1, "torque_limit_n_m"), float("inf"), "links[1].torque_limit_n_m"),
        (("links", 1, "force_limit_n"), 5.0, "links[1].force_limit_n"),  # a revolute joint's limit is a torque
    ],
)
def test_validation_names_the_field(path, value, field):
    with pytest.raises(ValueError, match=field.replace("[", r"\[").replace("]", r"\]")):
        RobotModel.from_dict(_broken(path, value))


def test_table1_torque_limits_and_what_a_limit_needs():
    """The Table-1 defaults (documented in the README), and a torque limit on a link without
    dynamics data (zero inertia) is refused saying so: the torques need the inertia."""
    np.testing.assert_array_equal(table1_robot().effort_limits, [2.0, 5.0, 0.5, 0.5, 0.5, 0.5])
    with pytest.raises(ValueError, match=r"links\[2\].inertia.*torque_limit_n_m but no dynamics data"):
        RobotModel.from_dict(_broken(("links", 2, "inertia"), [[0, 0, 0], [0, 0, 0], [0, 0, 0]]))
    unlimited = _broken(("links", 2, "inertia"), [[0, 0, 0], [0, 0, 0], [0, 0, 0]])
    del unlimited["links"][2]["torque_limit_n_m"]
    with pytest.raises(ValueError, match="the GJM and the joint torques need every body's inertia"):
        RobotModel.from_dict(unlimited)


def test_joint_count_limits():
    d = table1_robot().to_dict()
    empty = copy.deepcopy(d)
    empty["links"] = []
    with pytest.raises(ValueError, match="links"):
        RobotModel.from_dict(empty)
    many = copy.deepcopy(d)
    many["links"] = d["links"] * 3  # 18 joints
    with pytest.raises(ValueError, match="links"):
        RobotModel.from_dict(many)
    twelve = copy.deepcopy(d)
    twelve["links"] = d["links"] * 2
    assert RobotModel.from_dict(twelve).n_joints == 12

"""Random but physical robot parameter sets for tests."""

from __future__ import annotations

import numpy as np

from engine.model import RobotModel
from engine.spatial import exp_so3


def random_inertia(rng: np.random.Generator, scale: float) -> list[list[float]]:
    """SPD inertia obeying the triangle inequality: a random box rotated randomly."""
    sides = rng.uniform(0.05, 1.0, 3)
    mass = 1.0
    principal = (
        mass / 12.0 * np.array([sides[1] ** 2 + sides[2] ** 2, sides[0] ** 2 + sides[2] ** 2, sides[0] ** 2 + sides[1] ** 2])
    )
    R = exp_so3(rng.normal(size=3))
    return (scale * R @ np.diag(principal) @ R.T).tolist()


def random_robot_dict(rng: np.random.Generator, n_joints: int, prismatic: float = 0.0) -> dict:
    """A random robot; each joint is prismatic with probability ``prismatic`` (else revolute)."""
    links = []
    for i in range(n_joints):
        axis = rng.normal(size=3)
        slides = prismatic > 0.0 and bool(rng.uniform() < prismatic)  # no draw otherwise: the same robots as before
        links.append(
            {
                "name": f"l{i}",
                "mass": float(rng.uniform(0.5, 15.0)),
                "joint_type": "prismatic" if slides else "revolute",
                "joint_axis": (axis / np.linalg.norm(axis)).tolist(),
                "a": rng.uniform(-0.5, 0.5, 3).tolist(),
                "b": rng.uniform(-0.5, 0.5, 3).tolist(),
                "inertia": random_inertia(rng, float(rng.uniform(0.5, 20.0))),
            }
        )
    return {
        "name": f"random{n_joints}",
        "base": {
            "mass": float(rng.uniform(50.0, 800.0)),
            "inertia": random_inertia(rng, float(rng.uniform(100.0, 2000.0))),
            "b": rng.uniform(-1.0, 1.0, 3).tolist(),
        },
        "links": links,
        "end_effector": {"C_e": exp_so3(rng.normal(size=3)).tolist()},
    }


def random_robot(rng: np.random.Generator, n_joints: int, prismatic: float = 0.0) -> RobotModel:
    return RobotModel.from_dict(random_robot_dict(rng, n_joints, prismatic))

"""Immutable free-floating robot model (Yoshida/SpaceDyn vectors, serial chain).

Conventions (see README): link frames are parallel to the base frame at q = 0; ``a_i`` runs
from joint i to the CoM of link i, ``b_i`` from the CoM of link i to joint i+1 (``b_0`` from the
base CoM to joint 1, ``b_n`` from the last CoM to the end-effector point), both in link i's
frame; inertias are about each CoM in the body's own frame. SI units throughout.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from functools import cached_property
from importlib import resources
from typing import Any

import numpy as np

from engine.errors import ParameterError, finite_array
from engine.kernels.chain import Chain
from engine.spatial import FloatArray, is_rotation

MAX_JOINTS = 12


def _frozen(arr: FloatArray) -> FloatArray:
    arr.setflags(write=False)
    return arr


def _mass(value: Any, field: str) -> float:
    try:
        mass = float(value)
    except (TypeError, ValueError) as exc:
        raise ParameterError(field, "expected a number") from exc
    if not math.isfinite(mass) or mass <= 0.0:
        raise ParameterError(field, f"mass must be finite and > 0, got {value!r}")
    return mass


def _inertia(value: Any, field: str) -> FloatArray:
    inertia = finite_array(value, (3, 3), field)
    scale = max(float(np.max(np.abs(inertia))), 1e-300)
    if not np.allclose(inertia, inertia.T, rtol=0.0, atol=1e-9 * scale):
        raise ParameterError(field, "inertia tensor must be symmetric")
    principal = np.linalg.eigvalsh(inertia)
    if principal[0] <= 1e-12 * scale:
        raise ParameterError(field, "inertia tensor must be positive definite")
    # Physical inertia: each principal moment at most the sum of the other two.
    p1, p2, p3 = principal
    if p3 > p1 + p2 + 1e-9 * scale:
        raise ParameterError(field, f"principal moments {principal.tolist()} violate the triangle inequality")
    return inertia


def _axis(value: Any, field: str) -> FloatArray:
    axis = np.array(finite_array(value, (3,), field))
    norm = float(np.linalg.norm(axis))
    if norm < 1e-9:
        raise ParameterError(field, "joint axis must be non-zero")
    axis = axis / norm
    axis.setflags(write=False)
    return axis


@dataclass(frozen=True)
class Link:
    """One link and the revolute joint that drives it (joint i moves link i)."""

    name: str
    mass: float
    joint_axis: FloatArray  # (3,) unit vector in link frame
    a: FloatArray  # (3,) m, joint i -> CoM i
    b: FloatArray  # (3,) m, CoM i -> joint i+1 (or end effector)
    inertia: FloatArray  # (3, 3) kg m^2 about the CoM, link frame


@dataclass(frozen=True)
class Base:
    """The floating carrier (body 0)."""

    mass: float
    inertia: FloatArray  # (3, 3) kg m^2 about the base CoM, base frame
    b: FloatArray  # (3,) m, base CoM -> joint 1


@dataclass(frozen=True, eq=False)
class RobotModel:
    """Free-floating serial manipulator on a floating base. Immutable; build with
    :meth:`from_dict`."""

    name: str
    base: Base
    links: tuple[Link, ...]
    C_e: FloatArray  # (3, 3) end-effector frame expressed in the last link's frame

    @property
    def n_joints(self) -> int:
        return len(self.links)

    @property
    def total_mass(self) -> float:
        return self.base.mass + sum(link.mass for link in self.links)

    # Stacked read-only views used by the vectorised kernels, computed once per model.
    @cached_property
    def masses(self) -> FloatArray:
        """``(n+1,)`` kg: base first, then links."""
        return _frozen(np.array([self.base.mass] + [link.mass for link in self.links]))

    @cached_property
    def inertias(self) -> FloatArray:
        """``(n+1, 3, 3)`` body-frame inertias, base first."""
        return _frozen(np.stack([self.base.inertia] + [link.inertia for link in self.links]))

    @cached_property
    def joint_axes(self) -> FloatArray:
        """``(n, 3)`` unit joint axes in link frames."""
        return _frozen(np.stack([link.joint_axis for link in self.links]))

    @cached_property
    def a_vectors(self) -> FloatArray:
        """``(n, 3)`` m."""
        return _frozen(np.stack([link.a for link in self.links]))

    @cached_property
    def b_vectors(self) -> FloatArray:
        """``(n+1, 3)`` m: ``b_0`` (base) then ``b_1..b_n``."""
        return _frozen(np.stack([self.base.b] + [link.b for link in self.links]))

    @cached_property
    def chain(self) -> Chain:
        """The model as the compiled kernels take it (private writable copies, never exposed
        for writing: the kernels only read them)."""
        return Chain(
            masses=np.array(self.masses),
            inertias=np.array(self.inertias),
            axes=np.array(self.joint_axes),
            a=np.array(self.a_vectors),
            b=np.array(self.b_vectors),
            C_e=np.array(self.C_e, dtype=float),
            total_mass=float(self.masses.sum()),
        )

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RobotModel:
        """Build and validate a model from the schema of ``robot-table1.yaml``.

        Raises ``ValueError`` naming the offending field (e.g. ``links[2].inertia``).
        """
        if not isinstance(data, dict):
            raise ParameterError("robot", "expected an object")
        name = data.get("name", "robot")
        if not isinstance(name, str) or not name.strip():
            raise ParameterError("name", "expected a non-empty string")
        base_data = data.get("base")
        if not isinstance(base_data, dict):
            raise ParameterError("base", "expected an object with mass, inertia and b")
        base = Base(
            mass=_mass(base_data.get("mass"), "base.mass"),
            inertia=_inertia(base_data.get("inertia"), "base.inertia"),
            b=finite_array(base_data.get("b"), (3,), "base.b"),
        )
        links_data = data.get("links")
        if not isinstance(links_data, list) or not 1 <= len(links_data) <= MAX_JOINTS:
            raise ParameterError("links", f"expected a list of 1 to {MAX_JOINTS} links")
        links = []
        for i, ld in enumerate(links_data):
            field = f"links[{i}]"
            if not isinstance(ld, dict):
                raise ParameterError(field, "expected an object")
            link_name = ld.get("name", f"link{i + 1}")
            if not isinstance(link_name, str):
                raise ParameterError(f"{field}.name", "expected a string")
            links.append(
                Link(
                    name=link_name,
                    mass=_mass(ld.get("mass"), f"{field}.mass"),
                    joint_axis=_axis(ld.get("joint_axis"), f"{field}.joint_axis"),
                    a=finite_array(ld.get("a"), (3,), f"{field}.a"),
                    b=finite_array(ld.get("b"), (3,), f"{field}.b"),
                    inertia=_inertia(ld.get("inertia"), f"{field}.inertia"),
                )
            )
        ee = data.get("end_effector", {"C_e": np.eye(3).tolist()})
        if not isinstance(ee, dict):
            raise ParameterError("end_effector", "expected an object with C_e")
        C_e = finite_array(ee.get("C_e", np.eye(3).tolist()), (3, 3), "end_effector.C_e")
        if not is_rotation(C_e):
            raise ParameterError("end_effector.C_e", "must be a rotation matrix (orthonormal, det +1)")
        return cls(name=name, base=base, links=tuple(links), C_e=C_e)

    def to_dict(self) -> dict[str, Any]:
        """The inverse of :meth:`from_dict` (plain lists and floats, JSON-ready)."""
        return {
            "name": self.name,
            "base": {
                "mass": self.base.mass,
                "inertia": self.base.inertia.tolist(),
                "b": self.base.b.tolist(),
            },
            "links": [
                {
                    "name": link.name,
                    "mass": link.mass,
                    "joint_axis": link.joint_axis.tolist(),
                    "a": link.a.tolist(),
                    "b": link.b.tolist(),
                    "inertia": link.inertia.tolist(),
                }
                for link in self.links
            ],
            "end_effector": {"C_e": self.C_e.tolist()},
        }


def table1_robot() -> RobotModel:
    """The 6-DOF robot of the paper's Table 1 with the frames of ``robot-table1.md``."""
    text = resources.files("engine").joinpath("data/table1_robot.json").read_text()
    return RobotModel.from_dict(json.loads(text))

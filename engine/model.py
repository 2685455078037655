"""Immutable free-floating robot model (Yoshida/SpaceDyn vectors, serial chain).

Conventions (see README): link frames are parallel to the base frame at q = 0; ``a_i`` runs
from joint i to the CoM of link i, ``b_i`` from the CoM of link i to joint i+1 (``b_0`` from the
base CoM to joint 1, ``b_n`` from the last CoM to the end-effector point), both in link i's
frame at q = 0; inertias are about each CoM in the body's own frame. SI units throughout.

Joints are revolute (``q_i`` in rad: link i turns about ``s_i``) or prismatic (``q_i`` in m: link
i slides along ``s_i``, so its CoM is at ``a_i + s_i q_i`` from joint i), each with optional
position limits ``lower <= q_i <= upper`` (rad or m; infinite when unlimited) and an optional
effort limit ``|tau_i| <= torque_limit_n_m`` (N m, revolute) or ``force_limit_n`` (N, prismatic),
both of which the planner checks (the effort along the executed trajectory, see
:mod:`engine.dynamics`). Every body needs a mass and a positive definite inertia: the GJM itself
depends on them (a free-floating robot without dynamics data cannot be planned at all).
:meth:`RobotModel.from_urdf` builds a model from a URDF file and :meth:`RobotModel.to_urdf` writes
one back (:mod:`engine.urdf`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from importlib import resources
from typing import Any

import numpy as np

from engine.bounds import MAX_EFFORT, MAX_INERTIA, MAX_JOINT_LIMIT, MAX_JOINTS, MAX_LENGTH_M, MAX_MASS_KG
from engine.errors import ParameterError, finite_array
from engine.geometry import Shape, capsule, shape_from_dict, shapes_from_list
from engine.kernels.chain import Chain
from engine.spatial import FloatArray, is_rotation
from engine.urdf import UrdfError, dict_to_urdf, urdf_element, urdf_to_dict

JOINT_TYPES: tuple[str, ...] = ("revolute", "prismatic")


def _frozen(arr: FloatArray) -> FloatArray:
    arr.setflags(write=False)
    return arr


def _mass(value: Any, field: str) -> float:
    try:
        mass = float(value)
    except (TypeError, ValueError) as exc:
        raise ParameterError(field, "expected a number") from exc
    if not math.isfinite(mass) or not 0.0 < mass <= MAX_MASS_KG:
        raise ParameterError(field, f"mass must be finite, > 0 and <= {MAX_MASS_KG:g} kg, got {value!r}")
    return mass


def _inertia(value: Any, field: str, effort_key: str | None = None) -> FloatArray:
    """A validated inertia tensor; ``effort_key`` names the link's effort limit, if it has one
    (a refusal then says that the limit needs the inertia too)."""
    given = finite_array(value, (3, 3), field, MAX_INERTIA)
    scale = max(float(np.max(np.abs(given))), 1e-300)
    if not np.allclose(given, given.T, rtol=0.0, atol=1e-9 * scale):
        raise ParameterError(field, "inertia tensor must be symmetric")
    inertia = _frozen(0.5 * (given + given.T))  # exactly the input when it is symmetric
    principal = np.linalg.eigvalsh(inertia)
    if principal[0] < -1e-12 * scale:
        raise ParameterError(
            field, f"inertia tensor must be positive definite: a principal moment is negative, {principal[0]:.6g} kg m^2"
        )
    if principal[0] <= 1e-12 * scale:  # none, or singular: a body the URDF gave no dynamics data
        needs = "the GJM and the joint torques need every body's inertia"
        if effort_key is not None:
            needs = f"this link has a {effort_key} but no dynamics data: the joint torques (and the GJM) need its inertia"
        raise ParameterError(field, f"inertia tensor must be positive definite, not zero or singular ({needs})")
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


def _limits(value: Any, field: str) -> tuple[float, float]:
    """``{"lower": x, "upper": y}`` (either may be null or missing: unlimited on that side)."""
    if value is None:
        return -math.inf, math.inf
    if not isinstance(value, dict):
        raise ParameterError(field, "expected an object with lower and upper (null for unlimited)")
    bounds = []
    for key, default in (("lower", -math.inf), ("upper", math.inf)):
        raw = value.get(key)
        if raw is None:
            bounds.append(default)
            continue
        try:
            number = float(raw)
        except (TypeError, ValueError) as exc:
            raise ParameterError(f"{field}.{key}", "expected a number or null") from exc
        if not math.isfinite(number) or abs(number) > MAX_JOINT_LIMIT:
            raise ParameterError(f"{field}.{key}", f"must be finite and within +-{MAX_JOINT_LIMIT:g} (null for unlimited)")
        bounds.append(number)
    if not bounds[0] < bounds[1]:
        raise ParameterError(field, f"lower ({bounds[0]:g}) must be smaller than upper ({bounds[1]:g})")
    return bounds[0], bounds[1]


#: The robot parameters' effort-limit key of each joint type: N m for a revolute joint, N for a prismatic one.
EFFORT_KEYS = {"revolute": "torque_limit_n_m", "prismatic": "force_limit_n"}


def _effort(data: dict[str, Any], field: str, joint_type: str) -> float:
    """The effort limit of a link's joint (``inf``: none): ``torque_limit_n_m`` for a revolute
    joint, ``force_limit_n`` for a prismatic one, finite and > 0 (null or left out: no limit)."""
    key = EFFORT_KEYS[joint_type]
    for other_type, other in EFFORT_KEYS.items():
        if other != key and data.get(other) is not None:
            raise ParameterError(f"{field}.{other}", f"a {joint_type} joint's effort limit is {key}, not {other} ({other_type})")
    raw = data.get(key)
    if raw is None:
        return math.inf
    try:
        limit = float(raw)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{field}.{key}", "expected a number or null") from exc
    if not (math.isfinite(limit) and 0.0 < limit <= MAX_EFFORT):
        raise ParameterError(
            f"{field}.{key}", f"must be finite, > 0 and <= {MAX_EFFORT:g} (null or left out: no limit), got {raw!r}"
        )
    return limit


def _collision_radius(value: Any, field: str) -> float:
    """A link's capsule radius (m, > 0 and at most :data:`engine.bounds.MAX_LENGTH_M`); null or
    left out: none."""
    if value is None:
        return 0.0
    try:
        radius = float(value)
    except (TypeError, ValueError) as exc:
        raise ParameterError(field, "expected a number or null") from exc
    if not (math.isfinite(radius) and 0.0 < radius <= MAX_LENGTH_M):
        raise ParameterError(field, f"must be finite, > 0 and at most {MAX_LENGTH_M:g} m (null for none), got {value!r}")
    return radius


def _collision_box(value: Any) -> tuple[FloatArray, FloatArray] | None:
    """The carrier's box ``{"size_m": [x, y, z], "center_m": [x, y, z]}`` (carrier frame, the
    centre about the carrier's CoM); null or left out: none."""
    if value is None:
        return None
    if not isinstance(value, dict):
        raise ParameterError("base.collision_box", "expected an object with size_m and center_m")
    extra = sorted(set(value) - {"size_m", "center_m"})
    if extra:
        raise ParameterError(f"base.collision_box.{extra[0]}", "not a field of the box (size_m, center_m)")
    centre = finite_array(value.get("center_m", [0.0, 0.0, 0.0]), (3,), "base.collision_box.center_m", MAX_LENGTH_M)
    box = shape_from_dict({"type": "box", "size_m": value.get("size_m")}, "base.collision_box")
    return _frozen(2.0 * box.dims), centre


@dataclass(frozen=True)
class Link:
    """One link and the joint that drives it (joint i moves link i). ``joint_axis`` is the
    rotation axis of a revolute joint or the sliding direction of a prismatic one."""

    name: str
    mass: float
    joint_axis: FloatArray  # (3,) unit vector in link frame
    a: FloatArray  # (3,) m, joint i -> CoM i (at q_i = 0)
    b: FloatArray  # (3,) m, CoM i -> joint i+1 (or end effector)
    inertia: FloatArray  # (3, 3) kg m^2 about the CoM, link frame
    joint_type: str = "revolute"  # one of JOINT_TYPES
    joint_name: str = ""  # the URDF joint name ("" for the default "joint<i>")
    lower: float = -math.inf  # position limits, rad (revolute) or m (prismatic)
    upper: float = math.inf
    effort_limit: float = math.inf  # |torque| N m (revolute) or |force| N (prismatic); inf: none
    collision_radius: float = 0.0  # m: a capsule from joint i to joint i+1 (or the end effector); 0: none
    collision_shapes: tuple[Shape, ...] = ()  # more shapes, link frame, about the CoM

    @property
    def shapes(self) -> tuple[Shape, ...]:
        """The link's collision shapes (link frame, positions about its CoM): the capsule of
        ``collision_radius`` from joint i's origin (``-a``; for a prismatic joint where it is at
        q = 0, as the link carries it) to the next joint's (``b``), then ``collision_shapes``."""
        if self.collision_radius > 0.0:
            return (capsule(-self.a, self.b, self.collision_radius), *self.collision_shapes)
        return self.collision_shapes

    @property
    def prismatic(self) -> bool:
        return self.joint_type == "prismatic"

    @property
    def limited(self) -> bool:
        return math.isfinite(self.lower) or math.isfinite(self.upper)


@dataclass(frozen=True)
class Base:
    """The floating carrier (body 0)."""

    mass: float
    inertia: FloatArray  # (3, 3) kg m^2 about the base CoM, base frame
    b: FloatArray  # (3,) m, base CoM -> joint 1
    name: str = "base"
    collision_box: tuple[FloatArray, FloatArray] | None = None  # (size (3,) m, centre (3,) m about the CoM)
    collision_shapes: tuple[Shape, ...] = ()  # more shapes, carrier frame, about the CoM

    @property
    def shapes(self) -> tuple[Shape, ...]:
        """The carrier's collision shapes (carrier frame, positions about its CoM)."""
        if self.collision_box is None:
            return self.collision_shapes
        size, centre = self.collision_box
        return (Shape("box", 0.0, centre, np.eye(3), 0.5 * size), *self.collision_shapes)


@dataclass(frozen=True, eq=False)
class RobotModel:
    """Free-floating serial manipulator on a floating base. Immutable; build with
    :meth:`from_dict`."""

    name: str
    base: Base
    links: tuple[Link, ...]
    C_e: FloatArray  # (3, 3) end-effector frame expressed in the last link's frame
    end_effector_name: str = "end_effector"

    @property
    def n_joints(self) -> int:
        return len(self.links)

    @property
    def joint_types(self) -> tuple[str, ...]:
        return tuple(link.joint_type for link in self.links)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(link.joint_name or f"joint{i + 1}" for i, link in enumerate(self.links))

    @cached_property
    def prismatic(self) -> np.ndarray:
        """``(n,)`` bool: which joints are prismatic (their ``q`` in m, the others' in rad)."""
        flags = np.array([link.prismatic for link in self.links], dtype=bool)
        flags.setflags(write=False)
        return flags

    @cached_property
    def limited(self) -> bool:
        """Whether any joint has a position limit."""
        return any(link.limited for link in self.links)

    @cached_property
    def lower_limits(self) -> FloatArray:
        """``(n,)`` rad or m, ``-inf`` where unlimited."""
        return _frozen(np.array([link.lower for link in self.links], dtype=float))

    @cached_property
    def upper_limits(self) -> FloatArray:
        """``(n,)`` rad or m, ``+inf`` where unlimited."""
        return _frozen(np.array([link.upper for link in self.links], dtype=float))

    @cached_property
    def effort_limits(self) -> FloatArray:
        """``(n,)`` N m (revolute) or N (prismatic), ``+inf`` where unlimited."""
        return _frozen(np.array([link.effort_limit for link in self.links], dtype=float))

    @cached_property
    def effort_limited(self) -> bool:
        """Whether any joint has a torque (force) limit: then every plan's torques are checked."""
        return bool(np.any(np.isfinite(self.effort_limits)))

    @cached_property
    def has_geometry(self) -> bool:
        """Whether any body has a collision shape."""
        return bool(self.base.shapes) or any(link.shapes for link in self.links)

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
            joints=np.stack(
                [np.where(self.prismatic, 1.0, 0.0), self.lower_limits, self.upper_limits, self.effort_limits], axis=1
            ),
        )

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RobotModel:
        """Build and validate a model from the schema of ``engine/data/table1_robot.json``: every
        number finite and within :mod:`engine.bounds`, masses > 0, inertias symmetric positive
        definite and physical, joint axes non-zero, ``C_e`` a rotation.

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
        base_name = base_data.get("name", "base")
        if not isinstance(base_name, str) or not base_name:
            raise ParameterError("base.name", "expected a non-empty string")
        base = Base(
            mass=_mass(base_data.get("mass"), "base.mass"),
            inertia=_inertia(base_data.get("inertia"), "base.inertia"),
            b=finite_array(base_data.get("b"), (3,), "base.b", MAX_LENGTH_M),
            name=base_name,
            collision_box=_collision_box(base_data.get("collision_box")),
            collision_shapes=shapes_from_list(base_data.get("collision_shapes"), "base.collision_shapes"),
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
            joint_type = ld.get("joint_type", "revolute")
            if joint_type not in JOINT_TYPES:
                raise ParameterError(f"{field}.joint_type", f"must be one of {', '.join(JOINT_TYPES)}")
            joint_name = ld.get("joint_name", "")
            if not isinstance(joint_name, str):
                raise ParameterError(f"{field}.joint_name", "expected a string")
            lower, upper = _limits(ld.get("limits"), f"{field}.limits")
            effort = _effort(ld, field, joint_type)
            links.append(
                Link(
                    name=link_name,
                    mass=_mass(ld.get("mass"), f"{field}.mass"),
                    joint_axis=_axis(ld.get("joint_axis"), f"{field}.joint_axis"),
                    a=finite_array(ld.get("a"), (3,), f"{field}.a", MAX_LENGTH_M),
                    b=finite_array(ld.get("b"), (3,), f"{field}.b", MAX_LENGTH_M),
                    inertia=_inertia(
                        ld.get("inertia"), f"{field}.inertia", EFFORT_KEYS[joint_type] if math.isfinite(effort) else None
                    ),
                    joint_type=joint_type,
                    joint_name=joint_name,
                    lower=lower,
                    upper=upper,
                    effort_limit=effort,
                    collision_radius=_collision_radius(ld.get("collision_radius_m"), f"{field}.collision_radius_m"),
                    collision_shapes=shapes_from_list(ld.get("collision_shapes"), f"{field}.collision_shapes"),
                )
            )
        ee = data.get("end_effector", {"C_e": np.eye(3).tolist()})
        if not isinstance(ee, dict):
            raise ParameterError("end_effector", "expected an object with C_e")
        C_e = finite_array(ee.get("C_e", np.eye(3).tolist()), (3, 3), "end_effector.C_e")
        if not is_rotation(C_e):
            raise ParameterError("end_effector.C_e", "must be a rotation matrix (orthonormal, det +1)")
        ee_name = ee.get("name", "end_effector")
        if not isinstance(ee_name, str) or not ee_name:
            raise ParameterError("end_effector.name", "expected a non-empty string")
        return cls(name=name, base=base, links=tuple(links), C_e=C_e, end_effector_name=ee_name)

    def to_dict(self) -> dict[str, Any]:
        """The inverse of :meth:`from_dict` (plain lists and floats, JSON-ready; unlimited
        joint limits are null)."""
        base: dict[str, Any] = {"mass": self.base.mass, "inertia": self.base.inertia.tolist(), "b": self.base.b.tolist()}
        if self.base.name != "base":
            base["name"] = self.base.name
        if self.base.collision_box is not None:
            size, centre = self.base.collision_box
            base["collision_box"] = {"size_m": size.tolist(), "center_m": centre.tolist()}
        if self.base.collision_shapes:
            base["collision_shapes"] = [shape.to_dict() for shape in self.base.collision_shapes]
        links: list[dict[str, Any]] = []
        for link in self.links:
            entry: dict[str, Any] = {
                "name": link.name,
                "mass": link.mass,
                "joint_type": link.joint_type,
                "joint_axis": link.joint_axis.tolist(),
                "a": link.a.tolist(),
                "b": link.b.tolist(),
                "inertia": link.inertia.tolist(),
            }
            if link.joint_name and link.joint_name != f"joint{len(links) + 1}":
                entry["joint_name"] = link.joint_name
            if link.limited:
                entry["limits"] = {
                    "lower": link.lower if math.isfinite(link.lower) else None,
                    "upper": link.upper if math.isfinite(link.upper) else None,
                }
            if math.isfinite(link.effort_limit):
                entry[EFFORT_KEYS[link.joint_type]] = link.effort_limit
            if link.collision_radius > 0.0:
                entry["collision_radius_m"] = link.collision_radius
            if link.collision_shapes:
                entry["collision_shapes"] = [shape.to_dict() for shape in link.collision_shapes]
            links.append(entry)
        end_effector: dict[str, Any] = {"C_e": self.C_e.tolist()}
        if self.end_effector_name != "end_effector":
            end_effector["name"] = self.end_effector_name
        return {"name": self.name, "base": base, "links": links, "end_effector": end_effector}

    @classmethod
    def from_urdf(
        cls,
        text: str | bytes,
        *,
        end_effector_link: str | None = None,
        tool_offset: tuple[Any, Any] | None = None,
        name: str | None = None,
        mesh_hulls: Callable[[str], FloatArray | None] | None = None,
    ) -> RobotModel:
        """The model of a URDF robot (see :mod:`engine.urdf`): the root link is the floating
        base, fixed joints are merged, the chain runs to ``end_effector_link`` (default: the only
        leaf after the last moving joint); ``tool_offset = (position (3,) m, rotation (3, 3))``
        places the end effector in that link's frame; ``mesh_hulls(filename)`` gives a ``<mesh>``
        collision's convex hull (:func:`engine.urdf.urdf_to_dict`). Raises
        :class:`engine.urdf.UrdfError` (a ``ParameterError``) naming the URDF element at fault."""
        params = urdf_to_dict(
            text, end_effector_link=end_effector_link, tool_offset=tool_offset, name=name, mesh_hulls=mesh_hulls
        )
        try:
            return cls.from_dict(params)
        except ParameterError as exc:  # the URDF checks come first; this names the URDF element anyway
            raise UrdfError(urdf_element(params, exc.field), f"{exc.field}: {exc.reason}") from None

    def to_urdf(self) -> str:
        """This model as URDF text that :meth:`from_urdf` and Pinocchio read back to the same
        model (see :func:`engine.urdf.dict_to_urdf`)."""
        return dict_to_urdf(self.to_dict(), [self.base.shapes, *(link.shapes for link in self.links)])


def table1_robot() -> RobotModel:
    """The 6-DOF robot of the paper's Table 1 with the frames of ``engine/data/table1_robot.json``."""
    text = resources.files("engine").joinpath("data/table1_robot.json").read_text()
    return RobotModel.from_dict(json.loads(text))


#: m: the radius of the Table-1 robot's link capsules in :func:`table1_with_geometry`.
TABLE1_LINK_RADIUS_M = 0.05
#: m: the edge of the Table-1 carrier's cube in :func:`table1_with_geometry`.
TABLE1_CARRIER_CUBE_M = 1.5


def table1_with_geometry() -> RobotModel:
    """The Table-1 robot with collision geometry (the paper gives none): each link a capsule of
    :data:`TABLE1_LINK_RADIUS_M` from its joint to the next, the carrier a cube of
    :data:`TABLE1_CARRIER_CUBE_M` about its CoM, whose top face is where joint 1 is mounted
    (``b_0 = (0.5, 0, 0.751)`` m); a uniform cube of the carrier's 450 kg has 169 kg m^2 about
    each axis, close to Table 1's 200."""
    data = table1_robot().to_dict()
    data["name"] = "table1-geometry"
    for link in data["links"]:
        link["collision_radius_m"] = TABLE1_LINK_RADIUS_M
    data["base"]["collision_box"] = {"size_m": [TABLE1_CARRIER_CUBE_M] * 3, "center_m": [0.0, 0.0, 0.0]}
    return RobotModel.from_dict(data)


#: URDF robots shipped with the engine (``engine/data/<file>``): preset id -> (file, end-effector link).
URDF_PRESETS: dict[str, tuple[str, str]] = {
    "arm7": ("arm7_spacecraft.urdf", "tool0"),
    "arm3": ("arm3.urdf", "tool0"),
}


def urdf_preset_text(preset: str) -> str:
    """The URDF text of a shipped robot (one of :data:`URDF_PRESETS`)."""
    filename, _ = URDF_PRESETS[preset]
    return resources.files("engine").joinpath(f"data/{filename}").read_text()


def urdf_robot(preset: str) -> RobotModel:
    """A shipped URDF robot: ``"arm7"``, a 7-joint arm on a spacecraft body (fixed mounting
    link, tool frame), or ``"arm3"``, a 3-joint arm (two revolute joints and a prismatic boom)."""
    _, end_effector = URDF_PRESETS[preset]
    return RobotModel.from_urdf(urdf_preset_text(preset), end_effector_link=end_effector, name=preset)

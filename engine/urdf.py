"""URDF import and export: a URDF serial arm on a floating base <-> the model's parameter set.

Reading (:func:`urdf_to_dict`, behind :meth:`engine.model.RobotModel.from_urdf`):

1. The text is parsed by ``defusedxml`` first (at most :data:`MAX_URDF_BYTES`, no DTD, so no
   entity expansion and no external entities; at most :data:`MAX_DEPTH` levels). The links and
   joints are counted before anything else (at most :data:`engine.bounds.MAX_URDF_LINKS` of each,
   at most :data:`engine.bounds.MAX_JOINTS` moving joints), so the work that follows is bounded,
   and every step after is linear in the document. Every element the model needs (robot, links
   with their ``inertial``, joints with ``parent``, ``child``, ``origin``, ``axis``, ``limit``) is
   checked there, so each refusal names its element; numbers are written as XML Schema doubles
   (no ``1_000``, no ``inf``). ``<collision>`` elements are read there too (see below); visual
   geometry, materials, transmissions and the like are not used and are left out.
2. The checked elements are read by `yourdfpy <https://github.com/clemense/yourdfpy>`_ (origins
   as 4x4 transforms, URDF's fixed-axis roll-pitch-yaw), whose object model also writes the
   export.
3. The root link is the floating base. Links joined by ``fixed`` joints form one rigid body
   (mass, centre of mass and inertia combined exactly, each ``inertial`` origin's rotation
   applied; massless links are frames). ``revolute`` and ``continuous`` joints (rad) and
   ``prismatic`` joints (m) move the chain from the root to ``end_effector_link`` (default: the
   only leaf link after the last moving joint). ``floating``, ``planar`` and ``mimic`` joints,
   and moving joints off that chain, are refused.
4. The bodies are expressed in the model's frames: parallel to the base at q = 0 (a URDF link
   frame turned by ``U_i`` at q = 0 gives ``s_i = U_i axis_i``, ``a_i = U_i c_i``,
   ``I_i = U_i I U_i^T``), see :mod:`engine.model`.

The parameter set this gives is not range-checked here: its numbers (which may overflow to
infinity when huge ones are combined) are checked by whoever builds the model from it, with the
same bounds and messages as any parameter set (:meth:`engine.model.RobotModel.from_dict`, and the
API's robot schema in ``service.schemas.robots``).

Position limits: a ``revolute`` or ``prismatic`` joint keeps ``lower``/``upper`` of its
``<limit>``; a revolute joint without ``<limit>`` (common in the wild), a ``continuous`` joint,
or a missing ``lower``/``upper`` attribute is unlimited on that side (URDF's default of 0 would
lock the joint). A positive ``effort`` is the joint's torque limit (N m, ``torque_limit_n_m``) or
force limit (N, prismatic, ``force_limit_n``), on continuous joints too; ``effort="0"`` (URDF's
placeholder, what exports write when it is unknown) or none means no limit, a negative one is
refused. ``velocity`` is not used: joint speed limits belong to the task.

Collision geometry: each link's ``<collision>`` elements become collision shapes of its body
(:mod:`engine.geometry`), their ``<origin>`` honoured: ``<box size>``, ``<cylinder radius
length>``, ``<sphere radius>``, ``<capsule radius length>`` (along the origin's z axis, as in
SDF), and ``<mesh filename scale>`` as the convex hull of the mesh, which a ``mesh_hulls``
callable gives for its file name (the service resolves ``mesh://<id>`` to a stored mesh);
without one, or for a name it does not know, the element is refused. A cylinder with a sphere
of its radius centred on each end face, in one link, is read as the capsule it makes up.

Writing (:func:`dict_to_urdf`): one URDF link per body with its frame at the joint, parallel to
the base at q = 0 (so every joint origin is a pure translation), the CoM as the ``inertial``
origin, and the end effector as a massless link on a fixed joint. Unlimited revolute joints are
``continuous``; ``effort`` is the torque (force) limit, 0 where there is none, and ``velocity``
is written as 0 (unknown). Each body's collision shapes are its link's ``<collision>`` elements
in standard URDF (which has no capsule, and Pinocchio's parser refuses ``<capsule>``): a capsule
is written as a cylinder with a sphere of its radius on each end face, which reading merges back
into the capsule (their union is exactly that capsule); a convex shape is left out with a comment
in its link, as URDF carries meshes as files only.
"""

from __future__ import annotations

import io
import math
import re
import xml.etree.ElementTree as ET
from collections import deque
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from defusedxml import DefusedXmlException
from defusedxml import ElementTree as SafeET

from engine.bounds import MAX_JOINTS, MAX_URDF_LINKS
from engine.errors import ParameterError
from engine.spatial import (
    FloatArray,
    is_rotation,
    matrix_to_quaternion,
    matrix_to_rpy_spacedyn,
    quaternion_to_matrix,
    rpy_spacedyn_to_matrix,
)

if TYPE_CHECKING:
    from engine.geometry import Shape

MAX_URDF_BYTES = 1 << 20
MAX_DEPTH = 32
MOVING_TYPES = ("revolute", "continuous", "prismatic")
REFUSED_TYPES = ("floating", "planar")
INERTIA_KEYS = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
#: A number as XML Schema writes a double (what URDF parsers read): no ``1_000``, ``inf`` or ``nan``.
NUMBER = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")


class UrdfError(ParameterError):
    """A URDF the engine cannot use; ``element`` names it (``<joint name="elbow">``) and ``field``
    the argument of :meth:`engine.model.RobotModel.from_urdf` at fault (``end_effector_link``, or the
    document: ``urdf``)."""

    def __init__(self, element: str, reason: str) -> None:
        super().__init__("end_effector_link" if "end_effector_link" in reason else "urdf", reason)
        self.args = (f"{element}: {reason}",)
        self.element = element


def _link(name: str) -> str:
    return f'<link name="{name}">'


def _joint(name: str) -> str:
    return f'<joint name="{name}">'


# --- the defusedxml pass: size, well-formedness, and every element the model uses ----------


def _parse_safely(text: str | bytes) -> ET.Element:
    data = text.encode("utf-8") if isinstance(text, str) else bytes(text)
    if len(data) > MAX_URDF_BYTES:
        raise UrdfError("<robot>", f"the URDF has {len(data)} bytes, more than the {MAX_URDF_BYTES} accepted")
    try:
        root = SafeET.fromstring(data, forbid_dtd=True, forbid_entities=True, forbid_external=True)
    except DefusedXmlException as exc:
        raise UrdfError("<robot>", f"refused: {type(exc).__name__} (no DTD, entities or external references)") from None
    except ET.ParseError as exc:
        raise UrdfError("<robot>", f"not well-formed XML: {exc}") from None
    depth = [(root, 1)]
    while depth:
        element, level = depth.pop()
        if level > MAX_DEPTH:
            raise UrdfError(f"<{element.tag}>", f"elements nested more than {MAX_DEPTH} deep")
        depth.extend((child, level + 1) for child in element)
    if root.tag != "robot":
        raise UrdfError(f"<{root.tag}>", "the root element must be <robot>")
    return root


def _numbers(element: ET.Element | None, attr: str, count: int, where: str, *, required: bool = False) -> list[float] | None:
    """The attribute as ``count`` finite numbers (None if absent and not required)."""
    if element is None:
        return None
    raw = element.get(attr)
    label = f"<{element.tag} {attr}>"
    if raw is None:
        if required:
            raise UrdfError(where, f"<{element.tag}> needs the attribute {attr}")
        return None
    parts = raw.split()
    hint = " (xacro expressions must be expanded first)" if "${" in raw or "$(" in raw else ""
    if not all(NUMBER.fullmatch(p) for p in parts):
        raise UrdfError(where, f"{label}: {raw!r} is not {count} number(s){hint}")
    values = [float(p) for p in parts]
    if len(values) != count or not all(math.isfinite(v) for v in values):
        raise UrdfError(where, f"{label}: {raw!r} is not {count} finite number(s){hint}")
    return values


def _check_origin(element: ET.Element | None, where: str) -> None:
    origin = element.find("origin") if element is not None else None
    _numbers(origin, "xyz", 3, where)
    _numbers(origin, "rpy", 3, where)


def _name(element: ET.Element, kind: str, seen: set[str]) -> str:
    name = element.get("name")
    if not name:
        raise UrdfError(f"<{kind}>", f"a <{kind}> needs a name attribute")
    if name in seen:
        raise UrdfError(f'<{kind} name="{name}">', f"two <{kind}> elements are named {name!r}")
    seen.add(name)
    return name


def _count(links: list[ET.Element], joints: list[ET.Element]) -> None:
    """Refuse a document with more links, joints or moving joints than a model may have, before
    any of them is read."""
    if not links:
        raise UrdfError("<robot>", "the URDF has no <link>: a robot needs at least its base link and one moving link")
    for kind, elements in (("link", links), ("joint", joints)):
        if len(elements) > MAX_URDF_LINKS:
            raise UrdfError("<robot>", f"the URDF has {len(elements)} <{kind}> elements, at most {MAX_URDF_LINKS}")
    moving = sum(joint.get("type") in MOVING_TYPES for joint in joints)
    if moving > MAX_JOINTS:
        raise UrdfError("<robot>", f"the URDF has {moving} moving joints (revolute, continuous, prismatic), at most {MAX_JOINTS}")


#: A collision geometry's element and its numeric attributes (count of numbers each).
COLLISION_GEOMETRY = {
    "box": {"size": 3},
    "cylinder": {"radius": 1, "length": 1},
    "sphere": {"radius": 1},
    "capsule": {"radius": 1, "length": 1},
    "mesh": {"scale": 3},
}


def _collisions(link: ET.Element, where: str) -> list[dict[str, Any]]:
    """A link's ``<collision>`` elements, checked: ``{"origin": (xyz, rpy), "type", numbers...}``."""
    out = []
    for collision in link.findall("collision"):
        _check_origin(collision, where)
        geometry = collision.find("geometry")
        shapes = [child for child in geometry] if geometry is not None else []
        if len(shapes) != 1 or shapes[0].tag not in COLLISION_GEOMETRY:
            raise UrdfError(where, f"a <collision> needs one <geometry> of {', '.join(f'<{k}>' for k in COLLISION_GEOMETRY)}")
        shape = shapes[0]
        entry: dict[str, Any] = {"type": shape.tag}
        for attr, count in COLLISION_GEOMETRY[shape.tag].items():
            values = _numbers(shape, attr, count, where, required=shape.tag != "mesh")
            if values is not None:
                if any(v <= 0.0 for v in values):
                    raise UrdfError(where, f"<{shape.tag} {attr}>: must be > 0")
                entry[attr] = values if count > 1 else values[0]
        if shape.tag == "mesh":
            filename = shape.get("filename")
            if not filename:
                raise UrdfError(where, "<mesh> needs a filename")
            entry["filename"] = filename
        origin = collision.find("origin")
        entry["origin"] = (
            _numbers(origin, "xyz", 3, where) or [0.0, 0.0, 0.0],
            _numbers(origin, "rpy", 3, where) or [0.0, 0.0, 0.0],
        )
        out.append(entry)
    return out


def _checked_copy(root: ET.Element) -> tuple[ET.Element, dict[str, list[dict[str, Any]]]]:
    """Check what the model uses and return a copy with only those elements (visual geometry,
    materials, transmissions, dynamics and the like are not read), and each link's checked
    collision geometry."""
    robot_name = root.get("name")
    if not robot_name:
        raise UrdfError("<robot>", "the <robot> needs a name attribute")
    links, joints = root.findall("link"), root.findall("joint")
    _count(links, joints)
    out = ET.Element("robot", {"name": robot_name})
    collisions: dict[str, list[dict[str, Any]]] = {}
    link_names: set[str] = set()
    for link in links:
        name = _name(link, "link", link_names)
        where = _link(name)
        kept = ET.SubElement(out, "link", {"name": name})
        found = _collisions(link, where)
        if found:
            collisions[name] = found
        inertial = link.find("inertial")
        if inertial is None:
            continue  # a frame: no mass
        _check_origin(inertial, where)
        mass = inertial.find("mass")
        if mass is None:
            raise UrdfError(where, "<inertial> needs a <mass value=...>")
        (value,) = _numbers(mass, "value", 1, where, required=True) or [0.0]
        if value < 0.0:
            raise UrdfError(where, f"negative mass {value:g} kg")
        inertia = inertial.find("inertia")
        if inertia is None:
            raise UrdfError(where, "<inertial> needs an <inertia> with ixx, ixy, ixz, iyy, iyz, izz")
        for key in INERTIA_KEYS:
            _numbers(inertia, key, 1, where, required=True)
        kept.append(_strip(inertial, ("origin", "mass", "inertia")))
    joint_names: set[str] = set()
    for joint in joints:
        name = _name(joint, "joint", joint_names)
        where = _joint(name)
        kind = joint.get("type")
        if kind in REFUSED_TYPES:
            raise UrdfError(where, f"{kind} joints are not supported (the root link is the only free body)")
        if kind not in MOVING_TYPES and kind != "fixed":
            raise UrdfError(where, f"unknown joint type {kind!r}; supported: fixed, {', '.join(MOVING_TYPES)}")
        if joint.find("mimic") is not None:
            raise UrdfError(where, "mimic joints are not supported (every joint of the chain is driven on its own)")
        for tag in ("parent", "child"):
            node = joint.find(tag)
            if node is None or not node.get("link"):
                raise UrdfError(where, f"the joint needs a <{tag} link=...>")
        _check_origin(joint, where)
        axis = _numbers(joint.find("axis"), "xyz", 3, where)
        if kind in MOVING_TYPES and axis is not None and math.hypot(*axis) < 1e-12:
            raise UrdfError(where, "the joint axis is zero")
        limit = joint.find("limit")
        for key in ("lower", "upper", "effort", "velocity"):
            _numbers(limit, key, 1, where)
        out.append(_strip(joint, ("parent", "child", "origin", "axis", "limit")))
    return out, collisions


def _strip(element: ET.Element, keep: tuple[str, ...]) -> ET.Element:
    """``element`` with its attributes and only the children named in ``keep`` (attributes only)."""
    kept = ET.Element(element.tag, dict(element.attrib))
    for child in element:
        if child.tag in keep:
            kept.append(ET.Element(child.tag, dict(child.attrib)))
    return kept


def _read(text: str | bytes) -> tuple[Any, dict[str, list[dict[str, Any]]]]:
    """The checked URDF as a ``yourdfpy.Robot`` (no meshes, no scene graph), and its links'
    collision geometry."""
    copy, collisions = _checked_copy(_parse_safely(text))
    checked = ET.tostring(copy, encoding="utf-8")
    import yourdfpy  # imported on first use: it brings trimesh along (about a second)

    try:
        urdf = yourdfpy.URDF.load(
            io.BytesIO(checked), build_scene_graph=False, load_meshes=False, build_collision_scene_graph=False
        )
    except Exception as exc:  # the checks above cover what it reads; anything else is still a URDF error
        raise UrdfError("<robot>", f"the URDF could not be read: {type(exc).__name__}: {exc}") from None
    return urdf.robot, collisions


# --- the tree: bodies (links joined by fixed joints) and the moving chain ------------------


def _transform(origin: np.ndarray | None) -> FloatArray:
    return np.eye(4) if origin is None else np.asarray(origin, dtype=float)


def _body_inertia(links: list[tuple[Any, FloatArray]], where: str, moving: bool) -> tuple[float, FloatArray, FloatArray]:
    """``(mass, com (3,), inertia about the com (3, 3))`` of the rigid links ``(link,
    T_frame_link)`` in the frame of the body (the first link)."""
    parts = []
    for link, T in links:
        inertial = link.inertial
        if inertial is None or inertial.mass is None:
            continue
        T_c = T @ _transform(inertial.origin)
        inertia = np.asarray(inertial.inertia, dtype=float)
        _check_physical(inertia, _link(link.name))
        if inertial.mass == 0.0 and not np.any(inertia):
            continue  # a frame
        R = T_c[:3, :3]
        parts.append((float(inertial.mass), T_c[:3, 3], R @ inertia @ R.T))
    mass = sum(m for m, _, _ in parts)
    if mass <= 0.0:
        merged = [link.name for link, _ in links[1:]]
        also = f" (with its fixed links {', '.join(merged)})" if merged else ""
        what = "the floating base" if not moving else "the body it moves"
        raise UrdfError(where, f"{what} has zero mass{also}: a moving body needs a mass")
    if len(parts) == 1:  # no arithmetic: a single massive link is kept exactly
        _, only_com, only_inertia = parts[0]
        return mass, np.array(only_com), np.array(only_inertia)
    com: FloatArray = np.sum([m * c for m, c, _ in parts], axis=0) / mass
    total = np.zeros((3, 3))
    for m, c, inertia in parts:
        d = c - com
        total += inertia + m * (float(d @ d) * np.eye(3) - np.outer(d, d))
    return mass, com, total


def _check_physical(inertia: FloatArray, where: str) -> None:
    """A link's own inertia (finite numbers): principal moments >= 0 and each at most the sum of
    the others. Computed on the tensor scaled to unit size, so huge numbers do not overflow."""
    scale = max(float(np.max(np.abs(inertia))), 1e-300)
    principal = np.linalg.eigvalsh(inertia / scale)
    if principal[0] < -1e-9:
        raise UrdfError(where, f"non-physical inertia: principal moments {(principal * scale).tolist()} must be >= 0")
    p1, p2, p3 = principal
    if p3 > p1 + p2 + 1e-9:
        raise UrdfError(
            where, f"non-physical inertia: principal moments {(principal * scale).tolist()} violate the triangle inequality"
        )


def _limits(joint: Any) -> dict[str, float | None] | None:
    if joint.type == "continuous" or joint.limit is None:
        return None
    lower, upper = joint.limit.lower, joint.limit.upper
    if lower is not None and upper is not None and not lower < upper:
        raise UrdfError(_joint(joint.name), f"<limit>: lower ({lower:g}) must be smaller than upper ({upper:g})")
    if lower is None and upper is None:
        return None
    return {"lower": lower, "upper": upper}


def _effort(joint: Any) -> float | None:
    """A joint's ``<limit effort>`` as its effort limit (None: no limit, including URDF's 0)."""
    effort = joint.limit.effort if joint.limit is not None else None
    if effort is None or effort == 0.0:
        return None
    if effort < 0.0:
        raise UrdfError(_joint(joint.name), f"<limit effort>: {effort:g} is negative (an effort limit is > 0, or 0 for none)")
    return float(effort)


def urdf_to_dict(
    text: str | bytes,
    *,
    end_effector_link: str | None = None,
    tool_offset: tuple[Any, Any] | None = None,
    name: str | None = None,
    mesh_hulls: Callable[[str], FloatArray | None] | None = None,
) -> dict[str, Any]:
    """The model parameters (the schema of :meth:`engine.model.RobotModel.from_dict`) of a URDF
    serial arm on a floating base; see the module docstring. ``tool_offset = (position (3,) m,
    rotation (3, 3))`` is the end-effector frame in ``end_effector_link``'s frame;
    ``mesh_hulls(filename)`` gives a ``<mesh>`` collision's convex hull ``(V, 3)`` (the mesh's
    own units, before ``scale``), None for a name it does not read, or raises ``LookupError``
    (its message then says why) for one it reads but cannot find. Huge numbers may give infinite parameters, which building the
    model refuses."""
    robot, collisions = _read(text)
    with np.errstate(over="ignore", invalid="ignore"):
        return _to_dict(robot, end_effector_link, tool_offset, name, collisions, mesh_hulls)


def _rpy(rpy: list[float]) -> FloatArray:
    """URDF's fixed-axis roll-pitch-yaw: ``Rz(yaw) Ry(pitch) Rx(roll)``, SpaceDyn's attitude of
    the negated angles (``(Rx(-r) Ry(-p) Rz(-y))^T``)."""
    return rpy_spacedyn_to_matrix(-np.asarray(rpy, dtype=float))


def _collision_shapes(
    entries: list[dict[str, Any]],
    link_pose: FloatArray,
    U: FloatArray,
    com: FloatArray,
    where: str,
    mesh_hulls: Callable[[str], FloatArray | None] | None,
) -> list[dict[str, Any]]:
    """A link's collision geometry as shapes of its body in the model's frame (``U`` turns the
    URDF body frame into the model's, ``com`` the body's CoM in the URDF body frame;
    ``link_pose`` the link's frame in the body's)."""
    shapes: list[dict[str, Any]] = []
    for entry in entries:
        xyz, rpy = entry["origin"]
        T = np.eye(4)
        T[:3, :3] = _rpy(rpy)
        T[:3, 3] = xyz
        T = link_pose @ T
        R = U @ T[:3, :3]
        p = U @ (T[:3, 3] - com)
        quaternion = matrix_to_quaternion(R).tolist()
        kind = entry["type"]
        if kind == "sphere":
            shapes.append({"type": "sphere", "radius_m": entry["radius"], "position_m": p.tolist()})
        elif kind == "capsule":
            half = 0.5 * entry["length"] * R[:, 2]
            shapes.append(
                {"type": "capsule", "radius_m": entry["radius"], "from_m": (p - half).tolist(), "to_m": (p + half).tolist()}
            )
        elif kind == "box":
            shapes.append({"type": "box", "size_m": list(entry["size"]), "position_m": p.tolist(), "quaternion": quaternion})
        elif kind == "cylinder":
            shapes.append(
                {
                    "type": "cylinder",
                    "radius_m": entry["radius"],
                    "length_m": entry["length"],
                    "position_m": p.tolist(),
                    "quaternion": quaternion,
                }
            )
        else:
            filename = entry["filename"]
            try:
                hull = mesh_hulls(filename) if mesh_hulls is not None else None
            except LookupError as exc:  # a name the callable knows how to read, but nothing by it
                raise UrdfError(where, f"<mesh filename={filename!r}>: {exc.args[0]}") from None
            if hull is None:
                raise UrdfError(
                    where,
                    f"<mesh filename={filename!r}>: a mesh collision needs its file, which a URDF upload does not carry: "
                    "store the mesh (POST /v1/meshes) and name it mesh://<its id>, or use <box>, <cylinder>, <sphere>",
                )
            scale = np.asarray(entry.get("scale", [1.0, 1.0, 1.0]))
            shapes.append(
                {
                    "type": "convex",
                    "vertices_m": (np.asarray(hull, dtype=float) * scale).tolist(),
                    "position_m": p.tolist(),
                    "quaternion": quaternion,
                }
            )
    return _merged_capsules(shapes)


def _merged_capsules(shapes: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """``shapes`` with each cylinder that has a sphere of its radius centred on each end face
    replaced by the capsule they make up (how :func:`dict_to_urdf` writes a capsule in standard
    URDF); the union is exactly that capsule, so this loses nothing whatever wrote them."""
    out = list(shapes)
    for cylinder in [s for s in shapes if s["type"] == "cylinder"]:
        r = cylinder["radius_m"]
        centre = np.asarray(cylinder["position_m"])
        half = 0.5 * cylinder["length_m"] * quaternion_to_matrix(cylinder["quaternion"])[:, 2]
        ends: list[dict[str, Any]] = []
        for point in (centre - half, centre + half):
            tol = 1e-9 * max(1.0, float(np.abs(point).max()), r)
            match = next(
                (
                    s
                    for s in out
                    if s["type"] == "sphere"
                    and all(s is not e for e in ends)
                    and abs(s["radius_m"] - r) <= tol
                    and float(np.abs(np.asarray(s["position_m"]) - point).max()) <= tol
                ),
                None,
            )
            if match is None:
                break
            ends.append(match)
        else:
            out[next(i for i, s in enumerate(out) if s is cylinder)] = {
                "type": "capsule",
                "radius_m": r,
                "from_m": (centre - half).tolist(),
                "to_m": (centre + half).tolist(),
            }
            out = [s for s in out if all(s is not e for e in ends)]
    return out


def _to_dict(
    robot: Any,
    end_effector_link: str | None,
    tool_offset: tuple[Any, Any] | None,
    name: str | None,
    collisions: dict[str, list[dict[str, Any]]] | None = None,
    mesh_hulls: Callable[[str], FloatArray | None] | None = None,
) -> dict[str, Any]:
    links = {link.name: link for link in robot.links}
    parent_joint: dict[str, Any] = {}
    children: dict[str, list[Any]] = {}
    for joint in robot.joints:
        for role, link_name in (("parent", joint.parent), ("child", joint.child)):
            if link_name not in links:
                raise UrdfError(_joint(joint.name), f"its {role} link {link_name!r} does not exist")
        if joint.child in parent_joint:
            raise UrdfError(_link(joint.child), f"is the child of two joints ({parent_joint[joint.child].name}, {joint.name})")
        parent_joint[joint.child] = joint
        children.setdefault(joint.parent, []).append(joint)
    roots = [link for link in links if link not in parent_joint]
    if len(roots) != 1:
        what = "no root link (the joints form a loop)" if not roots else f"{len(roots)} root links ({', '.join(roots)})"
        raise UrdfError("<robot>", f"the URDF must be one tree with one root link (the floating base); it has {what}")
    root = roots[0]

    # Bodies: each link's body (the link at its top) and its pose in the body frame at q = 0;
    # the links of each body, and the moving joints below each body, in one pass.
    body_of: dict[str, str] = {root: root}
    pose: dict[str, FloatArray] = {root: np.eye(4)}
    links_of: dict[str, list[str]] = {root: [root]}
    moving_below: dict[str, list[Any]] = {}
    order = deque([root])
    reached = 1
    while order:
        parent = order.popleft()
        for joint in children.get(parent, []):
            child = joint.child
            if joint.type == "fixed":
                body_of[child] = body_of[parent]
                pose[child] = pose[parent] @ _transform(joint.origin)
                links_of[body_of[child]].append(child)
            else:
                body_of[child] = child
                pose[child] = np.eye(4)
                links_of[child] = [child]
                moving_below.setdefault(body_of[parent], []).append(joint)
            order.append(child)
            reached += 1
    if reached != len(links):
        missing = sorted(set(links) - set(body_of))
        raise UrdfError(_link(missing[0]), "is not connected to the root link (the joints form a loop)")

    moving = [j for j in robot.joints if j.type in MOVING_TYPES]
    if end_effector_link is not None:
        if end_effector_link not in links:
            raise UrdfError(_link(end_effector_link), "end_effector_link: the URDF has no such link")
        chain: list[Any] = []
        body = body_of[end_effector_link]
        while body != root:
            joint = parent_joint[body]
            chain.append(joint)
            body = body_of[joint.parent]
        chain.reverse()
        on_chain = {j.name for j in chain}
        for joint in moving:
            if joint.name not in on_chain:
                raise UrdfError(
                    _joint(joint.name),
                    f"is a moving joint off the chain from {root!r} to end_effector_link {end_effector_link!r}: "
                    "a second moving branch (or joints beyond the end effector) is not supported",
                )
        ee_name = end_effector_link
    else:
        chain = []
        body = root
        while True:
            below = moving_below.get(body, [])
            if len(below) > 1:
                raise UrdfError(
                    _joint(below[1].name),
                    f"a second moving branch from the body of link {body!r} (besides joint {below[0].name!r}): "
                    "only serial chains are supported",
                )
            if not below:
                break
            chain.append(below[0])
            body = below[0].child
        leaves = [link for link in links_of[body] if not children.get(link)]
        if len(leaves) != 1:
            raise UrdfError(
                _link(body),
                f"the last body has {len(leaves)} leaf links ({', '.join(leaves)}): name one as end_effector_link",
            )
        ee_name = leaves[0]
    if not chain:
        raise UrdfError("<robot>", "no revolute, continuous or prismatic joint between the root link and the end effector")

    # Bodies' inertial properties in their frames, then the model's frames (parallel at q = 0).
    def members(top: str) -> list[tuple[Any, FloatArray]]:
        return [(links[k], pose[k]) for k in links_of[top]]  # the body's own link first

    collisions = collisions or {}

    def body_shapes(top: str, U: FloatArray, com: FloatArray) -> list[dict[str, Any]]:
        out: list[dict[str, Any]] = []
        for k in links_of[top]:
            out += _collision_shapes(collisions.get(k, []), pose[k], U, com, _link(k), mesh_hulls)
        return out

    base_mass, base_com, base_inertia = _body_inertia(members(root), _link(root), moving=False)
    U = np.eye(3)
    prev_com = base_com
    params_links: list[dict[str, Any]] = []
    b_prev: FloatArray | None = None
    for joint in chain:
        X = pose[joint.parent] @ _transform(joint.origin)  # joint frame in the parent body's frame, q = 0
        b_vec = U @ (X[:3, 3] - prev_com)
        if params_links:
            params_links[-1]["b"] = b_vec.tolist()
        else:
            b_prev = b_vec
        U = U @ X[:3, :3]
        axis = np.asarray(joint.axis if joint.axis is not None else (1.0, 0.0, 0.0), dtype=float)
        mass, com, inertia = _body_inertia(members(joint.child), _link(joint.child), moving=True)
        entry: dict[str, Any] = {
            "name": joint.child,
            "joint_name": joint.name,
            "joint_type": "prismatic" if joint.type == "prismatic" else "revolute",
            "mass": mass,
            "joint_axis": (U @ (axis / np.linalg.norm(axis))).tolist(),
            "a": (U @ com).tolist(),
            "b": [0.0, 0.0, 0.0],
            "inertia": (U @ inertia @ U.T).tolist(),
        }
        limits = _limits(joint)
        if limits is not None:
            entry["limits"] = limits
        effort = _effort(joint)
        if effort is not None:
            entry["force_limit_n" if joint.type == "prismatic" else "torque_limit_n_m"] = effort
        shapes = body_shapes(joint.child, U, com)
        if shapes:
            entry["collision_shapes"] = shapes
        params_links.append(entry)
        prev_com = com
    T_ee = pose[ee_name]
    label = ee_name
    if tool_offset is not None:
        position, rotation = tool_offset
        p = np.asarray(position, dtype=float)
        R = np.asarray(rotation, dtype=float)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise UrdfError("tool_offset", "the tool position must be 3 finite numbers (m)")
        if not is_rotation(R):
            raise UrdfError("tool_offset", "the tool rotation must be a rotation matrix")
        tool = np.eye(4)
        tool[:3, :3] = R
        tool[:3, 3] = p
        T_ee = T_ee @ tool
        # a name of its own: a link of the file may be called so already
        label = _unique(f"{ee_name}_tool", {link for names in links_of.values() for link in names})
    params_links[-1]["b"] = (U @ (T_ee[:3, 3] - prev_com)).tolist()
    assert b_prev is not None
    base: dict[str, Any] = {"name": root, "mass": base_mass, "inertia": base_inertia.tolist(), "b": b_prev.tolist()}
    base_shapes = body_shapes(root, np.eye(3), base_com)
    if base_shapes:
        base["collision_shapes"] = base_shapes
    return {
        "name": name or robot.name,
        "base": base,
        "links": params_links,
        "end_effector": {"name": label, "C_e": (U @ T_ee[:3, :3]).tolist()},
    }


def urdf_element(params: dict[str, Any], field: str) -> str:
    """The URDF element behind a field of the parameter set (``links[2].inertia`` -> the link
    of the third body)."""
    if field.startswith("links[") and "]" in field:
        index = int(field[len("links[") : field.index("]")])
        return _link(params["links"][index]["name"])
    if field.startswith("base"):
        return _link(params["base"].get("name", "base"))
    if field.startswith("end_effector"):
        return _link(params["end_effector"].get("name", "end_effector"))
    return "<robot>"


# --- writing ---------------------------------------------------------------------------


def _unique(name: str, taken: set[str]) -> str:
    candidate, k = name, 2
    while candidate in taken:
        candidate, k = f"{name}_{k}", k + 1
    taken.add(candidate)
    return candidate


def _origin(position: Any, rotation: Any = None) -> FloatArray:
    T = np.eye(4)
    T[:3, 3] = np.asarray(position, dtype=float)
    if rotation is not None:
        T[:3, :3] = np.asarray(rotation, dtype=float)
    return T


def dict_to_urdf(params: dict[str, Any], body_shapes: Sequence[Sequence[Shape]] = ()) -> str:
    """URDF text of a parameter set (:meth:`engine.model.RobotModel.to_dict`) with each body's
    collision shapes (``body_shapes``: the carrier's, then each link's, in the body's frame about
    its CoM; see the module docstring). Pinocchio and :func:`urdf_to_dict` read it back to the
    same model."""
    import yourdfpy
    from lxml import etree

    link_names: set[str] = set()
    joint_names: set[str] = set()
    base = params["base"]
    parent = _unique(base.get("name", "base"), link_names)
    body_links = [parent]
    robot = yourdfpy.Robot(name=params["name"])
    robot.links.append(
        yourdfpy.Link(
            name=parent,
            inertial=yourdfpy.Inertial(
                origin=np.eye(4), mass=float(base["mass"]), inertia=np.array(base["inertia"], dtype=float)
            ),
        )
    )
    offset = np.array(base["b"], dtype=float)
    for i, link in enumerate(params["links"]):
        child = _unique(link.get("name") or f"link{i + 1}", link_names)
        body_links.append(child)
        limits = link.get("limits") or {}
        lower, upper = limits.get("lower"), limits.get("upper")
        kind = link.get("joint_type", "revolute")
        effort = link.get("force_limit_n" if kind == "prismatic" else "torque_limit_n_m")
        effort = 0.0 if effort is None else float(effort)
        if kind == "revolute" and lower is None and upper is None:
            kind = "continuous"  # a continuous joint's <limit> carries its effort only
            limit = yourdfpy.Limit(effort=effort, velocity=0.0) if effort > 0.0 else None
        else:
            limit = yourdfpy.Limit(effort=effort, velocity=0.0, lower=lower, upper=upper)
        robot.links.append(
            yourdfpy.Link(
                name=child,
                inertial=yourdfpy.Inertial(
                    origin=_origin(link["a"]), mass=float(link["mass"]), inertia=np.array(link["inertia"], dtype=float)
                ),
            )
        )
        robot.joints.append(
            yourdfpy.Joint(
                name=_unique(link.get("joint_name") or f"joint{i + 1}", joint_names),
                type=kind,
                parent=parent,
                child=child,
                origin=_origin(offset),
                axis=np.array(link["joint_axis"], dtype=float),
                limit=limit,
            )
        )
        offset = np.array(link["a"], dtype=float) + np.array(link["b"], dtype=float)
        parent = child
    end_effector = params.get("end_effector") or {}
    ee = _unique(end_effector.get("name", "end_effector"), link_names)
    robot.links.append(yourdfpy.Link(name=ee))
    robot.joints.append(
        yourdfpy.Joint(
            name=_unique(f"{ee}_joint", joint_names),
            type="fixed",
            parent=parent,
            child=ee,
            origin=_origin(offset, end_effector.get("C_e", np.eye(3))),
        )
    )
    tree = yourdfpy.URDF(robot=robot, build_scene_graph=False, load_meshes=False).write_xml()
    elements = {element.get("name"): element for element in tree.getroot().iter("link")}
    # the link frame is at the joint, the CoM at `a`; the carrier's frame is at its CoM
    coms = [np.zeros(3), *(np.array(link["a"], dtype=float) for link in params["links"])]
    for element, com, shapes in zip([elements[name] for name in body_links], coms, body_shapes, strict=False):
        for shape in shapes:
            _write_collision(element, shape, com, etree)
    etree.indent(tree)
    return etree.tostring(tree, pretty_print=True, xml_declaration=True, encoding="UTF-8").decode("utf-8")


def _write_collision(link: Any, shape: Shape, com: FloatArray, etree: Any) -> None:
    """Append ``shape`` (in the body's frame about its CoM at ``com`` of the link frame) to the
    lxml ``link`` element as standard URDF: a capsule as a cylinder and a sphere at each end
    (:func:`_merged_capsules` reads them back as one capsule), a convex shape as a comment, since
    URDF carries meshes as files only."""

    def add(geometry: str, position: FloatArray, rotation: FloatArray | None = None, **numbers: Any) -> None:
        collision = etree.SubElement(link, "collision")
        origin = {"xyz": _text(com + position)}
        if rotation is not None:
            origin["rpy"] = _text(_rpy_of(rotation))
        etree.SubElement(collision, "origin", origin)
        etree.SubElement(etree.SubElement(collision, "geometry"), geometry, {k: _text(v) for k, v in numbers.items()})

    if shape.type == "sphere":
        add("sphere", shape.position, radius=shape.radius)
    elif shape.type == "box":
        add("box", shape.position, shape.rotation, size=2.0 * shape.dims)
    elif shape.type == "cylinder":
        add("cylinder", shape.position, shape.rotation, radius=shape.dims[0], length=2.0 * shape.dims[1])
    elif shape.type == "capsule":
        half = shape.dims[0] * shape.rotation[:, 2]
        add("cylinder", shape.position, shape.rotation, radius=shape.radius, length=2.0 * shape.dims[0])
        add("sphere", shape.position - half, radius=shape.radius)
        add("sphere", shape.position + half, radius=shape.radius)
    else:
        count = 0 if shape.vertices is None else shape.vertices.shape[0]
        link.append(
            etree.Comment(
                f" a convex collision shape of {count} vertices is not written: URDF carries meshes as files only "
                '(store the mesh, POST /v1/meshes, and name it <mesh filename="mesh://<its id>"/>) '
            )
        )


def _text(values: Any) -> str:
    """Numbers as URDF attribute text, each exactly (the shortest text that reads back to it)."""
    return " ".join(repr(float(v)) for v in np.atleast_1d(values))


def _rpy_of(R: FloatArray) -> FloatArray:
    """URDF's roll-pitch-yaw of a rotation matrix (the inverse of :func:`_rpy`)."""
    return -matrix_to_rpy_spacedyn(R)

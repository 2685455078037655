"""A stored plan's trajectory in the format asked for (:mod:`service.schemas.trajectories`):
JSON, CSV, MATLAB/Octave ``.mat``, numpy ``.npz`` or a ROS 2 ``JointTrajectory``, all written
from the plan's SI record.

CSV, MAT and NPZ hold the arrays of the JSON trajectory under the same names and in the same units
(:meth:`service.schemas.plans.Trajectory.arrays`). In CSV each column is one component of one of
them, named ``<array>[<component>]`` (``joint_angles_deg[joint1]``, ``base_position_m[x]``,
``ee_attitude_quaternion[w]``, ``singular_values[1]``); a joint's columns are those of its unit
(revolute joints in ``_deg``, prismatic ones in ``_m``), and an empty field is a value that is not
finite (null in JSON). Numbers are written as the shortest text that reads back to the same
double (Python's ``repr``), so a CSV reads back bit for bit."""

from __future__ import annotations

import csv
import io
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from service.errors import ConflictError, NotFoundError
from service.infra import jsonio
from service.infra.storage import unpack_trajectory
from service.models import Plan
from service.schemas.plans import Trajectory
from service.schemas.robots import model_of
from service.schemas.trajectories import EXTENSIONS, MEDIA_TYPES, RosJointTrajectory, first_non_finite
from service.usecases.figures import robot_parameters
from service.usecases.plans import record_from_storage

#: Names of the columns of the arrays with a fixed number of them.
COMPONENTS = {
    "base_position_m": ("x", "y", "z"),
    "ee_position_m": ("x", "y", "z"),
    "ee_position_desired_m": ("x", "y", "z"),
    "base_attitude_quaternion": ("w", "x", "y", "z"),
    "ee_attitude_quaternion": ("w", "x", "y", "z"),
    "ee_attitude_desired_quaternion": ("w", "x", "y", "z"),
    "mount_force_n": ("x", "y", "z"),
    "mount_torque_n_m": ("x", "y", "z"),
}
JOINT_ARRAYS = {
    "joint_angles_deg": False,
    "joint_velocities_deg_s": False,
    "joint_displacements_m": True,
    "joint_velocities_m_s": True,
    "joint_accelerations_deg_s2": False,
    "joint_accelerations_m_s2": True,
    "joint_torques_n_m": False,
    "joint_forces_n": True,
}


@dataclass(frozen=True)
class Export:
    """An exported trajectory: its bytes, media type and file name."""

    content: bytes
    media_type: str
    filename: str


def load(session: Session, plan_id: str) -> tuple[dict[str, np.ndarray], list[str]]:
    """A stored plan's SI record and its robot's joint names (``joint1`` ... when its robot is gone)."""
    row = session.scalar(select(Plan).where(Plan.id == plan_id))
    if row is None:
        raise NotFoundError("plan", plan_id)
    record = record_from_storage(unpack_trajectory(row.trajectory_data))
    n = record["q"].shape[1]
    parameters = robot_parameters(session, row)
    names = list(model_of(parameters).joint_names) if parameters is not None else []
    return record, names if len(names) == n else [f"joint{j + 1}" for j in range(n)]


def columns(record: dict[str, np.ndarray], joint_names: list[str]) -> Iterator[tuple[str, np.ndarray]]:
    """The CSV's columns in order: ``(header, values per sample)``."""
    prismatic = record["prismatic"].astype(bool)
    for name, values in Trajectory.arrays(record).items():
        if values.ndim == 1:
            yield name, values
        elif name in JOINT_ARRAYS:
            for j, joint in enumerate(joint_names):
                if prismatic[j] == JOINT_ARRAYS[name]:
                    yield f"{name}[{joint}]", values[:, j]
        else:
            labels = COMPONENTS.get(name) or tuple(str(i + 1) for i in range(values.shape[1]))
            for i, label in enumerate(labels):
                yield f"{name}[{label}]", values[:, i]


def _text(value: float) -> str:
    return repr(value) if value == value and abs(value) != float("inf") else ""


def to_csv(record: dict[str, np.ndarray], joint_names: list[str]) -> bytes:
    """One header row, then one row per sample."""
    header, data = zip(*columns(record, joint_names), strict=True)
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(header)
    writer.writerows([_text(v) for v in row] for row in np.column_stack(data).tolist())
    return buf.getvalue().encode()


def to_mat(record: dict[str, np.ndarray], joint_names: list[str], plan_id: str) -> bytes:
    """A MATLAB 5 ``.mat`` (MATLAB and Octave ``load``): the arrays as matrices (a sample per
    row, ``t_s`` a column), ``joint_names`` a cell array of strings, ``plan_id`` a string."""
    variables: dict[str, object] = dict(Trajectory.arrays(record))
    variables["joint_names"] = np.array(joint_names, dtype=object)
    variables["plan_id"] = plan_id
    buf = io.BytesIO()
    import scipy.io  # 0.35 s of imports: only for a .mat export

    scipy.io.savemat(buf, variables, do_compression=True, oned_as="column")
    return buf.getvalue()


def to_npz(record: dict[str, np.ndarray], joint_names: list[str]) -> bytes:
    """A compressed ``.npz``; ``joint_names`` is a unicode array (loads without pickle)."""
    buf = io.BytesIO()
    arrays: dict[str, Any] = {**Trajectory.arrays(record), "joint_names": np.array(joint_names)}
    np.savez_compressed(buf, **arrays)
    return buf.getvalue()


def to_ros(record: dict[str, np.ndarray], joint_names: list[str], plan_id: str) -> bytes:
    """A ``trajectory_msgs/JointTrajectory`` as JSON; a plan whose joints are not finite is a 409."""
    bad = first_non_finite(record)
    if bad is not None:
        raise ConflictError(
            f"plan {plan_id!r} is not finite from t = {bad:g} s (it diverged): it has no ROS joint trajectory; "
            "the other formats export it with nulls (empty CSV fields, NaN)"
        )
    return jsonio.dumps_large(RosJointTrajectory.from_record(record, joint_names).model_dump(mode="json"))


def encode(record: dict[str, np.ndarray], joint_names: list[str], fmt: str, plan_id: str) -> bytes:
    """A plan's record in ``fmt`` (a key of :data:`MEDIA_TYPES`)."""
    if fmt == "json":
        return jsonio.dumps_large(Trajectory.arrays(record))
    if fmt == "csv":
        return to_csv(record, joint_names)
    if fmt == "mat":
        return to_mat(record, joint_names, plan_id)
    if fmt == "npz":
        return to_npz(record, joint_names)
    return to_ros(record, joint_names, plan_id)


def export(session: Session, plan_id: str, fmt: str) -> Export:
    """The plan's trajectory in ``fmt`` (a key of :data:`MEDIA_TYPES`)."""
    record, joint_names = load(session, plan_id)
    session.rollback()  # done with the database: no transaction held while encoding
    return Export(encode(record, joint_names, fmt, plan_id), MEDIA_TYPES[fmt], f"plan-{plan_id}.{EXTENSIONS[fmt]}")

"""A plan's trajectory exported: the formats and their media types, and the ROS 2
``trajectory_msgs/JointTrajectory`` message (as JSON, in the message's own field names).

Every format is written from the plan's SI record (:func:`service.usecases.plans.record_of`):
``json`` is the plan's `trajectory` section (:class:`service.schemas.plans.Trajectory`), ``csv``,
``mat`` and ``npz`` hold the same arrays under the same names and units, ``ros`` the joint
positions and rates in SI units (rad, m, rad/s, m/s) as ROS expects them."""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import Field
from typing_extensions import TypeAliasType

from service.schemas.common import Output

TrajectoryFormat = TypeAliasType("TrajectoryFormat", Literal["json", "csv", "mat", "npz", "ros"])

#: Each format's media type, in the order the server prefers them when `Accept` allows several.
MEDIA_TYPES: dict[str, str] = {
    "json": "application/json",
    "csv": "text/csv",
    "mat": "application/x-matlab-data",
    "npz": "application/x-npz",
    "ros": "application/vnd.spacearm.ros-joint-trajectory+json",
}
#: The file name extension of each format (``Content-Disposition``).
EXTENSIONS = {"json": "json", "csv": "csv", "mat": "mat", "npz": "npz", "ros": "ros.json"}
assert set(MEDIA_TYPES) == set(TrajectoryFormat.__value__.__args__) == set(EXTENSIONS)


class RosTime(Output):
    """``builtin_interfaces/Duration`` (and ``Time``): whole seconds and nanoseconds, ``0 <= nanosec < 1e9``."""

    sec: int = Field(description="whole seconds, s")
    nanosec: int = Field(description="nanoseconds (1e-9 s), 0 to 999,999,999")

    @classmethod
    def of(cls, seconds: float) -> RosTime:
        """``seconds`` (>= 0) to the nearest nanosecond."""
        sec, nanosec = divmod(round(seconds * 1e9), 1_000_000_000)
        return cls(sec=int(sec), nanosec=int(nanosec))


class RosHeader(Output):
    """``std_msgs/Header``: a zero stamp (start on receipt) and no frame (joint space)."""

    stamp: RosTime = Field(description="when to start; zero: as soon as it is received")
    frame_id: str = Field(description="empty: a joint trajectory has no frame")


class RosJointTrajectoryPoint(Output):
    """``trajectory_msgs/JointTrajectoryPoint``, SI units."""

    positions: list[float] = Field(description="joint positions in the order of `joint_names`: rad (revolute), m (prismatic)")
    velocities: list[float] = Field(
        description="joint rates: rad/s, m/s; the rate the plan commands from this sample to the next (0 at the last)"
    )
    accelerations: list[float] = Field(
        description="joint accelerations of the executed trajectory, rad/s^2 or m/s^2 (empty: a plan stored before "
        "its dynamics were computed)"
    )
    effort: list[float] = Field(
        description="joint torques (N m) or forces (N) along the executed trajectory (empty: a plan stored before "
        "its dynamics were computed)"
    )
    time_from_start: RosTime = Field(description="the sample's time since the start")


class RosJointTrajectory(Output):
    """``trajectory_msgs/JointTrajectory`` (ROS 2) as JSON, with the message's field names: one
    point per sample of the plan."""

    header: RosHeader = Field(description="the message header")
    joint_names: list[str] = Field(description="the robot's joints, in the order of each point's values")
    points: list[RosJointTrajectoryPoint] = Field(description="one point per sample of the plan")

    @classmethod
    def from_record(cls, record: dict[str, np.ndarray], joint_names: list[str]) -> RosJointTrajectory:
        """The message of a plan's SI record (finite joints only: the caller checks)."""
        q, qd = record["q"].tolist(), record["qd"].tolist()
        n = len(q)
        known = (
            "qdd" in record and "tau" in record and bool(np.isfinite(record["qdd"]).all() and np.isfinite(record["tau"]).all())
        )
        qdd: list[list[float]] = record["qdd"].tolist() if known else [[] for _ in range(n)]
        tau: list[list[float]] = record["tau"].tolist() if known else [[] for _ in range(n)]
        return cls(
            header=RosHeader(stamp=RosTime(sec=0, nanosec=0), frame_id=""),
            joint_names=joint_names,
            points=[
                RosJointTrajectoryPoint(
                    positions=q[k], velocities=qd[k], accelerations=qdd[k], effort=tau[k], time_from_start=RosTime.of(t)
                )
                for k, t in enumerate(record["t"].tolist())
            ],
        )


def first_non_finite(record: dict[str, np.ndarray]) -> float | None:
    """The time of the first sample whose joint positions or rates are not finite, or None."""
    bad = ~(np.isfinite(record["q"]).all(axis=1) & np.isfinite(record["qd"]).all(axis=1))
    if not bad.any():
        return None
    t = float(record["t"][int(np.argmax(bad))])
    return t if math.isfinite(t) else math.nan

"""Robots: parameter sets, URDF documents, joints, the GJM at a state."""

from __future__ import annotations

from datetime import datetime

from pydantic import (
    ConfigDict,
    Field,
)

from engine.trajectory import PAPER_Q0_DEG
from engine.urdf import MAX_URDF_BYTES
from service.schemas.common import (
    DET_UNITS,
    Inertia,
    Input,
    JointType,
    JointUnit,
    JointValues,
    LimitValue,
    Mass,
    Output,
    Quaternion,
    Rotation,
    Vec3,
)

# --- robots -------------------------------------------------------------------------------


class BaseParams(Input):
    name: str | None = Field(default=None, max_length=200, description="the base link's name (default `base`)")
    mass: Mass
    inertia: Inertia = Field(description="kg m^2 about the base CoM, base frame")
    b: Vec3 = Field(description="m, base CoM to joint 1, base frame")


class JointLimits(Input):
    lower: LimitValue | None = Field(default=None, description="rad (revolute) or m (prismatic); null: unlimited below")
    upper: LimitValue | None = Field(default=None, description="rad (revolute) or m (prismatic); null: unlimited above")


class LinkParams(Input):
    name: str | None = Field(default=None, max_length=200, description="the link's name (for reports only)")
    mass: Mass
    joint_type: JointType = Field(
        default="revolute", description="revolute: q in rad about joint_axis; prismatic: q in m along it"
    )
    joint_name: str | None = Field(default=None, max_length=200, description="the joint's name (default `joint<i>`)")
    joint_axis: Vec3 = Field(
        description="joint axis in the link frame, a direction (dimensionless; normalised, must not be zero)"
    )
    a: Vec3 = Field(description="m, joint i to link i CoM (at q = 0), link frame")
    b: Vec3 = Field(description="m, link i CoM to joint i+1 (or the end effector), link frame")
    inertia: Inertia = Field(description="kg m^2 about the link CoM, link frame")
    limits: JointLimits | None = Field(default=None, description="position limits (SI); null: unlimited")


class EndEffectorParams(Input):
    name: str | None = Field(default=None, max_length=200, description="the end-effector frame's name")
    C_e: Rotation = Field(description="end-effector frame in the last link's frame (rotation matrix)")


class RobotParams(Input):
    """A robot parameter set in the schema of ``robot-table1.yaml`` (SI units)."""

    name: str = Field(min_length=1, max_length=200, description="the robot's name")
    base: BaseParams = Field(description="the free-floating base (carrier)")
    links: list[LinkParams] = Field(min_length=1, max_length=12, description="the links from the base out, one per joint")
    end_effector: EndEffectorParams | None = Field(
        default=None, description="the end-effector frame (default: the last link's frame)"
    )


class RobotUrdfIn(Input):
    """A robot from a URDF file, sent as text in the JSON body (``urdf``): the root link is the
    floating base, fixed joints are merged, the chain runs to ``end_effector_link``."""

    model_config = ConfigDict(
        allow_inf_nan=False,
        json_schema_extra={"examples": [{"urdf": "<robot name='my-arm'>...</robot>", "end_effector_link": "tool0"}]},
    )

    urdf: str = Field(min_length=1, max_length=MAX_URDF_BYTES, description="the URDF document (XML text, no DTD)")
    end_effector_link: str | None = Field(
        default=None, max_length=200, description="the end-effector link; default: the only leaf after the last moving joint"
    )
    tool_position_m: Vec3 | None = Field(default=None, description="tool offset: position in end_effector_link's frame, m")
    tool_attitude_quaternion: Quaternion | None = Field(
        default=None, description="tool offset: attitude in end_effector_link's frame [w, x, y, z] (default identity)"
    )
    name: str | None = Field(default=None, min_length=1, max_length=200, description="the robot's name (default: the URDF's)")


class JointOut(Output):
    """A joint of a stored robot, with the unit of its position in the API and its limits."""

    name: str = Field(description="the joint's name")
    type: JointType = Field(description="revolute or prismatic")
    unit: JointUnit = Field(description="the unit of its position in the API: `_deg` or `_m` lists")
    lower_deg: float | None = Field(default=None, description="revolute joints: lower position limit, deg (null: unlimited)")
    upper_deg: float | None = Field(default=None, description="revolute joints: upper position limit, deg (null: unlimited)")
    lower_m: float | None = Field(default=None, description="prismatic joints: lower position limit, m (null: unlimited)")
    upper_m: float | None = Field(default=None, description="prismatic joints: upper position limit, m (null: unlimited)")


class RobotOut(Output):
    id: str = Field(description="the robot's id (`table1` for the paper's robot)")
    name: str = Field(description="the robot's name")
    preset: bool = Field(description="a preset shipped with the service (cannot be deleted)")
    n_joints: int = Field(description="number of joints (and links)")
    parameters: RobotParams = Field(
        description="the parameter set, SI units, normalised (joint axes of unit length); derived from the URDF for URDF robots"
    )
    joints: list[JointOut] = Field(default_factory=list, description="the joints in chain order, with their units and limits")
    notes: list[str] = Field(default_factory=list, description="what the service assumed, e.g. joints without limits")
    created_at: datetime = Field(description="when it was stored (UTC)")


class RobotList(Output):
    items: list[RobotOut] = Field(description="this page of robots, oldest first")
    total: int = Field(description="number of robots stored")


class JacobianRequest(Input):
    """A state of the robot: its joint positions and the base pose."""

    joint_angles_deg: JointValues | None = Field(
        default=None, description="revolute joint angles, deg (null at prismatic joints)", examples=[list(PAPER_Q0_DEG)]
    )
    joint_displacements_m: JointValues | None = Field(
        default=None, description="prismatic joint positions, m (null at revolute joints)"
    )
    base_position_m: Vec3 | None = Field(default=None, description="base CoM in world, m (default origin)")
    base_attitude_quaternion: Quaternion | None = Field(default=None, description="base attitude [w, x, y, z] (default identity)")


class JacobianOut(Output):
    gjm: list[list[float]] = Field(description="6 x n generalized Jacobian: joint rates (rad/s) to [v (m/s); w (rad/s)]")
    singular_values: list[float] = Field(
        description="singular values of the GJM, descending (units of the GJM: m/rad for the linear rows, 1 for the angular)"
    )
    determinant: float | None = Field(description=f"det of the GJM, {DET_UNITS}; null unless it is square")
    manipulability: float = Field(
        description=f"the product of the singular values (sqrt(det(J J^T)) for 6 or more joints), {DET_UNITS}"
    )
    condition_number: float | None = Field(
        description="largest over smallest singular value (dimensionless); null if the GJM is singular"
    )
    ee_position_m: list[float] = Field(description="end-effector position, m (world)")
    ee_attitude_quaternion: list[float] = Field(description="end-effector attitude [w, x, y, z] (end effector -> world)")

"""Request and response bodies (pydantic). SI units; angles in degrees only where a name ends
in ``_deg`` (or ``_deg_s``); quaternions are ``[w, x, y, z]``.

Joint positions come in two index-aligned lists, one per unit: ``..._deg`` holds the revolute
joints (deg) and ``..._m`` the prismatic ones (m), each with null at the joints of the other
type (a list may be left out when the robot has no joint of its unit). So an all-revolute robot
keeps its plain ``q0_deg`` list."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal, get_args

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationInfo, field_validator

from engine.metrics import AGGREGATIONS, ATTITUDE_TERMS, check_weights
from engine.redundancy import MAX_CENTERING_GAIN
from engine.spatial import matrix_to_quaternion, rpy_spacedyn_to_matrix
from engine.trajectory import MAX_DURATION_S, PAPER_Q0_DEG, PAPER_TARGET_POSITION, PAPER_TARGET_RPY
from engine.tuning import MAX_BITS_PER_GENE, MAX_GENERATIONS, MAX_POPULATION
from engine.urdf import MAX_URDF_BYTES

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]
#: Joint positions of one unit, index-aligned with the robot's joints (null: a joint of the other unit).
JointValues = Annotated[list[float | None], Field(min_length=1, max_length=12)]
Quaternion = Annotated[list[float], Field(min_length=4, max_length=4, description="unit quaternion [w, x, y, z]")]
Matrix3 = Annotated[list[Vec3], Field(min_length=3, max_length=3)]

# The objective's options, as the engine defines them (checked below so the two cannot drift).
AggregationName = Literal["max", "rms", "final"]
AttitudeTermName = Literal["angle", "eq18"]
assert set(get_args(AggregationName)) == set(AGGREGATIONS) and set(get_args(AttitudeTermName)) == set(ATTITUDE_TERMS)
AttitudeTerm = Annotated[
    AttitudeTermName,
    Field(
        description="attitude term of B: `angle` = rotation angle (rad); `eq18` = the paper's eq. 18 as printed, "
        "sqrt(sum (dp_i dphi_i)^2) (m rad), which reproduces the paper's B values"
    ),
]


def _weights(value: list[float]) -> list[float]:
    return list(check_weights(value))


Weights = Annotated[
    list[float],
    Field(min_length=2, max_length=2, description="(w1, w2) of B: finite, >= 0, not both zero"),
    AfterValidator(_weights),
]

PAPER_TARGET_QUATERNION = [round(float(x), 12) for x in matrix_to_quaternion(rpy_spacedyn_to_matrix(PAPER_TARGET_RPY))]

PAPER_TASK_EXAMPLE: dict[str, Any] = {
    "q0_deg": list(PAPER_Q0_DEG),
    "target_position_m": list(PAPER_TARGET_POSITION),
    "target_attitude_quaternion": PAPER_TARGET_QUATERNION,
    "duration_s": 15.0,
    "ramp_time_s": 1.5,
    "dt_s": 0.25,
    "profile": "trapezoidal",
    "joint_speed_limit_deg_s": 6.0,
}


class Input(BaseModel):
    """A request body: every number must be finite (NaN and infinities, which JSON parsers accept
    as ``NaN``/``Infinity`` literals or overflow to, are rejected with the field path)."""

    model_config = ConfigDict(allow_inf_nan=False)


# --- robots -------------------------------------------------------------------------------


class BaseParams(Input):
    name: str | None = Field(default=None, max_length=200, description="the base link's name (default `base`)")
    mass: float = Field(description="kg")
    inertia: Matrix3 = Field(description="kg m^2 about the base CoM, base frame")
    b: Vec3 = Field(description="m, base CoM to joint 1, base frame")


class JointLimits(Input):
    lower: float | None = Field(default=None, description="rad (revolute) or m (prismatic); null: unlimited below")
    upper: float | None = Field(default=None, description="rad (revolute) or m (prismatic); null: unlimited above")


class LinkParams(Input):
    name: str | None = None
    mass: float = Field(description="kg")
    joint_type: Literal["revolute", "prismatic"] = Field(
        default="revolute", description="revolute: q in rad about joint_axis; prismatic: q in m along it"
    )
    joint_name: str | None = Field(default=None, max_length=200, description="the joint's name (default `joint<i>`)")
    joint_axis: Vec3 = Field(description="unit joint axis in the link frame")
    a: Vec3 = Field(description="m, joint i to link i CoM (at q = 0), link frame")
    b: Vec3 = Field(description="m, link i CoM to joint i+1 (or the end effector), link frame")
    inertia: Matrix3 = Field(description="kg m^2 about the link CoM, link frame")
    limits: JointLimits | None = Field(default=None, description="position limits (SI); null: unlimited")


class EndEffectorParams(Input):
    name: str | None = Field(default=None, max_length=200, description="the end-effector frame's name")
    C_e: Matrix3 = Field(description="end-effector frame in the last link's frame (rotation matrix)")


class RobotParams(Input):
    """A robot parameter set in the schema of ``robot-table1.yaml`` (SI units)."""

    model_config = ConfigDict(extra="allow", allow_inf_nan=False)

    name: str = Field(min_length=1, max_length=200)
    base: BaseParams
    links: list[LinkParams] = Field(min_length=1, max_length=12)
    end_effector: EndEffectorParams | None = None


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


class JointOut(BaseModel):
    name: str
    type: Literal["revolute", "prismatic"]
    unit: Literal["deg", "m"] = Field(description="the unit of its position in the API: `_deg` or `_m` lists")
    lower_deg: float | None = Field(default=None, description="revolute joints: lower position limit, deg (null: unlimited)")
    upper_deg: float | None = None
    lower_m: float | None = Field(default=None, description="prismatic joints: lower position limit, m (null: unlimited)")
    upper_m: float | None = None


class RobotOut(BaseModel):
    id: str
    name: str
    preset: bool
    n_joints: int
    parameters: dict[str, Any] = Field(description="the parameter set (SI units; derived from the URDF for URDF robots)")
    joints: list[JointOut] = Field(default_factory=list, description="the joints in chain order, with their units and limits")
    notes: list[str] = Field(default_factory=list, description="what the service assumed, e.g. joints without limits")
    created_at: datetime


class RobotList(BaseModel):
    items: list[RobotOut]
    total: int


class JacobianRequest(Input):
    joint_angles_deg: JointValues | None = Field(
        default=None, description="revolute joint angles, deg (null at prismatic joints)", examples=[list(PAPER_Q0_DEG)]
    )
    joint_displacements_m: JointValues | None = Field(
        default=None, description="prismatic joint positions, m (null at revolute joints)"
    )
    base_position_m: Vec3 | None = Field(default=None, description="base CoM in world, m (default origin)")
    base_attitude_quaternion: Quaternion | None = Field(default=None, description="base attitude [w, x, y, z] (default identity)")


class JacobianOut(BaseModel):
    gjm: list[list[float]] = Field(description="6 x n generalized Jacobian: joint rates (rad/s) to [v (m/s); w (rad/s)]")
    singular_values: list[float]
    determinant: float | None = Field(description="det of the GJM; null unless it is square")
    manipulability: float
    condition_number: float | None
    ee_position_m: list[float]
    ee_attitude_quaternion: list[float]


# --- tasks --------------------------------------------------------------------------------


class TaskIn(Input):
    """A point-to-point Cartesian task; the start pose is the forward kinematics of ``q0_deg``
    with the base at rest at the origin."""

    model_config = ConfigDict(json_schema_extra={"examples": [PAPER_TASK_EXAMPLE]}, allow_inf_nan=False)

    q0_deg: JointValues | None = Field(
        default=None, description="initial joint angles of the revolute joints, deg (null at prismatic joints)"
    )
    q0_m: JointValues | None = Field(
        default=None, description="initial positions of the prismatic joints, m (null at revolute joints)"
    )
    tracks: Literal["pose", "position"] = Field(
        default="pose",
        description="what the plan follows: the whole `pose` (needs 6 joints or more) or the `position` only (3 or more)",
    )
    target_position_m: Vec3 = Field(description="target end-effector position, m")
    target_attitude_quaternion: Quaternion | None = Field(
        default=None,
        description="target end-effector attitude [w, x, y, z]; required for pose tasks (position tasks keep the start one)",
    )
    duration_s: float = Field(default=15.0, gt=0, le=MAX_DURATION_S, description="s")
    ramp_time_s: float = Field(default=1.5, ge=0, le=300, description="s, trapezoidal profile only; at most duration_s / 2")
    dt_s: float = Field(default=0.25, gt=0, le=1, description="planner step, s")
    profile: Literal["trapezoidal", "quintic"] = "trapezoidal"
    joint_speed_limit_deg_s: float = Field(default=6.0, gt=0, description="symmetric speed limit of the revolute joints, deg/s")
    joint_speed_limit_m_s: float | None = Field(
        default=None, gt=0, description="symmetric speed limit of the prismatic joints, m/s (null: none)"
    )


class TaskPreset(BaseModel):
    name: str
    description: str
    robot_id: str
    task: TaskIn


class TaskPresetList(BaseModel):
    items: list[TaskPreset]
    total: int


# --- plans --------------------------------------------------------------------------------


class MethodIn(Input):
    name: str = Field(default="adaptive", description="inverse: inverse, dls, adaptive, wdls, sdls, svf")
    params: dict[str, float] = Field(default_factory=dict, description="method parameters; missing ones take defaults")


class SecondaryIn(Input):
    """A secondary objective in the null space of a redundant arm (more joints than the task
    tracks: 7+ for a pose, 4+ for a position)."""

    objective: Literal["min_base_rotation", "joint_centering"] = Field(
        description="`min_base_rotation`: keep the carrier's attitude still (reaction null space); "
        "`joint_centering`: pull the joints towards the middle of their limits"
    )
    gain: float | None = Field(
        default=None,
        ge=0,
        le=MAX_CENTERING_GAIN,
        description="min_base_rotation: in [0, 1] (1 = the full minimiser, default 1); joint_centering: 1/s (default 0.5)",
    )


class PlanRequest(Input):
    model_config = ConfigDict(
        allow_inf_nan=False,
        json_schema_extra={
            "examples": [
                {
                    "robot_id": "table1",
                    "task": PAPER_TASK_EXAMPLE,
                    "method": {"name": "adaptive", "params": {"lambda_max": 0.06, "epsilon": 0.12}},
                    "feedback_gain": 0.0,
                    "aggregation": "max",
                    "weights": [0.5, 0.5],
                    "replay": True,
                }
            ]
        },
    )

    robot_id: str | None = Field(default=None, description="a stored robot; or give `robot` inline")
    robot: RobotParams | None = Field(default=None, description="inline robot parameters (replace robot_id)")
    task: TaskIn
    method: MethodIn = Field(default_factory=MethodIn)
    feedback_gain: float = Field(default=0.0, ge=0, description="1/s, pose-error feedback added to the path twist")
    aggregation: AggregationName = "max"
    weights: Weights = [0.5, 0.5]
    attitude_term: AttitudeTerm = "angle"
    replay: bool = Field(default=True, description="re-integrate the plan with solve_ivp and report the gaps")
    secondary: SecondaryIn | None = Field(default=None, description="a null-space objective for a redundant arm")


class PlanMetrics(BaseModel):
    objective_b: float | None = Field(description="objective B (m + rad weighted); null when the speed limit is broken")
    position_error_max_m: float | None
    position_error_rms_m: float | None
    position_error_final_m: float | None
    attitude_error_max_rad: float | None
    attitude_error_rms_rad: float | None
    attitude_error_final_rad: float | None
    coupled_error_max_m_rad: float | None = Field(default=None, description="eq. 18 as printed: sqrt(sum (dp_i dphi_i)^2)")
    coupled_error_rms_m_rad: float | None = None
    coupled_error_final_m_rad: float | None = None
    attitude_term: AttitudeTermName = "angle"
    max_joint_speed_deg_s: float | None
    joint_speed_limit_deg_s: float | None = None
    joint_speed_limit_respected: bool
    min_singular_value: float | None
    time_of_min_singular_value_s: float | None
    min_abs_det_gjm: float | None = Field(description="of the tracked rows of the GJM when they are square; else null")
    time_of_min_abs_det_gjm_s: float | None
    tracks: Literal["pose", "position"] = "pose"
    max_linear_joint_speed_m_s: float | None = Field(default=None, description="prismatic joints (0 without any)")
    joint_speed_limit_m_s: float | None = None
    position_limits_respected: bool | None = None
    position_limit_joint: int | None = Field(default=None, description="the first joint (1-based) found outside its limits")
    time_position_limit_left_s: float | None = None
    base_attitude_change_max_rad: float | None = Field(default=None, description="the carrier's largest rotation from its start")
    base_attitude_change_final_rad: float | None = None


class Trajectory(BaseModel):
    t_s: list[float]
    joint_angles_deg: list[list[float | None]] = Field(description="revolute joints, deg (null in prismatic columns)")
    joint_velocities_deg_s: list[list[float | None]]
    joint_displacements_m: list[list[float | None]] | None = Field(
        default=None, description="prismatic joints, m (null in revolute columns); only for robots with prismatic joints"
    )
    joint_velocities_m_s: list[list[float | None]] | None = None
    base_position_m: list[list[float | None]]
    base_attitude_quaternion: list[list[float | None]]
    ee_position_m: list[list[float | None]]
    ee_position_desired_m: list[list[float | None]]
    ee_attitude_quaternion: list[list[float | None]]
    ee_attitude_desired_quaternion: list[list[float | None]]
    singular_values: list[list[float | None]]
    det_gjm: list[float | None]
    damping: list[list[float | None]]
    position_error_m: list[float | None]
    attitude_error_rad: list[float | None]


class ReplayOut(BaseModel):
    success: bool
    message: str
    path_position_error_max_m: float | None
    path_position_error_final_m: float | None
    path_attitude_error_max_rad: float | None
    path_attitude_error_final_rad: float | None
    plan_gap_position_max_m: float | None
    plan_gap_attitude_max_rad: float | None
    base_attitude_gap_max_rad: float | None
    linear_momentum_residual_max_n_s: float | None
    angular_momentum_residual_max_n_m_s: float | None
    com_drift_max_m: float | None


class PlanSummary(BaseModel):
    id: str
    robot_id: str | None
    method: dict[str, Any]
    success: bool
    message: str
    metrics: PlanMetrics
    elapsed_s: float
    created_at: datetime


PLAN_SECTIONS = ("trajectory", "replay")


class PlanOut(PlanSummary):
    """A plan: the summary, and the sections asked for with ``fields`` (all by default)."""

    trajectory: Trajectory | None = Field(
        default=None, description="every sample of the plan (left out when `fields` does not name it)"
    )
    replay: ReplayOut | None = Field(default=None, description="the independent replay's checks; null if not replayed")


class PlanList(BaseModel):
    items: list[PlanSummary]
    total: int


# --- tuning jobs --------------------------------------------------------------------------

JobStatus = Literal["queued", "running", "succeeded", "failed", "cancelled"]


class GASettings(Input):
    population: int = Field(default=40, ge=2, le=MAX_POPULATION)
    generations: int = Field(default=50, ge=1, le=MAX_GENERATIONS)
    crossover_probability: float = Field(default=0.8, ge=0, le=1)
    mutation_probability: float = Field(default=0.02, ge=0, le=1, description="per-bit flip probability")
    bits_per_gene: int = Field(default=16, ge=2, le=MAX_BITS_PER_GENE)
    elitism: int = Field(default=1, ge=0, description="best individuals kept unchanged; < population")
    seed: int | None = Field(default=0, ge=0, description="null for a random seed")

    @field_validator("elitism")
    @classmethod
    def _elitism_below_population(cls, value: int, info: ValidationInfo) -> int:
        population = info.data.get("population")
        if population is not None and value >= population:
            raise ValueError(f"must be smaller than population ({population})")
        return value


class ObjectiveSettings(Input):
    weights: Weights = [0.5, 0.5]
    aggregation: AggregationName = "max"
    attitude_term: AttitudeTerm = "angle"
    task_aggregation: Literal["mean", "max"] = "mean"


class TuningJobRequest(Input):
    model_config = ConfigDict(
        allow_inf_nan=False,
        json_schema_extra={
            "examples": [
                {
                    "robot_id": "table1",
                    "tasks": [PAPER_TASK_EXAMPLE],
                    "method": "adaptive",
                    "bounds": {"lambda_max": [0.0001, 0.2], "epsilon": [0.0001, 0.3]},
                    "ga": {
                        "population": 40,
                        "generations": 50,
                        "crossover_probability": 0.8,
                        "mutation_probability": 0.02,
                        "bits_per_gene": 16,
                        "elitism": 1,
                        "seed": 1,
                    },
                    "objective": {"weights": [0.5, 0.5], "aggregation": "max"},
                    "compare_with_dls": True,
                }
            ]
        },
    )

    robot_id: str | None = Field(default=None, description="a stored robot; or give `robot` inline")
    robot: RobotParams | None = None
    tasks: list[TaskIn] = Field(min_length=1, max_length=20)
    method: str = Field(default="adaptive", description="the inverse to tune (a method with parameters)")
    bounds: dict[str, Annotated[list[float], Field(min_length=2, max_length=2)]] | None = Field(
        None, description="search interval [lo, hi] per parameter; missing parameters take default bounds"
    )
    ga: GASettings = Field(default_factory=GASettings)
    objective: ObjectiveSettings = Field(default_factory=ObjectiveSettings)
    feedback_gain: float = Field(default=0.0, ge=0)
    compare_with_dls: bool = Field(default=True, description="also tune constant-damping DLS with the same GA settings")


class JobProgress(BaseModel):
    generation: int = 0
    generations: int = 0
    evaluations: int = 0
    best_objective_b: float | None = None
    best_params: dict[str, float] | None = None
    phase: str | None = Field(default=None, description="which GA is running: the tuned method or the dls baseline")


class TuningJobOut(BaseModel):
    id: str
    status: JobStatus
    robot_id: str | None
    method: str
    progress: JobProgress
    attempts: int
    max_attempts: int
    cancel_requested: bool
    error: str | None
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None


class TuningJobList(BaseModel):
    items: list[TuningJobOut]
    total: int


class HistoryRecord(BaseModel):
    generation: int
    best: float | None
    mean: float | None
    feasible: int


class DLSBaseline(BaseModel):
    lambda_: float | None = Field(alias="lambda", serialization_alias="lambda")
    objective_b: float | None

    model_config = ConfigDict(populate_by_name=True)


class TuningJobResult(BaseModel):
    best_params: dict[str, float]
    best_objective_b: float | None
    best_metrics: list[PlanMetrics] = Field(description="metrics of the best parameters, one per task")
    history: list[HistoryRecord]
    evaluations: int
    elapsed_s: float
    dls_baseline: DLSBaseline | None
    improvement_over_dls_percent: float | None


class Health(BaseModel):
    status: str
    kernels: str | None = Field(default=None, description="the engine's compiled kernels: loading, ok or failed: ...")
    database: str | None = None
    revision: str | None = None
    head: str | None = None

"""Request and response bodies (pydantic). SI units; angles in degrees only where a name ends
in ``_deg`` (or ``_deg_s``); quaternions are ``[w, x, y, z]``."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal, get_args

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationInfo, field_validator, model_validator

from engine.metrics import AGGREGATIONS, ATTITUDE_TERMS, check_weights
from engine.spatial import matrix_to_quaternion, rpy_spacedyn_to_matrix
from engine.trajectory import MAX_DURATION_S, MIN_DT_S, PAPER_Q0_DEG, PAPER_TARGET_POSITION, PAPER_TARGET_RPY
from engine.tuning import MAX_BITS_PER_GENE, MAX_GENERATIONS, MAX_POPULATION

# Every number in a request is bounded (an overflow inside the engine is ruled out by the schema).
MAX_LENGTH_M = 1e3
MAX_ANGLE_DEG = 36_000.0  # a hundred turns
MAX_INERTIA = 1e12  # kg m^2
MAX_MASS_KG = 1e9
MAX_MAGNITUDE = 1e6  # method parameters, gains, weights, quaternion components
Length = Annotated[float, Field(ge=-MAX_LENGTH_M, le=MAX_LENGTH_M)]
AngleDeg = Annotated[float, Field(ge=-MAX_ANGLE_DEG, le=MAX_ANGLE_DEG)]
Magnitude = Annotated[float, Field(ge=-MAX_MAGNITUDE, le=MAX_MAGNITUDE)]
Mass = Annotated[float, Field(gt=0, le=MAX_MASS_KG, description="kg")]
Vec3 = Annotated[list[Length], Field(min_length=3, max_length=3)]
Quaternion = Annotated[
    list[Magnitude],
    Field(min_length=4, max_length=4, description="unit quaternion [w, x, y, z] (normalised; must not be zero)"),
]
InertiaRow = Annotated[list[Annotated[float, Field(ge=-MAX_INERTIA, le=MAX_INERTIA)]], Field(min_length=3, max_length=3)]
Inertia = Annotated[
    list[InertiaRow],
    Field(
        min_length=3,
        max_length=3,
        description="kg m^2; symmetric positive definite, each principal moment at most the sum of the others",
    ),
]
RotationRow = Annotated[list[Annotated[float, Field(ge=-1.000001, le=1.000001)]], Field(min_length=3, max_length=3)]
Rotation = Annotated[list[RotationRow], Field(min_length=3, max_length=3, description="a rotation matrix (orthonormal, det +1)")]

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
    list[Annotated[float, Field(ge=0, le=MAX_MAGNITUDE)]],
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


def _no_nul(value: Any) -> Any:
    """Text must not contain NUL characters (PostgreSQL cannot store them; no field needs them)."""
    if isinstance(value, str):
        if "\x00" in value:
            raise ValueError("must not contain NUL characters (\\u0000)")
    elif isinstance(value, dict):
        for key, item in value.items():
            _no_nul(key)
            _no_nul(item)
    elif isinstance(value, list | tuple):
        for item in value:
            _no_nul(item)
    return value


class Input(BaseModel):
    """A request body, strictly typed: every number must be finite (NaN and infinities, which
    JSON parsers accept as ``NaN``/``Infinity`` literals or overflow to, are rejected with the
    field path), no text for a number and no number for a boolean, no unknown fields, no NUL
    characters in text."""

    model_config = ConfigDict(allow_inf_nan=False, strict=True, extra="forbid")

    @field_validator("*", mode="after")
    @classmethod
    def _text_without_nul(cls, value: Any) -> Any:
        return _no_nul(value)


# --- robots -------------------------------------------------------------------------------


class BaseParams(Input):
    mass: Mass
    inertia: Inertia = Field(description="kg m^2 about the base CoM, base frame")
    b: Vec3 = Field(description="m, base CoM to joint 1, base frame")


class LinkParams(Input):
    name: str | None = Field(default=None, max_length=200)
    mass: Mass
    joint_axis: Vec3 = Field(description="joint axis in the link frame (normalised; must not be zero)")
    a: Vec3 = Field(description="m, joint i to link i CoM, link frame")
    b: Vec3 = Field(description="m, link i CoM to joint i+1 (or the end effector), link frame")
    inertia: Inertia = Field(description="kg m^2 about the link CoM, link frame")


class EndEffectorParams(Input):
    C_e: Rotation = Field(description="end-effector frame in the last link's frame (rotation matrix)")


class RobotParams(Input):
    """A robot parameter set in the schema of ``robot-table1.yaml`` (SI units)."""

    name: str = Field(min_length=1, max_length=200)
    base: BaseParams
    links: list[LinkParams] = Field(min_length=1, max_length=12)
    end_effector: EndEffectorParams | None = None


class RobotOut(BaseModel):
    id: str
    name: str
    preset: bool
    n_joints: int
    parameters: dict[str, Any]
    created_at: datetime


class RobotList(BaseModel):
    items: list[RobotOut]
    total: int


class JacobianRequest(Input):
    joint_angles_deg: list[AngleDeg] = Field(
        min_length=1, max_length=12, examples=[list(PAPER_Q0_DEG)], description="deg, one per joint of the robot"
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

    q0_deg: list[AngleDeg] = Field(
        min_length=1, max_length=12, description="initial joint angles, deg; one per joint of the robot"
    )
    target_position_m: Vec3 = Field(description="target end-effector position, m")
    target_attitude_quaternion: Quaternion = Field(description="target end-effector attitude [w, x, y, z]")
    duration_s: float = Field(default=15.0, gt=0, le=MAX_DURATION_S, description="s")
    ramp_time_s: float = Field(default=1.5, ge=0, le=300, description="s, trapezoidal profile only; at most duration_s / 2")
    dt_s: float = Field(default=0.25, ge=MIN_DT_S, le=1, description="planner step, s; duration_s / dt_s at most 20,000 steps")
    profile: Literal["trapezoidal", "quintic"] = "trapezoidal"
    joint_speed_limit_deg_s: float = Field(default=6.0, gt=0, le=MAX_MAGNITUDE, description="symmetric joint speed limit, deg/s")


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
    name: str = Field(default="adaptive", max_length=40, description="inverse: inverse, dls, adaptive, wdls, sdls, svf")
    params: dict[Annotated[str, Field(max_length=40)], Magnitude] = Field(
        default_factory=dict, max_length=4, description="method parameters; missing ones take defaults"
    )


class OneRobot(Input):
    """A request naming its robot: ``robot_id`` (a stored robot) or ``robot`` (inline), exactly
    one of the two (``oneOf`` in the schema)."""

    model_config = ConfigDict(json_schema_extra={"oneOf": [{"required": ["robot_id"]}, {"required": ["robot"]}]})

    @model_validator(mode="after")
    def _exactly_one(self) -> Any:
        if (getattr(self, "robot_id", None) is None) == (getattr(self, "robot", None) is None):
            raise ValueError("give exactly one of robot_id (a stored robot, e.g. 'table1') and robot (inline parameters)")
        return self

    def stored(self) -> dict[str, Any]:
        """The request as stored (JSON; the robot field not given is left out, as in the request)."""
        data = self.model_dump(mode="json")
        for name in ("robot_id", "robot"):
            if data.get(name) is None:
                data.pop(name, None)
        return data


class PlanRequest(OneRobot):
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

    # Optional but not nullable: left out when not used (a null is refused like any wrong type).
    robot_id: str = Field(  # type: ignore[assignment]
        default=None, min_length=1, max_length=64, description="a stored robot; or give `robot` inline (one of the two)"
    )
    robot: RobotParams = Field(default=None, description="inline robot parameters (instead of robot_id)")  # type: ignore[assignment]
    task: TaskIn
    method: MethodIn = Field(default_factory=MethodIn)
    feedback_gain: float = Field(
        default=0.0, ge=0, le=MAX_MAGNITUDE, description="1/s, pose-error feedback added to the path twist"
    )
    aggregation: AggregationName = "max"
    weights: Weights = [0.5, 0.5]
    attitude_term: AttitudeTerm = "angle"
    replay: bool = Field(default=True, description="re-integrate the plan with solve_ivp and report the gaps")


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
    min_abs_det_gjm: float | None
    time_of_min_abs_det_gjm_s: float | None


class Trajectory(BaseModel):
    t_s: list[float]
    joint_angles_deg: list[list[float | None]]
    joint_velocities_deg_s: list[list[float | None]]
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
    seed: int | None = Field(default=0, ge=0, le=2**63 - 1, description="null for a random seed")

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


class TuningJobRequest(OneRobot):
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

    # Optional but not nullable: left out when not used (a null is refused like any wrong type).
    robot_id: str = Field(  # type: ignore[assignment]
        default=None, min_length=1, max_length=64, description="a stored robot; or give `robot` inline (one of the two)"
    )
    robot: RobotParams = Field(default=None, description="inline robot parameters (instead of robot_id)")  # type: ignore[assignment]
    tasks: list[TaskIn] = Field(min_length=1, max_length=20)
    method: str = Field(default="adaptive", max_length=40, description="the inverse to tune (a method with parameters)")
    bounds: dict[Annotated[str, Field(max_length=40)], Annotated[list[Magnitude], Field(min_length=2, max_length=2)]] | None = (
        Field(None, max_length=4, description="search interval [lo, hi] per parameter; missing parameters take default bounds")
    )
    ga: GASettings = Field(default_factory=GASettings)
    objective: ObjectiveSettings = Field(default_factory=ObjectiveSettings)
    feedback_gain: float = Field(default=0.0, ge=0, le=MAX_MAGNITUDE, description="1/s, pose-error feedback")
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

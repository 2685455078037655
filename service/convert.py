"""Conversions between API bodies and the engine (degrees <-> radians, quaternions <-> matrices),
and JSON sanitising of small bodies (NaN and infinities become null)."""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from typing import Any

import numpy as np
from sqlalchemy.orm import Session

from engine import CartesianTask, Metrics, PlanResult, ReplayResult, RobotModel
from engine.errors import ParameterError
from engine.kinematics import as_state, forward_kinematics
from engine.paths import SpeedLimits, make_path
from engine.planner import check_task
from engine.spatial import matrix_to_quaternion, quaternion_to_matrix
from engine.trajectory import MAX_DURATION_S, start_pose
from engine.urdf import UrdfError
from service.errors import ApiValidationError, NotFoundError
from service.infra import jsonio
from service.models import Robot
from service.schemas.robots import RobotParams, RobotUrdfIn
from service.schemas.tasks import ArcPathIn, PathIn, RasterPathIn, TaskIn, WaypointsPathIn


def clean(value: Any) -> Any:
    """JSON-safe copy: numpy to lists, NaN/inf to None."""
    if isinstance(value, np.ndarray):
        return clean(value.tolist())
    if isinstance(value, dict):
        return {str(k): clean(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [clean(v) for v in value]
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, int | np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        v = float(value)
        return v if math.isfinite(v) else None
    return value


def field_path(field: str) -> list[str | int]:
    """``links[2].inertia`` -> ``["links", 2, "inertia"]``."""
    path: list[str | int] = []
    for part in field.replace("]", "").split("."):
        name, _, index = part.partition("[")
        path.append(name)
        if index:
            path.append(int(index))
    return path


_MODELS: OrderedDict[bytes, RobotModel] = OrderedDict()
_MODELS_LOCK = threading.Lock()
MODEL_CACHE_SIZE = 64


def robot_model(parameters: dict[str, Any], loc: tuple[str | int, ...] = ("body", "robot")) -> RobotModel:
    """The validated model of a parameter set. Models are immutable, so the last few are kept
    (keyed by their parameters), which spares stored robots the validation on every request."""
    key = jsonio.dumps_sorted(parameters)
    with _MODELS_LOCK:
        cached = _MODELS.get(key)
        if cached is not None:
            _MODELS.move_to_end(key)
            return cached
    try:
        model = RobotModel.from_dict(parameters)
    except ParameterError as exc:
        path = [*loc, *field_path(exc.field)]
        raise ApiValidationError(f"invalid robot parameters: {exc}", [{"loc": path, "msg": exc.reason}]) from None
    with _MODELS_LOCK:
        _MODELS[key] = model
        while len(_MODELS) > MODEL_CACHE_SIZE:
            _MODELS.popitem(last=False)
    return model


def resolve_robot(session: Session, robot_id: str | None, inline: RobotParams | None) -> tuple[str | None, RobotModel]:
    """The robot of a request: inline parameters win over ``robot_id`` (a stored robot)."""
    if inline is not None:
        return None, robot_model(inline.model_dump(exclude_none=True), ("body", "robot"))
    if robot_id is None:
        raise ApiValidationError(
            "give either robot_id (a stored robot, e.g. 'table1') or an inline robot",
            [{"loc": ["body", "robot_id"], "msg": "robot_id or robot is required"}],
        )
    robot = session.get(Robot, robot_id)
    if robot is None:
        raise NotFoundError("robot", robot_id)
    return robot.id, robot_model(robot.parameters)


#: Engine names of task fields -> API names (at the task's top level).
TASK_FIELDS = {
    "q": "q0_deg",
    "q0": "q0_deg",
    "target_position": "target_position_m",
    "target_attitude": "target_attitude_quaternion",
    "duration": "duration_s",
    "ramp_time": "ramp_time_s",
    "dt": "dt_s",
    "profile": "profile",
    "joint_speed_limit": "joint_speed_limit_deg_s",
    "linear_joint_speed_limit": "joint_speed_limit_m_s",
    "tracks": "tracks",
}
#: Engine names of path fields -> API names (under ``path.<type>``).
PATH_FIELDS = {
    "position": "position_m",
    "attitude_quaternion": "attitude_quaternion",
    "segment_durations": "segment_durations_s",
    "max_speed": "max_speed_m_s",
    "max_angular_speed": "max_angular_speed_deg_s",
    "max_acceleration": "max_acceleration_m_s2",
    "max_angular_acceleration": "max_angular_acceleration_deg_s2",
    "centre": "centre_m",
    "angle": "angle_deg",
    "via_position": "via_position_m",
    "end_position": "end_position_m",
    "corner": "corner_m",
    "scan_edge": "scan_edge_m",
    "step_edge": "step_edge_m",
    "line_spacing": "line_spacing_m",
    "standoff": "standoff_m",
    "scan_speed": "scan_speed_m_s",
    "scan_acceleration": "scan_acceleration_m_s2",
    "turn_radius": "turn_radius_m",
}
DEFAULT_DURATION_S = 15.0


def _invalid(loc: list[str | int], reason: str) -> ApiValidationError:
    shown = loc[2:] if loc[:2] == ["body", "task"] else loc[1:] if loc[:1] == ["body"] else loc
    where = "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in shown).lstrip(".")
    return ApiValidationError(f"invalid task: {where}: {reason}", [{"loc": loc, "msg": reason}])


def _matrix(quaternion: list[float], loc: list[str | int]) -> np.ndarray:
    try:
        return quaternion_to_matrix(np.asarray(quaternion, dtype=float))
    except ValueError as exc:
        raise _invalid(loc, str(exc)) from None


def path_spec(path: PathIn, task: TaskIn, loc: list[str | int]) -> dict[str, Any]:
    """Keyword arguments of :func:`engine.paths.make_path` for a non-line path (SI units)."""

    def limits(p: WaypointsPathIn | RasterPathIn) -> SpeedLimits:
        return SpeedLimits(
            p.max_speed_m_s,
            math.radians(p.max_angular_speed_deg_s),
            p.max_acceleration_m_s2,
            math.radians(p.max_angular_acceleration_deg_s2),
        )

    if isinstance(path, WaypointsPathIn):
        return {
            "positions": np.array([w.position_m for w in path.waypoints], dtype=float),
            "attitudes": np.array(
                [
                    _matrix(w.attitude_quaternion, [*loc, "waypoints", i, "attitude_quaternion"])
                    for i, w in enumerate(path.waypoints)
                ]
            ),
            "limits": limits(path),
            "segment_durations": None if path.segment_durations_s is None else np.array(path.segment_durations_s),
            "duration_override": task.duration_s,
        }
    if isinstance(path, ArcPathIn):
        timing = {
            "attitude": path.attitude,
            "duration": DEFAULT_DURATION_S if task.duration_s is None else task.duration_s,
            "ramp_time": task.ramp_time_s,
            "profile": task.profile,
        }
        three_points = {"via_position_m": path.via_position_m, "end_position_m": path.end_position_m}
        centred = {"centre_m": path.centre_m, "axis": path.axis, "angle_deg": path.angle_deg}
        if any(v is not None for v in three_points.values()):
            for name, value in centred.items():
                if value is not None:
                    raise _invalid([*loc, name], "give either centre_m, axis and angle_deg or via_position_m and end_position_m")
            for name, value in three_points.items():
                if value is None:
                    raise _invalid([*loc, name], "required with the other of via_position_m and end_position_m")
            return {"via_position": path.via_position_m, "end_position": path.end_position_m, **timing}
        for name, value in centred.items():
            if value is None:
                raise _invalid([*loc, name], "required: give centre_m, axis and angle_deg (or via_position_m and end_position_m)")
        assert path.angle_deg is not None
        return {"centre": path.centre_m, "axis": path.axis, "angle": math.radians(path.angle_deg), **timing}
    assert isinstance(path, RasterPathIn)
    return {
        "corner": path.corner_m,
        "scan_edge": path.scan_edge_m,
        "step_edge": path.step_edge_m,
        "line_spacing": path.line_spacing_m,
        "standoff": path.standoff_m,
        "scan_speed": path.scan_speed_m_s,
        "scan_acceleration": path.scan_acceleration_m_s2,
        "turn_radius": path.turn_radius_m,
        "sensor_axis": path.sensor_axis,
        "approach": limits(path),
        "pass_index": path.pass_index,
        "duration_override": task.duration_s,
    }


def _engine_error(
    exc: ParameterError, kind: str, loc: tuple[str | int, ...], model: RobotModel | None = None
) -> ApiValidationError:
    """The 422 of an engine error, at the task field (``q0_deg``, ``duration_s``, ...) or the
    path field (``path.<type>.<field>``) it names."""
    parts = field_path(exc.field)
    head = str(parts[0])
    if head == "q0" and model is not None and len(parts) == 2 and isinstance(parts[1], int):
        # a joint outside its limits: the list of its unit
        return _invalid([*loc, "q0_m" if model.links[parts[1]].prismatic else "q0_deg", parts[1]], exc.reason)
    if head in TASK_FIELDS:
        return _invalid([*loc, TASK_FIELDS[head], *parts[1:]], exc.reason)
    names = [PATH_FIELDS.get(p, p) if isinstance(p, str) else p for p in parts]
    if kind == "waypoints" and names[-1] == "attitude":
        names[-1] = "attitude_quaternion"
    return _invalid([*loc, "path", kind, *names], exc.reason)


def urdf_model(body: RobotUrdfIn, loc: tuple[str | int, ...] = ("body",)) -> RobotModel:
    """The model of a URDF body; a URDF the engine refuses is a 422 naming the URDF element (in
    the detail and in the problem's ``element`` member)."""
    tool = None
    if body.tool_position_m is not None or body.tool_attitude_quaternion is not None:
        try:
            rotation = quaternion_to_matrix(body.tool_attitude_quaternion) if body.tool_attitude_quaternion else np.eye(3)
        except ValueError as exc:
            path = [*loc, "tool_attitude_quaternion"]
            raise ApiValidationError(f"tool_attitude_quaternion: {exc}", [{"loc": path, "msg": str(exc)}]) from None
        tool = (np.asarray(body.tool_position_m or [0.0, 0.0, 0.0], dtype=float), rotation)
    try:
        return RobotModel.from_urdf(body.urdf, end_effector_link=body.end_effector_link, tool_offset=tool, name=body.name)
    except UrdfError as exc:
        field = "end_effector_link" if "end_effector_link" in exc.reason else "urdf"
        error = ApiValidationError(f"invalid URDF: {exc}", [{"loc": [*loc, field], "msg": str(exc)}])
        error.extra["element"] = exc.element
        raise error from None


def joint_positions(
    model: RobotModel,
    deg: list[float | None] | None,
    m: list[float | None] | None,
    fields: tuple[str, str],
    loc: tuple[str | int, ...],
) -> np.ndarray:
    """``q (n,)`` (rad, m) from the API's two index-aligned lists ``fields`` (degrees for the
    revolute joints, metres for the prismatic ones, null at the other joints)."""
    n = model.n_joints
    deg_field, m_field = fields
    errors: list[dict[str, Any]] = []
    for values, field in ((deg, deg_field), (m, m_field)):
        if values is not None and len(values) != n:
            errors.append({"loc": [*loc, field], "msg": f"expected {n} values (one per joint), got {len(values)}"})
    if errors:
        raise ApiValidationError(f"{errors[0]['loc'][-1]}: {errors[0]['msg']}", errors)
    q = np.empty(n)
    for j, link in enumerate(model.links):
        field, other = (m_field, deg_field) if link.prismatic else (deg_field, m_field)
        mine, theirs = (m, deg) if link.prismatic else (deg, m)
        kind = "prismatic (m)" if link.prismatic else "revolute (deg)"
        value = mine[j] if mine is not None else None
        if value is None:
            errors.append(
                {"loc": [*loc, field, j], "msg": f"joint {j + 1} ({model.joint_names[j]}) is {kind}: give it in {field}"}
            )
            continue
        if theirs is not None and theirs[j] is not None:
            errors.append({"loc": [*loc, other, j], "msg": f"joint {j + 1} ({model.joint_names[j]}) is {kind}: null here"})
        q[j] = value if link.prismatic else math.radians(value)
    if errors:
        raise ApiValidationError("; ".join(f"{e['loc'][-2]}[{e['loc'][-1]}]: {e['msg']}" for e in errors), errors)
    return q


def build_task(model: RobotModel, task: TaskIn, loc: tuple[str | int, ...] = ("body", "task")) -> CartesianTask:
    """The engine's task of an API task (422s name the offending field)."""
    kind = task.path.type
    if kind == "line":
        return _line_task(model, task, loc)
    for name in ("target_position_m", "target_attitude_quaternion"):
        if getattr(task, name) is not None:
            raise _invalid([*loc, name], f"only for line paths (the {kind} path sets its own poses)")
    path_loc = [*loc, "path", kind]
    q0 = joint_positions(model, task.q0_deg, task.q0_m, ("q0_deg", "q0_m"), loc)
    try:
        position, attitude = start_pose(model, q0)
        path = make_path(kind, position, attitude, **path_spec(task.path, task, path_loc))
        if task.duration_s is None and path.duration > MAX_DURATION_S:
            raise _invalid(
                path_loc,
                f"the path takes {path.duration:.6g} s at its speeds (or durations), more than the {MAX_DURATION_S:g} s allowed: "
                "raise its speeds or give duration_s",
            )
        built = CartesianTask.following(path, q0, dt=task.dt_s, **_limits(task))
        check_task(model, built)
        return built
    except ParameterError as exc:
        raise _engine_error(exc, kind, loc, model) from None


def _limits(task: TaskIn) -> dict[str, Any]:
    """What the task tracks and its joint speed limits, in engine units."""
    return {
        "joint_speed_limit": math.radians(task.joint_speed_limit_deg_s),
        "linear_joint_speed_limit": math.inf if task.joint_speed_limit_m_s is None else task.joint_speed_limit_m_s,
        "tracks": task.tracks,
    }


def _line_task(model: RobotModel, task: TaskIn, loc: tuple[str | int, ...]) -> CartesianTask:
    if task.target_position_m is None:
        raise _invalid([*loc, "target_position_m"], "required for a line path")
    q0 = joint_positions(model, task.q0_deg, task.q0_m, ("q0_deg", "q0_m"), loc)
    if task.target_attitude_quaternion is not None:
        attitude = _matrix(task.target_attitude_quaternion, [*loc, "target_attitude_quaternion"])
    elif task.tracks == "pose":
        raise _invalid(
            [*loc, "target_attitude_quaternion"], "required for a pose task on a line path (a position task may leave it out)"
        )
    else:  # not tracked: the attitude at q0 is carried along for the figures
        attitude = forward_kinematics(model, as_state(model, q0)).ee_attitude
    try:
        built = CartesianTask.from_q0(
            model,
            q0,
            np.asarray(task.target_position_m, dtype=float),
            attitude,
            duration=DEFAULT_DURATION_S if task.duration_s is None else task.duration_s,
            ramp_time=task.ramp_time_s,
            dt=task.dt_s,
            profile=task.profile,
            **_limits(task),
        )
        check_task(model, built)
        return built
    except ParameterError as exc:
        raise _engine_error(exc, "line", loc, model) from None


def metrics_out(m: Metrics) -> dict[str, Any]:
    return clean(
        {
            "objective_b": m.objective_b,
            "position_error_max_m": m.position_error_max,
            "position_error_rms_m": m.position_error_rms,
            "position_error_final_m": m.position_error_final,
            "attitude_error_max_rad": m.attitude_error_max,
            "attitude_error_rms_rad": m.attitude_error_rms,
            "attitude_error_final_rad": m.attitude_error_final,
            "coupled_error_max_m_rad": m.coupled_error_max,
            "coupled_error_rms_m_rad": m.coupled_error_rms,
            "coupled_error_final_m_rad": m.coupled_error_final,
            "attitude_term": m.attitude_term,
            "max_joint_speed_deg_s": m.max_joint_speed_deg_s,
            "joint_speed_limit_deg_s": math.degrees(m.joint_speed_limit),
            "joint_speed_limit_respected": m.joint_speed_limit_respected,
            "min_singular_value": m.min_singular_value,
            "time_of_min_singular_value_s": m.time_of_min_singular_value,
            "min_abs_det_gjm": m.min_abs_det_J_g,
            "time_of_min_abs_det_gjm_s": m.time_of_min_abs_det_J_g,
            "tracks": m.tracks,
            "max_linear_joint_speed_m_s": m.max_linear_joint_speed,
            "joint_speed_limit_m_s": m.linear_joint_speed_limit,
            "position_limits_respected": m.position_limits_respected,
            "position_limit_joint": m.position_limit_joint + 1 if m.position_limit_joint >= 0 else None,
            "time_position_limit_left_s": m.time_position_limit_left,
            "base_attitude_change_max_rad": m.base_rotation_max,
            "base_attitude_change_final_rad": m.base_rotation_final,
        }
    )


def trajectory_out(r: PlanResult, prismatic: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """The stored and returned trajectory: numpy arrays (written by :mod:`service.infra.jsonio`, NaN as
    null). With ``prismatic (n,)`` flags, those joints' columns are NaN in the degree arrays and
    filled (m, m/s) in ``joint_displacements_m`` and ``joint_velocities_m_s``."""
    joints: dict[str, np.ndarray] = {"joint_angles_deg": np.degrees(r.q), "joint_velocities_deg_s": np.degrees(r.qd)}
    if prismatic is not None and np.any(prismatic):
        joints["joint_angles_deg"][:, prismatic] = np.nan
        joints["joint_velocities_deg_s"][:, prismatic] = np.nan
        joints["joint_displacements_m"] = np.where(prismatic, r.q, np.nan)
        joints["joint_velocities_m_s"] = np.where(prismatic, r.qd, np.nan)
    return {
        "t_s": r.t,
        **joints,
        "base_position_m": r.base_position,
        "base_attitude_quaternion": _quats(r.base_attitude),
        "ee_position_m": r.ee_position,
        "ee_position_desired_m": r.ee_position_desired,
        "ee_attitude_quaternion": _quats(r.ee_attitude),
        "ee_attitude_desired_quaternion": _quats(r.ee_attitude_desired),
        "singular_values": r.singular_values,
        "det_gjm": r.det_J_g,
        "damping": r.damping,
        "position_error_m": r.position_error,
        "attitude_error_rad": r.attitude_error,
    }


def _quats(R: np.ndarray) -> np.ndarray:
    ok = np.all(np.isfinite(R), axis=(-2, -1))
    out = np.full(R.shape[:-2] + (4,), np.nan)
    if np.any(ok):
        out[ok] = matrix_to_quaternion(R[ok])
    return out


def replay_out(r: ReplayResult) -> dict[str, Any]:
    return clean(
        {
            "success": r.success,
            "message": r.message,
            "path_position_error_max_m": r.path_position_error_max,
            "path_position_error_final_m": r.path_position_error_final,
            "path_attitude_error_max_rad": r.path_attitude_error_max,
            "path_attitude_error_final_rad": r.path_attitude_error_final,
            "plan_gap_position_max_m": r.plan_gap_position_max,
            "plan_gap_attitude_max_rad": r.plan_gap_attitude_max,
            "base_attitude_gap_max_rad": r.base_attitude_gap_max,
            "linear_momentum_residual_max_n_s": r.linear_momentum_residual_max,
            "angular_momentum_residual_max_n_m_s": r.angular_momentum_residual_max,
            "com_drift_max_m": r.com_drift_max,
        }
    )

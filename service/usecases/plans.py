"""Synchronous plans: a request converted once to the engine's objects, planned (and replayed),
stored and answered; stored plans read back.

A plan's trajectory is stored as its SI record (:func:`record_of`: the planner's arrays by their
engine names, joints in rad or m, attitudes as unit quaternions) in a compressed ``.npz``
(:mod:`service.infra.storage`), and converted to the API's units only on the way out
(:meth:`service.schemas.plans.Trajectory.arrays`). Plans stored before the record existed hold the
API's arrays; :func:`record_from_storage` reads both.

Plan bodies are written once, by orjson from the arrays (:mod:`service.infra.jsonio`): the
trajectory is neither copied into Python lists nor validated again on the way out."""

from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, fields
from datetime import datetime
from typing import Any, TypeVar, cast

import numpy as np
from pydantic import ValidationError
from sqlalchemy import ColumnElement, Connection, Select, Table, Text, case, func, insert, literal, or_, select
from sqlalchemy import cast as sql_cast
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from engine import CartesianTask, DurationSearch, Inverse, PlanResult, PlanSetup, RobotModel, replay, run_plan, shortest_duration
from engine.errors import ParameterError
from engine.executed import replay_executed
from engine.robustness import Robustness, robustness
from engine.spatial import matrix_to_quaternion, quaternion_to_matrix
from engine.uncertainty import Uncertainty
from service.errors import ApiValidationError, NotFoundError, body_invalid
from service.infra import jsonio
from service.infra.admission import work_cost
from service.infra.db import Database
from service.infra.loop import HandOff
from service.infra.lru import Lru
from service.infra.metrics import count_plan
from service.infra.quota import check_quota
from service.infra.settings import Settings
from service.infra.storage import pack_trajectory, unpack_trajectory
from service.models import Plan, Robot, new_id, utcnow
from service.schemas.common import located
from service.schemas.geometry import MeshIn
from service.schemas.methods import MethodOut
from service.schemas.plans import (
    PLAN_SECTIONS,
    DurationSearchOut,
    PlanList,
    PlanRequest,
    PlanRerun,
    PlanSummary,
    ReplayOut,
    ShortestDurationRequest,
    Trajectory,
    metrics_out,
)
from service.schemas.tasks import TaskIn
from service.schemas.uncertainty import RobustnessOut
from service.usecases import meshes, robots, rows

#: A plan whose joints turn more than this in all is not replayed (not physically meaningful).
REPLAY_MAX_TRAVEL_RAD = 200.0
#: Joint-steps a plan's robustness may take (two loops x samples x plan-steps x joints): about
#: ten seconds of one core, so that a synchronous request stays a request.
MAX_ROBUSTNESS_JOINT_STEPS = 5_000_000
#: The stored record's robustness bands (``(N+1, 3)``: smallest, median, largest over the samples).
ROBUSTNESS_BANDS = (
    "robust_open_position_band",
    "robust_open_attitude_band",
    "robust_closed_position_band",
    "robust_closed_attitude_band",
)


def _quaternions(*R: np.ndarray) -> tuple[np.ndarray, ...]:
    """The unit quaternions ``(..., 4)`` of each rotation array ``(..., 3, 3)``, NaN where a matrix
    is not finite (a diverged plan's samples); one kernel call for all of them."""
    stacked = np.concatenate(R)
    if np.isfinite(stacked).all():  # a plan that did not diverge: no masks (0.04 ms of numpy's reductions and copies)
        out = matrix_to_quaternion(stacked)
    else:
        ok = np.isfinite(stacked).all(axis=(-2, -1))
        out = np.full(stacked.shape[:-2] + (4,), np.nan)
        if ok.any():
            out[ok] = matrix_to_quaternion(stacked[ok])
    ends = np.cumsum([r.shape[0] for r in R]).tolist()
    return tuple(out[end - r.shape[0] : end] for r, end in zip(R, ends, strict=True))


def record_of(result: PlanResult, model: RobotModel) -> dict[str, np.ndarray]:
    """The stored record of a plan: its arrays in SI units by their engine names, attitudes as
    unit quaternions ``[w, x, y, z]``, the executed trajectory's accelerations, torques (forces)
    and mount wrench, ``prismatic (n,)`` (1.0 for a prismatic joint), the robot's
    ``effort_limit (n,)`` when planned (N m or N, inf: none; for the figures) and, for a plan
    with collision geometry, its ``clearance (N+1,)`` m."""
    base_attitude, ee_attitude, ee_attitude_desired = _quaternions(
        result.base_attitude, result.ee_attitude, result.ee_attitude_desired
    )
    return {
        "prismatic": np.asarray(model.prismatic, dtype=float),
        "effort_limit": np.asarray(model.effort_limits, dtype=float),
        "qdd": result.joint_accelerations,
        "tau": result.joint_torques,
        "mount_force": result.mount_force,
        "mount_torque": result.mount_torque,
        "t": result.t,
        "q": result.q,
        "qd": result.qd,
        "base_position": result.base_position,
        "base_attitude": base_attitude,
        "ee_position": result.ee_position,
        "ee_attitude": ee_attitude,
        "ee_position_desired": result.ee_position_desired,
        "ee_attitude_desired": ee_attitude_desired,
        "singular_values": result.singular_values,
        "det_J_g": result.det_J_g,
        "damping": result.damping,
        "position_error": result.position_error,
        "attitude_error": result.attitude_error,
        **({"clearance": result.clearance} if result.metrics.geometry_checked else {}),
    }


def robustness_record(robust: Robustness) -> dict[str, np.ndarray]:
    """The stored bands of a plan's robustness (:data:`ROBUSTNESS_BANDS`)."""
    bands = [a for loop in (robust.open_loop, robust.closed_loop) for a in (loop.position_error_band, loop.attitude_error_band)]
    return dict(zip(ROBUSTNESS_BANDS, bands, strict=True))


def record_from_storage(arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """A stored plan's SI record: the record itself, or (plans stored before it existed) the
    API's arrays converted back (degrees to radians; prismatic columns from the ``_m`` arrays)."""
    if "joint_angles_deg" not in arrays:
        return arrays
    q_deg, qd_deg = arrays["joint_angles_deg"], arrays["joint_velocities_deg_s"]
    prismatic = np.zeros(q_deg.shape[1:], dtype=bool)
    q, qd = np.radians(q_deg), np.radians(qd_deg)
    if "joint_displacements_m" in arrays:
        prismatic = np.isfinite(arrays["joint_displacements_m"]).any(axis=0)
        q = np.where(prismatic, arrays["joint_displacements_m"], q)
        qd = np.where(prismatic, arrays["joint_velocities_m_s"], qd)
    names = {
        "t": "t_s",
        "base_position": "base_position_m",
        "base_attitude": "base_attitude_quaternion",
        "ee_position": "ee_position_m",
        "ee_attitude": "ee_attitude_quaternion",
        "ee_position_desired": "ee_position_desired_m",
        "ee_attitude_desired": "ee_attitude_desired_quaternion",
        "singular_values": "singular_values",
        "det_J_g": "det_gjm",
        "damping": "damping",
        "position_error": "position_error_m",
        "attitude_error": "attitude_error_rad",
    }
    return {"q": q, "qd": qd, "prismatic": prismatic.astype(float), **{k: arrays[v] for k, v in names.items()}}


def attitudes(quaternions: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` of a record's quaternions (NaN where not finite)."""
    ok = np.all(np.isfinite(quaternions), axis=-1)
    out = np.full(quaternions.shape[:-1] + (3, 3), np.nan)
    if np.any(ok):
        out[ok] = quaternion_to_matrix(quaternions[ok])
    return out


def replay_skip_reason(result: PlanResult, max_steps: int) -> str | None:
    """Why a plan is not replayed synchronously, or None. The replay (a compiled DOP853 at tight
    tolerances) costs more the longer the plan and the further the joints turn: a plan longer
    than ``max_steps`` (``SPACEARM_MAX_REPLAY_STEPS``) or a diverged plan with absurd joint rates
    (found by the fuzz: 1e10 deg/s) would keep the request busy for minutes."""
    qd = np.nan_to_num(np.abs(result.qd), nan=np.inf)
    dt = np.diff(result.t)
    if dt.shape[0] > max_steps:
        return (
            f"not replayed: {dt.shape[0]} steps, more than the {max_steps} replayed synchronously "
            "(SPACEARM_MAX_REPLAY_STEPS); replay it with the engine's replay() offline"
        )
    if qd.shape[0] < dt.shape[0] or dt.shape[0] == 0:
        return None
    travel = float(np.sum(np.max(qd[: dt.shape[0]], axis=1) * dt))
    if not math.isfinite(travel):
        return "not replayed: the plan is not finite"
    if travel > REPLAY_MAX_TRAVEL_RAD:
        return (
            f"not replayed: the planned joints turn {travel:.3g} rad in all (more than {REPLAY_MAX_TRAVEL_RAD:g} rad), "
            "the plan is not physically meaningful"
        )
    return None


@dataclass(slots=True)
class PlanRow:
    """A plan's row before it is stored: the columns of :class:`service.models.Plan` (the ORM's
    instrumented object cost a plan 0.03 ms to build; the row is inserted by Core,
    :func:`insert_plan`, which gives it its id and time)."""

    robot_id: str | None
    request: dict[str, Any]
    method: dict[str, Any]
    success: bool
    message: str
    metrics: dict[str, Any]
    trajectory_data: bytes
    replay: dict[str, Any] | None
    robustness: dict[str, Any] | None
    elapsed_s: float
    id: str = ""
    created_at: datetime | None = None


@dataclass(frozen=True)
class Planned:
    """A request's plan, ready to store: the row and the SI record of its trajectory."""

    row: PlanRow
    record: dict[str, np.ndarray]
    joint_names: tuple[str, ...] = ()


@dataclass(frozen=True)
class Prepared:
    """A request converted to the engine's objects (once)."""

    robot_id: str | None
    model: RobotModel
    setup: PlanSetup
    inverse: Inverse
    uncertainty: Uncertainty | None = None


def check_uncertainty(setup: PlanSetup, uncertainty: Uncertainty) -> None:
    """Refuse a robustness that would cost more than :data:`MAX_ROBUSTNESS_JOINT_STEPS`
    (``ParameterError`` naming ``samples``)."""
    per_sample = 2 * (setup.task.n_steps + 1) * setup.model.n_joints
    if uncertainty.samples * per_sample > MAX_ROBUSTNESS_JOINT_STEPS:
        raise ParameterError(
            "samples",
            f"{uncertainty.samples} samples x 2 loops x {setup.task.n_steps + 1} plan-steps x {setup.model.n_joints} joints "
            f"= {uncertainty.samples * per_sample:.3g} joint-steps, at most {MAX_ROBUSTNESS_JOINT_STEPS:.3g} per plan: "
            f"at most {max(1, MAX_ROBUSTNESS_JOINT_STEPS // per_sample)} samples for this task",
        )


TASK_CACHE_SIZE = 64
#: Engine tasks by robot model (its identity; the model is kept beside the task) and the task's JSON.
_TASKS: Lru[tuple[int, str], tuple[RobotModel, CartesianTask]] = Lru(TASK_CACHE_SIZE)


def among_meshes(task: TaskIn) -> bool:
    """Whether ``task``'s obstacles name stored meshes (resolved in a database session)."""
    return task.scene is not None and any(isinstance(obstacle, MeshIn) for obstacle in task.scene.obstacles)


def engine_task(task: TaskIn, model: RobotModel) -> CartesianTask:
    """``task.to_engine(model)``, kept for the next request of the same task on the same model (a
    stored robot's model is kept too, :func:`service.schemas.robots.model_of`): building a task
    (its start pose, its path) cost a paper plan 0.2 ms of its request, and clients plan one task
    again and again with other methods and damping. Engine tasks are immutable. Tasks among
    stored meshes are built every time, as a mesh may have been deleted since."""
    if among_meshes(task):
        return task.to_engine(model)
    # The entry holds the model, so while it is kept the model's id names no other model.
    return _TASKS.get((id(model), task.model_dump_json()), lambda: (model, task.to_engine(model)))[1]


def _kept_robot(body: PlanRequest) -> RobotModel | None:
    """The model of the request's stored robot if this process read it before and the task names
    no stored mesh (read in a session), else None."""
    if body.robot is not None or body.robot_id is None or among_meshes(body.task):
        return None
    return robots.kept(body.robot_id)


def prepare(db: Database | None, body: PlanRequest) -> Prepared:
    """Resolve the robot (without a database: a preset or the inline robot) and convert the
    request: 422s name the API field the engine refused."""
    if db is None:
        robot_id, model = robots.resolve_preset(body.robot_id, body.robot)
        with located(body.task, "body", "task"):
            task = body.task.to_engine(model)
    elif (kept := _kept_robot(body)) is not None:  # no database session at all
        robot_id, model = body.robot_id, kept
        with located(body.task, "body", "task"):
            task = engine_task(body.task, model)
    else:
        with db.session() as session, meshes.hulls(session):  # no connection held while planning
            robot_id, model = robots.resolve(session, body.robot_id, body.robot)
            with located(body.task, "body", "task"):
                task = engine_task(body.task, model)
    with located(body.method, "body", "method"):
        inverse = body.method.to_engine()
    with located(body, "body"):
        setup = PlanSetup(model, task, body.options())
    uncertainty = None
    if body.uncertainty is not None:
        with located(body.uncertainty, "body", "uncertainty"):
            uncertainty = body.uncertainty.to_engine()
            check_uncertainty(setup, uncertainty)
    return Prepared(robot_id, model, setup, inverse, uncertainty)


T = TypeVar("T")

#: Threads for the executed trajectory's replay beside the planned one (:func:`finish`), and how
#: many of them are free.
_REPLAY_THREADS = max(1, os.cpu_count() or 1)
_REPLAYS = ThreadPoolExecutor(max_workers=_REPLAY_THREADS, thread_name_prefix="spacearm-replay")
_REPLAYS_FREE = threading.BoundedSemaphore(_REPLAY_THREADS)


def _beside(fn: Callable[..., T], *args: Any) -> Callable[[], T]:
    """Start ``fn(*args)`` in a replay thread if one is free (else it runs here when asked: a
    request, on the event loop or not, never waits behind other requests' replays); returns what
    gives its result."""
    if _REPLAYS_FREE.acquire(blocking=False):
        try:
            future = _REPLAYS.submit(fn, *args)
        except RuntimeError:  # the executor is shut down (the process is stopping)
            _REPLAYS_FREE.release()
        else:
            future.add_done_callback(lambda _: _REPLAYS_FREE.release())
            return future.result
    return lambda: fn(*args)


def finish(
    body: PlanRequest, prepared: Prepared, result: PlanResult, settings: Settings, started: float, request: dict[str, Any]
) -> Planned:
    """Replay the plan if asked and build its row (``request``: the request as stored)."""
    skipped = replay_skip_reason(result, settings.max_replay_steps) if body.replay else None
    replayed = None
    if skipped is not None:
        replayed = ReplayOut.skipped(skipped)
    elif body.replay:
        # the two replays at once: their integrators release the GIL (a paper plan: 1.9 and 1.2 ms)
        executed = _beside(replay_executed, prepared.model, result)
        replayed = ReplayOut.from_engine(replay(prepared.model, result), executed())
    record = record_of(result, prepared.model)
    robust: Robustness | None = None
    if prepared.uncertainty is not None:
        robust = robustness(prepared.setup, prepared.inverse, result, prepared.uncertainty)
        record.update(robustness_record(robust))
    row = PlanRow(
        robot_id=prepared.robot_id,
        request=request,
        method=MethodOut.from_engine(result.inverse, result.secondary).model_dump(mode="json"),
        success=result.success,
        message=result.message,
        metrics=metrics_out(result.metrics),
        trajectory_data=pack_trajectory(record),
        replay=replayed.model_dump(mode="json") if replayed is not None else None,
        robustness=jsonio.clean(RobustnessOut.from_engine(robust).model_dump(mode="json")) if robust is not None else None,
        elapsed_s=time.perf_counter() - started,
    )
    return Planned(row, record, prepared.model.joint_names)


def joint_steps(prepared: Prepared, body: PlanRequest) -> float:
    """A prepared request's cost in joint-steps, as :func:`~service.infra.admission.plan_cost`
    estimates it from the body but with the task's real samples and the robot's real joints;
    infinite with collision geometry or uncertainty (the steps do not say their cost)."""
    if prepared.uncertainty is not None or prepared.setup.geometry.active:
        return math.inf
    return work_cost(prepared.setup.task.n_steps + 1, prepared.model.n_joints, 2.0 if body.replay else 1.0)


def compute(db: Database | None, settings: Settings, body: PlanRequest, *, within: float = math.inf) -> Planned:
    """Plan (and replay) a request (``db`` None: without a database, see :func:`prepare`).
    ``within``: the most joint-steps (:func:`joint_steps`) the plan may take here (on the event
    loop); a larger one raises :class:`~service.infra.loop.HandOff` with the plan as its rest."""
    started = time.perf_counter()
    prepared = prepare(db, body)

    def rest() -> Planned:
        result = run_plan(prepared.setup, prepared.inverse)
        return finish(body, prepared, result, settings, started, jsonio.clean(body.stored()))

    if joint_steps(prepared, body) > within:
        raise HandOff(rest, "the task is larger than its request said")
    return rest()


def compute_shortest(db: Database, settings: Settings, body: ShortestDurationRequest) -> tuple[Planned, DurationSearchOut]:
    """The shortest feasible duration of a request's task, and the plan at it (whose stored
    request carries that duration, so posting it to ``/v1/plans`` plans it again)."""
    started = time.perf_counter()
    prepared = prepare(db, body)
    with located(body.search, "body", "search"):
        found: DurationSearch = shortest_duration(
            prepared.setup,
            prepared.inverse,
            relative_tolerance=body.search.relative_tolerance,
            candidates=body.search.candidates,
            max_duration=body.search.max_duration_s,
        )
    stored = body.stored()
    del stored["search"]
    stored["task"] = {**stored["task"], **body.task.path_timing(found.plan.task)}
    request = jsonio.clean(PlanRequest.model_validate_json(jsonio.dumps(stored)).stored())
    return finish(body, prepared, found.plan, settings, started, request), DurationSearchOut.from_engine(found)


PLAN_TABLE = cast(Table, Plan.__table__)
PLAN_COLUMNS = tuple(PLAN_TABLE.columns)
assert {c.key for c in PLAN_COLUMNS} == {f.name for f in fields(PlanRow)}, "a PlanRow holds the plans table's columns"
INSERT_PLAN = insert(PLAN_TABLE)


def insert_plan(conn: Connection, settings: Settings, row: PlanRow) -> None:
    """Insert ``row`` (given its id and time) within the quota: a Core insert of its columns (the
    ORM's unit of work cost a plan 0.2 ms more)."""
    row.id, row.created_at = new_id(), utcnow()
    check_quota(conn, settings.storage_quota_bytes, len(row.trajectory_data))
    conn.execute(INSERT_PLAN, {column.key: getattr(row, column.key) for column in PLAN_COLUMNS})


def _robot_exists(db: Database, robot_id: str) -> bool:
    with db.session() as session:
        return session.scalar(select(Robot.id).where(Robot.id == robot_id)) is not None


def store(db: Database, settings: Settings, planned: Planned) -> PlanRow:
    """Store a plan within the quota; committed before the response goes out (a client's next
    request must see it). A plan of a stored robot deleted since it was read is a 404."""
    row = planned.row
    try:
        with db.connection() as conn:
            insert_plan(conn, settings, row)
    except IntegrityError:
        if row.robot_id is None or _robot_exists(db, row.robot_id):
            raise
        robots.forget(row.robot_id)  # deleted since the request read it (robots.kept)
        raise NotFoundError("robot", row.robot_id) from None
    count_plan(row.method["name"], row.success, row.elapsed_s)
    return row


SUMMARY_COLUMNS = (
    Plan.id,
    Plan.robot_id,
    Plan.request,
    Plan.method,
    Plan.success,
    Plan.message,
    Plan.metrics,
    Plan.robustness,
    Plan.elapsed_s,
    Plan.created_at,
)


def asked(stored: dict[str, Any] | None) -> PlanRequest | None:
    """A stored request as this version reads it (None if it cannot: a plan from an older version)."""
    try:
        return PlanRequest.model_validate(stored)
    except ValidationError:
        return None


def summary(row: PlanRow | Any, request: PlanRequest | None = None) -> PlanSummary:
    """A plan's summary from its row (or a row of :data:`SUMMARY_COLUMNS`); ``request``: the
    validated request the row stores, when the caller has it (a plan just made), so that it is
    not validated again."""
    return PlanSummary.model_validate(
        {
            "id": row.id,
            "robot_id": row.robot_id,
            "request": asked(row.request) if request is None else request,
            "method": row.method,
            "success": row.success,
            "message": row.message,
            "metrics": row.metrics,
            "robustness": row.robustness,
            "elapsed_s": row.elapsed_s,
            "created_at": row.created_at,
        },
        strict=False,
    )


def body_json(plan_summary: PlanSummary, sections: set[str], record: dict[str, np.ndarray] | None, replayed: Any) -> bytes:
    """The JSON body of a plan: its summary and the ``sections`` asked for."""
    parts: dict[str, Any] = {}
    if "trajectory" in sections and record is not None:
        parts["trajectory"] = Trajectory.arrays(record)
    if "replay" in sections:
        parts["replay"] = replayed
    ordered = {name: parts[name] for name in PLAN_SECTIONS if name in parts}
    return jsonio.dumps_large({**plan_summary.model_dump(mode="json"), **ordered})


@dataclass(frozen=True)
class PlanFilter:
    """What a plan list keeps (None: any): the stored robot, the path type, the method, the verdict."""

    robot_id: str | None = None
    path_type: str | None = None
    method: str | None = None
    success: bool | None = None

    def where(self) -> list[ColumnElement[bool]]:
        """SQL conditions on the stored JSON (``json_extract`` on SQLite, ``->>`` on PostgreSQL)."""
        out: list[ColumnElement[bool]] = []
        if self.robot_id is not None:
            out.append(Plan.robot_id == self.robot_id)
        if self.path_type is not None:
            kind = Plan.request[("task", "path", "type")].as_string()
            # requests stored before paths existed have none: they are lines
            out.append(or_(kind == self.path_type, kind.is_(None)) if self.path_type == "line" else kind == self.path_type)
        if self.method is not None:
            out.append(Plan.method["name"].as_string() == self.method)
        if self.success is not None:
            out.append(Plan.success.is_(self.success))
        return out


def listing(session: Session, limit: int, offset: int, kept: PlanFilter | None = None) -> PlanList:
    """A page of the plans ``kept`` keeps (all by default), newest first, and how many it keeps."""
    where = (kept or PlanFilter()).where()
    total = session.scalar(select(func.count()).select_from(Plan).where(*where)) or 0
    rows = session.execute(
        select(*SUMMARY_COLUMNS).where(*where).order_by(Plan.created_at.desc(), Plan.id).limit(limit).offset(offset)
    ).all()
    return PlanList(items=[summary(r) for r in rows], total=total)


#: Objects a merge patch replaces whole when this member differs from the stored one's (None: always).
REPLACED_WHEN_CHANGED: dict[tuple[str, ...], str | None] = {("task", "path"): "type", ("method",): "name", ("robot",): None}
#: Request members of which exactly one is given: giving one drops the other.
EITHER = ("robot_id", "robot")
#: A task's members that belong to its path type (a line's targets, and a duration that a
#: waypoints or raster path would be rescaled to): a patch that changes the path's type drops the
#: ones it does not give, so the new path starts from its own defaults.
PATH_BOUND = ("duration_s", "target_position_m", "target_attitude_quaternion")


def merge_patch(target: Any, patch: Any, at: tuple[str, ...] = ()) -> Any:
    """RFC 7396's MergePatch(target, patch), with :class:`service.schemas.plans.PlanRerun`'s
    additions: an object of :data:`REPLACED_WHEN_CHANGED` whose tag changes (or the inline robot)
    is replaced whole, and one of :data:`EITHER` given drops the other. A dozen lines, so written here rather than taken
    from a package (json-merge-patch implements RFC 7386 without the additions)."""
    if not isinstance(patch, dict):
        return patch
    replaced = at in REPLACED_WHEN_CHANGED
    tag = REPLACED_WHEN_CHANGED.get(at)
    if not isinstance(target, dict) or (replaced and (tag is None or (tag in patch and patch[tag] != target.get(tag)))):
        target = {}
    out = dict(target)
    if not at:
        for name in EITHER:
            if patch.get(name) is not None:
                out.pop(next(other for other in EITHER if other != name), None)
    for name, value in patch.items():
        if value is None:
            out.pop(name, None)
        else:
            out[name] = merge_patch(out.get(name), value, (*at, name))
    return out


def _path_bound_dropped(stored: dict[str, Any], patch: dict[str, Any]) -> dict[str, Any]:
    """``patch`` with a null for each of :data:`PATH_BOUND` it does not give, if it changes the
    stored task's path type."""
    task = patch.get("task")
    if not isinstance(task, dict):
        return patch
    path = task.get("path")
    stored_path = (stored.get("task") or {}).get("path") or {}
    if not isinstance(path, dict) or "type" not in path or path["type"] == stored_path.get("type", "line"):
        return patch
    return {**patch, "task": {**dict.fromkeys(PATH_BOUND), **task}}


def request_of(db: Database, body: dict[str, Any]) -> PlanRequest:
    """The plan request of a ``POST /v1/plans`` body: a plan request, or a :class:`PlanRerun`
    merged into its stored plan's request; validation errors under ``body`` as FastAPI's own
    (validated as FastAPI validates a typed body: the parsed JSON, strictly)."""
    try:
        if "from_plan_id" not in body:
            return PlanRequest.model_validate(body)
        rerun = PlanRerun.model_validate(body)
        with db.session() as session:
            stored = session.scalar(select(Plan.request).where(Plan.id == rerun.from_plan_id))
        if stored is None:
            raise NotFoundError("plan", rerun.from_plan_id)
        return PlanRequest.model_validate(merge_patch(stored, _path_bound_dropped(stored, rerun.patch())))
    except ValidationError as exc:
        raise body_invalid(exc) from None


def _read_query(plan_id: str, trajectory: bool, within: float) -> Select[Any]:
    """The one query of :func:`read`: the summary, and the stored trajectory if asked for and,
    with the stored request, of at most ``within`` bytes (finite: with their sizes)."""
    columns: list[Any] = [*SUMMARY_COLUMNS, Plan.replay]
    if not math.isinf(within):
        request_chars = func.length(sql_cast(Plan.request, Text))
        stored_bytes = func.length(Plan.trajectory_data) if trajectory else literal(0)
        columns += [request_chars.label("request_chars"), stored_bytes.label("stored_bytes")]
        if trajectory:
            columns.append(case((stored_bytes + request_chars <= within, Plan.trajectory_data)).label("trajectory_data"))
    elif trajectory:
        columns.append(Plan.trajectory_data)
    return select(*columns).where(Plan.id == plan_id)


def read(db: Database, plan_id: str, sections: set[str], *, within: float = math.inf) -> bytes:
    """A stored plan's JSON body with the ``sections`` asked for. ``within``: the most bytes of
    stored request and trajectory read, validated and encoded here (on the event loop,
    :data:`~service.infra.admission.INLINE_READ_BYTES`); a larger plan raises
    :class:`~service.infra.loop.HandOff` with the read without a limit as its rest (a query
    again, in a thread). The trajectory comes back from the database only within the limit."""
    trajectory = "trajectory" in sections
    with db.session() as session:
        found = session.execute(_read_query(plan_id, trajectory, within)).first()
    if found is None:
        raise NotFoundError("plan", plan_id)
    if not math.isinf(within) and found.request_chars + found.stored_bytes > within:
        raise HandOff(lambda: read(db, plan_id, sections), "the plan is larger than the event loop takes")
    record = record_from_storage(unpack_trajectory(found.trajectory_data)) if trajectory else None
    return body_json(summary(found), sections, record, found.replay)


def delete(db: Database, plan_id: str) -> None:
    rows.delete(db, Plan, plan_id, "plan")


def parse_sections(fields: str | None) -> set[str]:
    """The sections a ``fields`` query asks for; unknown names are a 422 naming the valid ones."""
    if fields is None:
        return set(PLAN_SECTIONS)
    names = {name.strip() for name in fields.split(",") if name.strip()}
    unknown = sorted(names - set(PLAN_SECTIONS))
    if unknown:
        msg = f"unknown section(s) {', '.join(unknown)}; valid: {', '.join(PLAN_SECTIONS)}"
        raise ApiValidationError.at(["query", "fields"], msg)
    return names


def rehearse(db: Database, settings: Settings) -> None:
    """Take the OpenAPI example of a plan request through every step of a plan request, the
    database insert included, and roll it back: the API's start-up runs it so that the first
    real request finds the connection, the compiled statements and the code paths warm."""
    body = PlanRequest.model_validate(PlanRequest.model_config["json_schema_extra"]["examples"][0])  # type: ignore[index]
    planned = compute(db, settings, body)
    with db.engine.connect() as conn:
        try:
            row = planned.row
            insert_plan(conn, settings, row)
            body_json(summary(row), set(PLAN_SECTIONS), planned.record, row.replay)
            # the event loop's statement (with a bound that any plan meets: the bound is a parameter)
            found = conn.execute(_read_query(row.id, True, 2**62)).one()
            record_from_storage(unpack_trajectory(found.trajectory_data))
        finally:
            conn.rollback()

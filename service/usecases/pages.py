"""What the web pages show: the index's robots, recent plans and jobs; a plan's page, two plans
compared, a job's page; robots by name everywhere (:func:`robot_labels`)."""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from typing import Any

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from engine.inverses import METHODS, Param
from engine.metrics import DEG, LAYOUT
from engine.planner import ATTITUDE_TOLERANCE_RAD, POSITION_TOLERANCE_M
from engine.trajectory import PAPER_GA_OPTIMUM, PAPER_TASK_PARAMS
from service import figures
from service.infra.db import Database
from service.models import Plan, Robot, TuningJob
from service.schemas.plans import ReplayOut

#: The plan page's metrics card: (API name, label, unit shown, scale), from the metrics layout.
METRIC_ROWS = [(spec.api, spec.web.label, spec.web.unit, spec.web.scale) for spec in LAYOUT if spec.web is not None]

#: The replay card: (API name, label, unit shown, scale from the API's SI value), in the metrics
#: card's units (mm and deg).
REPLAY_ROWS: list[tuple[str, str, str, float]] = [
    ("path_position_error_max_m", "max position error against the path", "mm", 1e3),
    ("path_position_error_final_m", "final position error against the path", "mm", 1e3),
    ("path_attitude_error_max_rad", "max attitude error against the path", "deg", DEG),
    ("path_attitude_error_final_rad", "final attitude error against the path", "deg", DEG),
    ("plan_gap_position_max_m", "max gap to the plan: end-effector position", "mm", 1e3),
    ("plan_gap_attitude_max_rad", "max gap to the plan: end-effector attitude", "deg", DEG),
    ("base_attitude_gap_max_rad", "max gap to the plan: base attitude", "deg", DEG),
    ("linear_momentum_residual_max_n_s", "max linear momentum (ideally 0)", "N s", 1.0),
    ("angular_momentum_residual_max_n_m_s", "max angular momentum (ideally 0)", "N m s", 1.0),
    ("com_drift_max_m", "max drift of the system's centre of mass (ideally 0)", "mm", 1e3),
    ("executed_path_position_error_max_m", "executed smoothly: max position error against the path", "mm", 1e3),
    ("executed_path_attitude_error_max_rad", "executed smoothly: max attitude error against the path", "deg", DEG),
    ("executed_plan_gap_position_max_m", "executed smoothly: max gap to the plan, end-effector position", "mm", 1e3),
    ("executed_plan_gap_attitude_max_rad", "executed smoothly: max gap to the plan, end-effector attitude", "deg", DEG),
]
assert {row[0] for row in REPLAY_ROWS} == set(ReplayOut.model_fields) - {"success", "message"}

RECENT_PLANS = 20
RECENT_JOBS = 20
LISTED_ROBOTS = 50


def method_forms() -> list[dict[str, Any]]:
    """The plan form's methods, each parameter filled with a value that succeeds on the paper's
    task (the default preset; :data:`engine.trajectory.PAPER_TASK_PARAMS`), else its default."""
    return [
        {
            "name": name,
            "description": spec.description,
            "params": [
                {"name": p.name, "default": PAPER_TASK_PARAMS.get(name, {}).get(p.name, p.default), "unit": p.unit}
                for p in spec.params
            ],
        }
        for name, spec in METHODS.items()
    ]


#: The paper's own GA optimum, one click away on the index page (it fills the form), and why the
#: form does not start with it.
PAPER_VALUES = {
    "href": "/?preset=paper-line&replay=on&method=adaptive&"
    + "&".join(f"adaptive.{k}={v:g}" for k, v in PAPER_GA_OPTIMUM.items())
    + "#plan-form-section",
    "label": "the paper's own values (" + ", ".join(f"{k} {v:g}" for k, v in PAPER_GA_OPTIMUM.items()) + ")",
    "note": "The form starts with parameters tuned by the paper's GA for this reconstruction of the Table-1 robot. The "
    "paper tuned its values for its exact robot, whose frames it does not fully give: here the plan with them reaches "
    "8.54 deg/s on joint 4 near the singular point, over the 6 deg/s limit, so it fails.",
}


def method_params(name: str) -> tuple[Param, ...]:
    """The parameters of the method ``name`` (none for an unknown name: the API refuses it)."""
    spec = METHODS.get(name)
    return spec.params if spec is not None else ()


def robot_labels(session: Session) -> dict[str, str]:
    """Every stored robot's id -> the name the pages show: its name, numbered in the order the
    robots were stored where several share it (``arm``, ``arm (2)``)."""
    rows = session.execute(select(Robot.id, Robot.name).order_by(Robot.created_at, Robot.id)).all()
    counts = Counter(name for _, name in rows)
    seen: Counter[str] = Counter()
    labels = {}
    for robot_id, name in rows:
        seen[name] += 1
        labels[robot_id] = name if counts[name] == 1 or seen[name] == 1 else f"{name} ({seen[name]})"
    return labels


def robot_of(robot_id: str | None, request: dict[str, Any], labels: dict[str, str]) -> str:
    """The robot a plan or job was made for, by name: a stored robot's label, an inline robot's
    name, or (the robot deleted since) what the request named."""
    if robot_id is not None and robot_id in labels:
        return labels[robot_id]
    inline = request.get("robot")
    if isinstance(inline, dict) and inline.get("name"):
        return f"{inline['name']} (inline)"
    return "deleted robot" if request.get("robot_id") else "inline robot"


def path_type(task: dict[str, Any] | None) -> str:
    """A task's path type (``line`` for requests stored before paths had types)."""
    path = (task or {}).get("path") or {}
    return str(path.get("type") or "line")


def objective_text(metrics: dict[str, Any]) -> str | None:
    """B as the pages show it: ``infeasible`` where it is null (a broken speed or position limit
    makes B infinite), else None (show the number)."""
    value = metrics.get("objective_b")
    return "infeasible" if value is None or not math.isfinite(float(value)) else None


def _plan_row(row: Any, labels: dict[str, str]) -> dict[str, Any]:
    request = row.request or {}
    return {
        "id": row.id,
        "robot": robot_of(row.robot_id, request, labels),
        "path": path_type(request.get("task")),
        "method": row.method,
        "success": row.success,
        "metrics": row.metrics,
        "b_text": objective_text(row.metrics),
        "created_at": row.created_at,
    }


def _plans(session: Session, labels: dict[str, str], limit: int) -> list[dict[str, Any]]:
    rows = session.execute(
        select(Plan.id, Plan.robot_id, Plan.request, Plan.method, Plan.success, Plan.metrics, Plan.created_at)
        .order_by(Plan.created_at.desc(), Plan.id)
        .limit(limit)
    ).all()
    return [_plan_row(r, labels) for r in rows]


def index(db: Database) -> dict[str, Any]:
    with db.session() as s:
        labels = robot_labels(s)
        robots = s.scalars(select(Robot).order_by(Robot.created_at, Robot.id).limit(LISTED_ROBOTS)).all()
        jobs = s.scalars(select(TuningJob).order_by(TuningJob.created_at.desc(), TuningJob.id).limit(RECENT_JOBS)).all()
        return {
            "robots": [
                {"id": r.id, "label": labels[r.id], "preset": r.preset, "n_joints": len(r.parameters.get("links", []))}
                for r in robots
            ],
            "plans": _plans(s, labels, RECENT_PLANS),
            "jobs": [
                {
                    "id": j.id,
                    "status": j.status,
                    "method": j.request.get("method"),
                    "robot": robot_of(j.robot_id, j.request, labels),
                    "path": ", ".join(sorted({path_type(t) for t in j.request.get("tasks") or []})),
                    "progress": j.progress or {},
                    "created_at": j.created_at,
                }
                for j in jobs
            ],
        }


def replay_verdict(success: bool, replay: dict[str, Any] | None, position_only: bool = False) -> str | None:
    """What the replay says about the plan's verdict, in words: whether the independently
    re-integrated motion stays on the path (within the plan's tolerances, 5 cm and 5 deg; the
    position alone for a task that tracks the position only), and so whether it confirms the
    plan's success or its failure."""
    if not replay:
        return None
    if not replay.get("success"):
        return f"not replayed: {replay.get('message')}"
    position = replay.get("path_position_error_max_m")
    attitude = None if position_only else replay.get("path_attitude_error_max_rad")
    if position is None:
        return "the replay is not finite: it confirms the plan's failure" if not success else "the replay is not finite"
    within = position <= POSITION_TOLERANCE_M and (attitude is None or attitude <= ATTITUDE_TOLERANCE_RAD)
    angle = "" if attitude is None else f" and {_number(attitude, DEG)} deg"
    where = f"{_number(position, 1e3)} mm{angle} from the path at most"
    if within and success:
        return f"the replay stays on the path ({where}): it confirms the plan's success"
    if within:
        return f"the replay stays on the path ({where}); the plan failed on a joint limit, which the replay does not check"
    if not success:
        return f"the replay leaves the path too ({where}): it confirms the plan's failure"
    return f"the replay leaves the path ({where}) although the plan stayed on it"


def _number(value: float | None, scale: float) -> str:
    return "—" if value is None else f"{value * scale:.3g}"


def plan(db: Database, plan_id: str) -> dict[str, Any] | None:
    """A plan's page: its summary, robot and path, metrics, and the replay in words and rows."""
    found = compare(db, [plan_id])
    return found[0] if found else None


def compare(db: Database, plan_ids: Sequence[str]) -> list[dict[str, Any]]:
    """The pages of the plans ``plan_ids`` that exist, in that order."""
    with db.session() as s:
        labels = robot_labels(s)
        rows = s.execute(
            select(
                Plan.id,
                Plan.robot_id,
                Plan.request,
                Plan.method,
                Plan.success,
                Plan.message,
                Plan.metrics,
                Plan.replay,
                Plan.elapsed_s,
                Plan.created_at,
            ).where(Plan.id.in_(list(plan_ids)))
        ).all()
        robots: dict[str, Any] = dict(
            s.execute(select(Robot.id, Robot.parameters).where(Robot.id.in_({r.robot_id for r in rows}))).all()
        )
    by_id = {r.id: r for r in rows}
    out = []
    for plan_id in plan_ids:
        row = by_id.get(plan_id)
        if row is None:
            continue
        out.append(
            {
                **_plan_row(row, labels),
                "robot_id": row.robot_id,
                "message": row.message,
                "replay": row.replay,
                "replay_verdict": replay_verdict(row.success, row.replay, row.metrics.get("tracks") == "position"),
                "elapsed_s": row.elapsed_s,
                "units": metric_units(robots.get(row.robot_id) or (row.request or {}).get("robot"), row.metrics),
            }
        )
    return out


def metric_units(robot: dict[str, Any] | None, metrics: dict[str, Any]) -> dict[str, str]:
    """Units of the metrics card that depend on the plan: B's terms (the attitude term, none for
    a position task) and det J_g's (:func:`service.figures.gjm_units`, from the robot's joints)."""
    position_only = metrics.get("tracks") == "position"
    term = {"eq18": " + w2·m·rad", "angle": " + w2·rad"}.get(str(metrics.get("attitude_term")), " + w2·attitude term")
    out = {"objective_b": "w1·m" + ("" if position_only else term)}
    links = (robot or {}).get("links") or []
    rows = 3 if position_only else 6
    if len(links) == rows:
        prismatic = np.array([isinstance(link, dict) and link.get("joint_type") == "prismatic" for link in links])
        out["min_abs_det_gjm"] = figures.gjm_units(prismatic, rows)
    return out


def plan_choices(db: Database, limit: int = 50) -> list[dict[str, Any]]:
    """Recent plans for the compare form: id and a label (method, robot, path, verdict, time)."""
    with db.session() as s:
        plans = _plans(s, robot_labels(s), limit)
    return [{"id": p["id"], "label": choice_label(p)} for p in plans]


def choice_label(p: dict[str, Any]) -> str:
    params = " ".join(f"{k}={v:.4g}" for k, v in (p["method"].get("params") or {}).items())
    verdict = "ok" if p["success"] else "failed"
    return f"{p['method']['name']} {params} · {p['robot']} · {p['path']} · {verdict} · {p['created_at']:%H:%M:%S}".replace(
        "  ", " "
    )


def job(db: Database, job_id: str) -> dict[str, Any] | None:
    with db.session() as s:
        row = s.get(TuningJob, job_id)
        if row is None:
            return None
        return {
            "id": row.id,
            "status": row.status,
            "method": row.request.get("method"),
            "robot": robot_of(row.robot_id, row.request, robot_labels(s)),
            "request": row.request,
            "progress": row.progress or {},
            "result": row.result,
            "error": row.error,
            "created_at": row.created_at,
        }


def robot_options(db: Database) -> list[dict[str, str]]:
    """Every stored robot for the plan form's dropdown: id and label."""
    with db.session() as s:
        return [{"id": robot_id, "label": label} for robot_id, label in robot_labels(s).items()]

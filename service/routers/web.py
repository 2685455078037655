"""Server-rendered HTML pages (Jinja2, no external assets): the index at ``/`` with robots,
recent plans and tuning jobs and the forms; a plan page with its metrics and figures; a job
page with live progress (it polls the JSON API) and the convergence figure.

The forms post to ``/web/...``; those handlers forward the request to the JSON API in-process
(``httpx.ASGITransport`` on this same app, with the caller's headers), so the page goes through
exactly the validation, limits and authentication of ``POST /v1/plans`` and
``POST /v1/tuning-jobs``. All routes here are left out of the OpenAPI document."""

from __future__ import annotations

import hmac
import json
import math
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs

import httpx
from fastapi import APIRouter, Request
from fastapi.responses import HTMLResponse, RedirectResponse, Response
from jinja2 import Environment, FileSystemLoader, select_autoescape
from sqlalchemy import select

from engine.inverses import METHODS
from service import figures
from service.deps import get_db
from service.models import Plan, Robot, TuningJob
from service.routers.tasks import PRESETS
from service.security import KEY_COOKIE

router = APIRouter(include_in_schema=False)

TEMPLATES = Path(__file__).resolve().parent.parent / "templates"
env = Environment(loader=FileSystemLoader(TEMPLATES), autoescape=select_autoescape(["html"]))

FORWARDED_HEADERS = ("authorization", "cookie", "x-api-key")

METRIC_ROWS = [
    ("objective_b", "objective B", "", 1.0),
    ("position_error_max_m", "max position error", "mm", 1e3),
    ("position_error_rms_m", "RMS position error", "mm", 1e3),
    ("position_error_final_m", "final position error", "mm", 1e3),
    ("attitude_error_max_rad", "max attitude error", "deg", 180.0 / math.pi),
    ("attitude_error_rms_rad", "RMS attitude error", "deg", 180.0 / math.pi),
    ("attitude_error_final_rad", "final attitude error", "deg", 180.0 / math.pi),
    ("max_joint_speed_deg_s", "max joint speed", "deg/s", 1.0),
    ("joint_speed_limit_deg_s", "joint speed limit", "deg/s", 1.0),
    ("joint_speed_limit_respected", "speed limit respected", "", None),
    ("min_singular_value", "min singular value σ_min", "", 1.0),
    ("time_of_min_singular_value_s", "time of min σ_min", "s", 1.0),
    ("min_abs_det_gjm", "min |det J_g|", "", 1.0),
    ("time_of_min_abs_det_gjm_s", "time of min |det J_g|", "s", 1.0),
]


def fmt(value: Any, scale: float | None = 1.0) -> str:
    if value is None:
        return "—"
    if isinstance(value, bool) or scale is None:
        return "yes" if value else "no"
    if isinstance(value, int | float):
        v = float(value) * scale
        return f"{v:.4g}" if math.isfinite(v) else "—"
    return str(value)


env.filters["fmt"] = fmt


def page(name: str, status_code: int = 200, **context: Any) -> HTMLResponse:
    return HTMLResponse(env.get_template(name).render(**context), status_code=status_code)


def method_forms() -> list[dict[str, Any]]:
    return [
        {
            "name": name,
            "description": spec.description,
            "params": [{"name": p.name, "default": p.default, "unit": p.unit} for p in spec.params],
        }
        for name, spec in METHODS.items()
    ]


def index_context(request: Request) -> dict[str, Any]:
    with get_db(request).session() as s:
        robots = s.scalars(select(Robot).order_by(Robot.created_at, Robot.id).limit(50)).all()
        plans = s.execute(
            select(Plan.id, Plan.robot_id, Plan.method, Plan.success, Plan.metrics, Plan.created_at)
            .order_by(Plan.created_at.desc(), Plan.id)
            .limit(20)
        ).all()
        jobs = s.scalars(select(TuningJob).order_by(TuningJob.created_at.desc(), TuningJob.id).limit(20)).all()
        return {
            "robots": [
                {"id": r.id, "name": r.name, "preset": r.preset, "n_joints": len(r.parameters.get("links", []))} for r in robots
            ],
            "plans": [r._asdict() for r in plans],
            "jobs": [
                {
                    "id": j.id,
                    "status": j.status,
                    "method": j.request.get("method"),
                    "progress": j.progress or {},
                    "created_at": j.created_at,
                }
                for j in jobs
            ],
            "methods": method_forms(),
            "presets": list(PRESETS.values()),
        }


@router.get("/", response_class=HTMLResponse)
def index(request: Request) -> HTMLResponse:
    return page("index.html", form={}, **index_context(request))


@router.get("/plans/{plan_id}", response_class=HTMLResponse)
def plan_page(plan_id: str, request: Request) -> HTMLResponse:
    with get_db(request).session() as s:
        row = s.execute(
            select(
                Plan.id,
                Plan.robot_id,
                Plan.method,
                Plan.success,
                Plan.message,
                Plan.metrics,
                Plan.replay,
                Plan.elapsed_s,
                Plan.created_at,
            ).where(Plan.id == plan_id)
        ).first()
    if row is None:
        return page("error.html", 404, title="Plan not found", detail=f"plan {plan_id!r} does not exist")
    plan = row._asdict()
    return page(
        "plan.html",
        plan=plan,
        metric_rows=METRIC_ROWS,
        figure_names=list(figures.PLAN_FIGURES),
        figure_titles=figures.FIGURE_TITLES,
        threshold=figures.singular_threshold(plan["method"]),
    )


@router.get("/jobs/{job_id}", response_class=HTMLResponse)
def job_page(job_id: str, request: Request) -> HTMLResponse:
    with get_db(request).session() as s:
        job = s.get(TuningJob, job_id)
        if job is None:
            return page("error.html", 404, title="Tuning job not found", detail=f"tuning job {job_id!r} does not exist")
        data: dict[str, Any] = {
            "id": job.id,
            "status": job.status,
            "method": job.request.get("method"),
            "request": job.request,
            "progress": job.progress or {},
            "result": job.result,
            "error": job.error,
            "created_at": job.created_at,
        }
    return page("job.html", job=data, request_json=json.dumps(data["request"].get("ga", {})))


async def _form(request: Request) -> dict[str, str]:
    body = (await request.body()).decode("utf-8", errors="replace")
    return {k: v[-1] for k, v in parse_qs(body, keep_blank_values=True).items()}


async def _forward(request: Request, path: str, body: dict[str, Any]) -> httpx.Response:
    headers = {k: v for k, v in request.headers.items() if k.lower() in FORWARDED_HEADERS}
    key = request.cookies.get(KEY_COOKIE)
    if key and "authorization" not in {k.lower() for k in headers}:
        # The sign-in cookie (SameSite=Strict, so only our own pages send it) stands for the key.
        headers["authorization"] = f"Bearer {key}"
    transport = httpx.ASGITransport(app=request.app)
    async with httpx.AsyncClient(transport=transport, base_url="http://spacearm.internal", timeout=600) as client:
        return await client.post(path, json=body, headers=headers)


def _float(form: dict[str, str], key: str, default: float | None = None) -> float | None:
    text = form.get(key, "").strip()
    if not text:
        return default
    try:
        return float(text)
    except ValueError:
        return math.nan  # the API rejects it with a field path


def _plan_body(form: dict[str, str]) -> dict[str, Any]:
    preset = PRESETS.get(form.get("preset", "paper-line"), PRESETS["paper-line"])
    task = preset.task.model_dump()
    for key in ("duration_s", "dt_s", "joint_speed_limit_deg_s"):
        value = _float(form, key)
        if value is not None:
            task[key] = value
    method = form.get("method", "adaptive")
    params: dict[str, float] = {}
    spec = METHODS.get(method)
    for p in spec.params if spec else ():
        value = _float(form, f"{method}.{p.name}")
        if value is not None:
            params[p.name] = value
    return {
        "robot_id": form.get("robot_id") or preset.robot_id,
        "task": task,
        "method": {"name": method, "params": params},
        "feedback_gain": _float(form, "feedback_gain", 0.0),
        "replay": form.get("replay") == "on",
    }


def _problem_text(response: httpx.Response) -> str:
    try:
        problem = response.json()
    except ValueError:
        return f"{response.status_code}: {response.text[:500]}"
    errors = problem.get("errors") or []
    lines = [str(problem.get("detail", problem))] + [f"{e.get('field')}: {e.get('message')}" for e in errors]
    return "\n".join(lines)


@router.get("/login", response_class=HTMLResponse)
def login_page(next: str = "/") -> HTMLResponse:
    return page("login.html", next=_local(next))


@router.post("/login")
async def login(request: Request) -> Response:
    """Check a key and keep it in an HttpOnly, SameSite=Strict cookie for the pages."""
    form = await _form(request)
    key = form.get("key", "").strip()
    target = _local(form.get("next", "/"))
    keys = [k.encode() for k in request.app.state.settings.keys()]  # noqa: SIM118
    valid = False
    for known in keys:  # every key compared, in constant time
        valid |= hmac.compare_digest(key.encode(), known)
    if not keys:
        return RedirectResponse(target, status_code=303)  # authentication is off
    if not valid:
        return page("login.html", 401, next=target, error="that key is not valid")
    response = RedirectResponse(target, status_code=303)
    response.set_cookie(KEY_COOKIE, key, httponly=True, samesite="strict", path="/")
    return response


@router.get("/logout")
def logout() -> Response:
    response = RedirectResponse("/login", status_code=303)
    response.delete_cookie(KEY_COOKIE, path="/")
    return response


def _local(target: str) -> str:
    """Only redirect within this site."""
    return target if target.startswith("/") and not target.startswith("//") else "/"


@router.post("/web/plans")
async def submit_plan(request: Request) -> Response:
    form = await _form(request)
    response = await _forward(request, "/v1/plans", _plan_body(form))
    if response.status_code == 201:
        return RedirectResponse(f"/plans/{response.json()['id']}", status_code=303)
    context = index_context(request)
    return page("index.html", response.status_code, form=form, form_error=_problem_text(response), **context)


@router.post("/web/tuning-jobs")
async def submit_job(request: Request) -> Response:
    form = await _form(request)
    preset = PRESETS.get(form.get("preset", "paper-line"), PRESETS["paper-line"])
    population = _float(form, "population", 8.0)
    generations = _float(form, "generations", 5.0)
    body = {
        "robot_id": preset.robot_id,
        "tasks": [preset.task.model_dump()],
        "method": form.get("method", "adaptive"),
        "ga": {
            "population": int(population) if population is not None and math.isfinite(population) else population,
            "generations": int(generations) if generations is not None and math.isfinite(generations) else generations,
            "seed": 1,
        },
        "compare_with_dls": form.get("compare_with_dls") == "on",
    }
    response = await _forward(request, "/v1/tuning-jobs", body)
    if response.status_code in (200, 201, 202):
        return RedirectResponse(f"/jobs/{response.json()['id']}", status_code=303)
    context = index_context(request)
    return page("index.html", response.status_code, form={}, job_form_error=_problem_text(response), **context)

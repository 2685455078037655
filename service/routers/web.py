"""Server-rendered HTML pages (Jinja2, no external assets): the index at ``/`` with robots,
recent plans and tuning jobs and the forms; a plan page with its metrics and figures; a job
page with live progress (it polls the JSON API) and the convergence figure.

The forms post to ``/web/...``; those handlers check the form's CSRF token and its ``Origin``
(:func:`check_form`), then forward the request to the JSON API in-process
(``httpx.ASGITransport`` on this same app), so the page goes through exactly the validation and
limits of ``POST /v1/plans`` and ``POST /v1/tuning-jobs``. With keys configured, the pages need
a sign-in session (:mod:`service.infra.sessions`). All routes here are left out of the OpenAPI
document.

CSRF: every form carries a token. Signed in, it is the session's own token (kept server-side);
otherwise it is double-submitted: a random ``spacearm_csrf`` cookie (HttpOnly, SameSite=Strict)
that the form must echo. A form whose ``Origin`` (or, without one, ``Referer``) names another
site is refused either way."""

from __future__ import annotations

import hmac
import json
import math
import secrets
from typing import Any
from urllib.parse import parse_qs, urlsplit

import httpx
from fastapi import APIRouter, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import HTMLResponse, RedirectResponse, Response

from service import figures
from service.deps import JobId, PlanId, SessionRoute, get_db
from service.html import env
from service.infra.logs import REQUEST_ID
from service.infra.sessions import CSRF_COOKIE, SESSION_COOKIE, close_session, open_session
from service.usecases import pages, presets

router = APIRouter(include_in_schema=False, route_class=SessionRoute)

FORWARDED_HEADERS = ("x-request-id",)


def page(name: str, status_code: int = 200, *, request: Request | None = None, **context: Any) -> HTMLResponse:
    """A rendered page; with ``request``, its forms get the CSRF token (and a cookie if needed)."""
    token, fresh = csrf_token(request) if request is not None else ("", False)
    response = HTMLResponse(env.get_template(name).render(csrf_token=token, **context), status_code=status_code)
    if fresh:
        secure = request.app.state.settings.cookie_secure if request is not None else False
        response.set_cookie(CSRF_COOKIE, token, httponly=True, samesite="strict", secure=secure, path="/")
    return response


def csrf_token(request: Request) -> tuple[str, bool]:
    """The token the request's forms must carry: the session's, or the double-submit cookie's
    (``fresh`` when a new cookie must be set)."""
    session = request.scope.get("state", {}).get("web_session")
    if session is not None:
        return session.csrf_token, False
    existing = request.cookies.get(CSRF_COOKIE, "")
    return (existing, False) if len(existing) >= 32 else (secrets.token_urlsafe(32), True)


class FormRejectedError(Exception):
    pass


def check_form(request: Request, form: dict[str, str]) -> None:
    """Refuse a form from another site: its ``Origin`` (or ``Referer``) must be this site and its
    CSRF token must match (compared in constant time)."""
    host = request.headers.get("host", "")
    origin = request.headers.get("origin") or request.headers.get("referer") or ""
    if origin and urlsplit(origin).netloc != host:
        raise FormRejectedError(f"the form came from another site ({urlsplit(origin).netloc or origin})")
    expected, fresh = csrf_token(request)
    sent = form.get("csrf_token", "")
    if fresh or not sent or not hmac.compare_digest(sent.encode(), expected.encode()):
        raise FormRejectedError("the form has expired or was not sent by this site; reload the page and try again")


def rejected(request: Request, error: FormRejectedError) -> HTMLResponse:
    return page("error.html", 403, request=request, title="Form refused", detail=str(error))


def index_context(request: Request) -> dict[str, Any]:
    return {**pages.index(get_db(request)), "methods": pages.method_forms(), "presets": list(presets.PRESETS.values())}


@router.get("/", response_class=HTMLResponse)
def index(request: Request) -> HTMLResponse:
    return page("index.html", request=request, form={}, **index_context(request))


@router.get("/plans/{plan_id:id}", response_class=HTMLResponse)
def plan_page(plan_id: PlanId, request: Request) -> HTMLResponse:
    plan = pages.plan(get_db(request), plan_id)
    if plan is None:
        return page("error.html", 404, request=request, title="Plan not found", detail=f"plan {plan_id!r} does not exist")
    return page(
        "plan.html",
        request=request,
        plan=plan,
        metric_rows=pages.METRIC_ROWS,
        figure_names=list(figures.PLAN_FIGURES),
        figure_titles=figures.FIGURE_TITLES,
        threshold=figures.singular_threshold(plan["method"]),
    )


@router.get("/jobs/{job_id:id}", response_class=HTMLResponse)
def job_page(job_id: JobId, request: Request) -> HTMLResponse:
    data = pages.job(get_db(request), job_id)
    if data is None:
        return page(
            "error.html", 404, request=request, title="Tuning job not found", detail=f"tuning job {job_id!r} does not exist"
        )
    return page("job.html", request=request, job=data, request_json=json.dumps(data["request"].get("ga", {})))


async def _form(request: Request) -> dict[str, str]:
    body = (await request.body()).decode("utf-8", errors="replace")
    return {k: v[-1] for k, v in parse_qs(body, keep_blank_values=True).items()}


async def _forward(request: Request, path: str, body: dict[str, Any]) -> httpx.Response:
    headers = {k: v for k, v in request.headers.items() if k.lower() in FORWARDED_HEADERS}
    if (request_id := REQUEST_ID.get()) is not None:  # the given or generated id: one id in both requests' logs
        headers["x-request-id"] = request_id
    # The form passed check_form (and the session check, with keys configured): the in-process
    # request carries this process's internal token, which never leaves it.
    headers["authorization"] = f"Bearer {request.app.state.internal_token}"
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
    preset = presets.PRESETS.get(form.get("preset", "paper-line"), presets.PRESETS["paper-line"])
    task = preset.task.model_dump()
    for key in ("duration_s", "dt_s", "joint_speed_limit_deg_s"):
        value = _float(form, key)
        if value is not None:
            task[key] = value
    method = form.get("method", "adaptive")
    params: dict[str, float] = {}
    for p in pages.method_params(method):
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
def login_page(request: Request, next: str = "/") -> HTMLResponse:
    return page("login.html", request=request, next=_local(next))


@router.post("/login")
async def login(request: Request) -> Response:
    """Check a key and open a session (:mod:`service.infra.sessions`): the cookie holds the session's
    random token (HttpOnly, SameSite=Strict, Secure when configured), never the key."""
    form = await _form(request)
    target = _local(form.get("next", "/"))
    try:
        check_form(request, form)
    except FormRejectedError as error:
        return rejected(request, error)
    key = form.get("key", "").strip()
    settings = request.app.state.settings
    keys = settings.keys()
    if not keys:
        return RedirectResponse(target, status_code=303)  # authentication is off
    valid = False
    for known in keys:  # every key compared, in constant time
        valid |= hmac.compare_digest(key.encode(), known.encode())
    if not valid:
        return page("login.html", 401, request=request, next=target, error="that key is not valid")
    token, _ = await run_in_threadpool(open_session, get_db(request), key, settings.session_hours)
    response = RedirectResponse(target, status_code=303)
    max_age = int(settings.session_hours * 3600)
    response.set_cookie(
        SESSION_COOKIE, token, httponly=True, samesite="strict", secure=settings.cookie_secure, path="/", max_age=max_age
    )
    response.delete_cookie(CSRF_COOKIE, path="/")
    return response


@router.get("/logout", response_class=HTMLResponse)
def logout_page(request: Request) -> HTMLResponse:
    return page("logout.html", request=request)


@router.post("/logout")
async def logout(request: Request) -> Response:
    """End the session: its row is deleted, so the cookie no longer opens anything anywhere."""
    form = await _form(request)
    try:
        check_form(request, form)
    except FormRejectedError as error:
        return rejected(request, error)
    await run_in_threadpool(close_session, get_db(request), request.cookies.get(SESSION_COOKIE, ""))
    response = RedirectResponse("/login", status_code=303)
    response.delete_cookie(SESSION_COOKIE, path="/")
    return response


def _local(target: str) -> str:
    """Only redirect within this site."""
    return target if target.startswith("/") and not target.startswith("//") else "/"


@router.post("/web/plans")
async def submit_plan(request: Request) -> Response:
    form = await _form(request)
    try:
        check_form(request, form)
    except FormRejectedError as error:
        return rejected(request, error)
    response = await _forward(request, "/v1/plans", _plan_body(form))
    if response.status_code == 201:
        return RedirectResponse(f"/plans/{response.json()['id']}", status_code=303)
    context = index_context(request)
    return page("index.html", response.status_code, request=request, form=form, form_error=_problem_text(response), **context)


@router.post("/web/tuning-jobs")
async def submit_job(request: Request) -> Response:
    form = await _form(request)
    try:
        check_form(request, form)
    except FormRejectedError as error:
        return rejected(request, error)
    preset = presets.PRESETS.get(form.get("preset", "paper-line"), presets.PRESETS["paper-line"])
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
    return page("index.html", response.status_code, request=request, form={}, job_form_error=_problem_text(response), **context)

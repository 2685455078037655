"""Server-rendered HTML pages (Jinja2, no external assets): the index at ``/`` with robots
(by name), recent plans and tuning jobs and the forms (plan, tune, upload a robot, compare two
plans, delete); a plan page with its metrics, replay and figures; two plans compared
(``/plans/compare``); a plan's interactive 3D view (``/plans/{id}/view``, three.js, with its
scene at ``/plans/{id}/scene.json``); a job page with live progress (it follows the JSON API).

The forms post to ``/web/...``; those handlers check the form's CSRF token and its ``Origin``
(:func:`check_form`), then forward the request to the JSON API in-process
(``httpx.ASGITransport`` on this same app), so the page goes through exactly the validation and
limits of ``POST /v1/plans``, ``POST /v1/tuning-jobs``, ``POST /v1/robots`` and the ``DELETE``s.
The API's errors come back next to the form's fields (:mod:`service.usecases.forms`). With keys
configured, the pages need a sign-in session (:mod:`service.infra.sessions`). All routes here are
left out of the OpenAPI document.

CSRF: every form carries a token. Signed in, it is the session's own token (kept server-side);
otherwise it is double-submitted: a random ``spacearm_csrf`` cookie (HttpOnly, SameSite=Strict)
that the form must echo. A form whose ``Origin`` (or, without one, ``Referer``) names another
site is refused either way."""

from __future__ import annotations

import hmac
import json
import secrets
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, quote, urlsplit

import httpx
from fastapi import APIRouter, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse, HTMLResponse, JSONResponse, RedirectResponse, Response
from starlette.datastructures import UploadFile

from service import figures
from service.deps import JobId, PlanId, SessionRoute, get_db
from service.html import env
from service.infra.logs import REQUEST_ID
from service.infra.sessions import CSRF_COOKIE, SESSION_COOKIE, close_session, open_session
from service.usecases import forms, pages, presets, scene

router = APIRouter(include_in_schema=False, route_class=SessionRoute)

FORWARDED_HEADERS = ("x-request-id",)
FAVICON = Path(__file__).resolve().parents[1] / "static" / "favicon.ico"


def page(name: str, status_code: int = 200, *, request: Request | None = None, **context: Any) -> HTMLResponse:
    """A rendered page; with ``request``, its forms get the CSRF token (and a cookie if needed)."""
    token, fresh = csrf_token(request) if request is not None else ("", False)
    response = HTMLResponse(env().get_template(name).render(csrf_token=token, **context), status_code=status_code)
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
    db = get_db(request)
    return {
        **pages.index(db),
        "robot_options": pages.robot_options(db),
        "plan_choices": pages.plan_choices(db),
        "figure_titles": figures.FIGURE_TITLES,
        "methods": pages.method_forms(),
        "presets": list(presets.PRESETS.values()),
        "paper_values": pages.PAPER_VALUES,
    }


def index_page(request: Request, status_code: int = 200, **context: Any) -> HTMLResponse:
    """The index with the forms' state: ``form``/``errors`` (plan form), ``job_errors``,
    ``robot_form``/``robot_errors``, ``notice`` (an error of a delete)."""
    defaults: dict[str, Any] = {"form": {}, "errors": forms.FormErrors(), "job_form": {}, "job_errors": forms.FormErrors()}
    defaults |= {"robot_form": {}, "robot_errors": forms.FormErrors(), "notice": None}
    return page("index.html", status_code, request=request, **(defaults | context), **index_context(request))


@router.get("/", response_class=HTMLResponse)
def index(request: Request) -> HTMLResponse:
    # The query may fill the plan form (a link to the paper's own values does).
    return index_page(request, form=dict(request.query_params))


@router.get("/favicon.ico")
def favicon() -> FileResponse:
    """The site's icon (browsers ask for it at this path, also on the API's JSON and docs)."""
    return FileResponse(FAVICON, media_type="image/x-icon", headers={"Cache-Control": "public, max-age=86400"})


def _plan_context(plan: dict[str, Any]) -> dict[str, Any]:
    return {
        "plan": plan,
        "metric_rows": pages.METRIC_ROWS,
        "replay_rows": pages.REPLAY_ROWS,
        "threshold": figures.singular_threshold(plan["method"]),
    }


@router.get("/plans/{plan_id:id}", response_class=HTMLResponse)
def plan_page(plan_id: PlanId, request: Request) -> HTMLResponse:
    plan = pages.plan(get_db(request), plan_id)
    if plan is None:
        return page("error.html", 404, request=request, title="Plan not found", detail=f"plan {plan_id!r} does not exist")
    return page(
        "plan.html",
        request=request,
        **_plan_context(plan),
        figure_names=list(figures.PLAN_FIGURES),
        figure_titles=figures.FIGURE_TITLES,
        plan_choices=[c for c in pages.plan_choices(get_db(request)) if c["id"] != plan_id],
    )


@router.get("/plans/compare", response_class=HTMLResponse)
def compare_page(request: Request, a: str = "", b: str = "", figure: str = "joint-velocities") -> HTMLResponse:
    """Two plans side by side: their metrics and replays in one table, and any figure of both
    (``GET /v1/plans/compare/figures/{figure}``)."""
    db = get_db(request)
    choices = pages.plan_choices(db)
    if not a and not b and len(choices) >= 2:  # the two latest plans
        a, b = choices[1]["id"], choices[0]["id"]
    ids = [i for i in (a.strip(), b.strip()) if i]
    found = pages.compare(db, ids)
    missing = [i for i in ids if i not in {p["id"] for p in found}]
    context: dict[str, Any] = {
        "plans": found,
        "figure": figure if figure in figures.COMPARE_FIGURES else "joint-velocities",
        "figure_titles": figures.FIGURE_TITLES,
        "plan_choices": choices,
        "a": a,
        "b": b,
        "metric_rows": pages.METRIC_ROWS,
        "replay_rows": pages.REPLAY_ROWS,
    }
    if len(ids) != 2 or missing or a == b:
        detail = "choose two different plans" if not missing else f"no plan {', '.join(map(repr, missing))}"
        return page("compare.html", 404 if missing else 200, request=request, error=detail, **context)
    return page("compare.html", request=request, error=None, **context)


@router.get("/plans/{plan_id:id}/view", response_class=HTMLResponse)
def view_page(plan_id: PlanId, request: Request) -> HTMLResponse:
    """The plan's motion played back in 3D (``/static/view3d.js``: three.js, bundled offline)."""
    plan = pages.plan(get_db(request), plan_id)
    if plan is None:
        return page("error.html", 404, request=request, title="Plan not found", detail=f"plan {plan_id!r} does not exist")
    return page("view3d.html", request=request, plan=plan)


@router.get("/plans/{plan_id:id}/scene.json")
def scene_json(plan_id: PlanId, request: Request) -> JSONResponse:
    """The 3D view's scene: the arm's joint positions per frame (forward kinematics on the
    server), the carrier's box, obstacles (:mod:`service.usecases.scene`)."""
    return JSONResponse(scene.scene(get_db(request), plan_id), headers={"Cache-Control": "public, max-age=86400"})


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


async def _forward(request: Request, method: str, path: str, body: dict[str, Any] | None = None) -> httpx.Response:
    headers = {k: v for k, v in request.headers.items() if k.lower() in FORWARDED_HEADERS}
    if (request_id := REQUEST_ID.get()) is not None:  # the given or generated id: one id in both requests' logs
        headers["x-request-id"] = request_id
    # The form passed check_form (and the session check, with keys configured): the in-process
    # request carries this process's internal token, which never leaves it.
    headers["authorization"] = f"Bearer {request.app.state.internal_token}"
    transport = httpx.ASGITransport(app=request.app)
    # The page's own Host passed the allowlist, so the in-process request carries it too.
    base_url = f"http://{request.headers.get('host') or request.app.state.settings.internal_host()}"
    async with httpx.AsyncClient(transport=transport, base_url=base_url, timeout=600) as client:
        return await client.request(method, path, json=body, headers=headers)


def _errors(response: httpx.Response, locate: forms.Locator) -> forms.FormErrors:
    try:
        problem = response.json()
    except ValueError:
        problem = None
    return forms.form_errors(response.status_code, problem if isinstance(problem, dict) else None, locate, response.text)


@router.get("/login", response_class=HTMLResponse)
def login_page(request: Request, next: str = "/") -> HTMLResponse:
    return page("login.html", request=request, next=_local(next))


@router.post("/login")
async def login(request: Request) -> Response:
    """Check a key and open a session (:mod:`service.infra.sessions`): the cookie holds the session's
    random token (HttpOnly, SameSite=Strict, Secure when configured), never the key. Attempts are
    limited per client address (:mod:`service.infra.ratelimit`): beyond, 429 with ``Retry-After``."""
    form = await _form(request)
    target = _local(form.get("next", "/"))
    wait_s = request.app.state.login_limiter.hit(request.client.host if request.client else "")
    if wait_s is not None:
        refused = page("login.html", 429, request=request, next=target, error=f"too many attempts: try again in {wait_s} s")
        refused.headers["Retry-After"] = str(wait_s)
        return refused
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
    response = await _forward(request, "POST", "/v1/plans", forms.plan_body(form))
    if response.status_code == 201:
        return RedirectResponse(f"/plans/{response.json()['id']}", status_code=303)
    errors = _errors(response, forms.plan_locator(form.get("method", "adaptive")))
    return index_page(request, response.status_code, form=form, errors=errors)


@router.post("/web/tuning-jobs")
async def submit_job(request: Request) -> Response:
    form = await _form(request)
    try:
        check_form(request, form)
    except FormRejectedError as error:
        return rejected(request, error)
    response = await _forward(request, "POST", "/v1/tuning-jobs", forms.job_body(form))
    if response.status_code in (200, 201, 202):
        return RedirectResponse(f"/jobs/{response.json()['id']}", status_code=303)
    return index_page(request, response.status_code, job_form=form, job_errors=_errors(response, forms.job_locator))


@router.post("/web/robots")
async def upload_robot(request: Request) -> Response:
    """Store an uploaded robot file (JSON parameters or URDF; multipart form with ``file``, or the
    document pasted in ``document``) through ``POST /v1/robots``; back to the robots' list."""
    form: dict[str, str] = {}
    document = ""
    async with request.form(max_files=1, max_fields=20) as data:
        for key, value in data.multi_items():
            if isinstance(value, UploadFile):
                document = (await value.read()).decode("utf-8", errors="replace")
                form["filename"] = value.filename or ""
            else:
                form[key] = value
    try:
        check_form(request, form)
    except FormRejectedError as error:
        return rejected(request, error)
    document = document or form.get("document", "")
    try:
        body = forms.robot_body(document, form.get("end_effector_link", ""), form.get("name", ""))
    except forms.RobotFileError as exc:
        return index_page(request, 422, robot_form=form, robot_errors=forms.FormErrors(fields={"file": str(exc)}))
    response = await _forward(request, "POST", "/v1/robots", body)
    if response.status_code == 201:
        return RedirectResponse(f"/?robot={quote(response.json()['id'])}#robots", status_code=303)
    return index_page(request, response.status_code, robot_form=form, robot_errors=_errors(response, forms.robot_locator))


DELETABLE = {"robots": ("/v1/robots/", "robots"), "plans": ("/v1/plans/", "plans"), "tuning-jobs": ("/v1/tuning-jobs/", "jobs")}


@router.post("/web/{kind}/{item_id}/delete")
async def delete_item(kind: str, item_id: str, request: Request) -> Response:
    """Delete a robot, plan or tuning job through the API's ``DELETE``; back to its list on the
    index (a refusal, such as a preset robot's 409, is shown there)."""
    form = await _form(request)
    try:
        check_form(request, form)
    except FormRejectedError as error:
        return rejected(request, error)
    if kind not in DELETABLE:
        return page("error.html", 404, request=request, title="Not found", detail=f"nothing to delete at {kind!r}")
    prefix, section = DELETABLE[kind]
    response = await _forward(request, "DELETE", prefix + quote(item_id, safe=""))
    if response.status_code == 204:
        return RedirectResponse(f"/#{section}", status_code=303)
    errors = _errors(response, lambda loc: ("", loc))
    return index_page(request, response.status_code, notice=f"could not delete {item_id}: {'; '.join(errors.general)}")

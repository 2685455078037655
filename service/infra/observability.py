"""Request ids and HTTP metrics: one pure ASGI middleware around the whole application (outside
Starlette's error middleware, so even a 500 from an unexpected exception carries the id and is
counted).

- ``X-Request-ID``: taken from the request when it is 1 to 128 printable ASCII characters
  (``!`` to ``~``), a new ``uuid4().hex`` otherwise; echoed on every response and set in
  :data:`service.infra.logs.REQUEST_ID` for the request's log lines (the access log's too).
- :data:`service.infra.metrics.HTTP_REQUESTS` / ``HTTP_SECONDS``: by method, route template
  (``/v1/plans/{plan_id}``, never the raw path: ids would make a series each) and status;
  requests that reach no route (unknown paths, answers of the guards before routing: 400, 401,
  413, OPTIONS) count under the route ``<unrouted>``.
"""

from __future__ import annotations

import re
import time
import uuid
from contextvars import ContextVar
from typing import Any

from fastapi import FastAPI
from starlette.routing import BaseRoute, Match, Mount, Route
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.infra import metrics
from service.infra.logs import REQUEST_ID

HEADER = b"x-request-id"
VALID_ID = re.compile(rb"[\x21-\x7e]{1,128}")
METHODS = frozenset({"GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS"})
UNROUTED = "<unrouted>"

#: Set in a task whose requests are not counted (the API's own warm-up requests at start-up).
UNCOUNTED: ContextVar[bool] = ContextVar("spacearm_uncounted", default=False)


def request_id(scope: Scope) -> str:
    """The request's valid ``X-Request-ID``, or a new one."""
    for name, value in scope.get("headers", []):
        if name == HEADER:
            return value.decode("ascii") if VALID_ID.fullmatch(value) else uuid.uuid4().hex
    return uuid.uuid4().hex


def route_template(routes: list[BaseRoute], scope: Scope) -> str:
    """The path template of the route that answered (set in the scope by the router), else of the
    first top-level route or mount matching the path (docs, static files), else ``<unrouted>``."""
    route = scope.get("route")
    template = getattr(route, "path_format", None)
    if isinstance(template, str):
        return template
    for candidate in routes:
        if isinstance(candidate, Route | Mount) and candidate.matches(scope)[0] is not Match.NONE:
            return candidate.path_format
    return UNROUTED


class ObservabilityMiddleware:
    def __init__(self, app: ASGIApp, routes: list[BaseRoute]) -> None:
        self.app = app
        self.routes = routes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        rid = request_id(scope)
        token = REQUEST_ID.set(rid)
        header = (HEADER, rid.encode("ascii"))
        status = 500  # unless a response starts

        async def sender(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = int(message["status"])
                headers = [(k, v) for k, v in message.get("headers", []) if k.lower() != HEADER]
                message = dict(message, headers=[*headers, header])
            await send(message)

        counted = not UNCOUNTED.get()
        start = time.perf_counter()
        if counted:
            metrics.HTTP_IN_PROGRESS.inc()
        try:
            await self.app(scope, receive, sender)
        except BaseException:
            # REQUEST_ID stays set: uvicorn logs the traceback from this task after we return
            self._count(counted, scope, status, start)
            raise
        self._count(counted, scope, status, start)
        REQUEST_ID.reset(token)

    def _count(self, counted: bool, scope: Scope, status: int, start: float) -> None:
        if not counted:
            return
        metrics.HTTP_IN_PROGRESS.dec()
        method = scope.get("method", "")
        labels = (method if method in METHODS else "other", route_template(self.routes, scope), str(status))
        metrics.HTTP_REQUESTS.labels(*labels).inc()
        metrics.HTTP_SECONDS.labels(*labels).observe(time.perf_counter() - start)


def install(app: FastAPI) -> None:
    """Wrap ``app``'s whole middleware stack (built on its first request) in
    :class:`ObservabilityMiddleware`; the app's metrics registry (served by ``GET /metrics``,
    :mod:`service.routers.metrics`)."""
    app.state.metrics_registry = metrics.registry_for(lambda: getattr(app.state, "db", None))
    build = app.build_middleware_stack

    def build_observed() -> Any:
        return ObservabilityMiddleware(build(), app.routes)

    app.build_middleware_stack = build_observed  # type: ignore[method-assign]

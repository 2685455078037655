"""HTTP details the routers do not handle themselves (a pure ASGI middleware, so it covers
every route, present and future):

- ``HEAD`` on every ``GET`` route: answered by the ``GET`` handler without the body (the headers,
  ``Content-Length`` included, are the ``GET``'s).
- ``OPTIONS`` on every path: 204 with the complete ``Allow`` (404 for an unknown path); a 405
  carries the complete ``Allow`` too (several routes may share a path, one per method).
- A request with both ``Content-Length`` and ``Transfer-Encoding`` is refused with 400: the two
  disagree on where the body ends, the shape of a request-smuggling attempt (RFC 9112 6.3).
"""

from __future__ import annotations

from starlette.routing import Match, Mount
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.errors import problem

PROBED = ("GET", "POST", "PUT", "PATCH", "DELETE")


def allowed_methods(app: ASGIApp, scope: Scope) -> list[str]:
    """Every method some route accepts at ``scope``'s path (with HEAD for GET, and OPTIONS):
    each method is probed against the routes (included routers answer a full match only for
    their own methods), a mount (the static files) answers reads."""
    methods: set[str] = set()
    for route in getattr(app, "routes", []):
        if isinstance(route, Mount):
            if route.matches(dict(scope, method="GET"))[0] is not Match.NONE:
                methods.add("GET")
            continue
        methods |= {m for m in PROBED if route.matches(dict(scope, method=m))[0] is Match.FULL}
    if not methods:
        return []
    if "GET" in methods:
        methods.add("HEAD")
    methods.add("OPTIONS")
    order = ["GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS"]
    return sorted(methods, key=order.index)


class MethodsMiddleware:
    def __init__(self, app: ASGIApp, router: ASGIApp) -> None:
        self.app = app
        self.router = router  # the FastAPI app, whose routes are matched

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = {name for name, _ in scope.get("headers", [])}
        if b"content-length" in headers and b"transfer-encoding" in headers:
            detail = "the request has both Content-Length and Transfer-Encoding; send one of them"
            await problem(400, detail, instance=scope.get("path"))(scope, receive, send)
            return
        method = scope["method"]
        if method == "OPTIONS" and not any(name == b"access-control-request-method" for name in headers):
            allowed = allowed_methods(self.router, scope)
            if not allowed:
                await problem(404, "no such resource", instance=scope.get("path"))(scope, receive, send)
                return
            await send({"type": "http.response.start", "status": 204, "headers": [(b"allow", ", ".join(allowed).encode())]})
            await send({"type": "http.response.body", "body": b""})
            return
        if method == "HEAD":
            get = dict(scope, method="GET")
            await self.app(get, receive, _without_body(send))
            if "route" in get:  # for the metrics' route label (service.infra.observability)
                scope["route"] = get["route"]
            return
        await self.app(scope, receive, self._complete_allow(scope, send))

    def _complete_allow(self, scope: Scope, send: Send) -> Send:
        async def sender(message: Message) -> None:
            if message["type"] == "http.response.start" and message["status"] == 405:
                allowed = ", ".join(allowed_methods(self.router, scope)).encode()
                kept = [(k, v) for k, v in message.get("headers", []) if k.lower() != b"allow"]
                message = dict(message, headers=[*kept, (b"allow", allowed)])
            await send(message)

        return sender


def _without_body(send: Send) -> Send:
    async def sender(message: Message) -> None:
        if message["type"] == "http.response.body":
            message = dict(message, body=b"")
        await send(message)

    return sender

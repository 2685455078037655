"""Guards in front of the routers (pure ASGI middleware, so they cover every router, present and
future):

- ``BodyLimitMiddleware``: request bodies over ``SPACEARM_MAX_BODY_BYTES`` (1 MiB) get 413, from
  ``Content-Length`` before anything is read, and by counting the bytes as they arrive when there
  is no ``Content-Length`` (chunked uploads).
- ``BearerAuthMiddleware``: with ``SPACEARM_API_KEYS`` set, every request under ``/v1`` needs
  ``Authorization: Bearer <key>`` (401 with ``WWW-Authenticate: Bearer`` otherwise); the web
  pages need the sign-in cookie set by ``POST /login`` (GETs under ``/v1`` accept it too). Keys are
  compared with :func:`hmac.compare_digest` against every configured key and never logged.
  ``/healthz``, ``/readyz``, ``/openapi.json``, ``/docs`` and ``/login`` stay open.
"""

from __future__ import annotations

import hmac
import logging
from urllib.parse import quote

from fastapi import FastAPI
from starlette.responses import RedirectResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.errors import BodyTooLargeError, field_error, problem
from service.settings import Settings

log = logging.getLogger("spacearm.api")


class BodyLimitMiddleware:
    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        for name, value in scope.get("headers", []):
            if name == b"content-length":
                try:
                    declared = int(value)
                except ValueError:
                    declared = 0
                if declared > self.max_bytes:
                    detail = f"request body of {declared} bytes is larger than {self.max_bytes} bytes"
                    response = problem(413, detail, instance=scope.get("path"), errors=[field_error(["body"], detail)])
                    await response(scope, receive, send)
                    return
        received = 0

        async def limited() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.max_bytes:
                    raise BodyTooLargeError(self.max_bytes)
            return message

        try:
            await self.app(scope, limited, send)
        except BodyTooLargeError as exc:  # read outside FastAPI's body parsing (no handler saw it)
            response = problem(413, str(exc.detail), instance=scope.get("path"), errors=[field_error(["body"], str(exc.detail))])
            await response(scope, receive, send)


#: Cookie that carries an API key for the web pages (set by ``POST /login``: HttpOnly,
#: SameSite=Strict, so other sites cannot make a browser send it).
KEY_COOKIE = "spacearm_key"
PAGE_PREFIXES = ("/plans/", "/jobs/", "/web/")


def _protected(path: str) -> bool:
    return path == "/v1" or path.startswith("/v1/")


def _page(path: str) -> bool:
    """The web pages, which read the database directly and so need a key like ``/v1``."""
    return path == "/" or path.startswith(PAGE_PREFIXES)


def _cookie(scope: Scope) -> bytes:
    for name, value in scope.get("headers", []):
        if name == b"cookie":
            for part in value.split(b";"):
                key, _, token = part.strip().partition(b"=")
                if key == KEY_COOKIE.encode():
                    return token.strip()
    return b""


class BearerAuthMiddleware:
    def __init__(self, app: ASGIApp, keys: list[str]) -> None:
        self.app = app
        self.keys = [k.encode() for k in keys]

    def _valid(self, token: bytes) -> bool:
        ok = False
        for key in self.keys:  # every key compared, in constant time
            ok |= hmac.compare_digest(token, key)
        return ok

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        path = scope.get("path", "") if scope["type"] == "http" else ""
        api, web = _protected(path), _page(path)
        if not self.keys or not (api or web):
            await self.app(scope, receive, send)
            return
        header = b""
        for name, value in scope.get("headers", []):
            if name == b"authorization":
                header = value
                break
        scheme, _, token = header.partition(b" ")
        if scheme.lower() == b"bearer" and token.strip() and self._valid(token.strip()):
            await self.app(scope, receive, send)
            return
        # The sign-in cookie opens the pages, and reads under /v1 (the pages' figures and job
        # polling); writes under /v1 still need the Authorization header.
        cookie = _cookie(scope)
        read = scope.get("method") in ("GET", "HEAD")
        if cookie and self._valid(cookie) and (web or read):
            await self.app(scope, receive, send)
            return
        if web and read:
            await RedirectResponse(f"/login?next={quote(path)}", status_code=303)(scope, receive, send)
            return
        challenge = 'Bearer realm="spacearm"' + ("" if not header else ', error="invalid_token"')
        detail = "missing API key: send Authorization: Bearer <key>" if not header else "invalid API key"
        response = problem(
            401,
            detail,
            instance=scope.get("path"),
            headers={"WWW-Authenticate": challenge},
            errors=[field_error(["header", "Authorization"], detail)],
        )
        await response(scope, receive, send)


def install(app: FastAPI, settings: Settings) -> None:
    """Add the guards to ``app`` and say in the start-up log whether authentication is on."""
    keys = settings.keys()
    app.add_middleware(BodyLimitMiddleware, max_bytes=settings.max_body_bytes)
    app.add_middleware(BearerAuthMiddleware, keys=keys)  # added last = outermost: unauthenticated bodies are never read
    if keys:
        log.info("authentication is on: /v1 requires a bearer key (%d key(s) configured)", len(keys))
    else:
        log.warning(
            "authentication is OFF (SPACEARM_API_KEYS is not set): anyone who can reach the API can use it; the API binds to %s",
            settings.host,
        )

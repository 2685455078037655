"""Guards in front of the routers (pure ASGI middleware, so they cover every router, present and
future):

- ``TrustedHosts`` (Starlette's ``TrustedHostMiddleware``): only the ``Host`` names of
  ``SPACEARM_ALLOWED_HOSTS`` (default: the bind address and localhost) are answered, others get a
  400 problem detail, so a web page whose name was rebound to this machine's address (DNS
  rebinding) cannot drive the API.
- ``BodyLimitMiddleware``: request bodies over ``SPACEARM_MAX_BODY_BYTES`` (1 MiB) get 413, from
  ``Content-Length`` before anything is read, and by counting the bytes as they arrive when there
  is no ``Content-Length`` (chunked uploads).
- ``BearerAuthMiddleware``: with ``SPACEARM_API_KEYS`` set, every request under ``/v1`` (and to
  ``/metrics``) needs ``Authorization: Bearer <key>`` (401 with ``WWW-Authenticate: Bearer``
  otherwise); the web
  pages need a sign-in session (``POST /login``, :mod:`service.infra.sessions`; GETs under ``/v1``
  accept it too, ``/metrics`` does not). Keys are compared with :func:`hmac.compare_digest` against every configured
  key and never logged. ``/healthz``, ``/readyz``, ``/openapi.json``, ``/docs``, ``/static`` and
  ``/login`` stay open.
- ``MethodsMiddleware`` (:mod:`service.infra.http`): HEAD and OPTIONS everywhere, complete ``Allow``.
- ``CORSMiddleware`` (Starlette's), only with ``SPACEARM_CORS_ORIGINS``: pages of those origins
  may call the API. It answers preflights itself, outside the bearer check (a preflight carries no
  credentials) and outside ``MethodsMiddleware`` (which answers a plain ``OPTIONS`` with ``Allow``
  and leaves preflights alone). No cookies cross origins: a key is sent as a bearer header.
- ``SecurityHeadersMiddleware``: nosniff everywhere; CSP, no framing, no referrer and no caching
  (the pages carry CSRF tokens) on pages.
"""

from __future__ import annotations

import hmac
import logging
import secrets
from urllib.parse import quote

import anyio
from fastapi import FastAPI
from starlette.datastructures import Headers
from starlette.middleware.cors import CORSMiddleware
from starlette.middleware.trustedhost import TrustedHostMiddleware
from starlette.responses import RedirectResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.errors import BodyTooLargeError, field_error, problem
from service.infra.http import MethodsMiddleware
from service.infra.sessions import SESSION_COOKIE, find_session
from service.infra.settings import Settings

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


class TrustedHosts(TrustedHostMiddleware):
    """Starlette's check of the ``Host`` header, whose refusal (a plain-text "Invalid host
    header") goes out as a problem detail like every other error: the check passes a request on
    through :meth:`_trusted`, which marks its scope, so a response of an unmarked request is the
    refusal."""

    MARK = "spacearm.trusted_host"

    def __init__(self, app: ASGIApp, allowed_hosts: list[str]) -> None:
        self.inner = app
        super().__init__(self._trusted, allowed_hosts=allowed_hosts, www_redirect=False)

    async def _trusted(self, scope: Scope, receive: Receive, send: Send) -> None:
        scope[self.MARK] = True
        await self.inner(scope, receive, send)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await super().__call__(scope, receive, send)
            return

        async def sender(message: Message) -> None:
            if scope.get(self.MARK):
                await send(message)
            elif message["type"] == "http.response.start":
                host = Headers(scope=scope).get("host")
                detail = (
                    f"this API does not answer the Host {host!r} (SPACEARM_ALLOWED_HOSTS lists the names it answers)"
                    if host
                    else "the request has no Host header"
                )
                response = problem(400, detail, instance=scope.get("path"), errors=[field_error(["header", "host"], detail)])
                await response(scope, receive, send)
            # the refusal's own plain-text body is dropped

        await super().__call__(scope, receive, sender)


PAGE_PREFIXES = ("/plans/", "/jobs/", "/web/")


def _protected(path: str) -> bool:
    return path == "/v1" or path.startswith("/v1/") or path == "/metrics"


def _page(path: str) -> bool:
    """The web pages, which read the database directly and so need a key like ``/v1``."""
    return path == "/" or path.startswith(PAGE_PREFIXES)


def cookie_value(scope: Scope, name: str) -> str:
    for header, value in scope.get("headers", []):
        if header == b"cookie":
            for part in value.split(b";"):
                key, _, token = part.strip().partition(b"=")
                if key == name.encode():
                    return token.strip().decode("latin-1")
    return ""


class BearerAuthMiddleware:
    """Bearer keys for ``/v1``; sign-in sessions (:mod:`service.infra.sessions`) for the pages and for
    reads under ``/v1``. ``internal_token`` is a per-process random key that only in-process
    requests (the web forms forwarding to the API after their CSRF check) can know."""

    def __init__(self, app: ASGIApp, keys: list[str], internal_token: str) -> None:
        self.app = app
        self.keys = [k.encode() for k in keys]
        self.key_texts = keys
        self.internal = internal_token.encode()

    def _valid(self, token: bytes) -> bool:
        ok = hmac.compare_digest(token, self.internal)
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
        # A sign-in session opens the pages, and reads under /v1 (the pages' figures and job
        # progress); writes under /v1, and /metrics, need the Authorization header.
        read = scope.get("method") in ("GET", "HEAD") and path != "/metrics"
        cookie = cookie_value(scope, SESSION_COOKIE)
        if cookie and (web or read):
            db = scope["app"].state.db
            session = await anyio.to_thread.run_sync(find_session, db, cookie, self.key_texts)
            if session is not None:
                scope.setdefault("state", {})["web_session"] = session
                await self.app(scope, receive, send)
                return
        if web and read:
            await RedirectResponse(f"/login?next={quote(path)}", status_code=303)(scope, receive, send)
            return
        if web:  # a form posted without a valid session: sign in again
            await RedirectResponse("/login", status_code=303)(scope, receive, send)
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


def page_csp(inline_styles: bool = False) -> str:
    """The pages' Content-Security-Policy: scripts, styles and images from this site only, no
    framing, forms post to this site only. ``inline_styles`` also allows ``<style>`` elements
    and style attributes, and workers from ``blob:`` URLs, for ReDoc (:mod:`service.routers.docs`),
    which makes its styles and its search worker at run time; scripts stay this site's only."""
    style, workers = ("'self' 'unsafe-inline'", "'self' blob:") if inline_styles else ("'self'", "'self'")
    return (
        f"default-src 'self'; script-src 'self'; style-src {style}; worker-src {workers}; img-src 'self' data:; "
        "connect-src 'self'; object-src 'none'; base-uri 'none'; frame-ancestors 'none'; form-action 'self'"
    )


CSP = page_csp()


class SecurityHeadersMiddleware:
    """``X-Content-Type-Options: nosniff`` on every response; on HTML pages also the CSP,
    ``X-Frame-Options: DENY``, ``Referrer-Policy: same-origin`` (a page never leaks its URL,
    which may hold ids, to another site; ``no-referrer`` would also blank the ``Origin`` of the
    pages' own form posts, which the CSRF check reads) and ``Cache-Control: no-store`` (a page
    holds its form's CSRF token: no cache, shared or not, keeps it)."""

    def __init__(self, app: ASGIApp, csp: str = CSP) -> None:
        self.app = app
        self.csp = csp.encode()

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return

        async def sender(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = list(message.get("headers", []))
                names = {k.lower() for k, _ in headers}
                extra = [(b"x-content-type-options", b"nosniff")]
                content_type = next((v for k, v in headers if k.lower() == b"content-type"), b"")
                if content_type.startswith(b"text/html"):
                    extra += [(b"x-frame-options", b"DENY"), (b"referrer-policy", b"same-origin")]
                    extra.append((b"cache-control", b"no-store"))
                    if b"content-security-policy" not in names:
                        extra.append((b"content-security-policy", self.csp))
                message = dict(message, headers=headers + [(k, v) for k, v in extra if k not in names])
            await send(message)

        await self.app(scope, receive, sender)


#: What a page of another origin may send and read (with ``SPACEARM_CORS_ORIGINS``).
CORS_METHODS = ["GET", "HEAD", "POST", "DELETE"]
CORS_REQUEST_HEADERS = ["Authorization", "Content-Type", "Idempotency-Key", "If-None-Match", "Last-Event-ID", "X-Request-ID"]
CORS_EXPOSED_HEADERS = ["Location", "Retry-After", "ETag", "Allow", "WWW-Authenticate", "X-Request-ID"]


def install(app: FastAPI, settings: Settings) -> None:
    """Add the guards to ``app`` and say in the start-up log whether authentication is on."""
    keys = settings.keys()
    app.state.internal_token = secrets.token_urlsafe(32)
    app.add_middleware(BodyLimitMiddleware, max_bytes=settings.max_body_bytes)
    # added after = outside: unauthenticated bodies are never read
    app.add_middleware(BearerAuthMiddleware, keys=keys, internal_token=app.state.internal_token)
    app.add_middleware(MethodsMiddleware, router=app)
    origins = settings.cors_origin_list()
    if origins:
        app.add_middleware(
            CORSMiddleware,
            allow_origins=origins,
            allow_methods=CORS_METHODS,
            allow_headers=CORS_REQUEST_HEADERS,
            expose_headers=CORS_EXPOSED_HEADERS,
            allow_credentials=False,
            max_age=600,
        )
        log.info("CORS is on for %s", ", ".join(origins))
    hosts = settings.allowed_host_list()
    app.add_middleware(TrustedHosts, allowed_hosts=hosts)
    app.add_middleware(SecurityHeadersMiddleware)
    if "*" not in hosts:
        log.info("answering the Host names %s (SPACEARM_ALLOWED_HOSTS)", ", ".join(hosts))
    if keys:
        log.info("authentication is on: /v1 requires a bearer key (%d key(s) configured)", len(keys))
    else:
        log.warning(
            "authentication is OFF (SPACEARM_API_KEYS is not set): anyone who can reach the API can use it; the API binds to %s",
            settings.host,
        )

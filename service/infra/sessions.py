"""Sign-in sessions of the web pages (with ``SPACEARM_API_KEYS`` set).

The cookie holds a random token; the database keeps its SHA-256 (the ``web_sessions`` row id),
the SHA-256 of the key the session was opened with, a CSRF token and an expiry. A session is
valid while its row exists, has not expired and its key is still configured: signing out
deletes the row, and removing a key from ``SPACEARM_API_KEYS`` ends every session opened with it.
The key itself is never stored or put in a cookie."""

from __future__ import annotations

import hashlib
import secrets
from dataclasses import dataclass
from datetime import timedelta

from sqlalchemy import delete
from sqlalchemy.orm import Session

from service.infra.db import Database
from service.models import WebSession, utcnow

SESSION_COOKIE = "spacearm_session"
CSRF_COOKIE = "spacearm_csrf"


def digest(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


@dataclass(frozen=True)
class SessionInfo:
    csrf_token: str


def open_session(db: Database, key: str, hours: float) -> tuple[str, str]:
    """A new session for ``key``: ``(cookie token, csrf token)``. Expired sessions are purged."""
    token = secrets.token_urlsafe(32)
    csrf = secrets.token_urlsafe(32)
    now = utcnow()

    def store(session: Session) -> None:
        session.execute(delete(WebSession).where(WebSession.expires_at < now))
        expires = now + timedelta(hours=hours)
        session.add(WebSession(id=digest(token), key_digest=digest(key), csrf_token=csrf, created_at=now, expires_at=expires))

    db.write(store)
    return token, csrf


def find_session(db: Database, token: str, keys: list[str]) -> SessionInfo | None:
    """The session of a cookie token, if it is valid (exists, not expired, its key configured)."""
    if not token:
        return None
    with db.session() as session:
        row = session.get(WebSession, digest(token))
        if row is None or row.expires_at <= utcnow() or row.key_digest not in {digest(k) for k in keys}:
            return None
        return SessionInfo(csrf_token=row.csrf_token)


def close_session(db: Database, token: str) -> None:
    """Sign out: the session's row is deleted (the cookie no longer opens anything)."""
    if token:
        db.write(lambda session: session.execute(delete(WebSession).where(WebSession.id == digest(token))))

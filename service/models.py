"""SQLAlchemy 2.0 models. The schema only changes through the Alembic migrations in ``migrations/``."""

from __future__ import annotations

import uuid
from datetime import UTC, datetime
from typing import Any

from sqlalchemy import JSON, Boolean, DateTime, Float, ForeignKey, Index, Integer, LargeBinary, String, Text
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column
from sqlalchemy.types import TypeDecorator


def utcnow() -> datetime:
    return datetime.now(UTC)


def new_id() -> str:
    return uuid.uuid4().hex


class UTCDateTime(TypeDecorator[datetime]):
    """Timezone-aware UTC datetimes (SQLite stores naive values)."""

    impl = DateTime
    cache_ok = True

    def process_bind_param(self, value: datetime | None, dialect: Any) -> datetime | None:
        if value is None:
            return None
        if value.tzinfo is None:
            value = value.replace(tzinfo=UTC)
        return value.astimezone(UTC).replace(tzinfo=None)

    def process_result_value(self, value: datetime | None, dialect: Any) -> datetime | None:
        return None if value is None else value.replace(tzinfo=UTC)


class Base(DeclarativeBase):
    pass


class Robot(Base):
    __tablename__ = "robots"

    id: Mapped[str] = mapped_column(String(64), primary_key=True, default=new_id)
    name: Mapped[str] = mapped_column(String(200))
    parameters: Mapped[dict[str, Any]] = mapped_column(JSON)
    preset: Mapped[bool] = mapped_column(Boolean, default=False)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)


class Mesh(Base):
    """An uploaded mesh (STL or OBJ), stored once (its id is a hash of its bytes): what the scenes
    need of it, its convex hull, and what describes it."""

    __tablename__ = "meshes"

    id: Mapped[str] = mapped_column(String(64), primary_key=True)
    name: Mapped[str] = mapped_column(String(200))
    format: Mapped[str] = mapped_column(String(8))
    size_bytes: Mapped[int] = mapped_column(Integer)
    vertex_count: Mapped[int] = mapped_column(Integer)
    face_count: Mapped[int] = mapped_column(Integer)
    hull: Mapped[bytes] = mapped_column(LargeBinary)  # (V, 3) float64 little-endian, m
    bounds: Mapped[list[list[float]]] = mapped_column(JSON)  # [[x, y, z] min, [x, y, z] max], m
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow, index=True)


class Plan(Base):
    __tablename__ = "plans"

    id: Mapped[str] = mapped_column(String(64), primary_key=True, default=new_id)
    robot_id: Mapped[str | None] = mapped_column(String(64), ForeignKey("robots.id", ondelete="SET NULL"), nullable=True)
    request: Mapped[dict[str, Any]] = mapped_column(JSON)
    method: Mapped[dict[str, Any]] = mapped_column(JSON)
    success: Mapped[bool] = mapped_column(Boolean)
    message: Mapped[str] = mapped_column(Text)
    metrics: Mapped[dict[str, Any]] = mapped_column(JSON)
    trajectory_data: Mapped[bytes] = mapped_column(LargeBinary)  # service.infra.storage.pack_trajectory
    robustness: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)  # RobustnessOut, under uncertainty
    replay: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)
    elapsed_s: Mapped[float] = mapped_column(Float)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow, index=True)


class TuningJob(Base):
    """A GA tuning job; this table is the job queue."""

    __tablename__ = "tuning_jobs"
    __table_args__ = (Index("ix_tuning_jobs_status_created", "status", "created_at"),)

    id: Mapped[str] = mapped_column(String(64), primary_key=True, default=new_id)
    status: Mapped[str] = mapped_column(String(16), default="queued")
    robot_id: Mapped[str | None] = mapped_column(String(64), nullable=True)
    request: Mapped[dict[str, Any]] = mapped_column(JSON)
    progress: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)
    result: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)
    error: Mapped[str | None] = mapped_column(Text, nullable=True)
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    max_attempts: Mapped[int] = mapped_column(Integer, default=3)
    cancel_requested: Mapped[bool] = mapped_column(Boolean, default=False)
    lease_owner: Mapped[str | None] = mapped_column(String(128), nullable=True)
    worker_id: Mapped[str | None] = mapped_column(String(128), nullable=True)  # who claimed it last; kept once it ends
    lease_expires_at: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)
    idempotency_key: Mapped[str | None] = mapped_column(String(200), nullable=True, unique=True)
    idempotency_fingerprint: Mapped[str | None] = mapped_column(String(64), nullable=True)  # SHA-256 of the body
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    started_at: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)
    finished_at: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)
    updated_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow, onupdate=utcnow)


class JobGeneration(Base):
    """One finished generation of a tuning job's GA, appended as it ends (the job's history:
    progress, event stream, convergence figure). ``seq`` numbers the records of one ``attempt``
    from 1 (an event's id is ``<attempt>.<seq>``); ``phase`` is the method the GA tunes and
    ``role`` whether it is the job's own method or the DLS baseline; ``stage`` ``ga`` or
    ``refine`` (a record of the refinement after the GA)."""

    __tablename__ = "tuning_job_generations"

    job_id: Mapped[str] = mapped_column(String(64), ForeignKey("tuning_jobs.id", ondelete="CASCADE"), primary_key=True)
    attempt: Mapped[int] = mapped_column(Integer, primary_key=True)
    seq: Mapped[int] = mapped_column(Integer, primary_key=True)
    phase: Mapped[str] = mapped_column(String(16))
    role: Mapped[str] = mapped_column(String(16))
    stage: Mapped[str] = mapped_column(String(16), default="ga", server_default="ga")  # "ga" or "refine"
    generation: Mapped[int] = mapped_column(Integer)
    best: Mapped[float | None] = mapped_column(Float, nullable=True)
    mean: Mapped[float | None] = mapped_column(Float, nullable=True)
    feasible: Mapped[int] = mapped_column(Integer)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)


class Landscape(Base):
    """An objective landscape: ``grids`` holds its arrays (``service.infra.storage``), ``summary`` the rest."""

    __tablename__ = "landscapes"

    id: Mapped[str] = mapped_column(String(64), primary_key=True, default=new_id)
    robot_id: Mapped[str | None] = mapped_column(String(64), ForeignKey("robots.id", ondelete="SET NULL"), nullable=True)
    request: Mapped[dict[str, Any]] = mapped_column(JSON)
    summary: Mapped[dict[str, Any]] = mapped_column(JSON)
    grids: Mapped[bytes] = mapped_column(LargeBinary)
    elapsed_s: Mapped[float] = mapped_column(Float)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow, index=True)


class WebSession(Base):
    """A sign-in session of the web pages: the cookie holds a random token; its SHA-256 is the id.
    ``key_digest`` is the SHA-256 of the API key it was opened with (a session ends when that key
    is removed from ``SPACEARM_API_KEYS``); signing out deletes the row."""

    __tablename__ = "web_sessions"

    id: Mapped[str] = mapped_column(String(64), primary_key=True)
    key_digest: Mapped[str] = mapped_column(String(64))
    csrf_token: Mapped[str] = mapped_column(String(64))
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    expires_at: Mapped[datetime] = mapped_column(UTCDateTime)


class ServiceProbe(Base):
    """Rows the readiness probe rewrites, to prove the database takes writes."""

    __tablename__ = "service_probes"

    name: Mapped[str] = mapped_column(String(64), primary_key=True)
    updated_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)

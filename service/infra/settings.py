"""Configuration from ``SPACEARM_*`` environment variables (pydantic-settings)."""

from __future__ import annotations

import os
import socket
from functools import lru_cache
from typing import Literal

from pydantic import Field, SecretStr, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="SPACEARM_", extra="ignore")

    database_url: str = Field(default="sqlite:///./var/spacearm.db", description="SQLAlchemy URL of the database")
    host: str = Field(default="127.0.0.1", description="address the API binds to")
    port: int = Field(default=8000, ge=1, le=65535, description="port the API listens on")
    log_format: Literal["text", "json"] = Field(
        default="text",
        description="log lines as text, or as one JSON object per line (time, level, logger, message, request_id, job_id)",
    )
    log_level: Literal["debug", "info", "warning", "error"] = Field(
        default="info", description="lowest level logged; debug also shows Alembic's migration steps"
    )
    worker_poll_seconds: float = Field(default=1.0, gt=0, description="how often an idle worker looks for a queued job")
    job_lease_seconds: float = Field(default=60.0, gt=0, description="how long a job stays claimed without a heartbeat")
    job_max_attempts: int = Field(default=3, ge=1, description="claims of one job before it is failed for good")
    sqlite_busy_timeout_ms: int = Field(default=10_000, ge=0, description="SQLite busy timeout")
    api_keys: SecretStr | None = Field(
        default=None, description="comma-separated bearer keys; set, every /v1 request (and /metrics) needs one (never logged)"
    )
    max_queued_jobs: int = Field(default=100, ge=1, description="queued tuning jobs beyond which submissions get 429")
    max_body_bytes: int = Field(default=1024 * 1024, ge=1, description="request bodies above this get 413")
    max_replay_steps: int = Field(
        default=20_000,
        ge=0,
        description="plans with more steps are not replayed synchronously (the replay costs some 20 us per step: "
        "0.4 s for 20,000 steps on a 2-core machine)",
    )
    dask_scheduler: str | None = Field(
        default=None,
        description="address of a Dask scheduler (e.g. tcp://10.0.0.5:8786); set, workers spread each GA "
        "generation over the cluster (needs the `dask` extra)",
    )
    dask_chunks: int = Field(default=8, ge=1, description="pieces each generation is split into for the Dask cluster")
    api_processes: int = Field(
        default=1,
        ge=1,
        le=64,
        description="API processes `spacearm run` starts behind its one port (more than 1: each binds with SO_REUSEPORT "
        "and the kernel spreads connections over them; metrics are summed over them through PROMETHEUS_MULTIPROC_DIR; "
        "plan admission, rate limits and event-stream limits are per process)",
    )
    api_threads: int = Field(
        default=16,
        ge=2,
        le=256,
        description="threads of the API's pool for blocking handlers (database reads, plans but the cheapest, figures)",
    )
    db_pool_size: int | None = Field(
        default=None,
        ge=1,
        le=512,
        description="database connections per API process; default: api_threads + 2 (one for the retention sweep, one "
        "for the cheap plans the event loop runs), so a handler never waits for one",
    )
    db_pool_timeout_s: float = Field(
        default=5.0, gt=0, le=300, description="how long a request waits for a database connection before a 503"
    )
    max_concurrent_plans: int | None = Field(
        default=None, ge=1, le=256, description="synchronous plans computed at once per API process; default: the CPU count"
    )
    plan_queue: int = Field(
        default=1000,
        ge=0,
        le=10_000,
        description="plan requests that may wait for a slot at once, whatever their work (0: none wait); admission is by "
        "estimated work (plan_queue_timeout_s)",
    )
    plan_queue_timeout_s: float = Field(
        default=10.0,
        gt=0,
        le=600,
        description="the longest estimated wait for a slot a plan request is admitted with (and waits at most); beyond, "
        "a 503 with Retry-After",
    )
    storage_quota_bytes: int | None = Field(
        default=10 * 2**30,
        ge=1,
        description="size of the database beyond which new robots, meshes, plans, landscapes and jobs get 507; empty or "
        "`none` for no quota",
    )
    cookie_secure: bool = Field(default=False, description="mark the sign-in cookie Secure (set it when clients use HTTPS)")
    session_hours: float = Field(default=12.0, gt=0, le=24 * 365, description="lifetime of a web sign-in session")
    sse_heartbeat_s: float = Field(
        default=15.0, gt=0, le=300, description="seconds without events after which a job's event stream sends a heartbeat"
    )
    retention_days: float | None = Field(
        default=None,
        gt=0,
        description="finished tuning jobs, plans and landscapes older than this many days are deleted; unset (or empty): "
        "kept for ever",
    )
    retention_sweep_s: float = Field(default=600.0, gt=0, description="how often the API looks for expired rows")
    allowed_hosts: str = Field(
        default="",
        max_length=10_000,
        description="comma-separated host names and addresses the API answers in the Host header (`*.example.com` "
        "patterns, or `*` for any); empty: the bind address, localhost, 127.0.0.1 and ::1 (and the machine's name when "
        "bound to every address); other Host headers get 400 (DNS rebinding)",
    )
    login_attempts_per_minute: int = Field(
        default=10, ge=1, le=100_000, description="POST /login attempts per client address per minute; beyond, 429"
    )
    max_event_streams: int = Field(
        default=500, ge=1, le=100_000, description="job event streams open at once per API process; beyond, 503"
    )
    max_connections: int | None = Field(
        default=None,
        ge=1,
        le=1_000_000,
        description="open HTTP connections per API process; beyond, a new one gets 503 and is closed; default: 1000, "
        "fewer when the file-descriptor limit (ulimit -n) is lower",
    )
    header_timeout_s: float = Field(
        default=10.0, gt=0, le=3600, description="time a client has to send a request's line and headers"
    )
    body_timeout_s: float = Field(
        default=20.0, gt=0, le=3600, description="time a client has to send a request's body, plus a second per body_min_rate"
    )
    body_min_rate: int = Field(
        default=10_000, ge=1, le=1 << 30, description="bytes per second a slow body must keep up beyond body_timeout_s"
    )
    send_timeout_s: float = Field(
        default=60.0,
        gt=0,
        le=3600,
        description="time an answer may wait for a client that reads nothing of it (the server's send buffer full)",
    )
    cors_origins: str = Field(
        default="",
        max_length=10_000,
        description="comma-separated origins (scheme://host[:port]) whose browser pages may call the API (CORS), or `*` "
        "for any; empty: CORS off",
    )

    @field_validator("log_format", "log_level", mode="before")
    @classmethod
    def _lower(cls, value: object) -> object:
        return value.lower() if isinstance(value, str) else value

    @field_validator(
        "db_pool_size", "max_concurrent_plans", "storage_quota_bytes", "retention_days", "max_connections", mode="before"
    )
    @classmethod
    def _none(cls, value: object) -> object:
        """An optional number given empty or as ``none``: none (an empty value failed to parse as
        a number, which left no way to turn the storage quota off)."""
        return None if isinstance(value, str) and value.strip().lower() in ("", "none") else value

    def pool_size(self) -> int:
        return self.db_pool_size or self.api_threads + 2

    def plan_slots(self) -> int:
        return self.max_concurrent_plans or max(1, os.cpu_count() or 1)

    def allowed_host_list(self) -> list[str]:
        """The Host headers the API answers (``*`` for any); see :attr:`allowed_hosts`."""
        given = [h.strip().lower() for h in self.allowed_hosts.split(",") if h.strip()]
        if given:
            return given
        local = ["localhost", "127.0.0.1", "[::1]"]
        host = self.host.strip().lower()
        if host in ("", "0.0.0.0", "::", "[::]"):  # every address: the machine's own names too
            names = {socket.gethostname().lower(), socket.getfqdn().lower()}
            return local + sorted(n for n in names if n and n not in local)
        bound = f"[{host}]" if ":" in host and not host.startswith("[") else host
        return local if bound in local else [bound, *local]

    def internal_host(self) -> str:
        """A Host header the API answers, for its own in-process requests (the start-up rehearsal)."""
        hosts = self.allowed_host_list()
        concrete = [h for h in hosts if "*" not in h]
        if concrete:
            return concrete[0]
        patterns = [h for h in hosts if h != "*"]
        return patterns[0].replace("*", "internal", 1) if patterns else "localhost"

    def cors_origin_list(self) -> list[str]:
        """The origins CORS allows (empty: CORS is off); without a trailing slash, as browsers send them."""
        return [o.strip().rstrip("/") for o in self.cors_origins.split(",") if o.strip()]

    def keys(self) -> list[str]:
        """The configured API keys (empty: authentication is off)."""
        raw = self.api_keys.get_secret_value() if self.api_keys is not None else ""
        return [k.strip() for k in raw.split(",") if k.strip()]


@lru_cache
def get_settings() -> Settings:
    return Settings()

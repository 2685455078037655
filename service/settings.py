"""Configuration from ``SPACEARM_*`` environment variables (pydantic-settings)."""

from __future__ import annotations

from functools import lru_cache

from pydantic import Field, SecretStr
from pydantic_settings import BaseSettings, SettingsConfigDict


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="SPACEARM_", extra="ignore")

    database_url: str = Field(default="sqlite:///./var/spacearm.db", description="SQLAlchemy URL of the database")
    host: str = Field(default="127.0.0.1", description="address the API binds to")
    port: int = Field(default=8000, ge=1, le=65535, description="port the API listens on")
    worker_poll_seconds: float = Field(default=1.0, gt=0, description="how often an idle worker looks for a queued job")
    job_lease_seconds: float = Field(default=60.0, gt=0, description="how long a job stays claimed without a heartbeat")
    job_max_attempts: int = Field(default=3, ge=1, description="claims of one job before it is failed for good")
    sqlite_busy_timeout_ms: int = Field(default=10_000, ge=0, description="SQLite busy timeout")
    api_keys: SecretStr | None = Field(
        default=None, description="comma-separated bearer keys; set, every /v1 request needs one (never logged)"
    )
    max_queued_jobs: int = Field(default=100, ge=1, description="queued tuning jobs beyond which submissions get 429")
    max_body_bytes: int = Field(default=1024 * 1024, ge=1, description="request bodies above this get 413")
    max_replay_steps: int = Field(
        default=20_000,
        ge=0,
        description="plans with more steps are not replayed synchronously (the replay costs about 50 us per step: "
        "1 s for 20,000 steps)",
    )
    dask_scheduler: str | None = Field(
        default=None,
        description="address of a Dask scheduler (e.g. tcp://10.0.0.5:8786); set, workers spread each GA "
        "generation over the cluster (needs the `dask` extra)",
    )
    dask_chunks: int = Field(default=8, ge=1, description="pieces each generation is split into for the Dask cluster")

    def keys(self) -> list[str]:
        """The configured API keys (empty: authentication is off)."""
        raw = self.api_keys.get_secret_value() if self.api_keys is not None else ""
        return [k.strip() for k in raw.split(",") if k.strip()]


@lru_cache
def get_settings() -> Settings:
    return Settings()

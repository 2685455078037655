"""Liveness and readiness."""

from __future__ import annotations

from typing import Literal

from pydantic import (
    BaseModel,
    Field,
)
from typing_extensions import TypeAliasType

HealthStatus = TypeAliasType("HealthStatus", Literal["ok", "unavailable"])


class Health(BaseModel):
    """Liveness or readiness; the fields other than `status` are left out where they do not apply."""

    status: HealthStatus = Field(description="`ok`, or `unavailable` (readiness: see the other fields)")
    kernels: str | None = Field(default=None, description="the engine's compiled kernels: loading, ok or failed: ...")
    database: str | None = Field(default=None, description="the database: ok, or what is wrong with it")
    revision: str | None = Field(default=None, description="the database's Alembic revision")
    head: str | None = Field(default=None, description="the Alembic revision this version of the service needs")

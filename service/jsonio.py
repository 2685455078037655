"""JSON encoding for the service (orjson): numpy arrays and scalars are written directly, NaN and
infinities as null, aware datetimes in UTC with a ``Z``."""

from __future__ import annotations

from typing import Any

import orjson

OPTIONS = orjson.OPT_SERIALIZE_NUMPY | orjson.OPT_UTC_Z


def dumps(value: Any) -> bytes:
    """JSON bytes of ``value``."""
    return orjson.dumps(value, option=OPTIONS)


def dumps_text(value: Any) -> str:
    """JSON text of ``value`` (what SQLAlchemy's JSON columns store)."""
    return orjson.dumps(value, option=OPTIONS).decode()


def dumps_sorted(value: Any) -> bytes:
    """JSON bytes of ``value`` with sorted keys (a canonical form, for cache keys)."""
    return orjson.dumps(value, option=OPTIONS | orjson.OPT_SORT_KEYS)


loads = orjson.loads

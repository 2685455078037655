"""Logging of every process (API, worker, migrate, run): one configuration, two formats.

- ``SPACEARM_LOG_FORMAT=text`` (default): ``time LEVEL logger: message [request_id=... job_id=...]``.
- ``SPACEARM_LOG_FORMAT=json``: one JSON object per line (python-json-logger) with ``time``
  (ISO 8601, UTC), ``level``, ``logger``, ``message``, ``request_id`` (null outside a request),
  ``job_id`` where known, and any ``extra`` fields; access-log lines add ``client``, ``method``,
  ``path``, ``http_version`` and ``status_code``.

The request id and the job id come from context variables (:data:`REQUEST_ID`, set per request by
:class:`service.infra.observability.ObservabilityMiddleware`; :data:`JOB_ID`, set by the worker around a
job), copied onto every record by :class:`ContextFilter` on the handlers, so every line logged
while a request (or a job) is handled carries its id, uvicorn's access log included (uvicorn logs
it from the request's own task). Secrets in query strings are redacted from the access log
(a client that puts a key in a URL, ``?api_key=...``, must not leave it in the log) in both formats.
"""

from __future__ import annotations

import logging
import logging.config
import re
import sys
from collections.abc import Callable
from contextvars import ContextVar
from typing import Any, Literal

from pythonjsonlogger.core import RESERVED_ATTRS
from pythonjsonlogger.json import JsonFormatter

LogFormat = Literal["text", "json"]

#: The id of the HTTP request being handled (None outside a request).
REQUEST_ID: ContextVar[str | None] = ContextVar("spacearm_request_id", default=None)
#: The id of the tuning job being run (None outside a job).
JOB_ID: ContextVar[str | None] = ContextVar("spacearm_job_id", default=None)

#: Query parameters whose values are replaced by ``[redacted]`` in the access log.
SECRET_PARAMS = re.compile(r"(?i)([?&](?:[^=&]*(?:key|token|secret|password|passwd|auth|session|credential)[^=&]*)=)[^&#\s]*")

TEXT_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"
#: Loggers that are chatty at INFO (Alembic logs ~20 lines of plugin set-up per migration).
QUIET_LOGGERS = ("alembic",)


def redact(text: str) -> str:
    return SECRET_PARAMS.sub(r"\1[redacted]", text)


class ContextFilter(logging.Filter):
    """Copies the request id and the job id of the current context onto every record (handler
    filter: it sees the records of every logger, propagated ones included)."""

    def filter(self, record: logging.LogRecord) -> bool:
        if getattr(record, "request_id", None) is None:
            record.request_id = REQUEST_ID.get()
        if getattr(record, "job_id", None) is None:
            job_id = JOB_ID.get()
            if job_id is not None:
                record.job_id = job_id
        return True


class RedactSecretsFilter(logging.Filter):
    """Rewrites uvicorn access-log records (``args``: client, method, target, HTTP version,
    status): the target's secret query values are redacted, and the fields are set on the
    record for the JSON format."""

    def filter(self, record: logging.LogRecord) -> bool:
        args = record.args
        if isinstance(args, tuple) and len(args) >= 3 and isinstance(args[2], str):
            args = (*args[:2], redact(args[2]), *args[3:])
            record.args = args
            if len(args) == 5:
                record.client, record.method, record.path, record.http_version, record.status_code = args
        return True


class TextFormatter(logging.Formatter):
    """``TEXT_FORMAT`` with `` [request_id=... job_id=...]`` appended when they are known."""

    def format(self, record: logging.LogRecord) -> str:
        text = super().format(record)
        context = [f"{name}={value}" for name in ("request_id", "job_id") if (value := getattr(record, name, None)) is not None]
        if not context:
            return text
        head, newline, rest = text.partition("\n")  # after the message, before a traceback
        return f"{head} [{' '.join(context)}]{newline}{rest}"


def json_formatter() -> JsonFormatter:
    return JsonFormatter(
        "{levelname}{name}{message}",
        style="{",
        rename_fields={"levelname": "level", "name": "logger"},
        timestamp="time",
        # uvicorn's colour variant of some messages; the access log's args are in fields of their own
        reserved_attrs=[*RESERVED_ATTRS, "color_message", "taskName"],
    )


def logging_config(log_format: LogFormat = "text", level: str = "INFO", *, verbose: bool = False) -> dict[str, Any]:
    """A :func:`logging.config.dictConfig` of the process (root, uvicorn's loggers and the access
    log), also handed to uvicorn as its ``log_config``. ``verbose`` (or level DEBUG) lets the
    loggers of :data:`QUIET_LOGGERS` log at INFO."""
    level = level.upper()
    formatter: dict[str, Any] = {"()": json_formatter} if log_format == "json" else {"()": TextFormatter, "fmt": TEXT_FORMAT}
    quiet = "INFO" if verbose or level == "DEBUG" else "WARNING"
    return {
        "version": 1,
        "disable_existing_loggers": False,
        "filters": {"context": {"()": ContextFilter}, "redact_secrets": {"()": RedactSecretsFilter}},
        "formatters": {"main": formatter},
        "handlers": {
            "default": {
                "class": "logging.StreamHandler",
                "formatter": "main",
                "filters": ["context"],
                "stream": "ext://sys.stderr",
            },
            "access": {
                "class": "logging.StreamHandler",
                "formatter": "main",
                "filters": ["context", "redact_secrets"],
                "stream": "ext://sys.stdout",
            },
        },
        "root": {"handlers": ["default"], "level": level},
        "loggers": {
            "uvicorn": {"handlers": ["default"], "level": level, "propagate": False},
            "uvicorn.error": {"level": level},
            "uvicorn.access": {"handlers": ["access"], "level": level, "propagate": False},
            **{name: {"level": quiet} for name in QUIET_LOGGERS},
        },
    }


def configure(log_format: LogFormat = "text", level: str = "INFO", *, verbose: bool = False) -> dict[str, Any]:
    """Apply :func:`logging_config`; returns it (for uvicorn)."""
    config = logging_config(log_format, level, verbose=verbose)
    logging.config.dictConfig(config)
    return config


#: How a command tells its user something: ``say(message, error)``.
Say = Callable[[str, bool], None]


def messenger(log_format: LogFormat, logger: str) -> Say:
    """Plain lines (stdout, errors on stderr) in the text format; log records of ``logger`` in the
    JSON one, so that every line a command writes parses as JSON there too."""
    log = logging.getLogger(logger)

    def say(message: str, error: bool) -> None:
        if log_format == "json":
            log.log(logging.ERROR if error else logging.INFO, message)
        else:
            print(message, file=sys.stderr if error else sys.stdout, flush=True)

    return say

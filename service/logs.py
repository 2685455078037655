"""Logging of the API process: uvicorn's access log with secrets taken out of query strings
(a client that puts a key in a URL, ``?api_key=...``, must not leave it in the log)."""

from __future__ import annotations

import copy
import logging
import re
from typing import Any

from uvicorn.config import LOGGING_CONFIG

#: Query parameters whose values are replaced by ``[redacted]`` in the access log.
SECRET_PARAMS = re.compile(r"(?i)([?&](?:[^=&]*(?:key|token|secret|password|passwd|auth|session|credential)[^=&]*)=)[^&#\s]*")


def redact(text: str) -> str:
    return SECRET_PARAMS.sub(r"\1[redacted]", text)


class RedactSecretsFilter(logging.Filter):
    """Rewrites uvicorn access-log records: ``args[2]`` is the request target."""

    def filter(self, record: logging.LogRecord) -> bool:
        args = record.args
        if isinstance(args, tuple) and len(args) >= 3 and isinstance(args[2], str):
            record.args = (*args[:2], redact(args[2]), *args[3:])
        return True


def uvicorn_log_config() -> dict[str, Any]:
    """uvicorn's default logging configuration with :class:`RedactSecretsFilter` on the access log."""
    config = copy.deepcopy(LOGGING_CONFIG)
    config.setdefault("filters", {})["redact_secrets"] = {"()": RedactSecretsFilter}
    config["handlers"]["access"]["filters"] = ["redact_secrets"]
    return config

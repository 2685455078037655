"""The Jinja2 environment of the server-rendered pages (templates in ``service/templates``) and
its number filter, made on the first page rendered (Jinja2 is not imported by an API that
renders none)."""

from __future__ import annotations

import functools
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from jinja2 import Environment

TEMPLATES = Path(__file__).resolve().parent / "templates"


def fmt(value: Any, scale: float | None = 1.0) -> str:
    if value is None:
        return "—"
    if isinstance(value, bool) or scale is None:
        return "yes" if value else "no"
    if isinstance(value, int | float):
        v = float(value) * scale
        return f"{v:.4g}" if math.isfinite(v) else "—"
    return str(value)


@functools.cache
def env() -> Environment:
    """The environment (made once)."""
    from jinja2 import Environment, FileSystemLoader, select_autoescape

    environment = Environment(loader=FileSystemLoader(TEMPLATES), autoescape=select_autoescape(["html"]))
    environment.filters["fmt"] = fmt
    return environment

"""The Jinja2 environment of the server-rendered pages (templates in ``service/templates``) and
its number filter."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from jinja2 import Environment, FileSystemLoader, select_autoescape

TEMPLATES = Path(__file__).resolve().parent / "templates"
env = Environment(loader=FileSystemLoader(TEMPLATES), autoescape=select_autoescape(["html"]))


def fmt(value: Any, scale: float | None = 1.0) -> str:
    if value is None:
        return "—"
    if isinstance(value, bool) or scale is None:
        return "yes" if value else "no"
    if isinstance(value, int | float):
        v = float(value) * scale
        return f"{v:.4g}" if math.isfinite(v) else "—"
    return str(value)


env.filters["fmt"] = fmt

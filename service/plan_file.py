"""``spacearm plan FILE``: a plan request (the body of ``POST /v1/plans``) planned in this process,
without a server or a database, through the same use case (:func:`service.usecases.plans.compute`),
its verdict and metrics printed as a table (the plan page's rows, from the metrics layout)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any, TextIO

from fastapi.exceptions import RequestValidationError
from pydantic import ValidationError

from engine.errors import ParameterError
from service.errors import ApiError
from service.infra.settings import Settings
from service.schemas.common import API_LOCATION
from service.schemas.plans import PlanRequest
from service.usecases import plans, trajectories
from service.usecases.pages import METRIC_ROWS

#: Output formats by file name ending.
EXTENSIONS = {".ros.json": "ros", ".csv": "csv", ".mat": "mat", ".npz": "npz", ".json": "json"}


def table(metrics: dict[str, Any]) -> list[tuple[str, str, str]]:
    """``(label, value, unit)`` rows of a plan's API metrics."""
    out = []
    for api, label, unit, scale in METRIC_ROWS:  # the plan page's rows: (API name, label, unit, scale; None: yes/no)
        value = metrics.get(api or "")
        if value is None:
            text = "infeasible" if api == "objective_b" else "-"  # B is +inf when a limit is broken
        elif scale is None:
            text = "yes" if value else "no"
        else:
            text = f"{value * scale:.4g}"
        out.append((label, text, unit))
    return out


def _format_of(path: str) -> str | None:
    return next((fmt for end, fmt in EXTENSIONS.items() if path.lower().endswith(end)), None)


def _problems(exc: Exception) -> list[str]:
    """What is wrong with a request, a line per field (the API's field paths, without ``body.``)."""
    if isinstance(exc, ValidationError | RequestValidationError):
        return [f"{'.'.join(str(p) for p in e['loc'] if p != 'body')}: {e['msg']}" for e in exc.errors()]
    if isinstance(exc, ParameterError):
        where = getattr(exc, API_LOCATION, None) or [exc.field]
        return [f"{'.'.join(str(p) for p in where if p != 'body')}: {exc.reason}"]
    return [exc.detail if isinstance(exc, ApiError) else str(exc)]


def plan_file(path: str, trajectory: str | None, as_json: bool, settings: Settings, out: TextIO = sys.stdout) -> int:
    """Plan the request in ``path`` ('-': stdin); 0 if the plan succeeded, 1 if not, 2 if the request is invalid."""
    fmt = _format_of(trajectory) if trajectory else None
    if trajectory and fmt is None:
        print(f"spacearm plan: {trajectory}: unknown format (give .csv, .mat, .npz, .json or .ros.json)", file=sys.stderr)
        return 2
    try:
        text = sys.stdin.read() if path == "-" else Path(path).read_text()
        body = json.loads(text)
        if isinstance(body, dict) and "from_plan_id" in body:
            raise ApiError(422, "from_plan_id needs the server (POST /v1/plans): give the whole request here")
        planned = plans.compute(None, settings, PlanRequest.model_validate(body))
    except (OSError, json.JSONDecodeError) as exc:
        print(f"spacearm plan: {path}: {exc}", file=sys.stderr)
        return 2
    except (ValidationError, ParameterError, ApiError) as exc:
        print(f"spacearm plan: {path}: invalid request", file=sys.stderr)
        for line in _problems(exc):
            print(f"  {line}", file=sys.stderr)
        return 2
    row = planned.row
    if trajectory and fmt is not None:
        try:
            Path(trajectory).write_bytes(trajectories.encode(planned.record, list(planned.joint_names), fmt, "local"))
        except (OSError, ApiError) as exc:
            print(f"spacearm plan: {trajectory}: {exc.detail if isinstance(exc, ApiError) else exc}", file=sys.stderr)
            return 2
    if as_json:
        summary = {"success": row.success, "message": row.message, "method": row.method, "metrics": row.metrics}
        print(json.dumps({**summary, "replay": row.replay, "request": row.request}, indent=2), file=out)
        return 0 if row.success else 1
    params = ", ".join(f"{k} {v:g}" for k, v in row.method["params"].items())
    print(f"{'success' if row.success else 'FAILED'}: {row.message}", file=out)
    print(f"method {row.method['name']}{f' ({params})' if params else ''}; planned in {row.elapsed_s:.2f} s", file=out)
    rows = table(row.metrics)
    width = max(len(label) for label, _, _ in rows)
    value_width = max(len(value) for _, value, _ in rows)
    for label, value, unit in rows:
        print(f"  {label:<{width}}  {value:>{value_width}} {unit}".rstrip(), file=out)
    if row.replay is not None:
        print(f"replay: {row.replay['message']}", file=out)
    if trajectory:
        print(f"trajectory written to {trajectory}", file=out)
    return 0 if row.success else 1

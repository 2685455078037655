"""The web page's forms: the JSON API request each form makes (:func:`plan_body`,
:func:`job_body`, :func:`robot_body`), and the API's answer put back on the form
(:func:`form_errors`): each error next to the field it is about, in the form's words (the field's
own place, not the API's path such as ``body.task.duration_s``), and what no field owns once,
above the form."""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from service.usecases import pages, presets

#: An API error location (``loc`` without ``"body"``) -> the form field it belongs to, and the
#: part of the location still worth saying (e.g. ``links[2].mass`` inside an uploaded file).
Locator = Callable[[list[Any]], tuple[str, list[Any]]]


@dataclass
class FormErrors:
    """Messages by form field, and ``general``: what no field owns (each said once)."""

    fields: dict[str, str] = field(default_factory=dict)
    general: list[str] = field(default_factory=list)

    def __bool__(self) -> bool:
        return bool(self.fields or self.general)


def _float(form: dict[str, str], key: str, default: float | None = None) -> float | str | None:
    """The field's number; its text as typed when that is not a finite number ("abc", "inf",
    "1e400"), which the API rejects with the field's path (a NaN or an infinity could not even
    be sent: JSON has none)."""
    text = form.get(key, "").strip()
    if not text:
        return default
    try:
        value = float(text)
    except ValueError:
        return text
    return value if math.isfinite(value) else text


def _preset(form: dict[str, str]) -> presets.TaskPreset:
    return presets.PRESETS.get(form.get("preset", "paper-line"), presets.PRESETS["paper-line"])


def plan_body(form: dict[str, str]) -> dict[str, Any]:
    """``POST /v1/plans`` of the plan form: a task preset, its overrides, a method and its parameters."""
    preset = _preset(form)
    task = preset.task.model_dump()
    for key in ("duration_s", "dt_s", "joint_speed_limit_deg_s"):
        value = _float(form, key)
        if value is not None:
            task[key] = value
    method = form.get("method", "adaptive")
    params: dict[str, float | str] = {}
    for p in pages.method_params(method):
        value = _float(form, f"{method}.{p.name}")
        if value is not None:
            params[p.name] = value
    return {
        "robot_id": form.get("robot_id") or preset.robot_id,
        "task": task,
        "method": {"name": method, "params": params},
        "feedback_gain": _float(form, "feedback_gain", 0.0),
        "replay": form.get("replay") == "on",
    }


def _integer(value: float | str | None) -> float | int | str | None:
    return int(value) if isinstance(value, float) and value == int(value) else value


def job_body(form: dict[str, str]) -> dict[str, Any]:
    """``POST /v1/tuning-jobs`` of the job form: a task preset, a method, the GA's size."""
    preset = _preset(form)
    return {
        "robot_id": preset.robot_id,
        "tasks": [preset.task.model_dump()],
        "method": form.get("method", "adaptive"),
        "ga": {
            "population": _integer(_float(form, "population", 8.0)),
            "generations": _integer(_float(form, "generations", 5.0)),
            "seed": 1,
        },
        "compare_with_dls": form.get("compare_with_dls") == "on",
        "compare_with_bounded": form.get("compare_with_bounded") == "on",
    }


class RobotFileError(ValueError):
    """An uploaded robot file that is neither JSON nor URDF (its message is for the form)."""


def robot_body(document: str, end_effector_link: str = "", name: str = "") -> dict[str, Any]:
    """``POST /v1/robots`` of an uploaded file: a URDF (XML) or a JSON parameter set (or a JSON
    body with ``urdf`` already in it); the form's end-effector link and name, when given, win."""
    text = document.strip()
    if not text:
        raise RobotFileError("choose a robot file (JSON parameters or URDF)")
    if text.startswith("<"):
        body: dict[str, Any] = {"urdf": text}
    else:
        try:
            parsed = json.loads(text)
        except ValueError as exc:
            raise RobotFileError(f"neither URDF (XML) nor JSON: {exc}") from None
        if not isinstance(parsed, dict):
            raise RobotFileError("the JSON file must hold one object (the robot's parameters)")
        body = parsed
    if end_effector_link.strip() and "urdf" in body:
        body["end_effector_link"] = end_effector_link.strip()
    if name.strip():
        body["name"] = name.strip()
    return body


def _path(loc: Sequence[Any]) -> str:
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else ("." if out else "") + str(part)
    return out


def _words(message: str, loc: Sequence[Any]) -> str:
    """An API message in the form's words: pydantic's phrasing shortened, the field's own name
    (already beside it) dropped."""
    message = message.removeprefix("Value error, ").replace("Input should be", "must be")
    if loc and isinstance(loc[-1], str):
        message = message.removeprefix(f"{loc[-1]}: ")
    return message


def plan_locator(method: str) -> Locator:
    """Where the plan form shows an error: the task's overrides, the chosen method's parameters,
    the robot and the gain have fields; the rest of the task belongs to the preset."""

    def locate(loc: list[Any]) -> tuple[str, list[Any]]:
        match loc:
            case ["task", ("duration_s" | "dt_s" | "joint_speed_limit_deg_s") as name, *rest]:
                return name, rest
            case ["task", *rest]:
                return "preset", rest
            case ["method", "params", str(param), *rest]:
                return f"{method}.{param}", rest
            case ["method", *rest]:
                return "method", rest
            case [("robot_id" | "robot"), *rest]:
                return "robot_id", rest
            case ["feedback_gain", *rest]:
                return "feedback_gain", rest
        return "", loc

    return locate


def job_locator(loc: list[Any]) -> tuple[str, list[Any]]:
    match loc:
        case ["ga", ("population" | "generations") as name, *rest]:
            return name, rest
        case ["tasks", *rest]:
            return "preset", rest[1:] if rest and isinstance(rest[0], int) else rest
        case ["method", *rest]:
            return "method", rest
    return "", loc


def robot_locator(loc: list[Any]) -> tuple[str, list[Any]]:
    """The upload form: its link and name fields, else the file (with the place inside it)."""
    match loc:
        case [("end_effector_link" | "name") as name, *rest]:
            return name, rest
    return "file", loc


def form_errors(status: int, problem: dict[str, Any] | None, locate: Locator, text: str = "") -> FormErrors:
    """The API's problem answer (``status``, its JSON or None, else its ``text``) as errors by
    form field; errors without a field, or answers without errors, go to ``general``."""
    out = FormErrors()
    if problem is None:
        out.general.append(f"{status}: {text[:500]}")
        return out
    for error in problem.get("errors") or []:
        loc = [p for p in error.get("loc") or [] if p not in ("body", "query")]
        name, rest = locate(loc)
        message = _words(str(error.get("message", "")), loc)
        if rest and not message.startswith(_path(rest)):
            message = f"{_path(rest)}: {message}"
        if not name:
            out.general.append(message)
        elif name in out.fields:
            out.fields[name] += "; " + message
        else:
            out.fields[name] = message
    if not out:
        out.general.append(str(problem.get("detail") or problem.get("title") or status))
    if problem.get("element") and "file" in out.fields:
        element = str(problem["element"])
        if element not in out.fields["file"]:
            out.fields["file"] += f" (at {element})"
    return out

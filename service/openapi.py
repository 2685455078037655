"""The OpenAPI document, post-processed for clients, generators and fuzzers: what the middleware
adds to every operation (authentication, optional without keys; body limit; busy database and
admission with ``Retry-After``; quota), error responses as problem+json, links and the
``Location`` header from the operations that create a resource to those that read it (clients
and stateful fuzzers follow them), ``robot_id`` xor ``robot`` as a ``oneOf``, the models of raw
bodies as components, and request defaults stated in descriptions so that generated types leave
them optional."""

from __future__ import annotations

import copy
import json
from typing import Any

from fastapi import FastAPI

from service.errors import PROBLEM_JSON
from service.schemas.plans import PlanRerun
from service.schemas.robots import ROBOT_CHOICE, RobotUrdfIn
from service.schemas.trajectories import RosJointTrajectory

BEARER = "bearerAuth"
RETRY_AFTER = {"Retry-After": {"schema": {"type": "integer", "minimum": 1}, "description": "seconds to wait before retrying"}}
LOCATION = {"Location": {"schema": {"type": "string"}, "description": "the path of the resource created (or accepted)"}}

#: Models of raw bodies (a route reads its request from a raw body, or writes its response as
#: bytes; documented by its ``openapi_extra`` or ``responses``, so FastAPI does not see them):
#: added to the components under their own names.
BODY_MODELS = (RobotUrdfIn, PlanRerun, RosJointTrajectory)

#: Operations that store something (and answer 507 when the storage quota is spent).
STORING = (
    "create_plan",
    "create_shortest_duration_plan",
    "create_robot",
    "create_mesh",
    "create_tuning_job",
    "create_landscape",
)
#: Synchronous plan work behind the plan admission (503 with Retry-After when it is full).
ADMITTED = ("create_plan", "create_shortest_duration_plan", "create_landscape", "create_robot", "create_mesh")

#: operationId -> (status, {link name: (target operationId, {parameter: runtime expression})}).
LINKS: dict[str, tuple[str, dict[str, tuple[str, dict[str, str]]]]] = {
    "create_plan": (
        "201",
        {
            "GetPlan": ("get_plan", {"plan_id": "$response.body#/id"}),
            "GetPlanFigure": ("get_plan_figure", {"plan_id": "$response.body#/id"}),
            "DeletePlan": ("delete_plan", {"plan_id": "$response.body#/id"}),
        },
    ),
    "create_shortest_duration_plan": (
        "201",
        {
            "GetPlan": ("get_plan", {"plan_id": "$response.body#/plan/id"}),
            "GetPlanFigure": ("get_plan_figure", {"plan_id": "$response.body#/plan/id"}),
        },
    ),
    "create_robot": (
        "201",
        {
            "GetRobot": ("get_robot", {"robot_id": "$response.body#/id"}),
            "ComputeJacobian": ("compute_jacobian", {"robot_id": "$response.body#/id"}),
            "DeleteRobot": ("delete_robot", {"robot_id": "$response.body#/id"}),
        },
    ),
    "create_mesh": (
        "201",
        {
            "GetMesh": ("get_mesh", {"mesh_id": "$response.body#/id"}),
            "DeleteMesh": ("delete_mesh", {"mesh_id": "$response.body#/id"}),
        },
    ),
    "create_landscape": (
        "201",
        {
            "GetLandscape": ("get_landscape", {"landscape_id": "$response.body#/id"}),
            "GetLandscapeHeatmap": ("get_landscape_heatmap", {"landscape_id": "$response.body#/id"}),
            "DeleteLandscape": ("delete_landscape", {"landscape_id": "$response.body#/id"}),
        },
    ),
    "create_tuning_job": (
        "202",
        {
            "GetTuningJob": ("get_tuning_job", {"job_id": "$response.body#/id"}),
            "GetTuningJobResult": ("get_tuning_job_result", {"job_id": "$response.body#/id"}),
            "GetTuningJobFigure": ("get_tuning_job_figure", {"job_id": "$response.body#/id"}),
            "CancelTuningJob": ("cancel_tuning_job", {"job_id": "$response.body#/id"}),
            "GetTuningJobEvents": ("get_tuning_job_events", {"job_id": "$response.body#/id"}),
            "DeleteTuningJob": ("delete_tuning_job", {"job_id": "$response.body#/id"}),
        },
    ),
}


def document_guards(doc: dict[str, Any], auth_required: bool) -> None:
    """Document what the middleware adds to every ``/v1`` operation: bearer authentication (401),
    the body-size limit (413), the queue limit of job submission (429), the admission and a busy
    or failing database (503 with ``Retry-After``) and the storage quota (507).

    With keys, each ``/v1`` operation requires the bearer scheme. Without, the scheme is optional
    (``{}`` among the requirements) for the whole document, at its root: client generators that
    see a requirement on an operation ask for an authenticated client there (openapi-python-client
    types such operations with ``AuthenticatedClient``), and none is needed."""
    schemes = doc.setdefault("components", {}).setdefault("securitySchemes", {})
    schemes[BEARER] = {
        "type": "http",
        "scheme": "bearer",
        "description": "`Authorization: Bearer <key>` with a key of `SPACEARM_API_KEYS`; "
        "only enforced when that variable is set (otherwise the API is open and binds to 127.0.0.1 by default)",
    }
    requirement: list[dict[str, list[str]]] = [{BEARER: []}]
    if not auth_required:
        doc["security"] = [{BEARER: []}, {}]
    for path, item in doc.get("paths", {}).items():
        if not path.startswith("/v1"):
            continue
        for method, op in item.items():
            if not isinstance(op, dict) or "responses" not in op:
                continue
            op_id = op.get("operationId")
            if auth_required:
                op.setdefault("security", requirement)
            resp = op["responses"]
            if auth_required:
                resp.setdefault("401", {"description": "missing or invalid API key"})
            busy = "too many plans in progress, or " if op_id in ADMITTED else ""
            if op_id == "get_tuning_job_events":
                busy = "`SPACEARM_MAX_EVENT_STREAMS` streams are open in this API process, or "
            resp.setdefault(
                "503",
                {
                    "description": f"{busy}the database is busy or unavailable; retry after `Retry-After` seconds",
                    "headers": RETRY_AFTER,
                },
            )
            if "requestBody" in op or method in ("post", "put", "patch"):
                resp.setdefault("413", {"description": "request body larger than 1 MiB"})
                resp.setdefault("422", {"description": "invalid body or parameters"})
            if op_id in STORING:
                resp.setdefault("507", {"description": "the storage quota (`SPACEARM_STORAGE_QUOTA_BYTES`) is spent"})
            if op_id == "create_tuning_job":
                resp.setdefault(
                    "429", {"description": "too many queued jobs; retry after `Retry-After` seconds", "headers": RETRY_AFTER}
                )


def document_links(doc: dict[str, Any]) -> None:
    """OpenAPI links (see :data:`LINKS`) and the ``Location`` header on the responses of the
    operations that create."""
    by_id = {op.get("operationId"): op for item in doc.get("paths", {}).values() for op in item.values() if isinstance(op, dict)}
    for op_id, (code, links) in LINKS.items():
        response = by_id[op_id]["responses"][code]
        response.setdefault("headers", {}).update(LOCATION)
        response["links"] = {
            name: {"operationId": target, "parameters": parameters}
            for name, (target, parameters) in links.items()
            if target in by_id
        }


def split_robot_choice(doc: dict[str, Any]) -> None:
    """A request schema marked with :data:`ROBOT_CHOICE` becomes a ``oneOf`` of two objects,
    ``<Name>StoredRobot`` (with ``robot_id``) and ``<Name>InlineRobot`` (with ``robot``), each
    closed (``additionalProperties: false``), so exactly one of the two fields is given. Client
    generators make a union of two typed models of it."""
    schemas = doc.get("components", {}).get("schemas", {})
    for name in [n for n, schema in schemas.items() if ROBOT_CHOICE in schema]:
        schema = schemas.pop(name)
        stored_field, inline_field = schema.pop(ROBOT_CHOICE)
        variants = []
        for suffix, keep, drop in (("StoredRobot", stored_field, inline_field), ("InlineRobot", inline_field, stored_field)):
            variant = copy.deepcopy(schema)
            variant["properties"].pop(drop)
            variant["required"] = [keep, *[r for r in variant.get("required", []) if r not in (keep, drop)]]
            variant["title"] = f"{schema.get('title', name)} ({'stored' if keep == stored_field else 'inline'} robot)"
            variant["examples"] = [e for e in schema.get("examples", []) if keep in e]
            if not variant["examples"]:
                variant.pop("examples")
            schemas[name + suffix] = variant
            variants.append({"$ref": f"#/components/schemas/{name}{suffix}"})
        schemas[name] = {
            "title": schema.get("title", name),
            "description": " ".join(
                filter(None, [schema.get("description"), f"Give exactly one of `{stored_field}` and `{inline_field}`."])
            ),
            "oneOf": variants,
        }


def document_body_models(doc: dict[str, Any]) -> None:
    """The schemas of :data:`BODY_MODELS` as components."""
    schemas = doc.setdefault("components", {}).setdefault("schemas", {})
    for model in BODY_MODELS:
        schema = model.model_json_schema(ref_template="#/components/schemas/{model}")
        for name, sub in schema.pop("$defs", {}).items():
            schemas.setdefault(name, sub)
        schemas.setdefault(model.__name__, schema)


def schema_refs(node: Any) -> set[str]:
    """The names of the component schemas ``node`` refers to directly."""
    if isinstance(node, dict):
        found = {node["$ref"].rsplit("/", 1)[-1]} if isinstance(node.get("$ref"), str) else set()
        return found.union(*(schema_refs(value) for value in node.values()))
    if isinstance(node, list):
        return set().union(*(schema_refs(value) for value in node))
    return set()


def reached_schemas(doc: dict[str, Any], node: Any) -> set[str]:
    """The names of the component schemas ``node`` reaches, directly or through others."""
    schemas = doc.get("components", {}).get("schemas", {})
    reached: set[str] = set()
    todo = schema_refs(node)
    while todo:
        name = todo.pop()
        if name not in reached and name in schemas:
            reached.add(name)
            todo |= schema_refs(schemas[name])
    return reached


def document_request_defaults(doc: dict[str, Any]) -> None:
    """In the schemas a request body reaches, a property's default is stated in its description
    (``default `1.5```) instead of as ``default``. The server fills in what a request leaves
    out, so such a property is optional; but TypeScript generators (openapi-typescript 7, by
    default) type a property with a ``default`` in a component schema as always present (true
    of responses, whose fields are ``required`` here anyway), and a client would have to send
    every defaulted field. Query parameters keep their ``default``."""
    schemas = doc.get("components", {}).get("schemas", {})
    bodies = [op["requestBody"] for item in doc.get("paths", {}).values() for op in item.values() if "requestBody" in op]
    for name in reached_schemas(doc, bodies):
        for prop in schemas[name].get("properties", {}).values():
            if "default" in prop:
                default = json.dumps(prop.pop("default"))
                prop["description"] = "; ".join(filter(None, [prop.get("description"), f"default `{default}`"]))


def install(app: FastAPI, auth_required: bool) -> None:
    """Error responses are ``application/problem+json`` of the ``Problem`` schema in the document;
    guards and links as above."""
    from fastapi.openapi.utils import get_openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema:
            return app.openapi_schema
        doc = get_openapi(
            title=app.title, version=app.version, description=app.description, routes=app.routes, tags=app.openapi_tags
        )
        ref = {"$ref": "#/components/schemas/Problem"}
        fastapi_422 = {"$ref": "#/components/schemas/HTTPValidationError"}
        document_guards(doc, auth_required)
        document_links(doc)
        document_body_models(doc)
        split_robot_choice(doc)
        document_request_defaults(doc)
        for item in doc.get("paths", {}).values():
            for op in item.values():
                for code, resp in op.get("responses", {}).items():
                    # FastAPI's errors are ours (problem+json); a body of its own (readiness's 503) is kept
                    schemas = [media.get("schema") for media in resp.get("content", {}).values()]
                    if code.isdigit() and int(code) >= 400 and all(schema in (ref, fastapi_422) for schema in schemas):
                        resp["content"] = {PROBLEM_JSON: {"schema": ref}}
                        if code == "422":
                            resp["description"] = "invalid body or parameters (field paths in `errors`)"
        schemas = doc.setdefault("components", {}).setdefault("schemas", {})
        for unused in ("HTTPValidationError", "ValidationError"):
            schemas.pop(unused, None)
        app.openapi_schema = doc
        return doc

    app.openapi = openapi  # type: ignore[method-assign]

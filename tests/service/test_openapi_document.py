"""The OpenAPI document as client generators read it (built in process; the same document the
live ``/openapi.json`` serves, which the generated-client tests use over HTTP): every operation
and property described, closed vocabularies as named enums that match the engine, always-present
response fields required, typed method and robot parameters, ``Location``/``Retry-After``
headers, figures as binary images, the event stream as text, request defaults optional."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest

from engine.inverses import METHODS
from engine.metrics import AGGREGATIONS, ATTITUDE_TERMS
from engine.paths import PATH_TYPES, PROFILES
from engine.tuning import ROBUST_STATISTICS
from engine.uncertainty import DISTRIBUTIONS
from service.app import create_app
from service.infra.settings import Settings
from service.openapi import reached_schemas, schema_refs

#: Response fields that may really be absent, and why.
OPTIONAL_IN_RESPONSES = {
    "PlanOut": {"trajectory", "replay"},  # sections chosen with `fields=`
    # robots with prismatic joints only
    "Trajectory": {"joint_displacements_m", "joint_velocities_m_s", "joint_accelerations_m_s2", "joint_forces_n", "clearance_m"},
    "Health": {"kernels", "database", "revision", "head"},  # liveness has only `status`
    "Problem": {"instance", "errors", "available"},  # `errors` only on a 422, `available` on a 406
    "MethodParams": {p.name for spec in METHODS.values() for p in spec.params},  # the method's own only
    "MethodOut": {"secondary"},  # plans with a null-space objective only
}


def _document(tmp_path: Path, keys: str = "") -> dict[str, Any]:
    settings = Settings(database_url=f"sqlite:///{tmp_path / 'unused.db'}", api_keys=keys or None)
    doc: dict[str, Any] = create_app(settings).openapi()
    return doc


@pytest.fixture(scope="module")
def doc(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    return _document(tmp_path_factory.mktemp("doc"))


def _operations(doc: dict[str, Any]) -> dict[str, dict[str, Any]]:
    return {op["operationId"]: op for item in doc["paths"].values() for op in item.values()}


def _enum(doc: dict[str, Any], name: str) -> list[str]:
    schema = doc["components"]["schemas"][name]
    assert schema["type"] == "string", name
    return list(schema["enum"])


def test_every_operation_parameter_and_property_is_described(doc: dict[str, Any]) -> None:
    ops = _operations(doc)
    assert len(ops) >= 28
    for op_id, op in ops.items():
        assert op.get("summary") and op.get("description"), op_id
        for param in op.get("parameters", []):
            assert param.get("description"), (op_id, param["name"])
    for name, schema in doc["components"]["schemas"].items():
        for prop, spec in schema.get("properties", {}).items():
            assert spec.get("description"), f"{name}.{prop}"


def test_quantities_state_their_units(doc: dict[str, Any]) -> None:
    """Every number's name or description says its unit (or that it is a count or without unit)."""
    unit = re.compile(
        r"_(m|s|deg|rad|kg|deg_s|m_s|m_s2|deg_s2|n|n_m|n_s|n_m_s|m_rad|percent)\b|"
        r"\b(m|s|deg|rad|kg|1/s|N|N m|N s|N m s|deg/s|m/s|rad/s|m rad|m\^3|kg m\^2|percent|dimensionless)\b|"
        r"singular values|0 to 1|\bB\b|probability|generation|"
        r"individuals|plans|bits|steps|rounds|count|number of|times|claims|HTTP status|indices|durations planned|_quaternion|"
        r"_index|\bindex\b"
    )
    for name, schema in doc["components"]["schemas"].items():
        for prop, spec in schema.get("properties", {}).items():
            kinds = re.findall(r'"type": "(number|integer)"', repr(spec).replace("'", '"'))
            if kinds and prop != "seed":
                assert unit.search(f"_{prop} {spec.get('description', '')}"), f"{name}.{prop}: {spec.get('description')}"


def test_closed_vocabularies_are_named_enums_matching_the_engine(doc: dict[str, Any]) -> None:
    assert _enum(doc, "MethodName") == list(METHODS)
    assert _enum(doc, "TunableMethodName") == [m for m, spec in METHODS.items() if spec.params]
    assert set(_enum(doc, "AggregationName")) == set(AGGREGATIONS)
    assert set(_enum(doc, "AttitudeTermName")) == set(ATTITUDE_TERMS)
    assert set(_enum(doc, "TimeProfile")) == set(PROFILES)
    assert _enum(doc, "JobStatus") == ["queued", "running", "succeeded", "failed", "cancelled"]
    assert _enum(doc, "PhaseRole") == ["tuned", "dls_baseline", "bounded_baseline", "nominal_tuned"]
    assert _enum(doc, "Stage") == ["ga", "refine"] and _enum(doc, "RobustStatistic") == list(ROBUST_STATISTICS)
    assert _enum(doc, "DistributionName") == list(DISTRIBUTIONS)
    assert set(_enum(doc, "ParamName")) == {p.name for spec in METHODS.values() for p in spec.params}
    schemas = doc["components"]["schemas"]
    assert {schemas[f"{t.capitalize()}PathIn"]["properties"]["type"]["const"] for t in PATH_TYPES} == set(PATH_TYPES)

    def ref(schema: str, prop: str) -> set[str]:
        return schema_refs(schemas[schema]["properties"][prop])

    assert ref("MethodOut", "name") == {"MethodName"} and ref("TuningJobOut", "status") == {"JobStatus"}
    assert ref("TuningJobOut", "method") == {"TunableMethodName"} and ref("TaskIn", "profile") == {"TimeProfile"}
    assert ref("ObjectiveSettings", "aggregation") == {"AggregationName"} and ref("JobPhase", "role") == {"PhaseRole"}
    assert ref("PlanMetrics", "attitude_term") == {"AttitudeTermName"} and ref("LandscapeOut", "method") == {"LandscapeMethod"}
    figures = [op for op_id, op in _operations(doc).items() if op_id.endswith("_figure")]
    names = [p["schema"] for op in figures for p in op["parameters"] if p["name"] == "name"]
    assert len(names) == 3 and all(s["type"] == "string" and s["enum"] for s in names)


def test_response_fields_are_required_and_typed(doc: dict[str, Any]) -> None:
    """Every response schema lists its fields as required but those that may really be absent;
    no response holds a free-form object; method and robot parameters are typed models. Request
    models shown in a response (a preset's task, a robot's parameters) are the request schemas."""
    ops = _operations(doc)
    responses = reached_schemas(doc, [op["responses"] for op in ops.values()])
    requests = reached_schemas(doc, [op.get("requestBody") for op in ops.values()])
    schemas = doc["components"]["schemas"]
    for name in sorted(responses - requests):
        schema = schemas[name]
        optional = set(schema.get("properties", {})) - set(schema.get("required", []))
        assert optional <= OPTIONAL_IN_RESPONSES.get(name, set()), (name, optional)
    for name in responses | requests:
        for prop, spec in schemas[name].get("properties", {}).items():
            for node in [spec, *spec.get("anyOf", [])]:
                assert not (node.get("type") == "object" and "properties" not in node), f"{name}.{prop} is untyped"
    assert schema_refs(schemas["RobotOut"]["properties"]["parameters"]) == {"RobotParams"}
    robot_body = ops["create_robot"]["requestBody"]["content"]["application/json"]["schema"]
    assert schema_refs(robot_body) == {"RobotParams", "RobotUrdfIn"} and "RobotUrdfIn" in requests
    assert schema_refs(schemas["MethodOut"]["properties"]["params"]) == {"MethodParams"}
    for name, prop in (("TuningJobResult", "best_params"), ("JobProgress", "best_params"), ("LandscapeOut", "best_params")):
        assert schema_refs(schemas[name]["properties"][prop]) == {"MethodParams"}, name
    # request defaults live in the descriptions: optional in generated types (openapi-typescript
    # types a component property with a `default` as always present)
    for name in requests:
        for prop, spec in schemas[name].get("properties", {}).items():
            assert "default" not in spec, f"{name}.{prop}"
    assert "default `0.25`" in schemas["TaskIn"]["properties"]["dt_s"]["description"]


def test_headers_images_and_event_stream_are_declared(doc: dict[str, Any]) -> None:
    ops = _operations(doc)
    for op_id, code in (
        ("create_plan", "201"),
        ("create_robot", "201"),
        ("create_shortest_duration_plan", "201"),
        ("create_landscape", "201"),
        ("create_tuning_job", "202"),
    ):
        assert ops[op_id]["responses"][code]["headers"]["Location"]["schema"] == {"type": "string"}, op_id
    for op_id, op in ops.items():
        for code, response in op["responses"].items():
            if code in ("429", "503"):
                assert response["headers"]["Retry-After"]["schema"]["type"] == "integer", (op_id, code)
    images = [op for op in ops.values() if "image/png" in op["responses"].get("200", {}).get("content", {})]
    assert len(images) == 4
    for op in images:
        content = op["responses"]["200"]["content"]
        assert set(content) == {"image/svg+xml", "image/png", "application/pdf"}
        assert all(media["schema"] == {"type": "string", "format": "binary"} for media in content.values())
        assert "ETag" in op["responses"]["200"]["headers"] and "304" in op["responses"]
    stream = ops["get_tuning_job_events"]["responses"]["200"]["content"]
    assert set(stream) == {"text/event-stream"} and stream["text/event-stream"]["schema"]["type"] == "string"


def test_security_is_optional_without_keys_and_required_with_them(doc: dict[str, Any], tmp_path: Path) -> None:
    """Without keys the bearer scheme is optional for the whole document (its root), so
    generators give every operation a plain client; with keys each /v1 operation requires it."""
    assert doc["security"] == [{"bearerAuth": []}, {}]
    assert not [op_id for op_id, op in _operations(doc).items() if "security" in op]
    keyed = _document(tmp_path, keys="k1")
    assert "security" not in keyed
    for op_id, op in _operations(keyed).items():
        expected = [{"bearerAuth": []}] if not op_id.endswith("z") else None  # healthz, readyz stay open
        assert op.get("security") == expected, op_id

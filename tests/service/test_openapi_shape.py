"""The OpenAPI document's shape does not drift: its operations (paths, methods, operation ids,
parameters, response codes) and its schemas (names, properties, required fields, enums) equal
the snapshot in ``openapi-shape.json`` (descriptions may change). Regenerate the snapshot only
for a deliberate API change: ``python tests/service/test_openapi_shape.py > tests/service/openapi-shape.json``."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

SNAPSHOT = Path(__file__).with_name("openapi-shape.json")


def shape(doc: dict[str, Any]) -> dict[str, Any]:
    """What clients generate code from, without the prose."""
    operations = {}
    for path, item in doc["paths"].items():
        for method, op in item.items():
            operations[f"{method.upper()} {path}"] = {
                "operationId": op.get("operationId"),
                "parameters": sorted([p["in"], p["name"], bool(p.get("required"))] for p in op.get("parameters", [])),
                "responses": sorted(op.get("responses", {})),
            }
    schemas = {
        name: {"required": sorted(s.get("required", [])), "properties": sorted(s.get("properties", {})), "enum": s.get("enum")}
        for name, s in doc["components"]["schemas"].items()
    }
    return {"operations": operations, "schemas": schemas}


def _document(tmp: Path) -> dict[str, Any]:
    from service.app import create_app
    from service.infra.settings import Settings

    doc: dict[str, Any] = create_app(Settings(database_url=f"sqlite:///{tmp / 'unused.db'}")).openapi()
    return doc


def test_the_document_has_the_snapshot_shape(tmp_path: Path) -> None:
    expected = json.loads(SNAPSHOT.read_text())
    actual = json.loads(json.dumps(shape(_document(tmp_path))))
    assert sorted(actual["operations"]) == sorted(expected["operations"])
    assert sorted(actual["schemas"]) == sorted(expected["schemas"])
    for name, op in expected["operations"].items():
        assert actual["operations"][name] == op, name
    for name, schema in expected["schemas"].items():
        assert actual["schemas"][name] == schema, name


if __name__ == "__main__":
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        json.dump(shape(_document(Path(tmp))), sys.stdout, indent=1, sort_keys=True)

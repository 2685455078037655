"""Collision geometry over the API (issue 19), against a real server: robots with collision shapes
(parameters and URDF, a URDF naming a stored mesh), task scenes with obstacles (primitives and
stored meshes), the clearance in metrics, verdicts, trajectories, exports and figures; meshes
uploaded, stored once, listed and deleted; every bad geometry a 422 naming its field; the
raster-target preset: the unavoided plan touches the fixture, the bounded inverse keeps the
clearance."""

from __future__ import annotations

import csv
import io
from typing import Any

import httpx
import numpy as np
import pytest

from engine.model import table1_with_geometry
from tests.service.conftest import PAPER_TASK

trimesh = pytest.importorskip("trimesh")
PANEL = {"type": "box", "size_m": [0.6, 0.6, 0.05], "position_m": [1.45, 0.0, 0.0]}


def _stl(mesh: Any) -> bytes:
    data: bytes = mesh.export(file_type="stl")
    return data


def _fields(r: httpx.Response) -> list[str]:
    assert r.status_code == 422, r.text
    return [e["field"] for e in r.json().get("errors") or []]


def test_the_geometry_preset_robot_and_a_robot_with_shapes_round_trip(client: httpx.Client) -> None:
    stored = client.get("/v1/robots/table1-geometry").json()
    assert stored["preset"] is True
    assert stored["parameters"]["base"]["collision_box"] == {"size_m": [1.5, 1.5, 1.5], "center_m": [0.0, 0.0, 0.0]}
    assert {link["collision_radius_m"] for link in stored["parameters"]["links"]} == {0.05}
    params = stored["parameters"]
    params["name"] = "with a box on link 4"
    params["links"][3]["collision_shapes"] = [
        {"type": "box", "size_m": [0.1, 0.2, 0.3], "position_m": [0.0, 0.1, 0.0], "quaternion": [1.0, 0.0, 0.0, 0.0]}
    ]
    created = client.post("/v1/robots", json=params)
    assert created.status_code == 201, created.text
    echoed = created.json()["parameters"]["links"][3]["collision_shapes"][0]
    assert echoed["type"] == "box" and echoed["size_m"] == [0.1, 0.2, 0.3]


def test_a_plan_reports_its_clearance_and_a_contact_fails_it(client: httpx.Client) -> None:
    task = {**PAPER_TASK, "clearance_m": 0.01, "scene": {"obstacles": [PANEL]}}
    r = client.post("/v1/plans", json={"robot_id": "table1-geometry", "task": task, "method": {"name": "dls"}})
    assert r.status_code == 201, r.text
    plan = r.json()
    m = plan["metrics"]
    assert plan["success"] is False and m["clearance_respected"] is False
    assert m["clearance_broken_pair"] == ["link6", "obstacle0"] and m["min_clearance_pair"] == ["link6", "obstacle0"]
    t, d = m["t_clearance_broken_s"], m["clearance_broken_distance_m"]
    assert "clearance broken: link6 and obstacle0" in plan["message"] and f"at t = {t:g} s" in plan["message"]
    assert d < 0.01 and m["min_clearance_m"] <= d
    clearance = plan["trajectory"]["clearance_m"]
    assert (
        len(clearance) == len(plan["trajectory"]["t_s"]) and min(clearance) == pytest.approx(m["min_clearance_m"], abs=1e-12)
    ) or (
        m["min_clearance_m"] < min(clearance)  # closer between two samples than at any
    )
    # the export carries the same column
    text = client.get(f"/v1/plans/{plan['id']}/trajectory", params={"format": "csv"}).text
    rows = list(csv.DictReader(io.StringIO(text)))
    np.testing.assert_allclose([float(row["clearance_m"]) for row in rows], clearance, rtol=0, atol=0)
    # far from the panel the plan passes; a robot without shapes has no clearance at all
    far = {**task, "scene": {"obstacles": [{**PANEL, "position_m": [3.0, 0.0, 0.0]}]}}
    tuned = {"name": "adaptive", "params": {"lambda_max": 0.04, "epsilon": 0.37}}
    ok = client.post(
        "/v1/plans", params={"fields": ""}, json={"robot_id": "table1-geometry", "task": far, "method": tuned}
    ).json()
    assert ok["success"] is True and ok["metrics"]["clearance_respected"] is True and ok["metrics"]["min_clearance_m"] > 0.01
    none = client.post("/v1/plans", json={"robot_id": "table1", "task": PAPER_TASK}).json()
    assert none["metrics"]["min_clearance_m"] is None and "clearance_m" not in none["trajectory"]
    for name in ("clearance", "scene-3d"):
        figure = client.get(f"/v1/plans/{plan['id']}/figures/{name}")
        assert figure.status_code == 200 and figure.headers["content-type"].startswith("image/svg+xml")
        assert b"obstacle0" in figure.content or name == "scene-3d"


@pytest.mark.parametrize(
    ("obstacle", "field"),
    [
        ({"type": "sphere", "radius_m": -0.1}, "body.task.scene.obstacles[0].sphere.radius_m"),
        ({"type": "sphere", "radius_m": 0.1, "position_m": [1e9, 0, 0]}, "body.task.scene.obstacles[0].sphere.position_m[0]"),
        ({"type": "box", "size_m": [1.0, 1.0, 1.0], "quaternion": [0, 0, 0, 0]}, "body.task.scene.obstacles[0].box.quaternion"),
        (
            {"type": "convex", "vertices_m": [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]},
            "body.task.scene.obstacles[0].convex.vertices_m",
        ),
        ({"type": "mesh", "mesh_id": "0" * 32}, "body.task.scene.obstacles[0].mesh.mesh_id"),
        ({"type": "cone"}, "body.task.scene.obstacles[0]"),
    ],
)
def test_bad_obstacles_are_422s_naming_the_field(client: httpx.Client, obstacle: dict[str, Any], field: str) -> None:
    task = {**PAPER_TASK, "scene": {"obstacles": [obstacle]}}
    fields = _fields(client.post("/v1/plans", json={"robot_id": "table1-geometry", "task": task}))
    assert any(f.startswith(field) for f in fields), fields


def test_bad_robot_geometry_and_obstacles_without_shapes_are_422s(client: httpx.Client) -> None:
    params = table1_with_geometry().to_dict()
    params["links"][2]["collision_radius_m"] = -0.1
    assert _fields(client.post("/v1/robots", json=params)) == ["body.links[2].collision_radius_m"]
    params["links"][2]["collision_radius_m"] = 0.05
    params["base"]["collision_box"] = {"size_m": [1.0, 1.0]}
    assert _fields(client.post("/v1/robots", json=params)) == ["body.base.collision_box.size_m"]
    task = {**PAPER_TASK, "scene": {"obstacles": [PANEL]}}
    assert _fields(client.post("/v1/plans", json={"robot_id": "table1", "task": task})) == ["body.task.scene.obstacles"]
    clearance = {"robot_id": "table1", "task": PAPER_TASK, "secondary": {"objective": "clearance"}}
    assert _fields(client.post("/v1/plans", json=clearance)) == ["body.secondary"]  # nor a 7-joint arm


def test_meshes_are_stored_once_checked_and_used_as_obstacles(client: httpx.Client) -> None:
    panel = trimesh.creation.box(extents=[0.6, 0.6, 0.05])
    panel.apply_translation([1.45, 0.0, 0.0])
    first = client.post("/v1/meshes", content=_stl(panel), params={"format": "stl", "name": "panel"})
    assert first.status_code == 201 and first.headers["location"] == f"/v1/meshes/{first.json()['id']}"
    mesh = first.json()
    assert (mesh["face_count"], mesh["hull_vertex_count"], mesh["name"]) == (12, 8, "panel")
    again = client.post("/v1/meshes", content=_stl(panel), headers={"content-type": "model/stl"})
    assert again.status_code == 200 and again.json()["id"] == mesh["id"]  # stored once
    assert mesh["id"] in [m["id"] for m in client.get("/v1/meshes").json()["items"]]
    # the same obstacle as a mesh and as a box: the same plan
    as_mesh = {**PAPER_TASK, "clearance_m": 0.01, "scene": {"obstacles": [{"type": "mesh", "mesh_id": mesh["id"]}]}}
    as_box = {**PAPER_TASK, "clearance_m": 0.01, "scene": {"obstacles": [PANEL]}}
    a = client.post("/v1/plans", params={"fields": ""}, json={"robot_id": "table1-geometry", "task": as_mesh}).json()
    b = client.post("/v1/plans", params={"fields": ""}, json={"robot_id": "table1-geometry", "task": as_box}).json()
    assert a["metrics"]["min_clearance_m"] == pytest.approx(b["metrics"]["min_clearance_m"], abs=1e-6)
    assert a["message"] == b["message"]
    # refused: not closed, not a mesh, too large, no format
    open_box = trimesh.Trimesh(vertices=panel.vertices, faces=panel.faces[:-2])
    r = client.post("/v1/meshes", content=_stl(open_box), params={"format": "stl"})
    assert r.status_code == 422 and "not closed" in r.json()["detail"]
    r = client.post("/v1/meshes", content=b"solid nothing", params={"format": "obj"})
    assert r.status_code == 422 and "no triangles" in r.json()["detail"]
    r = client.post("/v1/meshes", content=b"x" * (600 * 1024), params={"format": "stl"})  # under the body limit
    assert r.status_code == 413 and "bytes, more than the 524288" in r.json()["detail"]  # as a larger body is
    assert r.json()["errors"][0]["field"] == "body"
    r = client.post("/v1/meshes", content=_stl(panel))
    assert r.status_code == 422 and r.json()["errors"][0]["field"] == "query.format"
    fine = trimesh.creation.icosphere(subdivisions=4)  # a hull of 2562 vertices
    r = client.post("/v1/meshes", content=_stl(fine), params={"format": "stl"})
    assert r.status_code == 422 and "convex hull has" in r.json()["detail"]
    # a URDF names a stored mesh as its collision
    urdf = (
        table1_with_geometry()
        .to_urdf()
        .replace(
            '<link name="link6">',
            f'<link name="link6"><collision><geometry><mesh filename="mesh://{mesh["id"]}"/></geometry></collision>',
            1,
        )
    )
    robot = client.post("/v1/robots", json={"urdf": urdf})
    assert robot.status_code == 201, robot.text
    assert robot.json()["parameters"]["links"][5]["collision_shapes"][0]["type"] == "convex"
    # a stored plan with a box and the mesh, before the mesh is deleted
    both = {**as_box, "scene": {"obstacles": [PANEL, {"type": "mesh", "mesh_id": mesh["id"]}]}}
    c = client.post("/v1/plans", params={"fields": ""}, json={"robot_id": "table1-geometry", "task": both}).json()
    before = client.get(f"/v1/plans/{c['id']}/figures/scene-3d", params={"format": "svg"})  # rendered, and kept
    assert before.status_code == 200 and b"not drawn" not in before.content
    assert client.delete(f"/v1/meshes/{mesh['id']}").status_code == 204
    assert client.get(f"/v1/meshes/{mesh['id']}").status_code == 404
    # its figures keep the box (a deleted mesh took every obstacle with it) and say what they leave out
    assert len(client.get(f"/plans/{c['id']}/scene.json").json()["obstacles"]) == 1
    figure = client.get(f"/v1/plans/{c['id']}/figures/scene-3d", params={"format": "svg"})
    assert figure.status_code == 200 and b"not drawn (mesh deleted since): obstacle1" in figure.content
    assert figure.headers["x-figure-cache"] == "miss" and figure.headers["etag"] != before.headers["etag"]
    replanned = client.post("/v1/plans", json={"robot_id": "table1-geometry", "task": as_mesh})
    assert _fields(replanned) == ["body.task.scene.obstacles[0].mesh.mesh_id"]


def test_the_raster_target_preset_is_avoided_by_the_bounded_inverse(client: httpx.Client) -> None:
    preset = client.get("/v1/task-presets/raster-target").json()
    task = {**preset["task"], "dt_s": 0.5}  # half the samples: the same story, twice as fast
    avoided = client.post(
        "/v1/plans", params={"fields": ""}, json={"robot_id": preset["robot_id"], "task": task, "method": preset["method"]}
    )
    plain = client.post(
        "/v1/plans",
        params={"fields": ""},
        json={
            "robot_id": preset["robot_id"],
            "task": task,
            "method": {"name": "adaptive", "params": {"lambda_max": 0.02038, "epsilon": 0.12}},
        },
    )
    a, p = avoided.json(), plain.json()
    print(
        f"\nraster-target: adaptive {p['metrics']['min_clearance_m'] * 1e3:.1f} mm ({p['metrics']['min_clearance_pair']}), "
        f"bounded {a['metrics']['min_clearance_m'] * 1e3:.1f} mm, tracking {a['metrics']['position_error_max_m'] * 1e3:.1f} mm"
    )
    assert p["metrics"]["clearance_respected"] is False and p["metrics"]["clearance_broken_pair"] == ["link6", "obstacle1"]
    assert a["metrics"]["clearance_respected"] is True and a["metrics"]["min_clearance_m"] >= 0.02
    assert a["success"] is True, a["message"]


def test_a_robot_exported_as_urdf_and_stored_again_keeps_its_collision_geometry(client: httpx.Client) -> None:
    """GET .../urdf, then POST it: the stored robot's clearance against the raster-target scene is
    the original's, pair for pair (docs/robots.md: "read back to the same model")."""
    text = client.get("/v1/robots/table1-geometry/urdf")
    assert text.status_code == 200 and "<collision>" in text.text
    stored = client.post("/v1/robots", json={"urdf": text.text, "name": "table1-geometry-again"})
    assert stored.status_code == 201, stored.text
    preset = client.get("/v1/task-presets/raster-target").json()
    task = {**preset["task"], "dt_s": 0.5}
    metrics = []
    for robot_id in ("table1-geometry", stored.json()["id"]):
        r = client.post("/v1/plans", params={"fields": ""}, json={"robot_id": robot_id, "task": task, "method": preset["method"]})
        assert r.status_code == 201, r.text
        metrics.append(r.json()["metrics"])
    original, again = metrics
    assert again["min_clearance_pair"] == original["min_clearance_pair"]
    assert again["min_clearance_m"] == pytest.approx(original["min_clearance_m"], abs=1e-9)
    assert again["clearance_respected"] is original["clearance_respected"] is True


def test_mesh_refusals_say_what_is_wrong(client: httpx.Client) -> None:
    """A vertex that is not a number is said to be one (processing dropped it and the mesh read as
    "not closed"); a URDF naming a mesh id that is not stored says so (it said to do what it did)."""
    obj = "v nan 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 3 4\nf 1 4 2\nf 2 4 3\n"
    r = client.post("/v1/meshes", params={"format": "obj"}, content=obj.encode())
    assert r.status_code == 422 and "every coordinate must be finite" in r.json()["detail"]
    unknown = "0123456789abcdef0123456789abcdef"
    urdf = (
        table1_with_geometry()
        .to_urdf()
        .replace(
            '<link name="link6">',
            f'<link name="link6"><collision><geometry><mesh filename="mesh://{unknown}"/></geometry></collision>',
            1,
        )
    )
    r = client.post("/v1/robots", json={"urdf": urdf})
    assert r.status_code == 422 and f"no stored mesh '{unknown}'" in r.json()["detail"], r.text
    assert r.json()["element"] == '<link name="link6">'

"""Figures of plans and tuning jobs over real HTTP: every endpoint returns a valid SVG or PNG
for a real plan and job; unknown names are 404 problem details listing the valid names."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from typing import Any

import httpx
import numpy as np
import pytest

from service import figures
from tests.service.conftest import PAPER_TASK, Stack, job_body, wait_status

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
SVG_NS = "{http://www.w3.org/2000/svg}"
TIME_FIGURES = [
    "ee-velocity",
    "gjm-determinant",
    "joint-velocities",
    "joint-angles",
    "tracking-errors",
    "base-motion",
    "damping",
    "joint-torques",
    "carrier-wrench",
    "clearance",
    "robustness",
]
PLAN_NAMES = [*TIME_FIGURES, "scene-3d"]


def assert_svg(response: httpx.Response) -> ET.Element:
    assert response.status_code == 200, response.text
    assert response.headers["content-type"].startswith("image/svg+xml")
    root = ET.fromstring(response.content)
    assert root.tag == SVG_NS + "svg"
    assert float(root.attrib["width"].removesuffix("pt")) > 100
    return root


def assert_png(response: httpx.Response) -> None:
    assert response.status_code == 200, response.text
    assert response.headers["content-type"] == "image/png"
    assert response.content.startswith(PNG_MAGIC)
    assert response.content[12:16] == b"IHDR"
    width = int.from_bytes(response.content[16:20], "big")
    height = int.from_bytes(response.content[20:24], "big")
    assert width > 300 and height > 200


def svg_text(root: ET.Element) -> str:
    return " ".join(t for el in root.iter() for t in [el.text] if t)


@pytest.fixture(scope="module")
def plans(stack: Stack) -> dict[str, str]:
    with stack.client() as c:
        out = {}
        for name, params in (("adaptive", {"lambda_max": 0.06, "epsilon": 0.12}), ("dls", {"lambda": 0.05})):
            r = c.post("/v1/plans", json={"robot_id": "table1", "task": PAPER_TASK, "method": {"name": name, "params": params}})
            assert r.status_code == 201, r.text
            out[name] = r.json()["id"]
        return out


@pytest.mark.parametrize("name", TIME_FIGURES)
def test_plan_figure_svg_and_png(client: httpx.Client, plans: dict[str, str], name: str) -> None:
    root = assert_svg(client.get(f"/v1/plans/{plans['adaptive']}/figures/{name}"))
    text = svg_text(root)
    assert "time t [s]" in text  # axes carry units
    assert "[" in text.replace("time t [s]", "")
    assert_png(client.get(f"/v1/plans/{plans['adaptive']}/figures/{name}", params={"format": "png"}))


def test_plan_figures_have_units_legends_and_singular_region(client: httpx.Client, plans: dict[str, str]) -> None:
    pid = plans["adaptive"]
    text = svg_text(assert_svg(client.get(f"/v1/plans/{pid}/figures/joint-velocities")))
    for j in range(1, 7):
        assert f"joint {j}" in text  # a legend entry per joint
    assert "joint velocity [deg/s]" in text and "limit ±6 deg/s" in text
    assert "singular region" in text and "0.12" in text  # shaded with the plan's epsilon
    text = svg_text(assert_svg(client.get(f"/v1/plans/{pid}/figures/joint-angles")))
    assert "joint angle [deg]" in text
    text = svg_text(assert_svg(client.get(f"/v1/plans/{plans['dls']}/figures/gjm-determinant")))
    assert "ε (default)" in text  # dls has no epsilon: the documented default threshold


def test_plan_figure_is_cached(client: httpx.Client, plans: dict[str, str]) -> None:
    url = f"/v1/plans/{plans['dls']}/figures/damping"
    first = client.get(url)
    second = client.get(url)
    assert second.headers["x-figure-cache"] == "hit"
    assert first.content == second.content
    etag = second.headers["etag"]
    # RFC 9110's weak comparison, lists and "*" (a weak tag or a list got the whole figure again)
    for header in (etag, f"W/{etag}", f'"other", {etag}', "*"):
        revalidated = client.get(url, headers={"if-none-match": header})
        assert revalidated.status_code == 304 and revalidated.headers["etag"] == etag, header
    two_lines = client.get(url, headers=[("if-none-match", '"other"'), ("if-none-match", etag)])  # a list over two lines
    assert two_lines.status_code == 304
    for header in ('"other"', f'"{etag.strip(chr(34))}x"'):
        assert client.get(url, headers={"if-none-match": header}).status_code == 200, header


def test_unknown_figure_and_plan_are_404(client: httpx.Client, plans: dict[str, str]) -> None:
    r = client.get(f"/v1/plans/{plans['adaptive']}/figures/nope")
    assert r.status_code == 404
    assert r.headers["content-type"].startswith("application/problem+json")
    body = r.json()
    assert body["valid_names"] == PLAN_NAMES
    assert all(n in body["detail"] for n in PLAN_NAMES)
    missing = "0" * 32  # well-formed, not stored
    assert client.get(f"/v1/plans/{missing}/figures/damping").status_code == 404
    assert client.get("/v1/plans/not-an-id/figures/damping").status_code == 404
    r = client.get(f"/v1/tuning-jobs/{missing}/figures/nope")
    assert r.status_code == 404 and r.json()["valid_names"] == ["convergence"]
    assert client.get(f"/v1/tuning-jobs/{missing}/figures/convergence").status_code == 404
    assert client.get(f"/v1/plans/{plans['adaptive']}/figures/damping", params={"format": "gif"}).status_code == 422


def test_compare_tracking_errors(client: httpx.Client, plans: dict[str, str]) -> None:
    ids = f"{plans['dls']},{plans['adaptive']}"
    root = assert_svg(client.get("/v1/plans/compare/figures/tracking-errors", params={"ids": ids}))
    text = svg_text(root)
    assert plans["dls"][:8] in text and plans["adaptive"][:8] in text
    assert "position error |e_p| [mm]" in text
    assert_png(client.get("/v1/plans/compare/figures/tracking-errors", params={"ids": ids, "format": "png"}))
    r = client.get("/v1/plans/compare/figures/tracking-errors", params={"ids": f"{plans['dls']},missing"})
    assert r.status_code == 404
    r = client.get("/v1/plans/compare/figures/nope", params={"ids": ids})
    assert r.status_code == 404 and r.json()["valid_names"] == PLAN_NAMES
    assert client.get("/v1/plans/compare/figures/tracking-errors", params={"ids": ","}).status_code == 422
    # the plan routes are not shadowed
    assert client.get(f"/v1/plans/{plans['dls']}").status_code == 200
    assert client.get("/v1/plans/compare").status_code == 404


@pytest.mark.parametrize("name", PLAN_NAMES)
def test_compare_every_plan_figure(client: httpx.Client, plans: dict[str, str], name: str) -> None:
    """Any plan figure compares plans (the paper's Fig. 9: joint velocities of DLS and adaptive
    damping side by side), each plan's column titled by its method and id."""
    ids = f"{plans['dls']},{plans['adaptive']}"
    text = svg_text(assert_svg(client.get(f"/v1/plans/compare/figures/{name}", params={"ids": ids})))
    assert plans["dls"][:8] in text and plans["adaptive"][:8] in text
    assert "dls" in text and "adaptive" in text


def test_job_convergence_figure(client: httpx.Client) -> None:
    r = client.post("/v1/tuning-jobs", json=job_body(population=4, generations=3, compare=True))
    assert r.status_code == 202
    job_id = r.json()["id"]
    assert_svg(client.get(f"/v1/tuning-jobs/{job_id}/figures/convergence"))  # queued or running: still a figure
    job: dict[str, Any] = wait_status(client, job_id, ("succeeded", "failed"))
    assert job["status"] == "succeeded"
    root = assert_svg(client.get(f"/v1/tuning-jobs/{job_id}/figures/convergence"))
    text = svg_text(root)
    assert "adaptive: best B" in text and "DLS baseline: best B" in text and "generation" in text
    assert_png(client.get(f"/v1/tuning-jobs/{job_id}/figures/convergence", params={"format": "png"}))
    assert client.get(f"/v1/tuning-jobs/{job_id}/figures/convergence").headers["cache-control"] == "no-cache"


def test_openapi_lists_figures_not_pages(client: httpx.Client) -> None:
    doc = client.get("/openapi.json").json()
    paths = doc["paths"]
    op = paths["/v1/plans/{plan_id}/figures/{name}"]["get"]
    assert op["operationId"] == "get_plan_figure"
    assert set(op["responses"]["200"]["content"]) == {"image/svg+xml", "image/png", "application/pdf"}
    assert "/v1/tuning-jobs/{job_id}/figures/{name}" in paths
    assert "/v1/plans/compare/figures/{name}" in paths
    assert "/" not in paths and "/plans/{plan_id}" not in paths and "/web/plans" not in paths


def test_decimation_keeps_peaks_and_singular_intervals() -> None:
    t = np.linspace(0, 500, 20_001)
    y = np.sin(t)
    y[12_345] = 10.0
    tt, yy = figures.decimate(t, y)
    assert len(tt) <= figures.MAX_POINTS + 2 and yy.max() == 10.0 and tt[0] == 0 and tt[-1] == 500
    sigma = np.array([1.0, 0.5, 0.01, 0.02, 0.5, 0.01])
    assert figures.singular_intervals(np.arange(6.0), sigma, 0.1) == [(2.0, 4.0), (5.0, 5.0)]

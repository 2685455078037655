"""The web pages over real HTTP (no browser): robots by name everywhere, a robot uploaded (URDF
and JSON) and deleted through the page's forms, plans and jobs deleted, the forms' errors next
to their fields in the form's words and said once, a failed plan's B and replay card, two plans
compared, the favicon, the 3D view's page and scene (its arm against the plan's own end-effector
path), and the vendored three.js bundle rebuilt from its lockfile."""

from __future__ import annotations

import json
import re
import subprocess
from typing import Any

import httpx
import lxml.html
import numpy as np
import pytest

from engine.model import urdf_preset_text
from tests.service.conftest import PAPER_TASK, ROOT, Stack, job_body

HEX_ID = re.compile(r"\b[0-9a-f]{32}\b")


def parse(response: httpx.Response) -> Any:
    return lxml.html.fromstring(response.text)


def text_of(doc: Any, xpath: str) -> str:
    return " ".join(" ".join(e.itertext()) for e in doc.xpath(xpath))


def csrf(client: httpx.Client) -> str:
    """The index's form token (the double-submit cookie is kept by the client)."""
    token: str = parse(client.get("/")).xpath("//form[@id='plan-form']/input[@name='csrf_token']/@value")[0]
    return token


def upload(client: httpx.Client, content: str, filename: str, **fields: str) -> httpx.Response:
    files = {"file": (filename, content.encode(), "application/octet-stream")}
    return client.post("/web/robots", data={"csrf_token": csrf(client), **fields}, files=files)


def plan(client: httpx.Client, method: dict[str, Any], robot_id: str = "table1", **task: Any) -> str:
    body = {"robot_id": robot_id, "task": {**PAPER_TASK, **task}, "method": method, "replay": True}
    r = client.post("/v1/plans", params={"fields": ""}, json=body)
    assert r.status_code == 201, r.text
    plan_id: str = r.json()["id"]
    return plan_id


@pytest.fixture(scope="module")
def web(stack: Stack) -> Any:
    with httpx.Client(base_url=stack.url, timeout=60) as c:
        yield c


def test_robots_are_uploaded_named_and_deleted_from_the_page(web: httpx.Client) -> None:
    r = upload(web, urdf_preset_text("arm7"), "arm7.urdf", end_effector_link="tool0", name="inspection arm")
    assert r.status_code == 303, r.text
    robot_id = r.headers["location"].split("robot=")[1].split("#")[0]
    table1 = json.dumps(web.get("/v1/robots/table1").json()["parameters"] | {"name": "inspection arm"})
    r = upload(web, table1, "robot.json")
    assert r.status_code == 303, r.text
    second = r.headers["location"].split("robot=")[1].split("#")[0]
    assert web.get(f"/v1/robots/{robot_id}").json()["n_joints"] == 7

    doc = parse(web.get("/"))
    options = {o.get("value"): o.text_content() for o in doc.xpath("//select[@id='robot']/option")}
    assert options[robot_id] == "inspection arm" and options[second] == "inspection arm (2)"  # by name, in upload order
    assert options["table1"] == "table1"
    robots = [e.text_content().strip() for e in doc.xpath("//section[@id='robots']//td[@class='robot-name']")]
    assert robots[:4] == ["table1", "table1-geometry", "arm7", "arm3"] and "inspection arm (2)" in robots
    assert not HEX_ID.search(text_of(doc, "//section[@id='robots']//table") + text_of(doc, "//select[@id='robot']"))

    # a plan and a job of the uploaded robot show its name too
    plan_id = plan(web, {"name": "dls", "params": {"lambda": 0.05}}, robot_id=second, dt_s=0.5)
    job = web.post("/v1/tuning-jobs", json={**job_body(population=4, generations=1, compare=False), "robot_id": second}).json()
    doc = parse(web.get("/"))
    assert text_of(doc, f"//tr[@data-plan='{plan_id}']/td[@class='robot-name']").strip() == "inspection arm (2)"
    assert text_of(doc, f"//tr[@data-job='{job['id']}']/td[@class='robot-name']").strip() == "inspection arm (2)"
    assert "inspection arm (2)" in text_of(parse(web.get(f"/plans/{plan_id}")), "//*[@id='plan-robot']")

    # delete: the uploaded robot goes; a preset has no delete button, and a forged delete is refused
    assert not doc.xpath("//tr[@data-robot='table1']//form")
    r = web.post(f"/web/robots/{robot_id}/delete", data={"csrf_token": csrf(web)})
    assert r.status_code == 303 and r.headers["location"] == "/#robots"
    assert web.get(f"/v1/robots/{robot_id}").status_code == 404
    r = web.post("/web/robots/table1/delete", data={"csrf_token": csrf(web)})
    assert r.status_code == 409 and "preset" in text_of(parse(r), "//*[@id='notice']")
    assert web.post(f"/web/robots/{second}/delete", data={"csrf_token": "forged"}).status_code == 403
    assert web.get(f"/v1/robots/{second}").status_code == 200


def test_upload_errors_are_next_to_the_file_in_the_forms_words(web: httpx.Client) -> None:
    bad = web.get("/v1/robots/table1").json()["parameters"]
    bad["links"][2]["mass"] = -1.0
    r = upload(web, json.dumps(bad), "bad.json")
    assert r.status_code == 422
    doc = parse(r)
    assert text_of(doc, "//span[@class='field-error'][@data-field='file']") == "links[2].mass: must be greater than 0"
    assert "body." not in r.text
    r = upload(web, urdf_preset_text("arm3"), "arm3.urdf", end_effector_link="nope")
    message = text_of(parse(r), "//span[@class='field-error'][@data-field='end_effector_link']")
    assert r.status_code == 422 and message.startswith("the URDF has no such link")
    r = upload(web, "neither", "robot.txt")
    assert r.status_code == 422 and "neither URDF (XML) nor JSON" in r.text


def test_plan_form_errors_stand_next_to_their_fields_once(web: httpx.Client) -> None:
    form = {"csrf_token": csrf(web), "preset": "paper-line", "robot_id": "table1", "method": "dls"}
    r = web.post("/web/plans", data={**form, "dls.lambda": "-1", "duration_s": "-2", "replay": "on"})
    assert r.status_code == 422
    doc = parse(r)
    errors = {e.get("data-field"): e.text_content() for e in doc.xpath("//span[@class='field-error']")}
    assert errors == {"dls.lambda": "must be greater than or equal to 0", "duration_s": "must be greater than 0"}
    assert doc.xpath("//input[@name='dls.lambda']/@aria-invalid") == ["true"]
    assert doc.xpath("//input[@name='dls.lambda']/@value") == ["-1"]  # what was typed stays
    assert not doc.xpath("//*[@id='form-error']")  # every error has its field: nothing above the form
    assert "body." not in r.text and r.text.count("must be greater than 0") == 1
    # a preset whose task does not fit the robot: the error goes to the preset
    r = web.post("/web/plans", data={**form, "method": "adaptive", "robot_id": "arm3"})
    assert r.status_code == 422
    assert text_of(parse(r), "//span[@class='field-error'][@data-field='preset']").startswith("q0")
    # the job form too
    r = web.post(
        "/web/tuning-jobs", data={"csrf_token": csrf(web), "preset": "paper-line", "population": "1", "generations": "5"}
    )
    assert r.status_code == 422
    assert text_of(parse(r), "//span[@class='field-error'][@data-field='population']").startswith("must be greater")
    # text that is no finite number: an error beside its field too (these were a 500: the form sent a NaN or
    # an infinity, which JSON cannot carry)
    r = web.post("/web/plans", data={**form, "dls.lambda": "abc", "duration_s": "inf", "dt_s": "1e400"})
    assert r.status_code == 422, r.text
    errors = {e.get("data-field"): e.text_content() for e in parse(r).xpath("//span[@class='field-error']")}
    assert set(errors) == {"dls.lambda", "duration_s", "dt_s"}, errors
    assert parse(r).xpath("//input[@name='dls.lambda']/@value") == ["abc"]
    r = web.post(
        "/web/tuning-jobs", data={"csrf_token": csrf(web), "preset": "paper-line", "population": "ten", "generations": "5"}
    )
    assert r.status_code == 422, r.text
    assert text_of(parse(r), "//span[@class='field-error'][@data-field='population']")


def test_failed_plan_page_says_infeasible_and_the_replay_agrees(web: httpx.Client) -> None:
    failed = plan(web, {"name": "inverse"})
    doc = parse(web.get(f"/plans/{failed}"))
    assert text_of(doc, "//*[@id='plan-status']") == "failed"
    rows = {tr.xpath("string(th)").strip(): tr.xpath("string(td)").strip() for tr in doc.xpath("//table[@id='metrics']/tr")}
    assert rows["objective B [w1·m + w2·m·rad]"] == "infeasible"
    assert rows["min |det J_g| [m³/rad³]"] not in ("", "—")
    verdict = text_of(doc, "//*[@id='replay-verdict']")
    assert "confirms the plan's failure" in verdict and "leaves the path" in verdict
    replay = {tr.xpath("string(th)").strip(): tr.xpath("string(td)").strip() for tr in doc.xpath("//table[@id='replay']/tr")}
    stored = web.get(f"/v1/plans/{failed}", params={"fields": "replay"}).json()["replay"]
    assert float(replay["max position error against the path [mm]"]) == pytest.approx(
        stored["path_position_error_max_m"] * 1e3, rel=1e-3
    )
    assert all(re.search(r"\[(mm|deg|N s|N m s)\]$", label) for label in replay)  # the metrics card's units
    assert "path_position_error_max_m" not in web.get(f"/plans/{failed}").text and "success" not in verdict
    index = parse(web.get("/"))
    assert text_of(index, f"//tr[@data-plan='{failed}']/td[contains(@class, 'objective')]").strip() == "infeasible"
    # a position task: its attitude is not followed, so the replay's attitude does not count against it
    preset = web.get("/v1/task-presets/arm3-position").json()
    body = {"robot_id": "arm3", "task": preset["task"], "replay": True}
    position = web.post("/v1/plans", params={"fields": ""}, json=body).json()
    assert position["success"]
    doc = parse(web.get(f"/plans/{position['id']}"))
    assert "confirms the plan's success" in text_of(doc, "//*[@id='replay-verdict']")
    rows = {tr.xpath("string(th)").strip(): tr.xpath("string(td)").strip() for tr in doc.xpath("//table[@id='metrics']/tr")}
    assert "objective B [w1·m]" in rows and "min |det J_g| [m²/rad²]" in rows


def test_plans_compared_and_deleted_from_the_page(web: httpx.Client) -> None:
    a = plan(web, {"name": "adaptive", "params": {"lambda_max": 0.06, "epsilon": 0.12}})
    b = plan(web, {"name": "dls", "params": {"lambda": 0.05}})
    r = web.get("/plans/compare", params={"a": a, "b": b, "figure": "joint-velocities"})
    assert r.status_code == 200
    doc = parse(r)
    src = doc.xpath("//img[@id='compare-image']/@src")[0]
    assert src == f"/v1/plans/compare/figures/joint-velocities?ids={a},{b}"
    image = web.get(src)
    assert image.status_code == 200 and image.headers["content-type"].startswith("image/svg+xml")
    heads = text_of(doc, "//table[@id='compare-table']/tr[1]")
    assert "adaptive" in heads and "dls" in heads
    assert web.get("/plans/compare", params={"a": a, "b": "0" * 32}).status_code == 404
    # delete a plan and a job from the page
    r = web.post(f"/web/plans/{b}/delete", data={"csrf_token": csrf(web)})
    assert r.status_code == 303 and web.get(f"/v1/plans/{b}").status_code == 404
    job = web.post("/v1/tuning-jobs", json=job_body(population=4, generations=1, compare=False)).json()
    r = web.post(f"/web/tuning-jobs/{job['id']}/delete", data={"csrf_token": csrf(web)})
    assert r.status_code == 303 and web.get(f"/v1/tuning-jobs/{job['id']}").status_code == 404
    r = web.post(f"/web/plans/{b}/delete", data={"csrf_token": csrf(web)})
    assert r.status_code == 404 and "does not exist" in text_of(parse(r), "//*[@id='notice']")


def test_favicon(web: httpx.Client) -> None:
    r = web.get("/favicon.ico")
    assert r.status_code == 200 and r.headers["content-type"] == "image/x-icon"
    assert r.content[:4] == b"\x00\x00\x01\x00" and int.from_bytes(r.content[4:6], "little") == 3  # an ICO of 3 sizes
    icons = parse(web.get("/")).xpath("//link[@rel='icon']/@href")
    assert icons == ["/static/favicon.svg", "/favicon.ico"]
    svg = web.get("/static/favicon.svg")
    assert svg.status_code == 200 and svg.headers["content-type"].startswith("image/svg+xml")


def test_3d_view_page_and_scene(web: httpx.Client) -> None:
    plan_id = plan(web, {"name": "adaptive", "params": {"lambda_max": 0.06, "epsilon": 0.12}}, dt_s=0.5)
    page = web.get(f"/plans/{plan_id}/view")
    assert page.status_code == 200 and "script-src 'self'" in page.headers["content-security-policy"]
    doc = parse(page)
    scripts = doc.xpath("//script")
    assert [s.get("src") for s in scripts] == ["/static/view3d.js"] and not any((s.text or "").strip() for s in scripts)
    module = web.get("/static/view3d.js").text
    bundle = re.search(r'from "\./(three-[0-9.]+\.min\.js)"', module)
    assert bundle is not None and web.get(f"/static/{bundle.group(1)}").status_code == 200
    assert "MIT" in web.get("/static/three-LICENSE.txt").text

    scene = web.get(f"/plans/{plan_id}/scene.json").json()
    trajectory = web.get(f"/v1/plans/{plan_id}", params={"fields": "trajectory"}).json()["trajectory"]
    index = scene["frames"]["index"]
    points = np.array(scene["frames"]["points_m"])
    assert index == list(range(len(trajectory["t_s"]))) and points.shape == (len(index), 6 + 2, 3)
    assert scene["frames"]["t_s"] == trajectory["t_s"]
    # independent truth: the server's forward kinematics puts the arm's tip on the planner's own
    # end-effector positions, and its first point on the base CoM
    np.testing.assert_allclose(points[:, -1], np.array(trajectory["ee_position_m"]), atol=2e-5)
    np.testing.assert_allclose(points[:, 0], np.array(trajectory["base_position_m"]), atol=2e-5)
    # the carrier box has the base's mass and inertia: m (b² + c²) / 12 = I for each axis
    base = web.get("/v1/robots/table1").json()["parameters"]["base"]
    a, b, c = scene["carrier"]["size_m"]
    moments = np.array([b * b + c * c, a * a + c * c, a * a + b * b]) * base["mass"] / 12
    np.testing.assert_allclose(np.sort(moments), np.sort(np.linalg.eigvalsh(np.array(base["inertia"]))), rtol=1e-3)
    assert scene["obstacles"] == []
    # a plan with geometry: its collision box and its obstacles as triangle meshes (world frame)
    preset = web.get("/v1/task-presets/raster-target").json()
    task = {**preset["task"], "dt_s": 1.0}
    body = {"robot_id": preset["robot_id"], "task": task, "method": preset["method"]}
    target = web.post("/v1/plans", params={"fields": ""}, json=body).json()["id"]
    scene = web.get(f"/plans/{target}/scene.json").json()
    assert scene["carrier"]["size_m"] == [1.5, 1.5, 1.5]
    boxes = [np.array(o["positions_m"]) for o in scene["obstacles"]]
    assert [len(o["faces"]) for o in scene["obstacles"]] == [12, 12]  # two boxes
    np.testing.assert_allclose(boxes[0].min(axis=0), [1.15, -0.4, -0.3], atol=1e-9)
    np.testing.assert_allclose(boxes[1].max(axis=0), [1.6, 0.2, 0.1], atol=1e-9)
    assert web.get(f"/plans/{'0' * 32}/scene.json").status_code == 404
    assert web.get(f"/plans/{'0' * 32}/view").status_code == 404
    paths = web.get("/openapi.json").json()["paths"]
    assert not any("scene" in p or p.endswith("/view") or "favicon" in p for p in paths)


def test_vendored_three_is_what_the_lockfile_builds() -> None:
    """``service/static/three-<version>.min.js`` is the esbuild bundle of the pinned three.js
    (``web/package-lock.json``): rebuilt from the npm registry, byte for byte."""
    done = subprocess.run(["sh", str(ROOT / "web" / "build.sh"), "--check"], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    lock = json.loads((ROOT / "web" / "package-lock.json").read_text())
    version = lock["packages"]["node_modules/three"]["version"]
    assert (ROOT / "service" / "static" / f"three-{version}.min.js").is_file()
    assert f'from "./three-{version}.min.js"' in (ROOT / "service" / "static" / "view3d.js").read_text()


def test_the_form_starts_with_values_that_succeed_and_the_paper_values_are_one_click_away(web: httpx.Client) -> None:
    """Issue 18: submitting the index's plan form as it comes gives a successful plan; the paper's
    own values fill the form from one link, and with them the plan fails on the speed limit."""
    doc = parse(web.get("/"))
    form = {e.get("name"): e.get("value") for e in doc.xpath("//form[@id='plan-form']//input[@name]")}
    for select in doc.xpath("//form[@id='plan-form']//select"):  # what a browser sends: the selected option, else the first
        form[select.get("name")] = (select.xpath("./option[@selected]/@value") or select.xpath("./option/@value"))[0]
    assert form["method"] == "adaptive" and form["adaptive.lambda_max"] == "0.04" and form["adaptive.epsilon"] == "0.37"
    submitted = web.post("/web/plans", data=form, follow_redirects=False)
    assert submitted.status_code == 303, submitted.text
    plan_id = submitted.headers["location"].rsplit("/", 1)[-1]
    assert web.get(f"/v1/plans/{plan_id}").json()["success"] is True
    link = doc.xpath("//a[@id='paper-values-link']/@href")[0]
    paper = parse(web.get(link))
    values = {e.get("name"): e.get("value") for e in paper.xpath("//form[@id='plan-form']//input[@name]")}
    assert values["adaptive.lambda_max"] == "0.0571" and values["adaptive.epsilon"] == "0.0677"
    paper_form = {**form, **{k: values[k] for k in ("adaptive.lambda_max", "adaptive.epsilon")}}
    submitted = web.post("/web/plans", data=paper_form, follow_redirects=False)
    assert submitted.status_code == 303, submitted.text
    body = web.get(f"/v1/plans/{submitted.headers['location'].rsplit('/', 1)[-1]}").json()
    assert body["success"] is False and "8.54 deg/s" in doc.xpath("string(//p[@id='paper-values'])")
    assert body["metrics"]["max_joint_speed_deg_s"] == pytest.approx(8.54, abs=0.005)

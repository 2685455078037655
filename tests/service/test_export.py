"""Trajectory export over real HTTP: every format read back (csv module, scipy.io.loadmat, numpy,
the ROS message's JSON, and Octave's ``load`` when Octave is installed) to the values of the JSON
trajectory; content negotiation (``Accept``, ``?format=``, 406 with the list); the 406 of the
JSON-only plan resources; figures as PDF and as PNG at a chosen dpi."""

from __future__ import annotations

import csv
import io
import math
import re
import shutil
import struct
import subprocess
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
import scipy.io

from engine import spatial
from service import figures
from service.schemas.trajectories import MEDIA_TYPES
from service.usecases import plans as usecases_plans
from service.usecases import trajectories
from tests.service.conftest import PAPER_TASK

#: The 3-joint arm's position task (its third joint, the boom, is prismatic).
ARM3_PLAN = {
    "robot_id": "arm3",
    "method": {"name": "dls"},
    "feedback_gain": 0.5,
    "replay": False,
    "task": {
        "q0_deg": [0, 20, None],
        "q0_m": [None, None, 0.2],
        "tracks": "position",
        "target_position_m": [1.5156, 0.3, 1.2288],
        "duration_s": 20,
        "ramp_time_s": 2,
        "dt_s": 0.5,
        "joint_speed_limit_m_s": 0.05,
    },
}


@pytest.fixture(scope="module")
def plans(stack: Any) -> dict[str, dict[str, Any]]:
    """Two stored plans with their JSON (the paper's task on table1; the 3-joint arm with a prismatic joint)."""
    out = {}
    with stack.client() as c:
        for name, body in (("table1", {"robot_id": "table1", "task": PAPER_TASK, "replay": False}), ("arm3", ARM3_PLAN)):
            r = c.post("/v1/plans", json=body)
            assert r.status_code == 201, r.text
            out[name] = r.json()
    return out


def _arrays(plan: dict[str, Any]) -> dict[str, np.ndarray]:
    """The JSON trajectory as float arrays (null as NaN)."""
    return {k: np.array(v, dtype=float) for k, v in plan["trajectory"].items()}


def _joint_names(client: httpx.Client, robot_id: str) -> list[str]:
    return [j["name"] for j in client.get(f"/v1/robots/{robot_id}").json()["joints"]]


#: The joint arrays of prismatic joints (revolute joints have their own, in deg and N m).
PRISMATIC_ARRAYS = {"joint_displacements_m", "joint_velocities_m_s", "joint_accelerations_m_s2", "joint_forces_n"}


def _export(client: httpx.Client, plan_id: str, fmt: str) -> httpx.Response:
    r = client.get(f"/v1/plans/{plan_id}/trajectory", params={"format": fmt})
    assert r.status_code == 200, r.text
    assert r.headers["content-type"].split(";")[0] == MEDIA_TYPES[fmt]
    assert re.fullmatch(rf'attachment; filename="plan-{plan_id}\.[a-z.]+"', r.headers["content-disposition"])
    return r


@pytest.mark.parametrize("robot", ["table1", "arm3"])
def test_every_format_reads_back_to_the_json_trajectory(client: httpx.Client, plans: dict[str, Any], robot: str) -> None:
    plan = plans[robot]
    expected = _arrays(plan)
    names = _joint_names(client, robot)
    prismatic = np.array([j["type"] == "prismatic" for j in client.get(f"/v1/robots/{robot}").json()["joints"]])
    n_samples = expected["t_s"].shape[0]

    # json: the plan's trajectory section, exactly
    assert _export(client, plan["id"], "json").json() == plan["trajectory"]

    # csv (csv module): one header row, one row per sample, each column one component, bit for bit
    rows = list(csv.reader(io.StringIO(_export(client, plan["id"], "csv").text)))
    header, body = rows[0], rows[1:]
    assert len(body) == n_samples and all(len(row) == len(header) for row in body)
    columns = {name: np.array([float(row[i]) if row[i] else math.nan for row in body]) for i, name in enumerate(header)}
    seen = set()
    for column, values in columns.items():
        m = re.fullmatch(r"(\w+)(?:\[(.+)\])?", column)
        assert m is not None, column
        array, component = m.group(1), m.group(2)
        ref = expected[array]
        if component is None:
            want = ref
        elif array.startswith("joint_"):
            j = names.index(component)
            assert prismatic[j] == (array in PRISMATIC_ARRAYS), column  # a joint's columns are those of its unit
            want = ref[:, j]
        elif component in "wxyz":
            want = ref[:, ("wxyz" if ref.shape[1] == 4 else "xyz").index(component)]
        else:
            want = ref[:, int(component) - 1]
        np.testing.assert_array_equal(values, want, err_msg=column)
        seen.add(array)
    assert seen == set(expected)
    assert "t_s" in header and all(
        re.search(r"_(s|deg|deg_s|deg_s2|m|m_s|m_s2|n|n_m|rad|quaternion)$", h.split("[")[0])
        or h.split("[")[0] in ("singular_values", "det_gjm", "damping")
        for h in header
    )

    # mat (scipy.io.loadmat): the same arrays under the same names, t_s a column; joint names a cell array
    mat = scipy.io.loadmat(io.BytesIO(_export(client, plan["id"], "mat").content))
    for name, ref in expected.items():
        got = mat[name]
        np.testing.assert_array_equal(got.reshape(ref.shape), ref, err_msg=name)
        assert got.shape == (ref.shape if ref.ndim == 2 else (n_samples, 1)), name
    assert [str(cell[0]) for cell in mat["joint_names"].ravel()] == names
    assert str(mat["plan_id"][0]) == plan["id"]

    # npz (numpy, without pickle)
    with np.load(io.BytesIO(_export(client, plan["id"], "npz").content), allow_pickle=False) as npz:
        assert set(npz.files) == {*expected, "joint_names"}
        for name, ref in expected.items():
            np.testing.assert_array_equal(npz[name], ref, err_msg=name)
        assert npz["joint_names"].tolist() == names

    # ros: SI units (rad, m), joint names, time_from_start as sec/nanosec
    ros = _export(client, plan["id"], "ros").json()
    assert ros["joint_names"] == names and ros["header"] == {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": ""}
    assert len(ros["points"]) == n_samples
    positions = np.array([p["positions"] for p in ros["points"]])
    velocities = np.array([p["velocities"] for p in ros["points"]])
    want_q = np.where(prismatic, expected.get("joint_displacements_m", np.nan), np.radians(expected["joint_angles_deg"]))
    want_qd = np.where(prismatic, expected.get("joint_velocities_m_s", np.nan), np.radians(expected["joint_velocities_deg_s"]))
    np.testing.assert_allclose(positions, want_q, rtol=0, atol=1e-12)
    np.testing.assert_allclose(velocities, want_qd, rtol=0, atol=1e-12)
    times = np.array([p["time_from_start"]["sec"] + 1e-9 * p["time_from_start"]["nanosec"] for p in ros["points"]])
    np.testing.assert_allclose(times, expected["t_s"], rtol=0, atol=5e-10)
    assert all(0 <= p["time_from_start"]["nanosec"] < 1_000_000_000 for p in ros["points"])
    # the executed trajectory's accelerations and efforts, SI, per joint in its unit
    accelerations = np.array([p["accelerations"] for p in ros["points"]])
    effort = np.array([p["effort"] for p in ros["points"]])
    want_qdd = np.where(
        prismatic, expected.get("joint_accelerations_m_s2", np.nan), np.radians(expected["joint_accelerations_deg_s2"])
    )
    want_tau = np.where(prismatic, expected.get("joint_forces_n", np.nan), expected["joint_torques_n_m"])
    np.testing.assert_allclose(accelerations, want_qdd, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(effort, want_tau)


def test_the_mat_file_loads_in_octave(client: httpx.Client, plans: dict[str, Any], tmp_path: Path) -> None:
    octave = shutil.which("octave-cli") or shutil.which("octave")
    if octave is None:
        pytest.skip("Octave is not installed (apt-get install octave)")
    plan = plans["arm3"]
    (tmp_path / "plan.mat").write_bytes(_export(client, plan["id"], "mat").content)
    script = (
        "d = load('plan.mat'); printf('%d %d\\n', size(d.joint_angles_deg)); "
        "printf('%.17g\\n', d.t_s(end), d.joint_angles_deg(end, 2), d.joint_displacements_m(end, 3)); "
        "printf('%s\\n', d.joint_names{:}); printf('%d\\n', isnan(d.joint_angles_deg(1, 3)))"
    )
    done = subprocess.run(
        [octave, "--no-gui", "--quiet", "--eval", script], cwd=tmp_path, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    lines = done.stdout.split()
    traj = _arrays(plan)
    assert [int(v) for v in lines[:2]] == list(traj["joint_angles_deg"].shape)
    assert [float(v) for v in lines[2:5]] == [
        traj["t_s"][-1],
        traj["joint_angles_deg"][-1, 1],
        traj["joint_displacements_m"][-1, 2],
    ]
    assert lines[5:8] == _joint_names(client, "arm3") and lines[8] == "1"  # NaN in the prismatic column


def test_accept_chooses_the_format_and_format_wins(client: httpx.Client, plans: dict[str, Any]) -> None:
    url = f"/v1/plans/{plans['table1']['id']}/trajectory"
    cases = {
        None: "application/json",
        "*/*": "application/json",
        "text/html,application/xhtml+xml,*/*;q=0.8": "application/json",
        "text/csv": "text/csv",
        "text/*": "text/csv",
        "application/x-matlab-data": "application/x-matlab-data",
        "text/csv;q=0.5, application/x-npz": "application/x-npz",
        MEDIA_TYPES["ros"]: MEDIA_TYPES["ros"],
    }
    for accept, media in cases.items():
        r = client.get(url, headers={"Accept": accept} if accept else {})
        assert r.status_code == 200 and r.headers["content-type"].split(";")[0] == media, (accept, r.text[:200])
        assert r.headers["vary"] == "Accept"
    refused = client.get(url, headers={"Accept": "image/png"})
    assert refused.status_code == 406 and refused.headers["content-type"].startswith("application/problem+json")
    assert refused.json()["available"] == list(MEDIA_TYPES.values())
    assert (
        client.get(url, params={"format": "csv"}, headers={"Accept": "image/png"}).headers["content-type"].startswith("text/csv")
    )
    assert client.get(url, params={"format": "xlsx"}).status_code == 422
    assert client.get(f"/v1/plans/{'0' * 32}/trajectory").status_code == 404


def test_plan_resources_are_json_only(client: httpx.Client, plans: dict[str, Any], stack: Any) -> None:
    """`Accept: text/csv` on a plan no longer gets JSON: a 406 pointing to the trajectory export."""
    plan_id = plans["table1"]["id"]
    r = client.get(f"/v1/plans/{plan_id}", headers={"Accept": "text/csv"})
    assert r.status_code == 406 and r.json()["available"] == ["application/json"]
    assert f"/v1/plans/{plan_id}/trajectory" in r.json()["detail"]
    assert client.get(f"/v1/plans/{plan_id}", headers={"Accept": "application/json, text/csv"}).status_code == 200
    total = client.get("/v1/plans").json()["total"]
    posted = client.post("/v1/plans", json={"robot_id": "table1", "task": PAPER_TASK}, headers={"Accept": "text/csv"})
    assert posted.status_code == 406
    assert client.get("/v1/plans").json()["total"] == total  # refused before planning: nothing stored


def _png_size(content: bytes) -> tuple[int, int]:
    assert content[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = struct.unpack(">II", content[16:24])
    return width, height


def test_figures_as_pdf_and_png_at_a_dpi(client: httpx.Client, plans: dict[str, Any]) -> None:
    url = f"/v1/plans/{plans['table1']['id']}/figures/joint-angles"
    pdf = client.get(url, params={"format": "pdf"})
    assert pdf.status_code == 200 and pdf.headers["content-type"] == "application/pdf" and pdf.content.startswith(b"%PDF")
    assert client.get(url, params={"format": "pdf"}).headers["etag"] == pdf.headers["etag"]  # no creation date in it
    default = _png_size(client.get(url, params={"format": "png"}).content)
    sharp = _png_size(client.get(url, params={"format": "png", "dpi": 2 * figures.DPI}).content)
    print(f"\nPNG at the default dpi ({figures.DPI}) {default}, at {2 * figures.DPI} dpi {sharp}")
    assert sharp == (2 * default[0], 2 * default[1])
    assert client.get(url, params={"format": "png", "dpi": 20}).status_code == 422
    # vector formats ignore dpi: the same figure
    assert client.get(url, params={"dpi": 300}).headers["etag"] == client.get(url).headers["etag"]
    job_pdf = client.get(f"/v1/plans/compare/figures/tracking-errors?ids={plans['table1']['id']}&format=pdf")
    assert job_pdf.status_code == 200 and job_pdf.content.startswith(b"%PDF")


def test_a_diverged_plan_has_no_ros_trajectory() -> None:
    """(Not over HTTP: no request the API accepts makes a plan diverge on demand.)"""
    t = np.arange(4) * 0.5
    q = np.zeros((4, 2))
    q[2:, 1] = np.nan
    record = {"t": t, "q": q, "qd": np.zeros((4, 2)), "prismatic": np.zeros(2)}
    with pytest.raises(trajectories.ConflictError, match=r"not finite from t = 1 s"):
        trajectories.to_ros(record, ["a", "b"], "p")


def test_the_stored_attitudes_are_quaternions_and_null_where_the_plan_diverged() -> None:
    """(Not over HTTP, as above.) The record's three attitude arrays, converted in one call, keep
    their own rows: each finite matrix becomes its own quaternion, a non-finite one NaN."""
    rng = np.random.default_rng(7)
    rotations = [spatial.quaternion_to_matrix(rng.standard_normal((n, 4))) for n in (5, 5, 5)]
    rotations[1][3:] = np.nan  # the executed attitude diverged from the fourth sample
    rotations[2][0, 1, 1] = np.inf
    quaternions = usecases_plans._quaternions(*rotations)
    assert [q.shape for q in quaternions] == [(5, 4)] * 3
    for R, q in zip(rotations, quaternions, strict=True):
        finite = np.isfinite(R).all(axis=(1, 2))
        assert np.isnan(q[~finite]).all()
        assert np.allclose(q[finite], spatial.matrix_to_quaternion(R[finite]), atol=0, rtol=0)
    assert np.isnan(quaternions[1][3:]).all() and np.isnan(quaternions[2][0]).all() and np.isfinite(quaternions[0]).all()
    assert usecases_plans._quaternions(np.full((2, 3, 3), np.nan))[0].shape == (2, 4)

"""The stored form of trajectories and grids: every float64 bit, shape and name back, rows stored
as ``.npz`` or in the first form (no byte planes) by earlier versions still read, and no larger
than either."""

from __future__ import annotations

import io
import json
import zlib

import numpy as np
import pytest

from engine import make_inverse, paper_task, run_plan, table1_robot
from engine.planner import PlanSetup
from service.infra import storage
from service.infra.storage import MAGIC, MAGIC_1, pack_trajectory, unpack_trajectory
from service.usecases.plans import record_of


def test_every_bit_shape_and_name_comes_back() -> None:
    rng = np.random.default_rng(0)
    arrays = {
        "t": np.linspace(0.0, 15.0, 61),
        "q": rng.normal(size=(61, 6)),
        "att": rng.normal(size=(61, 3, 3)),
        "special": np.array([np.nan, np.inf, -np.inf, -0.0, 5e-324, 1.7976931348623157e308]),
        "empty": np.empty((0, 6)),
        "scalar": np.array(3.5),
        "from_lists": [[1.0, None], [None, 2.0]],
    }
    data = pack_trajectory(arrays)
    assert data.startswith(MAGIC)
    back = unpack_trajectory(data)
    assert list(back) == list(arrays)
    for name, value in arrays.items():
        expected = np.array([[1.0, np.nan], [np.nan, 2.0]]) if name == "from_lists" else np.asarray(value)
        assert back[name].shape == expected.shape and back[name].dtype == np.float64
        assert back[name].tobytes() == expected.astype(np.float64).tobytes(), name  # bit for bit, NaN and -0.0 too
    back["q"][0, 0] = 1.0  # writable copies


def test_rows_stored_as_npz_are_still_read_and_the_new_form_is_no_larger() -> None:
    model = table1_robot()
    result = run_plan(PlanSetup(model, paper_task(model)), make_inverse("adaptive", lambda_max=0.04, epsilon=0.37))
    record = record_of(result, model)
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **record)  # as earlier versions stored it
    old = unpack_trajectory(buffer.getvalue())
    new = pack_trajectory(record)
    assert set(old) == set(record) and all(np.array_equal(old[k], record[k], equal_nan=True) for k in record)
    assert all(np.array_equal(unpack_trajectory(new)[k], record[k], equal_nan=True) for k in record)
    print(f"\npaper plan record: {len(new)} bytes stored, {len(buffer.getvalue())} as .npz")
    assert len(new) <= 1.1 * len(buffer.getvalue())


def first_form(arrays: dict[str, np.ndarray]) -> bytes:
    """``arrays`` as ``spacearm-arrays-1`` stored them: the values end to end, compressed as they are."""
    header, offset = {}, 0
    for name, array in arrays.items():
        header[name] = [list(array.shape), offset]
        offset += array.nbytes
    head = json.dumps(header).encode()
    payload = b"".join(np.ascontiguousarray(a, dtype="<f8").tobytes() for a in arrays.values())
    return MAGIC_1 + len(head).to_bytes(4, "little") + head + zlib.compress(payload, 1)


def test_rows_of_the_first_form_are_still_read_and_the_byte_planes_are_no_larger() -> None:
    model = table1_robot()
    result = run_plan(PlanSetup(model, paper_task(model)), make_inverse("adaptive", lambda_max=0.06, epsilon=0.12))
    record = {k: np.asarray(v, dtype=float) for k, v in record_of(result, model).items()}
    old = first_form(record)
    back = unpack_trajectory(old)
    assert list(back) == list(record)
    assert all(back[k].tobytes() == record[k].tobytes() for k in record)
    new = pack_trajectory(record)
    print(f"\npaper plan record: {len(new)} bytes with byte planes, {len(old)} without")
    assert len(new) <= len(old)


@pytest.mark.parametrize("raw_planes", [0, 3, 8])
def test_blobs_say_how_many_planes_are_raw(raw_planes: int, monkeypatch: pytest.MonkeyPatch) -> None:
    arrays = {"q": np.random.default_rng(1).normal(size=(61, 6)), "t": np.linspace(0.0, 15.0, 61)}
    with monkeypatch.context() as m:
        m.setattr(storage, "RAW_PLANES", raw_planes)  # as another version would write it
        data = pack_trajectory(arrays)
    back = unpack_trajectory(data)
    assert all(back[k].tobytes() == arrays[k].tobytes() for k in arrays)

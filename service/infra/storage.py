"""How plans' trajectories (and landscapes' grids) are stored: their float64 arrays end to end in
one buffer, split into its eight byte planes (every value's first byte, then every second byte, ...)
and compressed by zlib (level 1), behind a magic line and a JSON header of names, shapes and
offsets: about a third of the size of the same numbers as JSON text.

The byte planes put the sign and exponent bytes of neighbouring values side by side, where zlib
finds them alike: a paper plan's 32.8 kB compress to 26.6 kB in 0.27 ms, against 28.3 kB in 0.46 ms
without them (the first form, ``spacearm-arrays-1``, still read).

It replaced numpy's compressed ``.npz`` (a zip of ``.npy`` members), which cost a paper plan's
request 3.1 ms of its 6.9 (zip members, a CRC and a deflate stream per array) against 0.2 ms.
Rows stored as ``.npz`` are still read (``allow_pickle=False``)."""

from __future__ import annotations

import io
import json
import zlib
from collections.abc import Mapping
from typing import Any

import numpy as np

MAGIC = b"spacearm-arrays-2\n"
#: The first form: the same without the byte planes.
MAGIC_1 = b"spacearm-arrays-1\n"


def _array(values: Any) -> np.ndarray:
    """A float64 array of ``values`` (nested lists with ``None`` for NaN, or an array)."""
    if isinstance(values, np.ndarray):
        return np.asarray(values, dtype=float)
    arr = np.array(values, dtype=object)
    missing = arr == None  # noqa: E711  (element-wise: JSON's null)
    return np.where(missing, np.nan, arr).astype(float)


def pack_trajectory(trajectory: Mapping[str, Any]) -> bytes:
    """The compressed bytes of a trajectory ``{name: array}`` (float64, little-endian)."""
    arrays = {name: np.asarray(_array(values), dtype="<f8", order="C") for name, values in trajectory.items()}
    header: dict[str, list[Any]] = {}
    offset = 0
    for name, array in arrays.items():
        header[name] = [list(array.shape), offset]
        offset += array.nbytes
    values = np.frombuffer(b"".join(array.tobytes() for array in arrays.values()), dtype=np.uint8)
    planes = values.reshape(-1, 8).T.tobytes()
    head = json.dumps(header, separators=(",", ":")).encode()
    return MAGIC + len(head).to_bytes(4, "little") + head + zlib.compress(planes, 1)


def unpack_trajectory(data: bytes) -> dict[str, np.ndarray]:
    """The arrays of :func:`pack_trajectory`'s bytes (or of a row stored as ``.npz``)."""
    planed = data.startswith(MAGIC)
    if not planed and not data.startswith(MAGIC_1):
        with np.load(io.BytesIO(data), allow_pickle=False) as archive:
            return {name: archive[name] for name in archive.files}
    start = len(MAGIC) + 4  # both magic lines have the same length
    size = int.from_bytes(data[len(MAGIC) : start], "little")
    header = json.loads(data[start : start + size])
    payload = zlib.decompress(data[start + size :])
    if planed:
        payload = np.frombuffer(payload, dtype=np.uint8).reshape(8, -1).T.tobytes()
    out = {}
    for name, (shape, offset) in header.items():
        count = int(np.prod(shape, dtype=np.int64))
        out[name] = np.frombuffer(payload, dtype="<f8", count=count, offset=offset).reshape(tuple(shape)).copy()
    return out

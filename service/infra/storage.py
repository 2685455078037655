"""How plans' trajectories are stored: the arrays in a compressed ``.npz`` (numpy's own format,
a zip of ``.npy`` members; read back with ``allow_pickle=False``), about a third of the size of
the same numbers as JSON text and faster to read."""

from __future__ import annotations

import io
from collections.abc import Mapping
from typing import Any

import numpy as np


def _array(values: Any) -> np.ndarray:
    """A float64 array of ``values`` (nested lists with ``None`` for NaN, or an array)."""
    if isinstance(values, np.ndarray):
        return np.asarray(values, dtype=float)
    arr = np.array(values, dtype=object)
    missing = arr == None  # noqa: E711  (element-wise: JSON's null)
    return np.where(missing, np.nan, arr).astype(float)


def pack_trajectory(trajectory: Mapping[str, Any]) -> bytes:
    """The compressed bytes of a trajectory ``{name: array}``."""
    buffer = io.BytesIO()
    arrays: dict[str, Any] = {name: _array(values) for name, values in trajectory.items()}
    np.savez_compressed(buffer, **arrays)
    return buffer.getvalue()


def unpack_trajectory(data: bytes) -> dict[str, np.ndarray]:
    """The arrays of :func:`pack_trajectory`'s bytes."""
    with np.load(io.BytesIO(data), allow_pickle=False) as archive:
        return {name: archive[name] for name in archive.files}

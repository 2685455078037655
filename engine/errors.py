"""The engine's input error, a ``ValueError`` that names the offending field, and the shared
check for arrays of finite numbers."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray


class ParameterError(ValueError):
    """Invalid input. ``field`` is a dotted path in the engine's own names (for example
    ``links[2].inertia`` or ``dt``); ``reason`` says what is wrong."""

    def __init__(self, field: str, reason: str) -> None:
        super().__init__(f"{field}: {reason}")
        self.field = field
        self.reason = reason

    def within(self, prefix: str) -> ParameterError:
        """The same error named inside ``prefix`` (``q0[2]`` within ``task`` is ``task.q0[2]``)."""
        return ParameterError(f"{prefix}.{self.field}", self.reason)


def finite_array(value: Any, shape: tuple[int, ...], field: str, bound: float | None = None) -> NDArray[np.float64]:
    """``value`` as a read-only float array of ``shape`` with every number finite (and, with
    ``bound``, of magnitude at most ``bound``)."""
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ParameterError(field, f"expected numbers of shape {shape}") from exc
    if arr.shape != shape:
        raise ParameterError(field, f"expected shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ParameterError(field, "every number must be finite")
    if bound is not None and arr.size and float(np.max(np.abs(arr))) > bound:
        raise ParameterError(field, f"every number must be within +-{bound:g}")
    arr.setflags(write=False)
    return arr

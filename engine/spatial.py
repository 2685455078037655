"""Rotation and vector helpers on SO(3), batched over leading axes.

All functions accept arrays with arbitrary leading (batch) axes: a vector is ``(..., 3)``, a
rotation matrix ``(..., 3, 3)``. Quaternions are scalar-first ``[w, x, y, z]``. The exponential
and logarithm maps and the quaternion conversions are thin loops over the compiled kernels of
:mod:`engine.kernels.so3`, which the planner uses too.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.kernels import so3

FloatArray = NDArray[np.floating[Any]]


def skew(v: ArrayLike) -> FloatArray:
    """Cross-product matrix ``[v]x`` of ``v (..., 3)``, shape ``(..., 3, 3)``."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


def cross(a: FloatArray, b: FloatArray) -> FloatArray:
    """``a x b`` over the last axis with broadcasting (faster than ``np.cross`` on small stacks)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack((a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0), axis=-1)


def _stack(x: ArrayLike, tail: tuple[int, ...]) -> tuple[FloatArray, tuple[int, ...]]:
    """``x`` as a C-contiguous writable float64 stack ``(N,) + tail`` and its leading shape."""
    arr = np.asarray(x, dtype=float)
    lead = arr.shape[: arr.ndim - len(tail)]
    flat: FloatArray = np.require(arr.reshape((-1,) + tail), np.float64, ["C", "W"])
    return flat, lead


def exp_so3(phi: ArrayLike) -> FloatArray:
    """Rotation matrix ``exp([phi]x) (..., 3, 3)`` of rotation vectors ``phi (..., 3)`` (rad);
    see :func:`engine.kernels.so3.exp_so3`."""
    flat, lead = _stack(phi, (3,))
    out = np.empty((flat.shape[0], 3, 3))
    so3.exp_so3_many(flat, out)
    return out.reshape(lead + (3, 3))


def log_so3(R: ArrayLike) -> FloatArray:
    """Rotation vector ``phi (..., 3)`` with ``exp([phi]x) = R``; angle in [0, pi]."""
    flat, lead = _stack(R, (3, 3))
    out = np.empty((flat.shape[0], 3))
    so3.log_so3_many(flat, out)
    return out.reshape(lead + (3,))


def rotation_angle(R: ArrayLike) -> FloatArray:
    """Angle (rad, in [0, pi]) of the rotation ``R (..., 3, 3)``, robust near 0 and pi."""
    flat, lead = _stack(R, (3, 3))
    out = np.empty(flat.shape[0])
    so3.rotation_angle_many(flat, out)
    return out.reshape(lead)


def axis_angle_rotation(axis: ArrayLike, angle: ArrayLike) -> FloatArray:
    """Rotation about the unit ``axis (..., 3)`` by ``angle (...)`` rad."""
    axis = np.asarray(axis, dtype=float)
    angle = np.asarray(angle, dtype=float)
    return exp_so3(axis * angle[..., None])


def matrix_to_quaternion(R: ArrayLike) -> FloatArray:
    """Unit quaternion ``[w, x, y, z] (..., 4)`` of ``R (..., 3, 3)`` (Shepperd's method), w >= 0."""
    flat, lead = _stack(R, (3, 3))
    out = np.empty((flat.shape[0], 4))
    so3.matrix_to_quaternion_many(flat, out)
    return out.reshape(lead + (4,))


def quaternion_to_matrix(q: ArrayLike) -> FloatArray:
    """Rotation matrix of the quaternion ``[w, x, y, z] (..., 4)``; normalised first.

    Raises ``ValueError`` if a quaternion has (near) zero norm.
    """
    flat, lead = _stack(q, (4,))
    norm = np.linalg.norm(flat, axis=-1)
    if np.any(norm < 1e-12) or not np.all(np.isfinite(norm)):
        raise ValueError("quaternion must be finite with non-zero norm")
    out = np.empty((flat.shape[0], 3, 3))
    so3.quaternion_to_matrix_many(flat, out)
    return out.reshape(lead + (3, 3))


def _rx(a: FloatArray) -> FloatArray:
    c, s = np.cos(a), np.sin(a)
    one, zero = np.ones_like(a), np.zeros_like(a)
    return np.stack((np.stack((one, zero, zero), -1), np.stack((zero, c, -s), -1), np.stack((zero, s, c), -1)), -2)


def _ry(a: FloatArray) -> FloatArray:
    c, s = np.cos(a), np.sin(a)
    one, zero = np.ones_like(a), np.zeros_like(a)
    return np.stack((np.stack((c, zero, s), -1), np.stack((zero, one, zero), -1), np.stack((-s, zero, c), -1)), -2)


def _rz(a: FloatArray) -> FloatArray:
    c, s = np.cos(a), np.sin(a)
    one, zero = np.ones_like(a), np.zeros_like(a)
    return np.stack((np.stack((c, -s, zero), -1), np.stack((s, c, zero), -1), np.stack((zero, zero, one), -1)), -2)


def rpy_spacedyn_to_matrix(angles: ArrayLike) -> FloatArray:
    """Attitude ``A (..., 3, 3)`` from SpaceDyn RPY angles ``(a, b, c) (..., 3)`` in rad.

    SpaceDyn's convention: the angles give the direction-cosine matrix
    ``C = Rx(a) Ry(b) Rz(c)`` and the attitude (body to world) is ``A = C^T``.
    """
    angles = np.asarray(angles, dtype=float)
    C = _rx(angles[..., 0]) @ _ry(angles[..., 1]) @ _rz(angles[..., 2])
    return np.swapaxes(C, -1, -2)


def matrix_to_rpy_spacedyn(A: ArrayLike) -> FloatArray:
    """SpaceDyn RPY angles ``(a, b, c) (..., 3)`` in rad of the attitude ``A``; inverse of
    :func:`rpy_spacedyn_to_matrix` with ``b`` in [-pi/2, pi/2]. In gimbal lock (``b`` = +-pi/2,
    where only ``c + sin(b) a`` is defined) ``a`` is 0 and ``c`` takes the whole turn."""
    C = np.swapaxes(np.asarray(A, dtype=float), -1, -2)
    b = np.arctan2(C[..., 0, 2], np.hypot(C[..., 0, 0], C[..., 0, 1]))
    locked = np.hypot(C[..., 0, 0], C[..., 0, 1]) < 1e-12  # a's and c's atan2 would read rounding noise
    a = np.where(locked, 0.0, np.arctan2(-C[..., 1, 2], C[..., 2, 2]))
    c = np.where(locked, np.arctan2(C[..., 1, 0], C[..., 1, 1]), np.arctan2(-C[..., 0, 1], C[..., 0, 0]))
    return np.stack((a, b, c), axis=-1)


def is_rotation(R: ArrayLike, tol: float = 1e-6) -> bool:
    """True if ``R (3, 3)`` is orthonormal with determinant +1 within ``tol``."""
    R = np.asarray(R, dtype=float)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        return False
    return bool(np.allclose(R @ R.T, np.eye(3), atol=tol) and abs(np.linalg.det(R) - 1.0) < tol)

"""Test oracle: the former numpy SO(3) helpers of the engine, batched over leading axes.

All functions accept arrays with arbitrary leading (batch) axes: a vector is ``(..., 3)``, a
rotation matrix ``(..., 3, 3)``. Quaternions are scalar-first ``[w, x, y, z]``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.spatial import skew

FloatArray = NDArray[np.floating[Any]]

__all__ = ["FloatArray", "exp_so3", "log_so3", "matrix_to_quaternion", "quaternion_to_matrix", "rotation_angle", "skew"]

_SMALL_ANGLE = 1e-8
# Row-major flat indices of the entries of [v]x equal to +v_k and to -v_k (k = 0, 1, 2).
_SKEW_PLUS = np.array([7, 2, 3])
_SKEW_MINUS = np.array([5, 6, 1])


def exp_so3(phi: ArrayLike) -> FloatArray:
    """Rotation matrix ``exp([phi]x)`` of a rotation vector ``phi (..., 3)`` (rad), Rodrigues:
    ``R = cos t I + (sin t / t) [phi]x + ((1 - cos t) / t^2) phi phi^T`` with ``t = |phi|``.

    With the half angle ``h = t / 2`` and ``w = sin h / h``, ``sin t / t = w cos h`` and
    ``(1 - cos t) / t^2 = w^2 / 2``: no coefficient suffers cancellation at small angles, and
    ``sin h / h`` is exact in floating point as ``h -> 0`` (``w = 1`` at ``h = 0``). Computed
    batch-last, with the same operations for every member whatever the batch shape.
    """
    phi = np.asarray(phi, dtype=float)
    lead = phi.shape[:-1]
    p = phi.reshape(-1, 3).T  # (3, N)
    sq = p * p
    half = 0.5 * np.sqrt(sq[0] + sq[1] + sq[2])
    sin_h, cos_h = np.sin(half), np.cos(half)
    w = np.divide(sin_h, half, out=np.ones_like(half), where=half > 0.0)
    R = np.empty((3, 3, p.shape[1]))
    np.multiply(((0.5 * w * w) * p)[:, None], p, out=R)
    flat = R.reshape(9, -1)
    flat[::4] += cos_h * cos_h - sin_h * sin_h
    v = (w * cos_h) * p
    flat[_SKEW_PLUS] += v
    flat[_SKEW_MINUS] -= v
    rotation: FloatArray = np.ascontiguousarray(R.transpose(2, 0, 1)).reshape(lead + (3, 3))
    return rotation


def log_so3(R: ArrayLike) -> FloatArray:
    """Rotation vector ``phi (..., 3)`` with ``exp([phi]x) = R``; angle in [0, pi]."""
    R = np.asarray(R, dtype=float)
    q = matrix_to_quaternion(R)
    w = q[..., 0]
    xyz = q[..., 1:]
    # Hemisphere with w >= 0 gives the angle in [0, pi].
    sign = np.where(w < 0.0, -1.0, 1.0)
    w = w * sign
    xyz = xyz * sign[..., None]
    s = np.linalg.norm(xyz, axis=-1)
    angle = 2.0 * np.arctan2(s, w)
    small = s < _SMALL_ANGLE
    scale = np.where(small, 2.0 / np.where(small, np.maximum(w, 1e-300), 1.0), angle / np.where(small, 1.0, s))
    return xyz * scale[..., None]


def rotation_angle(R: ArrayLike) -> FloatArray:
    """Angle (rad, in [0, pi]) of the rotation ``R (..., 3, 3)``, robust near 0 and pi."""
    q = matrix_to_quaternion(np.asarray(R, dtype=float))
    return 2.0 * np.arctan2(np.linalg.norm(q[..., 1:], axis=-1), np.abs(q[..., 0]))


def matrix_to_quaternion(R: ArrayLike) -> FloatArray:
    """Unit quaternion ``[w, x, y, z] (..., 4)`` of ``R (..., 3, 3)`` (Shepperd's method), w >= 0."""
    R = np.asarray(R, dtype=float)
    m00, m11, m22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    trace = m00 + m11 + m22
    candidates = np.stack((trace, m00, m11, m22), axis=-1)
    pick = np.argmax(candidates, axis=-1)
    q = np.empty(R.shape[:-2] + (4,))
    # Each branch divides by its largest component, so no branch loses precision.
    t = np.sqrt(np.maximum(1.0 + trace, 1e-300)) * 2.0
    q0 = np.stack(
        (0.25 * t, (R[..., 2, 1] - R[..., 1, 2]) / t, (R[..., 0, 2] - R[..., 2, 0]) / t, (R[..., 1, 0] - R[..., 0, 1]) / t),
        axis=-1,
    )
    t = np.sqrt(np.maximum(1.0 + m00 - m11 - m22, 1e-300)) * 2.0
    q1 = np.stack(
        ((R[..., 2, 1] - R[..., 1, 2]) / t, 0.25 * t, (R[..., 0, 1] + R[..., 1, 0]) / t, (R[..., 0, 2] + R[..., 2, 0]) / t),
        axis=-1,
    )
    t = np.sqrt(np.maximum(1.0 - m00 + m11 - m22, 1e-300)) * 2.0
    q2 = np.stack(
        ((R[..., 0, 2] - R[..., 2, 0]) / t, (R[..., 0, 1] + R[..., 1, 0]) / t, 0.25 * t, (R[..., 1, 2] + R[..., 2, 1]) / t),
        axis=-1,
    )
    t = np.sqrt(np.maximum(1.0 - m00 - m11 + m22, 1e-300)) * 2.0
    q3 = np.stack(
        ((R[..., 1, 0] - R[..., 0, 1]) / t, (R[..., 0, 2] + R[..., 2, 0]) / t, (R[..., 1, 2] + R[..., 2, 1]) / t, 0.25 * t),
        axis=-1,
    )
    q = np.choose(pick[..., None], (q0, q1, q2, q3))
    q = q * np.where(q[..., :1] < 0.0, -1.0, 1.0)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def quaternion_to_matrix(q: ArrayLike) -> FloatArray:
    """Rotation matrix of the quaternion ``[w, x, y, z] (..., 4)``; normalised first.

    Raises ``ValueError`` if a quaternion has (near) zero norm.
    """
    q = np.asarray(q, dtype=float)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(norm < 1e-12) or not np.all(np.isfinite(norm)):
        raise ValueError("quaternion must be finite with non-zero norm")
    w, x, y, z = np.moveaxis(q / norm, -1, 0)
    return np.stack(
        (
            np.stack((1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)), axis=-1),
            np.stack((2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)), axis=-1),
            np.stack((2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)), axis=-1),
        ),
        axis=-2,
    )

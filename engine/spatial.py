"""Rotation and vector helpers on SO(3), batched over leading axes.

All functions accept arrays with arbitrary leading (batch) axes: a vector is ``(..., 3)``, a
rotation matrix ``(..., 3, 3)``. Quaternions are scalar-first ``[w, x, y, z]``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.floating[Any]]

_SMALL_ANGLE = 1e-8


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


# Row-major flat indices of the entries of [v]x equal to +v_k and to -v_k (k = 0, 1, 2).
_SKEW_PLUS = np.array([7, 2, 3])
_SKEW_MINUS = np.array([5, 6, 1])


def cross(a: FloatArray, b: FloatArray) -> FloatArray:
    """``a x b`` over the last axis with broadcasting (faster than ``np.cross`` on small stacks)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack((a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0), axis=-1)


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


def axis_angle_rotation(axis: ArrayLike, angle: ArrayLike) -> FloatArray:
    """Rotation about the unit ``axis (..., 3)`` by ``angle (...)`` rad."""
    axis = np.asarray(axis, dtype=float)
    angle = np.asarray(angle, dtype=float)
    return exp_so3(axis * angle[..., None])


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
    :func:`rpy_spacedyn_to_matrix` with ``b`` in [-pi/2, pi/2]."""
    C = np.swapaxes(np.asarray(A, dtype=float), -1, -2)
    b = np.arcsin(np.clip(C[..., 0, 2], -1.0, 1.0))
    a = np.arctan2(-C[..., 1, 2], C[..., 2, 2])
    c = np.arctan2(-C[..., 0, 1], C[..., 0, 0])
    return np.stack((a, b, c), axis=-1)


def is_rotation(R: ArrayLike, tol: float = 1e-6) -> bool:
    """True if ``R (3, 3)`` is orthonormal with determinant +1 within ``tol``."""
    R = np.asarray(R, dtype=float)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        return False
    return bool(np.allclose(R @ R.T, np.eye(3), atol=tol) and abs(np.linalg.det(R) - 1.0) < tol)

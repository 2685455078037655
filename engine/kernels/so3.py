"""SO(3) kernels on single vectors and matrices, plus loops over stacks for the numpy wrappers
in :mod:`engine.spatial`. Quaternions are scalar-first ``[w, x, y, z]``."""

from __future__ import annotations

import numpy as np

from engine.kernels.jit import kernel

SMALL_ANGLE = 1e-8


@kernel
def exp_so3(phi, out):
    """``out (3, 3) = exp([phi]x)`` for a rotation vector ``phi (3,)`` (rad).

    Rodrigues with the half angle ``h = |phi| / 2`` and ``w = sin h / h``:
    ``sin t / t = w cos h`` and ``(1 - cos t) / t^2 = w^2 / 2``, so no coefficient suffers
    cancellation at small angles (``w = 1`` at ``h = 0``).
    """
    half = 0.5 * np.sqrt(phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2])
    sin_h = np.sin(half)
    cos_h = np.cos(half)
    w = sin_h / half if half > 0.0 else 1.0
    c2 = 0.5 * w * w
    diag = cos_h * cos_h - sin_h * sin_h
    vs = w * cos_h
    vx = vs * phi[0]
    vy = vs * phi[1]
    vz = vs * phi[2]
    px = c2 * phi[0]
    py = c2 * phi[1]
    pz = c2 * phi[2]
    out[0, 0] = px * phi[0] + diag
    out[0, 1] = px * phi[1] - vz
    out[0, 2] = px * phi[2] + vy
    out[1, 0] = py * phi[0] + vz
    out[1, 1] = py * phi[1] + diag
    out[1, 2] = py * phi[2] - vx
    out[2, 0] = pz * phi[0] - vy
    out[2, 1] = pz * phi[1] + vx
    out[2, 2] = pz * phi[2] + diag


@kernel
def quaternion_of(R):
    """Unit quaternion ``(w, x, y, z)`` of ``R (3, 3)`` by Shepperd's method (divide by the
    largest component, so no branch loses precision), ``w >= 0``."""
    m00 = R[0, 0]
    m11 = R[1, 1]
    m22 = R[2, 2]
    trace = m00 + m11 + m22
    pick = 0
    best = trace
    if m00 > best:
        pick = 1
        best = m00
    if m11 > best:
        pick = 2
        best = m11
    if m22 > best:
        pick = 3
    if pick == 0:
        t = np.sqrt(max(1.0 + trace, 1e-300)) * 2.0
        w, x, y, z = 0.25 * t, (R[2, 1] - R[1, 2]) / t, (R[0, 2] - R[2, 0]) / t, (R[1, 0] - R[0, 1]) / t
    elif pick == 1:
        t = np.sqrt(max(1.0 + m00 - m11 - m22, 1e-300)) * 2.0
        w, x, y, z = (R[2, 1] - R[1, 2]) / t, 0.25 * t, (R[0, 1] + R[1, 0]) / t, (R[0, 2] + R[2, 0]) / t
    elif pick == 2:
        t = np.sqrt(max(1.0 - m00 + m11 - m22, 1e-300)) * 2.0
        w, x, y, z = (R[0, 2] - R[2, 0]) / t, (R[0, 1] + R[1, 0]) / t, 0.25 * t, (R[1, 2] + R[2, 1]) / t
    else:
        t = np.sqrt(max(1.0 - m00 - m11 + m22, 1e-300)) * 2.0
        w, x, y, z = (R[1, 0] - R[0, 1]) / t, (R[0, 2] + R[2, 0]) / t, (R[1, 2] + R[2, 1]) / t, 0.25 * t
    scale = (-1.0 if w < 0.0 else 1.0) / np.sqrt(w * w + x * x + y * y + z * z)
    return w * scale, x * scale, y * scale, z * scale


@kernel
def matrix_to_quaternion(R, q):
    """``q (4,)``: the unit quaternion of ``R (3, 3)`` (see :func:`quaternion_of`)."""
    q[0], q[1], q[2], q[3] = quaternion_of(R)


@kernel
def quaternion_to_matrix(q, R):
    """``R (3, 3)`` of the quaternion ``q (4,)`` (normalised here; the caller rejects zero norm)."""
    norm = np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    w = q[0] / norm
    x = q[1] / norm
    y = q[2] / norm
    z = q[3] / norm
    R[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    R[0, 1] = 2.0 * (x * y - w * z)
    R[0, 2] = 2.0 * (x * z + w * y)
    R[1, 0] = 2.0 * (x * y + w * z)
    R[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    R[1, 2] = 2.0 * (y * z - w * x)
    R[2, 0] = 2.0 * (x * z - w * y)
    R[2, 1] = 2.0 * (y * z + w * x)
    R[2, 2] = 1.0 - 2.0 * (x * x + y * y)


@kernel
def log_so3(R, out):
    """Rotation vector ``out (3,)`` with ``exp([out]x) = R``; angle in [0, pi]."""
    w, x, y, z = quaternion_of(R)
    s = np.sqrt(x * x + y * y + z * z)
    scale = 2.0 / max(w, 1e-300) if s < SMALL_ANGLE else 2.0 * np.arctan2(s, w) / s
    out[0] = x * scale
    out[1] = y * scale
    out[2] = z * scale


@kernel
def rotation_angle(R):
    """Angle (rad, in [0, pi]) of the rotation ``R (3, 3)``."""
    w, x, y, z = quaternion_of(R)
    return 2.0 * np.arctan2(np.sqrt(x * x + y * y + z * z), abs(w))


# Loops over stacks, for the batched numpy wrappers.


@kernel
def exp_so3_many(phi, out):
    for i in range(phi.shape[0]):
        exp_so3(phi[i], out[i])


@kernel
def log_so3_many(R, out):
    for i in range(R.shape[0]):
        log_so3(R[i], out[i])


@kernel
def matrix_to_quaternion_many(R, out):
    for i in range(R.shape[0]):
        matrix_to_quaternion(R[i], out[i])


@kernel
def quaternion_to_matrix_many(q, out):
    for i in range(q.shape[0]):
        quaternion_to_matrix(q[i], out[i])


@kernel
def rotation_angle_many(R, out):
    for i in range(R.shape[0]):
        out[i] = rotation_angle(R[i])

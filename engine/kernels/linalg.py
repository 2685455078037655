"""Small dense linear algebra for the kernels: LU with partial pivoting on 6x6 systems, the 3x3
determinant and SPD solve."""

from __future__ import annotations

import numpy as np

from engine.kernels.jit import kernel


@kernel
def lu6(A, y):
    """Gaussian elimination with partial pivoting of ``A (6, 6)`` in place, applying the same row
    operations to ``y (6,)``: ``A`` becomes upper triangular. Returns the sign of the row
    permutation, or 0 if ``A`` is exactly singular."""
    sign = 1
    for col in range(6):
        piv = col
        for r in range(col + 1, 6):
            if abs(A[r, col]) > abs(A[piv, col]):
                piv = r
        if A[piv, col] == 0.0:
            return 0
        if piv != col:
            sign = -sign
            for c in range(6):
                A[col, c], A[piv, c] = A[piv, c], A[col, c]
            y[col], y[piv] = y[piv], y[col]
        for r in range(col + 1, 6):
            f = A[r, col] / A[col, col]
            for c in range(col + 1, 6):
                A[r, c] -= f * A[col, c]
            y[r] -= f * y[col]
    return sign


@kernel
def det6(J, A):
    """Determinant of a 6x6 matrix ``J``, eliminated in the scratch ``A (6, 6)``."""
    for r in range(6):  # element by element: an array assignment compiles numba's shape-error text
        for c in range(6):
            A[r, c] = J[r, c]
    y = A[0].copy()
    sign = lu6(A, y)
    det = float(sign)
    for i in range(6):
        det *= A[i, i]
    return det


@kernel
def solve6(H, b, x):
    """``x (6,)`` with ``H (6, 6) x = b`` (``H`` and ``b`` are not changed). Returns False if
    ``H`` is exactly singular."""
    A = H.copy()
    y = b.copy()
    if lu6(A, y) == 0:
        return False
    for r in range(5, -1, -1):
        acc = y[r]
        for c in range(r + 1, 6):
            acc -= A[r, c] * x[c]
        x[r] = acc / A[r, r]
    return True


@kernel
def det3(J):
    """Determinant of a 3x3 matrix ``J``."""
    return (
        J[0, 0] * (J[1, 1] * J[2, 2] - J[1, 2] * J[2, 1])
        - J[0, 1] * (J[1, 0] * J[2, 2] - J[1, 2] * J[2, 0])
        + J[0, 2] * (J[1, 0] * J[2, 1] - J[1, 1] * J[2, 0])
    )


@kernel
def solve3_spd(G, b, x):
    """``x (3,)`` with ``G x = b`` for a symmetric positive definite ``G (3, 3)`` (Cholesky)."""
    l00 = np.sqrt(G[0, 0])
    l10 = G[1, 0] / l00
    l20 = G[2, 0] / l00
    l11 = np.sqrt(G[1, 1] - l10 * l10)
    l21 = (G[2, 1] - l20 * l10) / l11
    l22 = np.sqrt(G[2, 2] - l20 * l20 - l21 * l21)
    y0 = b[0] / l00
    y1 = (b[1] - l10 * y0) / l11
    y2 = (b[2] - l20 * y0 - l21 * y1) / l22
    x[2] = y2 / l22
    x[1] = (y1 - l21 * x[2]) / l11
    x[0] = (y0 - l10 * x[1] - l20 * x[2]) / l00

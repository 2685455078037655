"""Small dense linear algebra for the kernels: LU with partial pivoting on 6x6 systems."""

from __future__ import annotations

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
    A[:, :] = J
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

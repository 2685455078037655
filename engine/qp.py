"""The bounded inverse's small QP from Python (tests, tools): thin wrappers of the compiled solver
:mod:`engine.kernels.qp` (the planner calls the kernels directly with preallocated buffers).

``min 1/2 qd^T H qd - g^T qd`` subject to ``lo <= qd <= hi`` and ``C qd <= d``; for the bounded
damped inverse ``H = J^T J + lambda^2 I`` and ``g = J^T xdot`` (:func:`bounded_dls`). Read the
kernel module for the method, the tolerances and what an infeasible problem returns.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from engine.kernels import qp as kernels
from engine.kernels import svd as svd_kernels
from engine.spatial import FloatArray

STATUS_NAMES = {
    kernels.SOLVED: "solved",
    kernels.INFEASIBLE: "infeasible",
    kernels.ITER_LIMIT: "iteration limit",
    kernels.INVALID: "invalid",
}


@dataclass(frozen=True)
class QPResult:
    """A solve: ``qd (n,)``; ``box_multipliers (n,)`` signed (> 0 at the upper bound, < 0 at the
    lower); ``row_multipliers (m,) >= 0``, so that ``H qd - g + C^T row_multipliers +
    box_multipliers = 0``; ``active`` the active constraint codes (``i``: upper bound of joint
    ``i``, ``n + i``: its lower bound, ``2 n + j``: row ``j``); ``status`` one of the kernel's
    ``SOLVED``, ``INFEASIBLE``, ``ITER_LIMIT``, ``INVALID``; ``iterations``; ``relax_weight`` the
    elastic weight ``rho`` used when infeasible (else 0)."""

    qd: FloatArray
    box_multipliers: FloatArray
    row_multipliers: FloatArray
    active: tuple[int, ...]
    status: int
    iterations: int
    relax_weight: float

    @property
    def status_name(self) -> str:
        return STATUS_NAMES[self.status]


def _bounds(n: int, lo: ArrayLike | None, hi: ArrayLike | None) -> tuple[FloatArray, FloatArray]:
    lo_a = np.full(n, -np.inf) if lo is None else np.array(np.broadcast_to(np.asarray(lo, dtype=float), (n,)))
    hi_a = np.full(n, np.inf) if hi is None else np.array(np.broadcast_to(np.asarray(hi, dtype=float), (n,)))
    return lo_a, hi_a


def _rows(n: int, C: ArrayLike | None, d: ArrayLike | None) -> tuple[FloatArray, FloatArray]:
    if C is None:
        return np.zeros((0, n)), np.zeros(0)
    C_a = np.ascontiguousarray(np.asarray(C, dtype=float).reshape(-1, n))
    d_a = np.ascontiguousarray(np.asarray(d, dtype=float).reshape(-1))
    if d_a.shape[0] != C_a.shape[0]:
        raise ValueError(f"C has {C_a.shape[0]} rows but d has {d_a.shape[0]} entries")
    return C_a, d_a


def result_from_buffers(buf: tuple, n: int, m: int, status: int, iterations: int) -> QPResult:
    """The solve a kernel left in ``buf`` (:func:`engine.kernels.qp.qp_buffers`), copied out."""
    _, _, vecs, ints = buf
    count = int(vecs[kernels.V_INFO, kernels.INFO_ACTIVE])
    return QPResult(
        qd=vecs[kernels.V_QD, :n].copy(),
        box_multipliers=vecs[kernels.V_BOX, :n].copy(),
        row_multipliers=vecs[kernels.V_ROWS, :m].copy(),
        active=tuple(int(c) for c in ints[kernels.I_ACTIVE, :count]),
        status=int(status),
        iterations=int(iterations),
        relax_weight=float(vecs[kernels.V_INFO, kernels.INFO_RHO]),
    )


def solve_qp(
    H: ArrayLike,
    g: ArrayLike,
    lo: ArrayLike | None = None,
    hi: ArrayLike | None = None,
    C: ArrayLike | None = None,
    d: ArrayLike | None = None,
    max_iter: int = 0,
) -> QPResult:
    """``min 1/2 x^T H x - g^T x`` s.t. ``lo <= x <= hi`` and ``C x <= d`` for a symmetric
    positive definite ``H (n, n)`` (``lo``/``hi`` scalars or ``(n,)``, +-inf allowed; ``C (m, n)``,
    ``d (m,)`` or None). ``max_iter`` 0 for the default limit."""
    H_a = np.ascontiguousarray(np.asarray(H, dtype=float))
    n = H_a.shape[0]
    g_a = np.ascontiguousarray(np.asarray(g, dtype=float).reshape(n))
    lo_a, hi_a = _bounds(n, lo, hi)
    C_a, d_a = _rows(n, C, d)
    buf = kernels.qp_buffers(n, C_a.shape[0])
    status, iterations = kernels.dense_qp(H_a, g_a, lo_a, hi_a, C_a, d_a, max_iter, buf)
    return result_from_buffers(buf, n, C_a.shape[0], status, iterations)


def bounded_dls(
    J: ArrayLike,
    lam: float,
    xdot: ArrayLike,
    lo: ArrayLike | None = None,
    hi: ArrayLike | None = None,
    C: ArrayLike | None = None,
    d: ArrayLike | None = None,
    max_iter: int = 0,
) -> QPResult:
    """The bounded damped least-squares inverse ``min |J qd - xdot|^2 + lam^2 |qd|^2`` s.t.
    ``lo <= qd <= hi`` and ``C qd <= d``, through the compiled thin SVD of ``J (p, n)`` and
    :func:`engine.kernels.qp.dls_qp` (``H = J^T J + lam^2 I``, ``g = J^T xdot``)."""
    J_a = np.ascontiguousarray(np.asarray(J, dtype=float))
    p, n = J_a.shape
    xdot_a = np.ascontiguousarray(np.asarray(xdot, dtype=float).reshape(p))
    lo_a, hi_a = _bounds(n, lo, hi)
    C_a, d_a = _rows(n, C, d)
    sv = svd_kernels.svd_buffers(n, p)
    svd_kernels.jacobi_svd(J_a, sv, False)
    _, U, s, V, _, _ = sv
    buf = kernels.qp_buffers(n, C_a.shape[0])
    damping = np.full(s.shape[0], float(lam))
    status, iterations = kernels.dls_qp(U, s, V, damping, float(lam), xdot_a, lo_a, hi_a, C_a, d_a, max_iter, buf)
    return result_from_buffers(buf, n, C_a.shape[0], status, iterations)

"""The clamped cubic spline through a plan's joint samples (the executed joint trajectory, see
:mod:`engine.executed`), one column per joint.

With knots ``t_0 < ... < t_N``, steps ``h_k = t_{k+1} - t_k``, mean rates ``d_k = (q_{k+1} -
q_k) / h_k`` and knot accelerations ``M_k``, the piece on ``[t_k, t_{k+1}]`` is
``q(t_k + s) = q_k + v_k s + M_k s^2 / 2 + (M_{k+1} - M_k) s^3 / (6 h_k)`` with the knot rate
``v_k = d_k - h_k (2 M_k + M_{k+1}) / 6``. Continuity of the rate at the inner knots and the
two end rates ``v_0``, ``v_N`` give the tridiagonal, strictly diagonally dominant system

    h_{k-1} M_{k-1} + 2 (h_{k-1} + h_k) M_k + h_k M_{k+1} = 6 (d_k - d_{k-1})   (0 < k < N)
    2 h_0 M_0 + h_0 M_1 = 6 (d_0 - v_0),   h_{N-1} M_{N-1} + 2 h_{N-1} M_N = 6 (v_N - d_{N-1}),

solved by the Thomas algorithm (no pivoting needed): O(N n) with no allocation but the
``(N+1,)`` elimination factors.
"""

from __future__ import annotations

import numpy as np

from engine.kernels.jit import kernel


@kernel
def clamped_spline(t, q, v_start, v_end, qd, qdd):
    """Knot rates ``qd (N+1, n)`` and accelerations ``qdd (N+1, n)`` of the clamped cubic
    spline through ``q (N+1, n)`` at ``t (N+1,)`` (N >= 1) with end rates ``v_start (n,)`` and
    ``v_end (n,)``."""
    N = t.shape[0] - 1
    n = q.shape[1]
    factor = np.empty(N + 1)  # the Thomas algorithm's modified super-diagonal
    for j in range(n):
        # Forward elimination, the right-hand side going into qdd.
        h = t[1] - t[0]
        d_prev = (q[1, j] - q[0, j]) / h
        diag = 2.0 * h
        factor[0] = h / diag
        qdd[0, j] = 6.0 * (d_prev - v_start[j]) / diag
        for k in range(1, N + 1):
            h_prev = h
            if k < N:
                h = t[k + 1] - t[k]
                d = (q[k + 1, j] - q[k, j]) / h
                rhs = 6.0 * (d - d_prev)
                diag = 2.0 * (h_prev + h) - h_prev * factor[k - 1]
                factor[k] = h / diag
                d_prev = d
            else:
                rhs = 6.0 * (v_end[j] - d_prev)
                diag = 2.0 * h_prev - h_prev * factor[k - 1]
            qdd[k, j] = (rhs - h_prev * qdd[k - 1, j]) / diag
        for k in range(N - 1, -1, -1):
            qdd[k, j] -= factor[k] * qdd[k + 1, j]
        for k in range(N):
            h = t[k + 1] - t[k]
            qd[k, j] = (q[k + 1, j] - q[k, j]) / h - h * (2.0 * qdd[k, j] + qdd[k + 1, j]) / 6.0
        h = t[N] - t[N - 1]
        qd[N, j] = (q[N, j] - q[N - 1, j]) / h + h * (qdd[N - 1, j] + 2.0 * qdd[N, j]) / 6.0


@kernel
def evaluate_spline(t, q, qd, qdd, times, q_out, qd_out, qdd_out):
    """The spline of knots ``t (N+1,)``, ``q``, ``qd``, ``qdd (N+1, n)`` (see
    :func:`clamped_spline`) at ``times (M,)`` (inside ``[t_0, t_N]``; a time outside extends
    the first or last piece) into ``q_out``, ``qd_out``, ``qdd_out (M, n)``."""
    N = t.shape[0] - 1
    n = q.shape[1]
    for m in range(times.shape[0]):
        k = np.searchsorted(t, times[m], side="right") - 1
        k = min(max(k, 0), N - 1)
        h = t[k + 1] - t[k]
        s = times[m] - t[k]
        for j in range(n):
            jerk = (qdd[k + 1, j] - qdd[k, j]) / h
            q_out[m, j] = q[k, j] + s * (qd[k, j] + s * (0.5 * qdd[k, j] + s * jerk / 6.0))
            qd_out[m, j] = qd[k, j] + s * (qdd[k, j] + 0.5 * s * jerk)
            qdd_out[m, j] = qdd[k, j] + s * jerk

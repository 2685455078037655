"""Thin SVD of a ``p x n`` Jacobian (``p`` = 6 for a pose, 3 for a position; n = 1..12) by
one-sided Jacobi rotations (Hestenes 1958; Demmel and Veselic 1992), warm-started from the
previous step.

With ``M = J`` when ``n <= p`` and ``M = J^T`` otherwise, ``M`` is ``r x c`` with ``c = m =
min(p, n)`` columns. Plane rotations accumulated in ``X (c, c)`` orthogonalise the columns of
``W = M X``; then ``s_i = |w_i|`` and ``y_i = w_i / s_i``, so ``M = Y diag(s) X^T``. A pair is
rotated while ``|w_i . w_j| > TOL |w_i| |w_j|``: the test is relative, so even tiny singular
values come out with high relative accuracy and orthogonal singular vectors. Along a plan the
Jacobian changes little between steps, so starting from the previous step's ``X``
(re-orthonormalised, sorted) leaves one or two sweeps instead of six to eight.

``M`` is scaled by its largest entry first, so neither huge nor tiny Jacobians overflow or
underflow in the squared norms. A non-finite Jacobian returns ``False`` with NaN outputs.
"""

from __future__ import annotations

import numpy as np

from engine.kernels.jit import kernel

TOL = 4.0e-16  # about 2 ulp of 1
TOL_SQ = TOL * TOL
MAX_SWEEPS = 40


def _round_robin(c: int) -> np.ndarray:
    """Rounds of disjoint column pairs covering every pair of ``c`` columns once (a round-robin
    tournament: the parallel Jacobi ordering), ``(5, 3, 2)`` padded with -1."""
    players = list(range(c)) + ([-1] if c % 2 else [])
    rounds = np.full((5, 3, 2), -1, dtype=np.int64)
    half = len(players) // 2
    for rnd in range(len(players) - 1):
        pairs = [(players[k], players[-1 - k]) for k in range(half)]
        pairs = [(min(a, b), max(a, b)) for a, b in pairs if a >= 0 and b >= 0]
        for slot, pair in enumerate(pairs):
            rounds[rnd, slot] = pair
        players = [players[0], players[-1], *players[1:-1]]
    return rounds


ROUNDS = np.stack([_round_robin(c) for c in range(7)])  # ROUNDS[c]: the schedule for c columns


@kernel
def svd_buffers(n, p=6):
    """``(Xt (m, m) warm start, U (p, m), s (m,), V (n, m), Wt (m, max(p, n)), sq (m,))`` for a
    ``p x n`` Jacobian, ``m = min(p, n)``. ``Xt`` and ``Wt`` hold the columns of ``X`` and ``W``
    as rows (contiguous for the rotations); ``Xt`` starts as the identity."""
    m = min(p, n)
    return (np.eye(m), np.empty((p, m)), np.empty(m), np.empty((n, m)), np.empty((m, max(p, n))), np.empty(m))


@kernel
def _orthonormalise(Xt):
    """Modified Gram-Schmidt on the rows of ``Xt`` (the columns of the warm start ``X``), so
    rounding does not accumulate over thousands of steps; a row that collapses is replaced by
    the first unit vector independent of the others."""
    c = Xt.shape[0]
    for j in range(c):
        for i in range(j):
            dot = 0.0
            for r in range(Xt.shape[1]):
                dot += Xt[i, r] * Xt[j, r]
            for r in range(Xt.shape[1]):
                Xt[j, r] -= dot * Xt[i, r]
        norm = 0.0
        for r in range(Xt.shape[1]):
            norm += Xt[j, r] * Xt[j, r]
        norm = np.sqrt(norm)
        if norm > 0.5:
            for r in range(Xt.shape[1]):
                Xt[j, r] /= norm
        else:
            # a column slice, as W's rows are, and a runtime bool: one _complete for both callers
            _complete(Xt[:, : Xt.shape[1]], j, np.bool_(True))


@kernel
def _complete(Yt, j, only_before):
    """Row ``j`` of ``Yt`` becomes a unit vector orthogonal to the unit rows before it (and,
    unless ``only_before``, after it): the first standard basis vector that keeps more than half
    its length after projection."""
    dim = Yt.shape[1]
    for e in range(dim):
        for r in range(dim):
            Yt[j, r] = 1.0 if r == e else 0.0
        for _ in range(2):
            for i in range(j if only_before else Yt.shape[0]):
                if i == j:
                    continue
                norm_i = 0.0
                dot = 0.0
                for r in range(dim):
                    norm_i += Yt[i, r] * Yt[i, r]
                    dot += Yt[i, r] * Yt[j, r]
                if abs(norm_i - 1.0) < 1e-6:
                    for r in range(dim):
                        Yt[j, r] -= dot * Yt[i, r]
        norm = 0.0
        for r in range(dim):
            norm += Yt[j, r] * Yt[j, r]
        norm = np.sqrt(norm)
        if norm > 0.5:
            for r in range(dim):
                Yt[j, r] /= norm
            return


@kernel
def jacobi_svd(J, buf, refresh):
    """Thin SVD ``J = U diag(s) V^T`` of ``J (p, n)`` into ``buf`` (see :func:`svd_buffers`;
    ``Xt`` is the warm start and is updated; ``refresh`` re-orthonormalises it first, which a
    caller does every few steps). ``s`` descending. Returns ``(finite, sweeps)``."""
    Xt, U, s, V, Wfull, sq = buf
    p = J.shape[0]
    n = J.shape[1]
    tall = n <= p
    c = Xt.shape[0]
    r = p if tall else n
    Wt = Wfull[:, :r]
    amax = 0.0
    finite = True
    for i in range(p):
        for j in range(n):
            v = abs(J[i, j])
            if not np.isfinite(v):
                finite = False
            elif v > amax:
                amax = v
    if not finite:
        s[:] = np.nan
        U[:] = np.nan
        V[:] = np.nan
        for i in range(c):
            for j in range(c):
                Xt[i, j] = 1.0 if i == j else 0.0
        return False, 0
    if refresh:
        _orthonormalise(Xt)
    scale = 1.0 / amax if amax > 0.0 else 1.0
    # W = (M / amax) X, with M = J (tall) or J^T
    for col in range(c):
        if tall:
            for row in range(r):
                acc = 0.0
                for k in range(c):
                    acc += J[row, k] * Xt[col, k]
                Wt[col, row] = acc * scale
        else:
            for row in range(r):
                acc = 0.0
                for k in range(c):
                    acc += J[k, row] * Xt[col, k]
                Wt[col, row] = acc * scale
    rot_t = np.empty(3)
    rot_g = np.empty(3)
    sweeps = 0
    for _ in range(MAX_SWEEPS):
        sweeps += 1
        for col in range(c):
            acc = 0.0
            for row in range(r):
                acc += Wt[col, row] * Wt[col, row]
            sq[col] = acc
        rotated = False
        largest = 0.0  # largest squared relative off-diagonal and rotation tangent in this sweep
        schedule = ROUNDS[c]
        for rnd in range(schedule.shape[0]):
            # The pairs of a round are disjoint: their (latency-bound) rotation angles are
            # independent of each other and computed first, then the rotations are applied.
            for p in range(schedule.shape[1]):
                i = schedule[rnd, p, 0]
                j = schedule[rnd, p, 1]
                rot_t[p] = 0.0
                if i < 0:
                    continue
                gamma = 0.0
                for row in range(r):
                    gamma += Wt[i, row] * Wt[j, row]
                alpha = sq[i]
                beta = sq[j]
                gg = gamma * gamma
                ab = alpha * beta
                if gg <= TOL_SQ * ab and ab > 0.0:  # |gamma| <= TOL |w_i| |w_j|
                    continue
                off_sq = gg / ab if ab > 0.0 else (gamma / alpha) * (gamma / beta)  # ab may underflow
                if not off_sq > TOL_SQ:
                    continue
                zeta = (beta - alpha) / (2.0 * gamma)
                if abs(zeta) > 1e150:
                    t = 0.5 / zeta
                else:
                    t = (1.0 if zeta >= 0.0 else -1.0) / (abs(zeta) + np.sqrt(1.0 + zeta * zeta))
                largest = max(largest, off_sq, t * t)
                rot_t[p] = t
                rot_g[p] = gamma
            for p in range(schedule.shape[1]):
                t = rot_t[p]
                if t == 0.0:
                    continue
                rotated = True
                i = schedule[rnd, p, 0]
                j = schedule[rnd, p, 1]
                cs = 1.0 / np.sqrt(1.0 + t * t)
                sn = cs * t
                for row in range(r):
                    wi = Wt[i, row]
                    wj = Wt[j, row]
                    Wt[i, row] = cs * wi - sn * wj
                    Wt[j, row] = sn * wi + cs * wj
                for row in range(c):
                    xi = Xt[i, row]
                    xj = Xt[j, row]
                    Xt[i, row] = cs * xi - sn * xj
                    Xt[j, row] = sn * xi + cs * xj
                sq[i] -= t * rot_g[p]
                sq[j] += t * rot_g[p]
        # Converged: no pair needed a rotation, or every off-diagonal and rotation was below
        # sqrt(TOL), so the off-diagonals left are of order TOL (quadratic convergence).
        if not rotated or largest < TOL:
            break
    for col in range(c):
        acc = 0.0
        for row in range(r):
            acc += Wt[col, row] * Wt[col, row]
        sq[col] = np.sqrt(acc)
    # Sort descending (selection sort; c <= 6), permuting the rows of Wt and Xt alike.
    for i in range(c - 1):
        best = i
        for j in range(i + 1, c):
            if sq[j] > sq[best]:
                best = j
        if best != i:
            sq[i], sq[best] = sq[best], sq[i]
            for row in range(r):
                Wt[i, row], Wt[best, row] = Wt[best, row], Wt[i, row]
            for row in range(c):
                Xt[i, row], Xt[best, row] = Xt[best, row], Xt[i, row]
    missing = False
    for col in range(c):
        s[col] = sq[col] * amax if amax > 0.0 else 0.0
        if sq[col] > 1e-290:
            inv = 1.0 / sq[col]
            for row in range(r):
                Wt[col, row] *= inv
        else:
            missing = True
            for row in range(r):
                Wt[col, row] = 0.0
    if missing:
        for col in range(c):
            if sq[col] <= 1e-290:
                _complete(Wt, col, np.bool_(False))
    Y = U if tall else V  # columns y_i = w_i / s_i
    Z = V if tall else U  # columns of X
    for col in range(c):
        for row in range(r):
            Y[row, col] = Wt[col, row]
        for row in range(c):
            Z[row, col] = Xt[col, row]
    return True, sweeps


@kernel
def svd_many(J, U, s, V):
    """Cold-started :func:`jacobi_svd` of each ``J[b] (p, n)``; ``U (B, p, m)``, ``s (B, m)``,
    ``V (B, n, m)``."""
    n = J.shape[2]
    refresh = np.bool_(False)  # a runtime bool: a literal False would compile another jacobi_svd
    for b in range(J.shape[0]):
        buf = svd_buffers(n, J.shape[1])
        jacobi_svd(J[b], buf, refresh)
        for i in range(buf[2].shape[0]):
            s[b, i] = buf[2][i]
            for r in range(J.shape[1]):
                U[b, r, i] = buf[1][r, i]
            for r in range(n):
                V[b, r, i] = buf[3][r, i]

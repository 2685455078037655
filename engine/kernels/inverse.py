"""The robust inverses as filters of the singular values, ``qd = sum_i g_i v_i u_i^T xdot``,
each reporting an effective damping per singular direction (the constant damping that would
give the same gain: ``lambda_i = sqrt(sigma_i / g_i - sigma_i^2)``, 0 where undamped).

Methods are chosen by number (the Python strategies in :mod:`engine.inverses` carry it) with
their parameters in a float array:

- ``PLAIN`` (no parameter): ``g_i = 1 / sigma_i`` where ``sigma_i > RCOND sigma_1``, else 0 (paper eq. 3).
- ``DLS`` (lambda): ``g_i = sigma_i / (sigma_i^2 + lambda^2)`` (paper eqs. 6 and 10).
- ``ADAPTIVE`` (lambda_max, epsilon): DLS with ``lambda_i = lambda_max (1 + cos(pi sigma_i /
  epsilon)) / 2`` where ``sigma_i < epsilon``, else 0 (paper eq. 16).
- ``WDLS`` (lambda_max, epsilon): DLS with ``lambda = lambda_max sqrt(1 - (sigma_min /
  epsilon)^2)`` where ``sigma_min < epsilon`` (Maciejewski and Klein 1988; Orocos KDL).
- ``SDLS`` (gamma_max): selectively damped least squares (Buss and Kim 2005).
- ``SVF`` (sigma0, nu): ``sigma_hat = (sigma^3 + nu sigma^2 + 2 sigma + 2 sigma0) / (sigma^2 +
  nu sigma + 2)``, ``g_i = 1 / sigma_hat_i`` (Colome and Torras 2015).
- ``BOUNDED`` (lambda): the DLS filter here; the planner's step loop then holds the joint rates
  in the box of the speed and position limits by a QP when the filter's rates leave it
  (:func:`engine.kernels.plan.bound_rates`). Without a joint state (this module) it is DLS.
"""

from __future__ import annotations

import numpy as np

from engine.kernels.jit import kernel
from engine.kernels.svd import jacobi_svd, svd_buffers

PLAIN, DLS, ADAPTIVE, WDLS, SDLS, SVF, BOUNDED = 0, 1, 2, 3, 4, 5, 6
MAX_PARAMS = 2
TINY = 1e-300
RCOND = 1e-12  # the plain inverse drops singular values below RCOND sigma_1


@kernel
def _damped_gain(s, lam):
    denom = s * s + lam * lam
    return s / denom if denom > TINY else 0.0


@kernel
def _effective_damping(s, gain):
    if gain > 0.0:
        lam_sq = s / max(gain, TINY) - s * s
        return np.sqrt(lam_sq) if lam_sq > 0.0 else 0.0
    return 0.0


@kernel
def _clamp_scale(values, limit):
    """Buss and Kim's ClampMaxAbs as a factor: ``values * factor`` has ``max |.| <= limit``."""
    peak = 0.0
    for v in values:
        if abs(v) > peak:
            peak = abs(v)
    if peak > limit:
        return limit / peak if peak > 0.0 else 1.0
    return 1.0


@kernel
def apply_inverse(method, params, J, U, s, V, xdot, qd, damping, scratch):
    """Joint rates ``qd (n,)`` for the task velocity ``xdot`` (its first ``p`` entries: a twist
    ``[v; w]`` for ``p = 6``, ``v`` for ``p = 3``) given the thin SVD ``U (p, m)``, ``s (m,)``,
    ``V (n, m)`` of ``J (p, n)``; writes the effective ``damping (m,)``. ``scratch (2, 6)``."""
    m = s.shape[0]
    n = V.shape[0]
    pose = U.shape[0] == 6
    proj = scratch[0]
    for i in range(m):
        acc = 0.0
        for r in range(3):  # the linear part, then the angular part of a pose (constant trip counts)
            acc += U[r, i] * xdot[r]
        if pose:
            for r in range(3, 6):
                acc += U[r, i] * xdot[r]
        proj[i] = acc
    gain = scratch[1]
    if method == SDLS:
        _sdls(params[0], J, U, s, V, proj, qd, damping)
        return
    if method == PLAIN:
        cut = RCOND * s[0]
        for i in range(m):
            gain[i] = 1.0 / s[i] if s[i] > cut else 0.0
            damping[i] = 0.0
    elif method == DLS or method == BOUNDED:  # noqa: SIM109 (plain comparisons in the compiled kernel)
        lam = params[0]
        for i in range(m):
            gain[i] = _damped_gain(s[i], lam)
            damping[i] = lam
    elif method == ADAPTIVE:
        lam_max = params[0]
        eps = params[1]
        for i in range(m):
            lam = 0.5 * lam_max * (1.0 + np.cos(np.pi * s[i] / eps)) if s[i] < eps else 0.0
            gain[i] = _damped_gain(s[i], lam)
            damping[i] = lam
    elif method == WDLS:
        ratio = min(max(s[m - 1] / params[1], 0.0), 1.0)
        lam = params[0] * np.sqrt(1.0 - ratio * ratio)
        for i in range(m):
            gain[i] = _damped_gain(s[i], lam)
            damping[i] = lam
    else:  # SVF
        sigma0 = params[0]
        nu = params[1]
        for i in range(m):
            si = s[i]
            s_hat = (si * si * si + nu * si * si + 2.0 * si + 2.0 * sigma0) / (si * si + nu * si + 2.0)
            gain[i] = 1.0 / s_hat
            damping[i] = _effective_damping(si, gain[i])
    for j in range(n):
        acc = 0.0
        for i in range(m):
            acc += V[j, i] * (gain[i] * proj[i])
        qd[j] = acc


@kernel
def _sdls(gamma_max, J, U, s, V, alpha, qd, damping):
    """Selectively damped least squares (Buss and Kim 2005, J. Graphics Tools 10(3)) at the
    velocity level, the twist split into its linear and angular 3-blocks (a position task has
    the linear block only). Per direction i:
    ``N_i = |u_i,lin| + |u_i,ang|``, ``M_i = sigma_i^-1 sum_j |v_ji| (|J_j,lin| + |J_j,ang|)``,
    ``gamma_i = min(1, N_i / M_i) gamma_max``, ``phi_i = ClampMaxAbs(sigma_i^-1 alpha_i v_i,
    gamma_i)``; ``qd = ClampMaxAbs(sum_i phi_i, gamma_max)``."""
    m = s.shape[0]
    n = V.shape[0]
    pose = U.shape[0] == 6
    col_norm = np.empty(n)
    for j in range(n):
        lin = 0.0
        ang = 0.0
        for r in range(3):
            lin += J[r, j] * J[r, j]
            if pose:
                ang += J[r + 3, j] * J[r + 3, j]
        col_norm[j] = np.sqrt(lin) + np.sqrt(ang)
    total = np.zeros(n)
    phi = np.empty(n)
    ratio = np.empty(m)
    for i in range(m):
        s_safe = max(s[i], TINY)
        lin = 0.0
        ang = 0.0
        for r in range(3):
            lin += U[r, i] * U[r, i]
            if pose:
                ang += U[r + 3, i] * U[r + 3, i]
        N = np.sqrt(lin) + np.sqrt(ang)
        Mi = 0.0
        for j in range(n):
            Mi += abs(V[j, i]) * col_norm[j]
        Mi /= s_safe
        gamma = min(1.0, N / max(Mi, TINY)) * gamma_max
        coef = alpha[i] / s_safe
        for j in range(n):
            phi[j] = coef * V[j, i]
        factor = _clamp_scale(phi, gamma)
        ratio[i] = factor
        for j in range(n):
            total[j] += phi[j] * factor
    final = _clamp_scale(total, gamma_max)
    for j in range(n):
        qd[j] = total[j] * final
    for i in range(m):
        damping[i] = _effective_damping(s[i], ratio[i] * final / max(s[i], TINY))


@kernel
def solve_many(method, params, J, xdot, qd, damping, sv):
    """Cold-started SVD and :func:`apply_inverse` for each member: ``params (B, P)``,
    ``J (B, p, n)``, ``xdot (B, p)``; writes ``qd (B, n)``, ``damping (B, m)``, ``sv (B, m)``."""
    n = J.shape[2]
    refresh = np.bool_(False)  # a runtime bool: a literal False would compile another jacobi_svd
    for b in range(J.shape[0]):
        buf = svd_buffers(n, J.shape[1])
        ok, _ = jacobi_svd(J[b], buf, refresh)
        if ok:
            apply_inverse(method, params[b], J[b], buf[1], buf[2], buf[3], xdot[b], qd[b], damping[b], np.empty((2, 6)))
        else:
            qd[b] = np.nan
            damping[b] = np.nan
        for i in range(buf[2].shape[0]):
            sv[b, i] = buf[2][i]

"""Test oracle: the former numpy GJM of the engine, under zero total momentum.

The textbook form (Umetani and Yoshida 1989) is ``J_g = J_m - J_b H_b^-1 H_bm`` with the
6x6 base inertia ``H_b``. Zero linear momentum fixes the system centre of mass, so the base
rotation follows from the 3x3 angular-momentum balance about the system CoM,
``H_s w_0 + H_sq qd = 0``; this is algebraically identical and only needs a 3x3 solve:

- ``w_0 = -H_s^-1 H_sq qd``
- ``v_0 = [r_g - r_0]x w_0 - J_Tw qd / M``
- ``v_e = (J_mv - J_Tw / M - [p_e - r_g]x H_s^-1 H_sq) qd``, ``w_e = (J_mw - H_s^-1 H_sq) qd``

where ``H_s = sum_i I_i + m_i [rho_i]x^T [rho_i]x`` (``rho_i = r_i - r_g``),
``H_sq`` column j ``= sum_{i>=j} I_i k_j + m_i rho_i x (k_j x (r_i - p_j))`` and
``J_Tw`` column j ``= sum_{i>=j} m_i k_j x (r_i - p_j)``. The sums over the subtree of joint j
are reverse cumulative sums, so the whole GJM is O(n) per configuration. :func:`gjm_batch`
assembles ``v_e`` as the rigid-body velocity ``v_0 + w_0 x (p_e - r_0) + J_mv qd``, which is
the same expression regrouped.
"""

from __future__ import annotations

import numpy as np
from oracle.kinematics import Kinematics, _weighted_sum, chain_constants
from oracle.spatial import FloatArray

from engine.model import RobotModel


def gjm_batch(model: RobotModel, kin: Kinematics) -> tuple[FloatArray, FloatArray]:
    """``(J_g (B, 6, n), base_map (B, 6, n))``, C-contiguous.

    ``J_g`` maps joint rates (rad/s) to the end-effector twist ``[v_e; w_e]`` (m/s, rad/s,
    world axes). ``base_map`` maps them to the base twist ``[v_0; w_0]`` (base CoM velocity,
    base angular velocity, world axes).

    Computed batch-last like :func:`engine.kinematics.kinematics_batch` (sums only over the
    outermost axis of a product, or written out, so that no result depends on the batch
    size). Cross products use vectors stored with their first two components repeated,
    ``(x, y, z, x, y)``, so that ``a x b = a[1:4] b[2:5] - a[2:5] b[1:4]`` needs no gathering.
    """
    c = chain_constants(model)
    n = c.n
    At = kin.body_attitudes.transpose(3, 1, 2, 0)  # (3, n+1, 3, B): At[k, i, r] = A_i[r, k]
    r = kin.body_com.transpose(1, 2, 0)  # (n+1, 3, B)
    k = kin.joint_axes.transpose(1, 2, 0)  # (n, 3, B)
    p = kin.joint_positions.transpose(1, 2, 0)
    p_e = kin.ee_position.T  # (3, B)
    batch = r.shape[-1]
    r_g = _weighted_sum(c.mass_fraction, r)
    neg_rho = r_g - r

    # Per body i: T_i = A_i I_i A_i^T + m_i (|rho_i|^2 I - rho_i rho_i^T), the inertia about the
    # system CoM (9 rows), and m_i rho_i (3 rows, then 2 for the extension); summed from the
    # tip, row i of `tails` becomes the sum over bodies i..n.
    tails = np.empty((n + 1, 14, batch))
    m_rho = tails[:, 9:12]
    np.multiply(c.neg_masses[:, None, None], neg_rho, out=m_rho)
    # Y[col, i, r] = (A_i L_i)[r, col] with I_i = L_i L_i^T; then
    # T_i = sum_col Y[col] Y[col]^T - m_i rho_i rho_i^T (+ the trace term below).
    Y = np.sum(c.inertia_sqrt_t * At[:, None], axis=0)
    terms = np.empty((4, n + 1, 3, 3, batch))
    np.multiply(Y[:, :, :, None], Y[:, :, None], out=terms[:3])
    np.multiply(m_rho[:, :, None], neg_rho[:, None], out=terms[3])
    T = tails[:, :9].reshape(n + 1, 3, 3, batch)
    np.sum(terms, axis=0, out=T)
    tails[:, 0:9:4] -= (terms[3, :, 0, 0] + terms[3, :, 1, 1] + terms[3, :, 2, 2])[:, None]
    for i in range(n - 1, -1, -1):
        tails[i, :12] += tails[i + 1, :12]
    tails[1:, 12:] = tails[1:, 9:11]
    tail_T = tails[1:, :9].reshape(n, 3, 3, batch)  # joint j (0-based): bodies j+1..n
    tail_W = tails[1:, 9:]  # sum of m_i rho_i over bodies j+1..n, extended

    # v[:, 0] = c_j = p_j - r_g, v[:, 1] = h_j = mu_j c_j - tail_W_j / M, v[:, 2] = p_e - p_j.
    v = np.empty((n, 3, 5, batch))
    np.subtract(p, r_g, out=v[:, 0, :3])
    np.multiply(c.tail_fraction[:, None, None], v[:, 0, :3], out=v[:, 1, :3])
    v[:, 1, :3] -= tail_W[:, :3] * (1.0 / c.total_mass)
    np.subtract(p_e, p, out=v[:, 2, :3])
    v[:, :, 3:] = v[:, :, :2]
    kx = np.concatenate((k, k[:, :2]), axis=1)[:, None]
    kv = np.empty((n, 3, 5, batch))  # k x v; x_j = k_j x c_j is extended
    np.subtract(kx[:, :, 1:4] * v[:, :, 2:5], kx[:, :, 2:5] * v[:, :, 1:4], out=kv[:, :, :3])
    kv[:, 0, 3:] = kv[:, 0, :2]

    # Angular momentum about the system CoM: H_s w_0 + H_sq qd = 0 with
    # H_sq_j = tail_T_j k_j - tail_W_j x (k_j x c_j).
    H_sq = np.sum(tail_T.transpose(2, 0, 1, 3) * k.transpose(1, 0, 2)[:, :, None], axis=0)
    H_sq -= tail_W[:, 1:4] * kv[:, 0, 2:5] - tail_W[:, 2:5] * kv[:, 0, 1:4]
    # Omega = -H_s^-1 H_sq via the cofactors of the symmetric positive definite H_s.
    factors = tails[0, :9][_COFACTOR_INDEX]
    cof = factors[0] * factors[1] - factors[2] * factors[3]  # (3, 3, B)
    det = tails[0, :3] * cof[0]
    cof *= -1.0 / (det[0] + det[1] + det[2])
    omega = np.empty((n, 5, batch))  # w_0 = Omega qd, extended
    np.sum(cof.transpose(1, 0, 2)[:, None] * H_sq.transpose(1, 0, 2)[:, :, None], axis=0, out=omega[:, :3])
    omega[:, 3:] = omega[:, :2]

    # rho_0 = r_0 - r_g and p_e - r_0, extended, crossed with Omega.
    u = np.empty((2, 5, batch))
    np.negative(neg_rho[0], out=u[0, :3])
    np.subtract(p_e, r[0], out=u[1, :3])
    u[:, 3:] = u[:, :2]
    ou = omega[:, None, 1:4] * u[:, 2:5] - omega[:, None, 2:5] * u[:, 1:4]  # (n, 2, 3, B)

    # base_map = [k x h + Omega x rho_0; Omega] and J_g = [v_0 + k x (p_e - p) + Omega x (p_e - r_0);
    # k + Omega] (rigid-body velocity of the end effector).
    out = np.empty((2, 6, n, batch))
    bm_v = out[1, :3].transpose(1, 0, 2)
    np.add(kv[:, 1, :3], ou[:, 0], out=bm_v)
    np.add(bm_v, kv[:, 2, :3], out=out[0, :3].transpose(1, 0, 2))
    out[0, :3] += ou[:, 1].transpose(1, 0, 2)
    np.add(k, omega[:, :3], out=out[0, 3:].transpose(1, 0, 2))
    out[1, 3:] = omega[:, :3].transpose(1, 0, 2)
    both = np.ascontiguousarray(out.transpose(0, 3, 1, 2))
    return both[0], both[1]


# Cofactors of a symmetric 3x3 H (flattened row-major): cof[s, r] = H[s+1, r+1] H[s+2, r+2]
# - H[s+2, r+1] H[s+1, r+2] (indices mod 3), as four gathered factor matrices.
_COFACTOR_INDEX = np.array(
    [[[3 * ((s + a) % 3) + (r + b) % 3 for r in range(3)] for s in range(3)] for a, b in ((1, 1), (2, 2), (2, 1), (1, 2))]
)

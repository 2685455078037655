"""Test oracle: the former numpy kinematics of the engine (SpaceDyn recursion), batched.

Recursion (``robot-table1.md``): ``A_i = A_{i-1} Rot(s_i, q_i)``, ``p_i = r_{i-1} + A_{i-1} b_{i-1}``,
``r_i = p_i + A_i a_i``, ``p_e = r_n + A_n b_n``, ``A_e = A_n C_e``.

The batched kernels work batch-last (the batch is the contiguous last axis of every
intermediate array), which keeps each numpy call long and cheap at the batch sizes of a GA
population, and return batch-first views. They only sum in ways whose order does not depend
on the batch size, so a configuration gets bit-identical results alone or in any batch.
"""

from __future__ import annotations

import numpy as np
from oracle.spatial import FloatArray, skew

from engine.kinematics import Kinematics
from engine.model import RobotModel

# Columns of the per-joint product A_j R~_j (R~_j is the joint rotation R_j extended by
# constant columns, see _ChainConstants.joint_terms): A_{j+1} (3 columns), then
# dr_{j+1} = r_{j+1} - r_j = A_j b_j + A_{j+1} a_{j+1}, A_j b_j = p_{j+1} - r_j and k_{j+1}.
_DR, _PB, _AXIS = 3, 4, 5
_COLUMNS = 6


class _ChainConstants:
    """Per-model arrays reused at every step (cached on the model instance).

    ``masses (n+1,)`` kg and ``inertias (n+1, 3, 3)`` kg m^2 (base first), ``total_mass``,
    ``mass_fraction (n+1,)``, ``tail_fraction (n,)`` (mass of links j+1..n over the total,
    0-based joint j), ``inertia_sqrt_t`` (Cholesky factors of the inertias) and the kinematic
    constants ``joint_terms``, ``ee_columns`` and ``prefix`` (see :func:`_chain`).
    """

    def __init__(self, model: RobotModel) -> None:
        n = model.n_joints
        self.n = n
        self.masses = model.masses
        self.total_mass = float(self.masses.sum())
        self.mass_fraction = self.masses / self.total_mass
        self.inertias = model.inertias
        self.neg_masses = -self.masses
        # inertia_sqrt_t[k, col, i] = L_i[k, col] with I_i = L_i L_i^T (Cholesky), for the GJM.
        self.inertia_sqrt_t = np.linalg.cholesky(model.inertias).transpose(1, 2, 0)[..., None, None]
        self.tail_fraction = np.cumsum(self.masses[1:][::-1])[::-1] / self.total_mass
        # joint_terms[p, j] (3, n, 3, _COLUMNS): R~_j = terms[0] + sin q_j terms[1] + cos q_j terms[2]
        # (Rodrigues: R_j = I + K_j^2 + sin K_j - cos K_j^2); a rotated column x gives
        # A_{j+1} x, a column with only a constant term y gives A_j y.
        K = skew(model.joint_axes)
        K2 = K @ K
        terms = np.zeros((3, n, 3, _COLUMNS))
        terms[0, :, :, :3] = np.eye(3) + K2
        terms[1, :, :, :3] = K
        terms[2, :, :, :3] = -K2
        terms[:, :, :, _DR] = np.einsum("pjkc,jc->pjk", terms[:, :, :, :3], model.a_vectors)
        terms[0, :, :, _DR] += model.b_vectors[:-1]
        terms[0, :, :, _PB] = model.b_vectors[:-1]
        terms[0, :, :, _AXIS] = model.joint_axes
        self.joint_terms = terms[..., None]
        # End effector, in the last link's frame: the columns of C_e and b_n.
        self.ee_columns = np.concatenate([model.C_e, model.b_vectors[-1][:, None]], axis=1)[..., None]
        # prefix[l, i] (n, n+2): r_i - r_0 = sum_l prefix[l, i] dr_{l+1} for i = 0..n, and the
        # last column gives the system CoM relative to r_0.
        prefix = np.zeros((n, n + 2))
        prefix[:, : n + 1] = np.triu(np.ones((n, n + 1)), 1)
        prefix[:, n + 1] = self.tail_fraction
        self.prefix = prefix[..., None, None]


def chain_constants(model: RobotModel) -> _ChainConstants:
    cached = model.__dict__.get("_chain_constants")
    if cached is None:
        cached = _ChainConstants(model)
        # The model is frozen; the cache is derived data, so bypassing __setattr__ is safe.
        model.__dict__["_chain_constants"] = cached
    return cached


def _transform(M: FloatArray, F: FloatArray, out: FloatArray) -> None:
    """``out[c, r, b] = sum_k F[k, r, b] M[k, c, b]``: the columns of ``A M`` for ``F (3, 3, B)``
    (the columns of A) and ``M (3, C, B)`` (or ``(3, C, 1)``).

    Sums in this module run over the outermost axis of a product, which numpy reduces in
    order whatever the batch size; einsum or sums over other axes may reorder them (by
    rounding error) when the batch has one member.
    """
    np.sum(M[:, :, None] * F[:, None], axis=0, out=out)


def _chain(model: RobotModel, q: FloatArray, base_attitude: FloatArray, origin: FloatArray, about_com: bool) -> Kinematics:
    """Batched kinematics; ``origin (B, 3)`` is the base position, or the system CoM if
    ``about_com``.

    Computed batch-last (each numpy call runs over the batch as its contiguous axis, and no
    result depends on the batch size) and returned as batch-first views.
    """
    c = chain_constants(model)
    batch, n = q.shape
    trig = np.empty((3, n, batch))  # 1, sin q, cos q
    trig[0] = 1.0
    q_t = np.ascontiguousarray(q.T)
    np.sin(q_t, out=trig[1])
    np.cos(q_t, out=trig[2])
    R = np.sum(c.joint_terms * trig[:, :, None, None, :], axis=0)  # (n, 3, _COLUMNS, B)
    # frames[i, k, r, b] = A_i[r, k] (the columns of A_i), then the extra columns of joint i.
    frames = np.empty((n + 1, _COLUMNS, 3, batch))
    frames[0, :3] = base_attitude.transpose(2, 1, 0)
    for j in range(n):
        _transform(R[j], frames[j, :3], frames[j + 1])
    ee = np.empty((4, 3, batch))  # A_n C_e (columns), A_n b_n
    _transform(c.ee_columns, frames[n, :3], ee)
    # points: r_0..r_n, the system CoM, p_1..p_n, p_e; relative to r_0 until shifted.
    points = np.empty((2 * n + 3, 3, batch))
    np.sum(c.prefix * frames[1:, _DR, None], axis=0, out=points[: n + 2])
    np.add(points[:n], frames[1:, _PB], out=points[n + 2 : 2 * n + 2])
    np.add(points[n], ee[3], out=points[-1])
    points += (origin.T - points[n + 1]) if about_com else origin.T
    return Kinematics(
        body_attitudes=frames[:, :3].transpose(3, 0, 2, 1),
        body_com=points[: n + 1].transpose(2, 0, 1),
        joint_positions=points[n + 2 : 2 * n + 2].transpose(2, 0, 1),
        joint_axes=frames[1:, _AXIS].transpose(2, 0, 1),
        ee_position=points[-1].T,
        ee_attitude=ee[:3].transpose(2, 1, 0),
    )


def _weighted_sum(w: FloatArray, x: FloatArray) -> FloatArray:
    """``sum_i w_i x[i]`` over the leading axis of ``x (L, ...)`` (see :func:`_transform`)."""
    total: FloatArray = (w.reshape((-1,) + (1,) * (x.ndim - 1)) * x).sum(axis=0)
    return total


def kinematics_batch(model: RobotModel, q: FloatArray, base_attitude: FloatArray, base_position: FloatArray) -> Kinematics:
    """Kinematics for ``q (B, n)`` rad, ``base_attitude (B, 3, 3)``, ``base_position (B, 3)`` m.

    The returned arrays are batch-first views of batch-last buffers (not C-contiguous).
    """
    return _chain(model, q, base_attitude, base_position, about_com=False)


def kinematics_about_com(model: RobotModel, q: FloatArray, base_attitude: FloatArray, com: FloatArray) -> Kinematics:
    """Kinematics with the base placed so that the system CoM is at ``com (B, 3)``.

    Zero linear momentum keeps the system CoM fixed, so this places the base exactly
    (no integration of the base position is needed).
    """
    return _chain(model, q, base_attitude, com, about_com=True)


def system_com(model: RobotModel, kin: Kinematics) -> FloatArray:
    """System centre of mass ``(B, 3)`` in m."""
    return _weighted_sum(chain_constants(model).mass_fraction, kin.body_com.transpose(1, 0, 2))

"""Secondary objectives in the null space of the tracked Jacobian (redundant arms: more joints
than the task tracks).

With the thin SVD ``J = U diag(s) V^T`` (``V (n, m)``), ``N = I - V V^T`` projects joint rates
onto motions the end effector does not see (``J N = 0`` exactly, whatever damping the inverse
applied to the primary rates ``qd_p``). Objectives, chosen by number:

- ``MIN_BASE_ROTATION`` (gain ``k`` in [0, 1]): the reaction null-space idea of Nenchev and
  Yoshida: among ``qd_p + N z`` choose the one whose carrier angular velocity ``w_0 = Omega qd``
  is smallest. With ``P = Omega N`` (3 x n) the least-squares choice is
  ``N z = -P^T (P P^T + delta^2 I)^-1 Omega qd_p`` (push-through identity: a 3x3 solve), and
  ``qd = qd_p + k N z``; ``k = 1`` is the minimiser. ``delta`` = :data:`NULL_SPACE_DAMPING`
  bounds the null-space rates where the null space barely moves the carrier (``|P| ~ 0``).
- ``JOINT_CENTERING`` (gain ``k`` in 1/s): ``qd = qd_p + N z`` with ``z = -k (q - q_c)``, which
  pulls each joint towards ``q_c`` (the middle of its limits; its start value when unlimited)
  without disturbing the end effector (Liegeois 1977).
- ``CLEARANCE`` (gain ``k`` in 1/s): ``qd = qd_p + N z`` with ``z`` the rates that raise each
  close pair's distance at ``k`` times its shortfall from the influence distance
  (:func:`engine.kernels.geometry.clearance_push`, computed by the planner).
"""

from __future__ import annotations

from engine.kernels.jit import kernel
from engine.kernels.linalg import solve3_spd

NONE, MIN_BASE_ROTATION, JOINT_CENTERING, CLEARANCE = 0, 1, 2, 3
NULL_SPACE_DAMPING = 1e-3  # dimensionless (rad/s of the carrier per rad/s of the joints)


@kernel
def add_null_motion(V, z, t, qd):
    """``qd += (I - V V^T) z``: the part of ``z (n,)`` the tracked Jacobian does not see
    (``V (n, m)`` its right singular vectors; ``t (>= m,)`` scratch)."""
    n = V.shape[0]
    m = V.shape[1]
    for i in range(m):
        acc = 0.0
        for j in range(n):
            acc += V[j, i] * z[j]
        t[i] = acc
    for j in range(n):
        acc = z[j]
        for i in range(m):
            acc -= V[j, i] * t[i]
        qd[j] += acc


@kernel
def null_space_step(objective, gain, V, Omega, q, centre, qd, work):
    """Add the secondary objective's null-space motion to ``qd (n,)`` in place. ``V (n, m)``
    the right singular vectors of the tracked Jacobian, ``Omega (3, n)`` the carrier's angular
    velocity per joint rate (any fixed axes), ``q (n,)`` and ``centre (n,)`` joint positions.
    ``work``: ``(P (3, n), OV (3, 6), t (6,), z (n,), G (3, 3), w (3,), y (3,))``; for
    ``CLEARANCE`` its ``z`` holds the rates to project on entry. Nothing happens when ``n <= m``
    (no null space) or for ``NONE``."""
    n = V.shape[0]
    m = V.shape[1]
    if objective == NONE or n <= m:
        return
    P, OV, t, z, G, w, y = work
    if objective == JOINT_CENTERING:
        for j in range(n):
            z[j] = -gain * (q[j] - centre[j])
        add_null_motion(V, z, t, qd)
        return
    if objective == CLEARANCE:  # the planner left the rates in ``z``
        add_null_motion(V, z, t, qd)
        return
    # MIN_BASE_ROTATION: P = Omega - (Omega V) V^T, G = P P^T + delta^2 I, y = G^-1 Omega qd_p
    for r in range(3):
        acc = 0.0
        for j in range(n):
            acc += Omega[r, j] * qd[j]
        w[r] = acc
        for i in range(m):
            acc = 0.0
            for j in range(n):
                acc += Omega[r, j] * V[j, i]
            OV[r, i] = acc
        for j in range(n):
            acc = Omega[r, j]
            for i in range(m):
                acc -= OV[r, i] * V[j, i]
            P[r, j] = acc
    for r in range(3):
        for c in range(r + 1):
            acc = 0.0
            for j in range(n):
                acc += P[r, j] * P[c, j]
            G[r, c] = acc
            G[c, r] = acc
        G[r, r] += NULL_SPACE_DAMPING * NULL_SPACE_DAMPING
    solve3_spd(G, w, y)
    for j in range(n):
        qd[j] -= gain * (P[0, j] * y[0] + P[1, j] * y[1] + P[2, j] * y[2])

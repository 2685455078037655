"""Kinematics of the free-floating chain and its generalized Jacobian, one configuration at a
time.

Kinematics (SpaceDyn recursion, link frames parallel to the base frame at q = 0):
``A_i = A_{i-1} Rot(s_i, q_i)``, ``p_i = r_{i-1} + A_{i-1} b_{i-1}``, ``r_i = p_i + A_i a_i``,
``p_e = r_n + A_n b_n``, ``A_e = A_n C_e``; the joint axis in world is ``k_i = A_{i-1} s_i``.
A prismatic joint slides instead: ``A_i = A_{i-1}``, ``r_i = p_i + A_i (a_i + s_i q_i)``.

GJM (zero total momentum). Zero linear momentum fixes the system centre of mass ``r_g``, so the
base rotation follows from the 3x3 angular-momentum balance about it,
``H_s w_0 + H_sq qd = 0`` with ``H_s = sum_i A_i I_i A_i^T + m_i (|rho_i|^2 I - rho_i rho_i^T)``
(``rho_i = r_i - r_g``) and column j of ``H_sq`` ``= T_j k_j - W_j x (k_j x (p_j - r_g))``, where
``T_j`` and ``W_j = sum m_i rho_i`` are sums over the bodies that joint j moves (a reverse
cumulative sum: O(n) per configuration). With ``Omega = -H_s^-1 H_sq`` (a Cholesky solve):

- base: ``w_0 = Omega qd``, ``v_0 = (k_j x h_j + Omega_j x (r_0 - r_g)) qd_j`` with
  ``h_j = (M_j / M)(p_j - r_g) - W_j / M`` (``M_j`` the mass moved by joint j);
- end effector: ``v_e = v_0 + w_0 x (p_e - r_0) + sum_j k_j x (p_e - p_j) qd_j``,
  ``w_e = w_0 + sum_j k_j qd_j``.

A prismatic joint j moves its bodies by ``k_j qd_j`` without turning them: its column of
``H_sq`` is ``W_j x k_j``, of the base velocity ``Omega_j x (r_0 - r_g) - (M_j / M) k_j``, and of
the GJM ``[v_0j + k_j + Omega_j x (p_e - r_0); Omega_j]``.

The loops compute the revolute column and replace it for a prismatic joint (a branch that a
revolute chain never takes), so revolute chains run the same arithmetic as before.

This is algebraically the textbook ``J_m - J_b H_b^-1 H_bm`` (Umetani and Yoshida 1989), checked
against Pinocchio in the tests.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from engine.kernels.jit import kernel


class Chain(NamedTuple):
    """A robot model as the kernels see it (float64, C-contiguous, SI units)."""

    masses: np.ndarray  # (n+1,) kg, base first
    inertias: np.ndarray  # (n+1, 3, 3) kg m^2 about each CoM, body frame
    axes: np.ndarray  # (n, 3) unit joint axes s_i in link frames
    a: np.ndarray  # (n, 3) m, joint i -> CoM i
    b: np.ndarray  # (n+1, 3) m, b_0 (base CoM -> joint 1) then CoM i -> joint i+1 / end effector
    C_e: np.ndarray  # (3, 3) end-effector frame in the last link's frame
    total_mass: float  # kg
    # (n, 4) per joint: SLIDE (1.0: prismatic, q in m; 0.0: revolute, q in rad), LOWER, UPPER position
    # limits (+-inf: none), EFFORT limit (N m or N; +inf: none)
    joints: np.ndarray


# Columns of Chain.joints (one array rather than four: kernels pass the chain by value).
SLIDE, LOWER, UPPER, EFFORT = 0, 1, 2, 3


# Buffers are plain tuples of arrays (numba types a tuple and a named tuple differently, and
# kernels build them too):
# kinematics: (att (n+1, 3, 3) body attitudes, base first; com (n+1, 3) body CoMs;
#              jpos (n, 3) joint positions p_i; jaxis (n, 3) world joint axes k_i;
#              ee_p (3,); ee_A (3, 3))
# gjm:        (J (6, n) end-effector twist map; base_map (6, n) base twist map [v_0; w_0];
#              Omega (3, n) base angular velocity map; tail_w (n, 3) W_j; tail_m (n,) M_j;
#              r_g (3,) system CoM; scratch (2, 3, 3))


@kernel
def kinematics_buffers(n):
    return (np.empty((n + 1, 3, 3)), np.empty((n + 1, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty(3), np.empty((3, 3)))


@kernel
def gjm_buffers(n):
    return (np.empty((6, n)), np.empty((6, n)), np.empty((3, n)), np.empty((n, 3)), np.empty(n), np.empty(3), np.empty((2, 3, 3)))


@kernel
def kinematics(ch, q, A0, origin, about_com, kin):
    """Kinematics of ``q (n,)`` rad with base attitude ``A0 (3, 3)``; the base CoM is at
    ``origin (3,)``, or, if ``about_com``, the base is placed so that the system CoM is there.
    Writes the kinematics buffers ``kin``.

    (The kernels index arrays element by element rather than through row views: a view of an
    array that several threads share, such as the model's, costs an atomic reference count.)
    """
    att, com, jpos, jaxis, ee_p, ee_A = kin
    n = q.shape[0]
    for r in range(3):
        com[0, r] = 0.0
        for c in range(3):
            att[0, r, c] = A0[r, c]
    for i in range(n):
        s0 = ch.axes[i, 0]
        s1 = ch.axes[i, 1]
        s2 = ch.axes[i, 2]
        b0 = ch.b[i, 0]
        b1 = ch.b[i, 1]
        b2 = ch.b[i, 2]
        for r in range(3):
            a0 = att[i, r, 0]
            a1 = att[i, r, 1]
            a2 = att[i, r, 2]
            jpos[i, r] = com[i, r] + a0 * b0 + a1 * b1 + a2 * b2
            jaxis[i, r] = a0 * s0 + a1 * s1 + a2 * s2
        # Rot(s, q) = cos q I + sin q [s]x + (1 - cos q) s s^T; a prismatic joint does not turn
        # (the identity) but moves the CoM by s q.
        cq = np.cos(q[i])
        sq = np.sin(q[i])
        a_0 = ch.a[i, 0]
        a_1 = ch.a[i, 1]
        a_2 = ch.a[i, 2]
        if ch.joints[i, SLIDE] != 0.0:
            cq = 1.0
            sq = 0.0
            a_0 += s0 * q[i]
            a_1 += s1 * q[i]
            a_2 += s2 * q[i]
        vq = 1.0 - cq
        R00 = cq + vq * s0 * s0
        R01 = vq * s0 * s1 - sq * s2
        R02 = vq * s0 * s2 + sq * s1
        R10 = vq * s1 * s0 + sq * s2
        R11 = cq + vq * s1 * s1
        R12 = vq * s1 * s2 - sq * s0
        R20 = vq * s2 * s0 - sq * s1
        R21 = vq * s2 * s1 + sq * s0
        R22 = cq + vq * s2 * s2
        for r in range(3):
            a0 = att[i, r, 0]
            a1 = att[i, r, 1]
            a2 = att[i, r, 2]
            n0 = a0 * R00 + a1 * R10 + a2 * R20
            n1 = a0 * R01 + a1 * R11 + a2 * R21
            n2 = a0 * R02 + a1 * R12 + a2 * R22
            att[i + 1, r, 0] = n0
            att[i + 1, r, 1] = n1
            att[i + 1, r, 2] = n2
            com[i + 1, r] = jpos[i, r] + n0 * a_0 + n1 * a_1 + n2 * a_2
    b0 = ch.b[n, 0]
    b1 = ch.b[n, 1]
    b2 = ch.b[n, 2]
    for r in range(3):
        a0 = att[n, r, 0]
        a1 = att[n, r, 1]
        a2 = att[n, r, 2]
        ee_p[r] = com[n, r] + a0 * b0 + a1 * b1 + a2 * b2
        for c in range(3):
            ee_A[r, c] = a0 * ch.C_e[0, c] + a1 * ch.C_e[1, c] + a2 * ch.C_e[2, c]
    for r in range(3):
        shift = origin[r]
        if about_com:
            g = 0.0
            for i in range(n + 1):
                g += ch.masses[i] * com[i, r]
            shift -= g / ch.total_mass
        ee_p[r] += shift
        for i in range(n + 1):
            com[i, r] += shift
        for i in range(n):
            jpos[i, r] += shift


@kernel
def system_com(masses, total_mass, com, out):
    """``out (3,)``: the system CoM of the bodies' CoMs ``com (n+1, 3)`` (masses ``(n+1,)``)."""
    for r in range(3):
        acc = 0.0
        for i in range(masses.shape[0]):
            acc += masses[i] * com[i, r]
        out[r] = acc / total_mass


@kernel
def fastest_joints(joints, peak):
    """The revolute joint and the prismatic joint with the largest ``peak (n,)`` (of speed,
    torque, ...), -1 where there is none of that kind (``joints``: :attr:`Chain.joints`)."""
    best = -1
    best_lin = -1
    for j in range(peak.shape[0]):
        if joints[j, SLIDE] != 0.0:
            if best_lin < 0 or peak[j] > peak[best_lin]:
                best_lin = j
        elif best < 0 or peak[j] > peak[best]:
            best = j
    return best, best_lin


@kernel
def _add_body(inertias, m, i, att, x, y, z, T, tmp):
    """``T += A_i I_i A_i^T + m (|rho|^2 I - rho rho^T)`` with ``rho = (x, y, z)``: body i's
    inertia about the system CoM. (Helpers in the loops take the arrays they need, not the
    chain: a call passes its arguments by value, and the chain is a large aggregate.)"""
    for r in range(3):
        i0 = inertias[i, r, 0]
        i1 = inertias[i, r, 1]
        i2 = inertias[i, r, 2]
        for c in range(3):
            tmp[r, c] = i0 * att[i, c, 0] + i1 * att[i, c, 1] + i2 * att[i, c, 2]
    sq = x * x + y * y + z * z
    for r in range(3):
        rr = x if r == 0 else (y if r == 1 else z)
        for c in range(3):
            rc = x if c == 0 else (y if c == 1 else z)
            T[r, c] += att[i, r, 0] * tmp[0, c] + att[i, r, 1] * tmp[1, c] + att[i, r, 2] * tmp[2, c] - m * rr * rc
        T[r, r] += m * sq


@kernel
def angular_map(ch, kin, g):
    """``Omega (3, n) = -H_s^-1 H_sq`` in the gjm buffers ``g``: the base angular velocity per
    joint rate (world axes), and the subtree sums ``tail_w``, ``tail_m`` and ``r_g`` that
    :func:`gjm` reuses."""
    att, com, jpos, jaxis, _, _ = kin
    _, _, Omega, tail_w, tail_m, r_g, scratch = g
    T = scratch[0]
    tmp = scratch[1]
    n = jaxis.shape[0]
    system_com(ch.masses, ch.total_mass, com, r_g)
    for r in range(3):
        for c in range(3):
            T[r, c] = 0.0
    w0 = 0.0
    w1 = 0.0
    w2 = 0.0
    mt = 0.0
    for j in range(n - 1, -1, -1):
        i = j + 1
        x = com[i, 0] - r_g[0]
        y = com[i, 1] - r_g[1]
        z = com[i, 2] - r_g[2]
        _add_body(ch.inertias, ch.masses[i], i, att, x, y, z, T, tmp)
        m = ch.masses[i]
        w0 += m * x
        w1 += m * y
        w2 += m * z
        mt += m
        tail_w[j, 0] = w0
        tail_w[j, 1] = w1
        tail_w[j, 2] = w2
        tail_m[j] = mt
        k0 = jaxis[j, 0]
        k1 = jaxis[j, 1]
        k2 = jaxis[j, 2]
        c0 = jpos[j, 0] - r_g[0]
        c1 = jpos[j, 1] - r_g[1]
        c2 = jpos[j, 2] - r_g[2]
        kc0 = k1 * c2 - k2 * c1
        kc1 = k2 * c0 - k0 * c2
        kc2 = k0 * c1 - k1 * c0
        # H_sq column j = T k - W x (k x c) (revolute), W x k (prismatic)
        Omega[0, j] = T[0, 0] * k0 + T[0, 1] * k1 + T[0, 2] * k2 - (w1 * kc2 - w2 * kc1)
        Omega[1, j] = T[1, 0] * k0 + T[1, 1] * k1 + T[1, 2] * k2 - (w2 * kc0 - w0 * kc2)
        Omega[2, j] = T[2, 0] * k0 + T[2, 1] * k1 + T[2, 2] * k2 - (w0 * kc1 - w1 * kc0)
        if ch.joints[j, SLIDE] != 0.0:
            Omega[0, j] = w1 * k2 - w2 * k1
            Omega[1, j] = w2 * k0 - w0 * k2
            Omega[2, j] = w0 * k1 - w1 * k0
    _add_body(ch.inertias, ch.masses[0], np.int64(0), att, com[0, 0] - r_g[0], com[0, 1] - r_g[1], com[0, 2] - r_g[2], T, tmp)
    # Cholesky of the symmetric positive definite H_s = T, then Omega = -H_s^-1 H_sq.
    l00 = np.sqrt(T[0, 0])
    l10 = T[1, 0] / l00
    l20 = T[2, 0] / l00
    l11 = np.sqrt(T[1, 1] - l10 * l10)
    l21 = (T[2, 1] - l20 * l10) / l11
    l22 = np.sqrt(T[2, 2] - l20 * l20 - l21 * l21)
    for j in range(n):
        y0 = Omega[0, j] / l00
        y1 = (Omega[1, j] - l10 * y0) / l11
        y2 = (Omega[2, j] - l20 * y0 - l21 * y1) / l22
        x2 = y2 / l22
        x1 = (y1 - l21 * x2) / l11
        x0 = (y0 - l10 * x1 - l20 * x2) / l00
        Omega[0, j] = -x0
        Omega[1, j] = -x1
        Omega[2, j] = -x2


@kernel
def gjm(ch, kin, g):
    """The GJM ``J (6, n)`` and the base twist map ``base_map (6, n)`` (world axes) of the
    configuration in ``kin``, into the gjm buffers ``g``."""
    angular_map(ch, kin, g)
    _, com, jpos, jaxis, ee_p, _ = kin
    J, bm, Omega, tail_w, tail_m, r_g, _ = g
    n = jaxis.shape[0]
    inv_m = 1.0 / ch.total_mass
    rho0 = com[0, 0] - r_g[0]
    rho1 = com[0, 1] - r_g[1]
    rho2 = com[0, 2] - r_g[2]
    pe0 = ee_p[0] - com[0, 0]
    pe1 = ee_p[1] - com[0, 1]
    pe2 = ee_p[2] - com[0, 2]
    for j in range(n):
        k0 = jaxis[j, 0]
        k1 = jaxis[j, 1]
        k2 = jaxis[j, 2]
        mu = tail_m[j] * inv_m
        h0 = mu * (jpos[j, 0] - r_g[0]) - tail_w[j, 0] * inv_m
        h1 = mu * (jpos[j, 1] - r_g[1]) - tail_w[j, 1] * inv_m
        h2 = mu * (jpos[j, 2] - r_g[2]) - tail_w[j, 2] * inv_m
        e0 = ee_p[0] - jpos[j, 0]
        e1 = ee_p[1] - jpos[j, 1]
        e2 = ee_p[2] - jpos[j, 2]
        o0 = Omega[0, j]
        o1 = Omega[1, j]
        o2 = Omega[2, j]
        v0 = (k1 * h2 - k2 * h1) + (o1 * rho2 - o2 * rho1)
        v1 = (k2 * h0 - k0 * h2) + (o2 * rho0 - o0 * rho2)
        v2 = (k0 * h1 - k1 * h0) + (o0 * rho1 - o1 * rho0)
        J[0, j] = v0 + (k1 * e2 - k2 * e1) + (o1 * pe2 - o2 * pe1)
        J[1, j] = v1 + (k2 * e0 - k0 * e2) + (o2 * pe0 - o0 * pe2)
        J[2, j] = v2 + (k0 * e1 - k1 * e0) + (o0 * pe1 - o1 * pe0)
        J[3, j] = k0 + o0
        J[4, j] = k1 + o1
        J[5, j] = k2 + o2
        if ch.joints[j, SLIDE] != 0.0:  # the joint slides its bodies along k: -mu k and k instead of k x h and k x e
            v0 = (o1 * rho2 - o2 * rho1) - mu * k0
            v1 = (o2 * rho0 - o0 * rho2) - mu * k1
            v2 = (o0 * rho1 - o1 * rho0) - mu * k2
            J[0, j] = v0 + k0 + (o1 * pe2 - o2 * pe1)
            J[1, j] = v1 + k1 + (o2 * pe0 - o0 * pe2)
            J[2, j] = v2 + k2 + (o0 * pe1 - o1 * pe0)
            J[3, j] = o0
            J[4, j] = o1
            J[5, j] = o2
        bm[0, j] = v0
        bm[1, j] = v1
        bm[2, j] = v2
        bm[3, j] = o0
        bm[4, j] = o1
        bm[5, j] = o2


@kernel
def kinematics_many(ch, q, A0, origin, about_com, att, com, jpos, jaxis, ee_p, ee_A):
    """:func:`kinematics` over a batch: ``q (B, n)``, ``A0 (B, 3, 3)``, ``origin (B, 3)``;
    outputs batch-first."""
    for b in range(q.shape[0]):
        kinematics(ch, q[b], A0[b], origin[b], about_com, (att[b], com[b], jpos[b], jaxis[b], ee_p[b], ee_A[b]))


@kernel
def gjm_many(ch, q, A0, origin, about_com, J, base_map):
    """GJM ``J (B, 6, n)`` and base map ``(B, 6, n)`` of a batch of configurations."""
    n = q.shape[1]
    kin = kinematics_buffers(n)
    g = gjm_buffers(n)
    for b in range(q.shape[0]):
        kinematics(ch, q[b], A0[b], origin[b], about_com, kin)
        gjm(ch, kin, g)
        for r in range(6):
            for j in range(n):
                J[b, r, j] = g[0][r, j]
                base_map[b, r, j] = g[1][r, j]

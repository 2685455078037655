"""Free-floating inverse dynamics of the chain (recursive Newton-Euler with a floating base,
Featherstone, Rigid Body Dynamics Algorithms, 2008, sec. 9.3), one configuration at a time.

No gravity and no external wrench: the base moves only by reaction. Given the joint positions
(through the kinematics buffers of :func:`engine.kernels.chain.kinematics`), rates ``qd``,
accelerations ``qdd`` and the base twist ``[v_0; w_0]`` (which zero momentum fixes: the GJM's
base map times ``qd``, or step 0 below), the routine finds the base acceleration, the joint
torques (forces for prismatic joints) and the wrench the arm exerts on the carrier at joint 1.

Spatial vectors are in one frame: the axes of the kinematics buffers (world axes, or the base
frame in the planner's loop) with the reference point ``O`` at the system CoM ``r_g`` (all
positions below are relative to it, ``rho_i = r_i - r_g``), so the composite inertia of the
whole system is block diagonal, ``diag(H_g, M 1)``. A motion vector is ``(w, u)``, ``u`` the
velocity of the body point passing through ``O``; a force vector ``(n, f)``, ``n`` the moment
about ``O``.

0. (Optional) The base twist from zero momentum, in the same recursion: the bodies' velocities
   with the base at rest, ``V_i = V_{i-1} + S_i qd_i``, give the momentum ``h = sum_i I_i V_i``,
   and ``diag(H_g, M 1) V_0 = -h`` (a 3x3 Cholesky solve and a division), the velocity-level
   twin of step 2. It is the GJM's ``base_map @ qd`` without forming the 6 x n map: the
   executed trajectory's dynamics, which need only the twist, spent 0.65 of their 1.57 µs a
   sample on the GJM.
1. Forward pass with the base acceleration set to zero: body velocities ``V_i = V_{i-1} + S_i
   qd_i`` and bias accelerations ``A_i = A_{i-1} + S_i qdd_i + V_i x S_i qd_i``, with the joint
   motion ``S = (k, (p - r_g) x k)`` (revolute about the axis ``k`` through ``p``) or ``(0, k)``
   (prismatic), and the bias forces ``f_i = I_i A_i + V_i x* I_i V_i`` (the rate of change of
   each body's momentum), the base's included.
2. The base acceleration ``A_0`` makes the total rate of change of momentum zero:
   ``diag(H_g, M) A_0 = -sum_i f_i``, a 3x3 Cholesky solve and a division.
3. Backward pass: the force transmitted by joint j is the subtree sum ``F_j = sum_{i >= j}
   (f_i + I_i A_0)``, its torque ``tau_j = S_j . F_j``; the carrier receives ``-F_1``.

``I_i A = (Ibar_i a + m_i rho_i x c, m_i c)`` with ``c = u + a x rho_i`` for ``A = (a, u)``, and
``I_i V = (Ibar_i w + m_i rho_i x v_i, m_i v_i)`` with the CoM velocity ``v_i = u + w x rho_i``
(``Ibar_i = A_i I_i A_i^T``, the inertia about the CoM in the buffers' axes).

Cost: O(n) per configuration, about the kinematics it needs (no allocation: the caller passes
:func:`dynamics_buffers`).
"""

from __future__ import annotations

import numpy as np

from engine.kernels.chain import EFFORT, SLIDE, fastest_joints, kinematics, kinematics_buffers, system_com
from engine.kernels.jit import kernel
from engine.kernels.linalg import solve3_spd
from engine.kernels.spline import clamped_spline

# dynamics buffers: (Iw (n+1, 3, 3) world inertias about the CoMs; vel (n+1, 6) body velocities
#                    (w, u); acc (n+1, 6) bias accelerations; force (n+1, 6) bias forces (n, f);
#                    H (3, 3) H_g; vec (3, 3): r_g, rho, the total bias force's moment)


@kernel
def dynamics_buffers(n):
    """Scratch for :func:`inverse_dynamics` of an ``n``-joint chain."""
    return (
        np.empty((n + 1, 3, 3)),
        np.empty((n + 1, 6)),
        np.empty((n + 1, 6)),
        np.empty((n + 1, 6)),
        np.empty((3, 3)),
        np.empty((3, 3)),
    )


@kernel
def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@kernel
def _joint_motion(jaxis, jpos, r_g, slide, j):
    """Joint j's motion subspace ``(k, (p_j - r_g) x k)`` (revolute) or ``(0, k)`` (prismatic)."""
    k0 = jaxis[j, 0]
    k1 = jaxis[j, 1]
    k2 = jaxis[j, 2]
    if slide != 0.0:
        return 0.0, 0.0, 0.0, k0, k1, k2
    u0, u1, u2 = _cross(jpos[j, 0] - r_g[0], jpos[j, 1] - r_g[1], jpos[j, 2] - r_g[2], k0, k1, k2)
    return k0, k1, k2, u0, u1, u2


@kernel
def _inertia_times(Iw, m, i, rho, x):
    """``I_i x`` for a motion vector ``x (6,)`` = ``(a, u)``: ``(Ibar a + m rho x c, m c)`` with
    ``c = u + a x rho``."""
    a0 = x[0]
    a1 = x[1]
    a2 = x[2]
    d0, d1, d2 = _cross(a0, a1, a2, rho[0], rho[1], rho[2])
    c0 = x[3] + d0
    c1 = x[4] + d1
    c2 = x[5] + d2
    e0, e1, e2 = _cross(rho[0], rho[1], rho[2], c0, c1, c2)
    n0 = Iw[i, 0, 0] * a0 + Iw[i, 0, 1] * a1 + Iw[i, 0, 2] * a2 + m * e0
    n1 = Iw[i, 1, 0] * a0 + Iw[i, 1, 1] * a1 + Iw[i, 1, 2] * a2 + m * e1
    n2 = Iw[i, 2, 0] * a0 + Iw[i, 2, 1] * a1 + Iw[i, 2, 2] * a2 + m * e2
    return n0, n1, n2, m * c0, m * c1, m * c2


@kernel
def _zero_momentum_twist(ch, com, jpos, jaxis, qd, Iw, H, vel, vec, twist):
    """Step 0: the base twist ``[v_0; w_0]`` at which the momentum about the system CoM is zero.
    With the base at rest the joints give the bodies the velocities ``V_i = V_{i-1} + S_i qd_i``
    (``vel``, overwritten) and the momentum ``h = sum_i I_i V_i``; moving the base by ``V_0``
    adds ``diag(H_g, M 1) V_0`` (the composite inertia about the system CoM), so ``H_g w_0 =
    -h_n`` and ``M u_0 = -h_f``, and the base CoM moves at ``v_0 = u_0 + w_0 x rho_0``. ``H``,
    ``Iw`` and ``vec[0]`` (``r_g``) as :func:`inverse_dynamics` has them; ``vec[1:]`` scratch."""
    n = qd.shape[0]
    r_g = vec[0]
    rho = vec[1]
    h = vec[2]
    h0 = h1 = h2 = h3 = h4 = h5 = 0.0
    for r in range(6):
        vel[0, r] = 0.0
    for i in range(1, n + 1):
        j = i - 1
        s0, s1, s2, s3, s4, s5 = _joint_motion(jaxis, jpos, r_g, ch.joints[j, SLIDE], j)
        vel[i, 0] = vel[j, 0] + s0 * qd[j]
        vel[i, 1] = vel[j, 1] + s1 * qd[j]
        vel[i, 2] = vel[j, 2] + s2 * qd[j]
        vel[i, 3] = vel[j, 3] + s3 * qd[j]
        vel[i, 4] = vel[j, 4] + s4 * qd[j]
        vel[i, 5] = vel[j, 5] + s5 * qd[j]
        for r in range(3):
            rho[r] = com[i, r] - r_g[r]
        L0, L1, L2, P0, P1, P2 = _inertia_times(Iw, ch.masses[i], i, rho, vel[i])
        h0 += L0
        h1 += L1
        h2 += L2
        h3 += P0
        h4 += P1
        h5 += P2
    h[0] = -h0
    h[1] = -h1
    h[2] = -h2
    w = twist[3:]
    solve3_spd(H, h, w)
    for r in range(3):
        rho[r] = com[0, r] - r_g[r]
    d0, d1, d2 = _cross(w[0], w[1], w[2], rho[0], rho[1], rho[2])
    M = ch.total_mass
    twist[0] = -h3 / M + d0
    twist[1] = -h4 / M + d1
    twist[2] = -h5 / M + d2


@kernel
def inverse_dynamics(ch, kin, twist, qd, qdd, work, tau, force, torque, base_acc, zero_momentum):
    """Free-floating inverse dynamics of one configuration (see the module docstring).

    ``kin``: the kinematics buffers of the configuration (any axes and origin; ``att[0]`` is the
    carrier's attitude in them); ``twist (6,)``: the base twist ``[v_0; w_0]`` (base CoM velocity
    m/s, angular velocity rad/s, in the buffers' axes); with ``zero_momentum`` (a numpy bool, so
    that one compilation serves both) an output instead: the twist at which the system's
    momentum is zero, the GJM's ``base_map @ qd`` (:func:`engine.kernels.chain.gjm`) found in the
    recursion (step 0 of the module docstring) without the 6 x n map; ``qd``, ``qdd (n,)``: joint
    rates and accelerations (rad/s, rad/s^2; m/s, m/s^2 for prismatic joints); ``work``:
    :func:`dynamics_buffers`.

    Writes ``tau (n,)`` joint torques (N m; N for prismatic joints), ``force (3,)`` N and
    ``torque (3,)`` N m: the wrench the arm exerts on the carrier, about joint 1's origin, in the
    carrier frame, and ``base_acc (6,)`` ``[dv_0/dt; dw_0/dt]`` (base CoM acceleration m/s^2 and
    angular acceleration rad/s^2, in the buffers' axes). Returns False if the configuration is
    not finite (``H_g`` has no Cholesky factor; the outputs are then not written)."""
    att, com, jpos, jaxis, _, _ = kin
    Iw, vel, acc, frc, H, vec = work
    n = qd.shape[0]
    M = ch.total_mass
    r_g = vec[0]
    rho = vec[1]
    system_com(ch.masses, M, com, r_g)
    for r in range(3):
        for c in range(3):
            H[r, c] = 0.0
    for i in range(n + 1):
        m = ch.masses[i]
        for r in range(3):
            rho[r] = com[i, r] - r_g[r]
        # Ibar_i = A_i I_i A_i^T, and H_g += Ibar_i + m (|rho|^2 1 - rho rho^T).
        for r in range(3):
            t0 = ch.inertias[i, 0, 0] * att[i, r, 0] + ch.inertias[i, 0, 1] * att[i, r, 1] + ch.inertias[i, 0, 2] * att[i, r, 2]
            t1 = ch.inertias[i, 1, 0] * att[i, r, 0] + ch.inertias[i, 1, 1] * att[i, r, 1] + ch.inertias[i, 1, 2] * att[i, r, 2]
            t2 = ch.inertias[i, 2, 0] * att[i, r, 0] + ch.inertias[i, 2, 1] * att[i, r, 1] + ch.inertias[i, 2, 2] * att[i, r, 2]
            for c in range(r, 3):
                value = att[i, c, 0] * t0 + att[i, c, 1] * t1 + att[i, c, 2] * t2
                Iw[i, r, c] = value
                Iw[i, c, r] = value
        sq = rho[0] * rho[0] + rho[1] * rho[1] + rho[2] * rho[2]
        for r in range(3):
            for c in range(3):
                H[r, c] += Iw[i, r, c] - m * rho[r] * rho[c]
            H[r, r] += m * sq
    if not (H[0, 0] > 0.0 and H[1, 1] > 0.0 and H[2, 2] > 0.0):
        return False
    if zero_momentum:
        _zero_momentum_twist(ch, com, jpos, jaxis, qd, Iw, H, vel, vec, twist)
    # Forward pass: velocities, bias accelerations (base acceleration zero) and bias forces.
    for i in range(n + 1):
        m = ch.masses[i]
        for r in range(3):
            rho[r] = com[i, r] - r_g[r]
        if i == 0:
            w0 = twist[3]
            w1 = twist[4]
            w2 = twist[5]
            # u: the velocity of the body point at O, v_0 + w_0 x (r_g - r_0)
            d0, d1, d2 = _cross(w0, w1, w2, rho[0], rho[1], rho[2])
            u0 = twist[0] - d0
            u1 = twist[1] - d1
            u2 = twist[2] - d2
            a0 = a1 = a2 = 0.0
            b0 = b1 = b2 = 0.0
        else:
            j = i - 1
            s0, s1, s2, s3, s4, s5 = _joint_motion(jaxis, jpos, r_g, ch.joints[j, SLIDE], j)
            w0 = vel[j, 0] + s0 * qd[j]
            w1 = vel[j, 1] + s1 * qd[j]
            w2 = vel[j, 2] + s2 * qd[j]
            u0 = vel[j, 3] + s3 * qd[j]
            u1 = vel[j, 4] + s4 * qd[j]
            u2 = vel[j, 5] + s5 * qd[j]
            # V_i x S qd = (w x s_w, w x s_u + u x s_w) qd
            c0, c1, c2 = _cross(w0, w1, w2, s0, s1, s2)
            a0 = acc[j, 0] + s0 * qdd[j] + c0 * qd[j]
            a1 = acc[j, 1] + s1 * qdd[j] + c1 * qd[j]
            a2 = acc[j, 2] + s2 * qdd[j] + c2 * qd[j]
            c0, c1, c2 = _cross(w0, w1, w2, s3, s4, s5)
            e0, e1, e2 = _cross(u0, u1, u2, s0, s1, s2)
            b0 = acc[j, 3] + s3 * qdd[j] + (c0 + e0) * qd[j]
            b1 = acc[j, 4] + s4 * qdd[j] + (c1 + e1) * qd[j]
            b2 = acc[j, 5] + s5 * qdd[j] + (c2 + e2) * qd[j]
        vel[i, 0] = w0
        vel[i, 1] = w1
        vel[i, 2] = w2
        vel[i, 3] = u0
        vel[i, 4] = u1
        vel[i, 5] = u2
        acc[i, 0] = a0
        acc[i, 1] = a1
        acc[i, 2] = a2
        acc[i, 3] = b0
        acc[i, 4] = b1
        acc[i, 5] = b2
        # f_i = I_i A_i + V_i x* (L, P), the momentum (L, P) = I_i V_i; x* is
        # (w, u) x* (n, f) = (w x n + u x f, w x f).
        f0, f1, f2, f3, f4, f5 = _inertia_times(Iw, m, i, rho, acc[i])
        L0, L1, L2, P0, P1, P2 = _inertia_times(Iw, m, i, rho, vel[i])
        c0, c1, c2 = _cross(w0, w1, w2, L0, L1, L2)
        e0, e1, e2 = _cross(u0, u1, u2, P0, P1, P2)
        d0, d1, d2 = _cross(w0, w1, w2, P0, P1, P2)
        frc[i, 0] = f0 + c0 + e0
        frc[i, 1] = f1 + c1 + e1
        frc[i, 2] = f2 + c2 + e2
        frc[i, 3] = f3 + d0
        frc[i, 4] = f4 + d1
        frc[i, 5] = f5 + d2
    # The base acceleration: diag(H_g, M) A_0 = -sum_i f_i.
    total = vec[2]
    lin0 = lin1 = lin2 = 0.0
    for r in range(3):
        s = 0.0
        for i in range(n + 1):
            s += frc[i, r]
        total[r] = -s
    for i in range(n + 1):
        lin0 -= frc[i, 3]
        lin1 -= frc[i, 4]
        lin2 -= frc[i, 5]
    acc0 = acc[0]  # the base's bias acceleration is zero: its row now holds A_0
    solve3_spd(H, total, acc0[:3])
    acc0[3] = lin0 / M
    acc0[4] = lin1 / M
    acc0[5] = lin2 / M
    # Backward pass: subtree sums of f_i + I_i A_0 give the joint forces.
    F0 = F1 = F2 = F3 = F4 = F5 = 0.0
    for i in range(n, 0, -1):
        for r in range(3):
            rho[r] = com[i, r] - r_g[r]
        g0, g1, g2, g3, g4, g5 = _inertia_times(Iw, ch.masses[i], i, rho, acc0)
        F0 += frc[i, 0] + g0
        F1 += frc[i, 1] + g1
        F2 += frc[i, 2] + g2
        F3 += frc[i, 3] + g3
        F4 += frc[i, 4] + g4
        F5 += frc[i, 5] + g5
        j = i - 1
        s0, s1, s2, s3, s4, s5 = _joint_motion(jaxis, jpos, r_g, ch.joints[j, SLIDE], j)
        tau[j] = s0 * F0 + s1 * F1 + s2 * F2 + s3 * F3 + s4 * F4 + s5 * F5
    # The carrier receives -F_1: its moment about joint 1 is -(n_O - (p_1 - r_g) x f).
    d0, d1, d2 = _cross(jpos[0, 0] - r_g[0], jpos[0, 1] - r_g[1], jpos[0, 2] - r_g[2], F3, F4, F5)
    n0 = d0 - F0
    n1 = d1 - F1
    n2 = d2 - F2
    for r in range(3):
        force[r] = -(att[0, 0, r] * F3 + att[0, 1, r] * F4 + att[0, 2, r] * F5)
        torque[r] = att[0, 0, r] * n0 + att[0, 1, r] * n1 + att[0, 2, r] * n2
    # The base CoM's acceleration from the spatial one: dv_0/dt = u' + a x rho_0 + w_0 x v_0.
    for r in range(3):
        rho[r] = com[0, r] - r_g[r]
    d0, d1, d2 = _cross(acc0[0], acc0[1], acc0[2], rho[0], rho[1], rho[2])
    e0, e1, e2 = _cross(twist[3], twist[4], twist[5], twist[0], twist[1], twist[2])
    base_acc[0] = acc0[3] + d0 + e0
    base_acc[1] = acc0[4] + d1 + e1
    base_acc[2] = acc0[5] + d2 + e2
    base_acc[3] = acc0[0]
    base_acc[4] = acc0[1]
    base_acc[5] = acc0[2]
    return True


@kernel
def inverse_dynamics_many(ch, q, qd, qdd, A0, origin, tau, force, torque, base_twist, base_acc):
    """:func:`inverse_dynamics` over samples: ``q``, ``qd``, ``qdd (N+1, n)``, base attitudes
    ``A0 (N+1, 3, 3)`` and base CoM positions ``origin (N+1, 3)`` m; the base twist of each
    sample from zero momentum. Writes ``tau (N+1, n)``, ``force``,
    ``torque (N+1, 3)`` (carrier frame), ``base_twist`` and ``base_acc (N+1, 6)`` (world axes).
    Returns the number of samples whose configuration was not finite (their rows are NaN)."""
    n = q.shape[1]
    kin = kinematics_buffers(n)
    work = dynamics_buffers(n)
    bad = 0
    for k in range(q.shape[0]):
        kinematics(ch, q[k], A0[k], origin[k], np.bool_(False), kin)
        if not inverse_dynamics(
            ch, kin, base_twist[k], qd[k], qdd[k], work, tau[k], force[k], torque[k], base_acc[k], np.bool_(True)
        ):
            bad += 1
            tau[k] = np.nan
            force[k] = np.nan
            torque[k] = np.nan
            base_twist[k] = np.nan
            base_acc[k] = np.nan
    return bad


@kernel
def trajectory_buffers(samples, n, rows):
    """Scratch and outputs of :func:`trajectory_dynamics` for ``samples`` samples of an
    ``n``-joint plan: ``(t (S,), q (S, n), qd (S, n), qdd (S, n), tau (R, n), force (R, 3), torque
    (R, 3))`` with ``R = rows`` (``samples`` to keep every sample, 1 for the peaks only)."""
    return (
        np.empty(samples),
        np.empty((samples, n)),
        np.empty((samples, n)),
        np.empty((samples, n)),
        np.empty((rows, n)),
        np.empty((rows, 3)),
        np.empty((rows, 3)),
    )


@kernel
def trajectory_dynamics(ch, dt, count, end_rate, work, record):
    """The inverse dynamics along a plan's executed trajectory (:mod:`engine.executed`): the
    clamped cubic spline through its first ``count`` joint samples ``work[1][:count] (count, n)``
    (``t_k = k dt``; from rest, to the plan's last commanded rate ``end_rate (n,)``), then the
    floating-base RNEA at every sample (the base twist from zero momentum; no gravity, so the
    configuration is taken with the base at the origin and unturned: torques and the mount
    wrench in the carrier frame do not depend on where the system is).

    ``work``: :func:`trajectory_buffers`. Writes the spline's knot rates and accelerations into
    ``work[2]``, ``work[3]``, and the torques (N m; N for prismatic joints) and mount wrench
    (what the arm exerts on the carrier at joint 1, carrier frame) into row ``k`` of ``work[4:]``
    with ``record``, else into row 0 (peaks only).

    Returns ``(ok, peak_revolute, its_joint, peak_prismatic, its_joint, over_joint, over_time,
    over_peak)``: the largest ``|torque|`` of a revolute joint (N m) and ``|force|`` of a
    prismatic one (N) with 0-based joints (-1: none), the joint furthest over its effort limit
    (``ch.joints[:, EFFORT]``) at the first sample where one is over (-1: none), that sample's
    time (s) and that joint's largest effort; ``ok`` false if a configuration was not finite (its efforts count as infinite).
    """
    t, q, qd, qdd, tau, force, torque = work
    n = q.shape[1]
    for k in range(count):
        t[k] = k * dt
    start = np.zeros(n)
    clamped_spline(t[:count], q[:count], start, end_rate, qd[:count], qdd[:count])
    kin = kinematics_buffers(n)
    dyn = dynamics_buffers(n)
    eye = np.eye(3)
    origin = np.zeros(3)
    twist = np.empty(6)
    base_acc = np.empty(6)
    peak = np.zeros(n)
    ok = True
    over_joint = -1
    over_time = np.nan
    for k in range(count):
        row = k if record else 0
        kinematics(ch, q[k], eye, origin, np.bool_(False), kin)
        if not inverse_dynamics(ch, kin, twist, qd[k], qdd[k], dyn, tau[row], force[row], torque[row], base_acc, np.bool_(True)):
            ok = False
            for j in range(n):
                tau[row, j] = np.nan
            for r in range(3):
                force[row, r] = np.nan
                torque[row, r] = np.nan
        worst = 1.0
        for j in range(n):
            effort = abs(tau[row, j])
            if not effort <= peak[j]:  # NaN counts as exceeding
                peak[j] = effort if np.isfinite(effort) else np.inf
            limit = ch.joints[j, EFFORT]
            if over_time != over_time and limit < np.inf and not effort <= worst * limit:
                worst = effort / limit if effort == effort else np.inf
                over_joint = j  # the joint furthest over its limit at the first sample where one is
        if over_joint >= 0 and over_time != over_time:
            over_time = t[k]
    best, best_lin = fastest_joints(ch.joints, peak)
    return (
        ok,
        peak[best] if best >= 0 else 0.0,
        best,
        peak[best_lin] if best_lin >= 0 else 0.0,
        best_lin,
        over_joint,
        over_time,
        peak[over_joint] if over_joint >= 0 else np.nan,
    )

"""The replay's compiled right-hand side and integrator.

Independent of the planner's formulation: the base twist comes from the textbook 6x6 momentum
equations ``H_b [v_0; w_0] + H_bm qd = 0`` (Umetani and Yoshida 1989) summed body by body, with
momenta about the base CoM, and is integrated as a state (the base position too, so the drift
of the system CoM is a check, not an assumption). The base attitude is a unit quaternion with
``dq/dt = 1/2 [0, w] (x) q`` (world-frame ``w``). Only the forward kinematics are shared with
the planner (they are checked against Pinocchio on their own).

The integrator is Dormand and Prince's DOP853 (Hairer, Norsett and Wanner, Solving ODEs I,
II.10) with the coefficients and the step-size control of ``scipy.integrate.solve_ivp``
(``method="DOP853"``), run on each plan step separately (the joint rates jump at the samples).
The joint motion is an input, a polynomial per step: linear for a plan
(:func:`integrate`), the executed cubic spline for :mod:`engine.executed`
(:func:`integrate_motion`).
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Any

import numpy as np

from engine.kernels.chain import SLIDE, kinematics, kinematics_buffers
from engine.kernels.jit import kernel
from engine.kernels.linalg import solve6
from engine.kernels.so3 import quaternion_to_matrix


def _dop853_coefficients() -> object:
    """scipy's DOP853 tableau (``scipy/integrate/_ivp/dop853_coefficients.py``), loaded from its
    file alone: importing it as ``scipy.integrate._ivp...`` runs ``scipy.integrate``'s package
    import, 0.3 s of every process's start, for a table of numbers."""
    scipy_spec = importlib.util.find_spec("scipy")
    assert scipy_spec is not None and scipy_spec.origin is not None, "scipy is a dependency"
    path = Path(scipy_spec.origin).parent / "integrate" / "_ivp" / "dop853_coefficients.py"
    spec = importlib.util.spec_from_file_location("spacearm_dop853_coefficients", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


_dop: Any = _dop853_coefficients()
N_STAGES = _dop.N_STAGES
A = np.ascontiguousarray(_dop.A[:N_STAGES, :N_STAGES])
B = np.ascontiguousarray(_dop.B)
C = np.ascontiguousarray(_dop.C[:N_STAGES])
E3 = np.ascontiguousarray(_dop.E3)
E5 = np.ascontiguousarray(_dop.E5)
SAFETY = 0.9
MIN_FACTOR = 0.2
MAX_FACTOR = 10.0
ERROR_EXPONENT = -1.0 / 8.0  # the error estimator is of order 7
MAX_STEPS_PER_INTERVAL = 100_000

OK, STEP_TOO_SMALL, TOO_MANY_STEPS, SINGULAR = 0, 1, 2, 3


@kernel
def _joint_motion(ch, kin, qd, v_j, w_j):
    """Velocities of each body's CoM ``v_j (n+1, 3)`` and angular velocities ``w_j (n+1, 3)``
    from the joint rates alone (base held still): joint j moves bodies j+1..n, a revolute one
    turning them about its axis, ``sum_j qd_j k_j x (r_i - p_j)``, a prismatic one sliding them
    along it, ``sum_j qd_j k_j``. Running sums over the joints (positions relative to the base
    CoM): ``w_i = sum qd_j k_j``, ``v_i = w_i x (r_i - r_0) - sum qd_j k_j x (p_j - r_0) +
    sum qd_j k_j`` (the last sum over prismatic joints, the others over revolute ones)."""
    _, com, jpos, jaxis, _, _ = kin
    n = qd.shape[0]
    w0 = 0.0
    w1 = 0.0
    w2 = 0.0
    c0 = 0.0
    c1 = 0.0
    c2 = 0.0
    l0 = 0.0
    l1 = 0.0
    l2 = 0.0
    for r in range(3):
        v_j[0, r] = 0.0
        w_j[0, r] = 0.0
    for i in range(1, n + 1):
        j = i - 1
        k0 = jaxis[j, 0]
        k1 = jaxis[j, 1]
        k2 = jaxis[j, 2]
        h = qd[j] * ch.joints[j, SLIDE]  # the sliding rate (0 for a revolute joint)
        g = qd[j] - h  # the turning rate (0 for a prismatic joint)
        p0 = jpos[j, 0] - com[0, 0]
        p1 = jpos[j, 1] - com[0, 1]
        p2 = jpos[j, 2] - com[0, 2]
        w0 += g * k0
        w1 += g * k1
        w2 += g * k2
        c0 += g * (k1 * p2 - k2 * p1)
        c1 += g * (k2 * p0 - k0 * p2)
        c2 += g * (k0 * p1 - k1 * p0)
        l0 += h * k0
        l1 += h * k1
        l2 += h * k2
        d0 = com[i, 0] - com[0, 0]
        d1 = com[i, 1] - com[0, 1]
        d2 = com[i, 2] - com[0, 2]
        v_j[i, 0] = (w1 * d2 - w2 * d1) - c0 + l0
        v_j[i, 1] = (w2 * d0 - w0 * d2) - c1 + l1
        v_j[i, 2] = (w0 * d1 - w1 * d0) - c2 + l2
        w_j[i, 0] = w0
        w_j[i, 1] = w1
        w_j[i, 2] = w2


@kernel
def _world_inertia(inertias, i, A, out, tmp):
    """``out = A I_i A^T`` (``tmp (3, 3)`` scratch)."""
    inertia = inertias[i]
    for r in range(3):
        for c in range(3):
            tmp[r, c] = inertia[r, 0] * A[c, 0] + inertia[r, 1] * A[c, 1] + inertia[r, 2] * A[c, 2]
    for r in range(3):
        for c in range(3):
            out[r, c] = A[r, 0] * tmp[0, c] + A[r, 1] * tmp[1, c] + A[r, 2] * tmp[2, c]


@kernel
def base_twist(ch, kin, qd, v_j, w_j, twist):
    """Base twist ``[v_0; w_0] (6,)`` with zero total momentum: ``H_b x = -H_bm qd``, both
    summed body by body (momenta about the base CoM). Returns False if ``H_b`` is singular."""
    att, com, _, _, _, _ = kin
    n = qd.shape[0]
    _joint_motion(ch, kin, qd, v_j, w_j)
    H = np.zeros((6, 6))
    rhs = np.zeros(6)
    Iw = np.empty((3, 3))
    tmp = np.empty((3, 3))
    for i in range(n + 1):
        m = ch.masses[i]
        x = com[i, 0] - com[0, 0]
        y = com[i, 1] - com[0, 1]
        z = com[i, 2] - com[0, 2]
        _world_inertia(ch.inertias, i, att[i], Iw, tmp)
        # linear momentum: m (v_0 + w_0 x rel + v_j) = m v_0 - m [rel]x w_0 + m v_j
        H[0, 0] += m
        H[1, 1] += m
        H[2, 2] += m
        H[0, 4] += m * z
        H[0, 5] -= m * y
        H[1, 3] -= m * z
        H[1, 5] += m * x
        H[2, 3] += m * y
        H[2, 4] -= m * x
        # angular momentum about the base CoM: I_w w + m rel x v
        H[3, 1] -= m * z
        H[3, 2] += m * y
        H[4, 0] += m * z
        H[4, 2] -= m * x
        H[5, 0] -= m * y
        H[5, 1] += m * x
        sq = x * x + y * y + z * z
        rel = (x, y, z)
        for r in range(3):
            for c in range(3):
                H[3 + r, 3 + c] += Iw[r, c] - m * rel[r] * rel[c]
            H[3 + r, 3 + r] += m * sq
        vx = v_j[i, 0]
        vy = v_j[i, 1]
        vz = v_j[i, 2]
        rhs[0] -= m * vx
        rhs[1] -= m * vy
        rhs[2] -= m * vz
        rhs[3] -= Iw[0, 0] * w_j[i, 0] + Iw[0, 1] * w_j[i, 1] + Iw[0, 2] * w_j[i, 2] + m * (y * vz - z * vy)
        rhs[4] -= Iw[1, 0] * w_j[i, 0] + Iw[1, 1] * w_j[i, 1] + Iw[1, 2] * w_j[i, 2] + m * (z * vx - x * vz)
        rhs[5] -= Iw[2, 0] * w_j[i, 0] + Iw[2, 1] * w_j[i, 1] + Iw[2, 2] * w_j[i, 2] + m * (x * vy - y * vx)
    return solve6(H, rhs, twist)


@kernel
def _rhs(ch, coef_k, t_k, t, y, dy, work):
    """``dy/dt`` of the replay state ``y = [r_0 (3); quaternion (4)]`` at time ``t`` inside the
    step that starts at ``t_k``, where the joints follow the polynomial ``q(t_k + s) = sum_p
    coef_k[p] s^p`` (``coef_k (P, n)``; P = 2 for the plan's linear motion)."""
    kin, q, qd, A0, v_j, w_j, twist = work
    s = t - t_k
    P = coef_k.shape[0]
    for j in range(q.shape[0]):
        pos = coef_k[P - 1, j]
        rate = (P - 1) * coef_k[P - 1, j]
        for p in range(P - 2, -1, -1):
            pos = pos * s + coef_k[p, j]
            if p > 0:
                rate = rate * s + p * coef_k[p, j]
        q[j] = pos
        qd[j] = rate
    quaternion_to_matrix(y[3:], A0)
    kinematics(ch, q, A0, y[:3], np.bool_(False), kin)
    ok = base_twist(ch, kin, qd, v_j, w_j, twist)
    w0 = twist[3]
    w1 = twist[4]
    w2 = twist[5]
    dy[0] = twist[0]
    dy[1] = twist[1]
    dy[2] = twist[2]
    dy[3] = 0.5 * (-w0 * y[4] - w1 * y[5] - w2 * y[6])
    dy[4] = 0.5 * (y[3] * w0 + w1 * y[6] - w2 * y[5])
    dy[5] = 0.5 * (y[3] * w1 + w2 * y[4] - w0 * y[6])
    dy[6] = 0.5 * (y[3] * w2 + w0 * y[5] - w1 * y[4])
    return ok


@kernel
def integrate(ch, t, q, qd, ys, rtol, atol):
    """Replay the plan ``t (N+1,)``, ``q (N+1, n)``, ``qd (N+1, n)`` (the joints move linearly,
    ``q_k + (t - t_k) qd_k``, over each step): ``ys[0]`` holds the start state, ``ys[k+1]``
    receives the state at ``t[k+1]`` (quaternion normalised). Returns ``(status, failed_step,
    n_function_evaluations)``."""
    N = t.shape[0] - 1
    coef = np.empty((N, 2, q.shape[1]))
    for k in range(N):
        for j in range(q.shape[1]):
            coef[k, 0, j] = q[k, j]
            coef[k, 1, j] = qd[k, j]
    return integrate_motion(ch, t, coef, ys, rtol, atol)


@kernel
def integrate_motion(ch, t, coef, ys, rtol, atol):
    """Integrate the base along a joint motion given piece by piece: over ``[t_k, t_{k+1}]``
    (``t (N+1,)``) the joints follow ``q(t_k + s) = sum_p coef[k, p] s^p`` (``coef (N, P, n)``).
    ``ys[0]`` holds the start state ``[r_0 (3); quaternion (4)]``, ``ys[k+1]`` receives the
    state at ``t[k+1]`` (quaternion normalised). Returns ``(status, failed_step,
    n_function_evaluations)``."""
    n = coef.shape[2]
    work = (
        kinematics_buffers(n),
        np.empty(n),
        np.empty(n),
        np.empty((3, 3)),
        np.empty((n + 1, 3)),
        np.empty((n + 1, 3)),
        np.empty(6),
    )
    dim = 7
    K = np.empty((N_STAGES + 1, dim))
    y = np.empty(dim)
    y_new = np.empty(dim)
    y_stage = np.empty(dim)
    f = np.empty(dim)
    f1 = np.empty(dim)
    scale = np.empty(dim)
    nfev = 0
    h_abs = 0.0
    for k in range(t.shape[0] - 1):
        t_k = t[k]
        t_end = t[k + 1]
        coef_k = coef[k]
        for i in range(dim):
            y[i] = ys[k, i]
        if not _rhs(ch, coef_k, t_k, t_k, y, f, work):
            return SINGULAR, k, nfev
        nfev += 1
        interval = t_end - t_k
        if k == 0 or not h_abs > 0.0:
            # Initial step (Hairer, Norsett and Wanner, II.4), as solve_ivp chooses it; later
            # steps start from the step size the previous interval ended with.
            for i in range(dim):
                scale[i] = atol + abs(y[i]) * rtol
            d0 = 0.0
            d1 = 0.0
            for i in range(dim):
                d0 += (y[i] / scale[i]) ** 2
                d1 += (f[i] / scale[i]) ** 2
            d0 = np.sqrt(d0 / dim)
            d1 = np.sqrt(d1 / dim)
            h0 = 1e-6 if (d0 < 1e-5 or d1 < 1e-5) else 0.01 * d0 / d1
            h0 = min(h0, interval)
            for i in range(dim):
                y_stage[i] = y[i] + h0 * f[i]
            _rhs(ch, coef_k, t_k, t_k + h0, y_stage, f1, work)
            nfev += 1
            d2 = 0.0
            for i in range(dim):
                d2 += ((f1[i] - f[i]) / scale[i]) ** 2
            d2 = np.sqrt(d2 / dim) / h0
            h1 = max(1e-6, h0 * 1e-3) if d1 <= 1e-15 and d2 <= 1e-15 else (0.01 / max(d1, d2)) ** (1.0 / 8.0)
            h_abs = min(100.0 * h0, h1, interval)
        tc = t_k
        steps = 0
        while tc < t_end:
            steps += 1
            if steps > MAX_STEPS_PER_INTERVAL:
                return TOO_MANY_STEPS, k, nfev
            min_step = 10.0 * abs(np.nextafter(tc, np.inf) - tc)
            if h_abs < min_step:
                h_abs = min_step
            rejected = False
            while True:
                if h_abs < min_step:
                    return STEP_TOO_SMALL, k, nfev
                t_new = tc + h_abs
                if t_new > t_end:
                    t_new = t_end
                h = t_new - tc
                h_abs = abs(h)
                # One DOP853 step.
                for i in range(dim):
                    K[0, i] = f[i]
                for s in range(1, N_STAGES):
                    for i in range(dim):
                        acc = 0.0
                        for st in range(s):
                            acc += K[st, i] * A[s, st]
                        y_stage[i] = y[i] + acc * h
                    _rhs(ch, coef_k, t_k, tc + C[s] * h, y_stage, K[s], work)
                for i in range(dim):
                    acc = 0.0
                    for st in range(N_STAGES):
                        acc += K[st, i] * B[st]
                    y_new[i] = y[i] + h * acc
                _rhs(ch, coef_k, t_k, t_new, y_new, K[N_STAGES], work)
                nfev += N_STAGES
                err5 = 0.0
                err3 = 0.0
                for i in range(dim):
                    sc = atol + max(abs(y[i]), abs(y_new[i])) * rtol
                    e5 = 0.0
                    e3 = 0.0
                    for st in range(N_STAGES + 1):
                        e5 += K[st, i] * E5[st]
                        e3 += K[st, i] * E3[st]
                    err5 += (e5 / sc) ** 2
                    err3 += (e3 / sc) ** 2
                error_norm = 0.0 if err5 == 0.0 and err3 == 0.0 else h_abs * err5 / np.sqrt((err5 + 0.01 * err3) * dim)
                if error_norm < 1.0:
                    factor = MAX_FACTOR if error_norm == 0.0 else min(MAX_FACTOR, SAFETY * error_norm**ERROR_EXPONENT)
                    if rejected:
                        factor = min(1.0, factor)
                    h_abs *= factor
                    break
                h_abs *= max(MIN_FACTOR, SAFETY * error_norm**ERROR_EXPONENT)
                rejected = True
            tc = t_new
            for i in range(dim):
                y[i] = y_new[i]
                f[i] = K[N_STAGES, i]
        norm = np.sqrt(y[3] * y[3] + y[4] * y[4] + y[5] * y[5] + y[6] * y[6])
        for i in range(3):
            ys[k + 1, i] = y[i]
        for i in range(3, 7):
            ys[k + 1, i] = y[i] / norm
    return OK, -1, nfev


@kernel
def evaluate_samples(ch, q, qd, ys, ee_p, ee_A, base_A, lin_res, ang_res, com):
    """At each sample: the end-effector pose, the base attitude, the total linear momentum
    (N s) and the angular momentum about the world origin (N m s), each summed body by body
    from the body's own velocity (the base twist solved again at the sample), and the system
    CoM."""
    n = q.shape[1]
    kin = kinematics_buffers(n)
    v_j = np.empty((n + 1, 3))
    w_j = np.empty((n + 1, 3))
    twist = np.empty(6)
    A0 = np.empty((3, 3))
    Iw = np.empty((3, 3))
    tmp = np.empty((3, 3))
    for k in range(q.shape[0]):
        quaternion_to_matrix(ys[k, 3:], A0)
        kinematics(ch, q[k], A0, ys[k, :3], np.bool_(False), kin)
        att, bcom, _, _, p_e, A_e = kin
        for r in range(3):
            ee_p[k, r] = p_e[r]
            for c in range(3):
                ee_A[k, r, c] = A_e[r, c]
                base_A[k, r, c] = A0[r, c]
        base_twist(ch, kin, qd[k], v_j, w_j, twist)
        P = np.zeros(3)
        L = np.zeros(3)
        g = np.zeros(3)
        for i in range(n + 1):
            m = ch.masses[i]
            d0 = bcom[i, 0] - bcom[0, 0]
            d1 = bcom[i, 1] - bcom[0, 1]
            d2 = bcom[i, 2] - bcom[0, 2]
            v = np.empty(3)
            w = np.empty(3)
            v[0] = twist[0] + (twist[4] * d2 - twist[5] * d1) + v_j[i, 0]
            v[1] = twist[1] + (twist[5] * d0 - twist[3] * d2) + v_j[i, 1]
            v[2] = twist[2] + (twist[3] * d1 - twist[4] * d0) + v_j[i, 2]
            for r in range(3):
                w[r] = twist[3 + r] + w_j[i, r]
            _world_inertia(ch.inertias, i, att[i], Iw, tmp)
            r0 = bcom[i, 0]
            r1 = bcom[i, 1]
            r2 = bcom[i, 2]
            for r in range(3):
                P[r] += m * v[r]
                L[r] += Iw[r, 0] * w[0] + Iw[r, 1] * w[1] + Iw[r, 2] * w[2]
                g[r] += m * bcom[i, r]
            L[0] += m * (r1 * v[2] - r2 * v[1])
            L[1] += m * (r2 * v[0] - r0 * v[2])
            L[2] += m * (r0 * v[1] - r1 * v[0])
        lin_res[k] = np.sqrt(P[0] * P[0] + P[1] * P[1] + P[2] * P[2])
        ang_res[k] = np.sqrt(L[0] * L[0] + L[1] * L[1] + L[2] * L[2])
        for r in range(3):
            com[k, r] = g[r] / ch.total_mass

"""The planner's step loop (the paper's Figure 2), for each parameter set of a range, with running metrics.

At each sample ``t_k = k dt`` (k = 0..N): the kinematics and GJM at ``q_k`` in the base frame
(base attitude the identity, system CoM at the origin: both follow from rigid motions, so the
world quantities are rotations of these by the base attitude ``A_0`` and a shift by the fixed
system CoM); the commanded twist (the path's mean twist over the step plus ``gain *
pose_error``) rotated into the base frame; the thin SVD (warm-started) of the tracked rows of
the GJM (all six for a pose task, the three linear ones for a position task) and the robust
inverse, giving ``qd_k``, plus the secondary objective's null-space motion on a redundant arm
(:mod:`engine.kernels.redundancy`). Then the paper's joint update ``q_{k+1} = q_k + qd_k dt``
and the base attitude integrated over the step along that linear joint motion: the base angular
velocity in the base frame, ``w_b(t) = Omega_b(q_k + (t - t_k) qd_k) qd_k``, depends on the
joints only, so ``dA_0/dt = A_0 [w_b]x`` is integrated with the fourth-order Magnus method on
Simpson's nodes, ``A_0 <- A_0 exp(h/6 (w_a + 4 w_m + w_b) + h^2/12 w_a x w_b)``, on sub-steps
``h`` short enough that no revolute joint turns more than ``SUBSTEP_ANGLE`` and no prismatic
joint slides more than ``SUBSTEP_LENGTH`` in one (one sub-step in ordinary plans; the end point
is the next step's configuration, so a sub-step costs one extra evaluation).

Metrics are accumulated as the plan runs (no per-sample storage needed): errors (max, RMS,
final), per-joint peak speeds (revolute and prismatic apart), the smallest singular value and
|det| of the tracked Jacobian when it is square, with their times, the first sample where a
joint is outside its position limits, and the carrier's rotation from its start. A non-finite
Jacobian or joint rate ends the plan as diverged.

The ``bounded`` inverse (:func:`bound_rates`) holds each step's joint rates in the box of the
speed limits and of the position limits one step ahead, by the exact QP of
:mod:`engine.kernels.qp` when the damped least-squares rates leave it.

Clearance (``geo``: shapes, hull vertices, pairs and the scene's settings of
:mod:`engine.kernels.geometry`; no pairs: nothing is checked). At every sample each pair's
distance (GJK, or the bounding spheres' lower bound for pairs too far to matter); between
samples the distance of a pair can shrink at most at its speed bound (the speeds of its shapes'
points under the step's joint rates and the carrier's reaction, at the interval's ends), so
``(d_k + d_{k+1} - v dt) / 2`` bounds it from below on the interval; where that bound is below
the clearance the interval is bisected (the planner's own joint line and Magnus base step to
each midpoint) down to 1/64 of a step, and a bound still below it there counts as a contact.
The ``bounded`` inverse adds a velocity damper per pair closer than the influence distance
(:func:`engine.kernels.geometry.avoidance_rows`) to its QP; the ``clearance`` secondary
objective pushes close pairs apart in the null space.

Dynamics (``dynamics`` set): the executed trajectory's joint torques and mount wrench
(:func:`engine.kernels.dynamics.trajectory_dynamics`) after the loop, for every sample (a plan
that keeps its trace) or for their peaks only (metrics-only evaluation, whose joint samples are
kept in a per-plan buffer of ``(N+1, n)`` for the spline, which needs them all). About 2 µs per
sample; metrics-only evaluations do it only when the robot has an effort limit.
"""

from __future__ import annotations

import numpy as np

from engine.kernels.chain import (
    LOWER,
    SLIDE,
    UPPER,
    angular_map,
    fastest_joints,
    gjm,
    gjm_buffers,
    kinematics,
    kinematics_buffers,
)
from engine.kernels.dynamics import trajectory_buffers, trajectory_dynamics
from engine.kernels.geometry import (
    HIT_D,
    HIT_PAIR,
    MIN_D,
    MIN_PAIR,
    T_HIT,
    T_MIN_D,
    avoidance_rows,
    clearance_buffers,
    clearance_push,
    joint_reach,
    note_distance,
    pair_speeds,
    pose_all,
    pose_into,
    reset_stats,
    sample_distances,
    shape_distance,
)
from engine.kernels.inverse import BOUNDED, apply_inverse
from engine.kernels.jit import kernel, unlinked
from engine.kernels.linalg import det3, det6
from engine.kernels.qp import INVALID, V_QD, dls_qp, qp_buffers
from engine.kernels.redundancy import CLEARANCE, NONE, null_space_step
from engine.kernels.so3 import exp_so3, log_so3, rotation_angle
from engine.kernels.svd import jacobi_svd, svd_buffers

SUBSTEP_ANGLE = 0.25  # rad of revolute joint travel per attitude sub-step
SUBSTEP_LENGTH = 0.1  # m of prismatic joint travel per attitude sub-step
MAX_SUBSTEPS = 64
REFRESH_EVERY = 16  # steps between re-orthonormalisations of the SVD's warm start

# Layout of a plan's metrics vector.
POS_MAX, POS_RMS, POS_FINAL = 0, 1, 2
ATT_MAX, ATT_RMS, ATT_FINAL = 3, 4, 5
CPL_MAX, CPL_RMS, CPL_FINAL = 6, 7, 8
MAX_SPEED, MAX_SPEED_JOINT = 9, 10
MIN_SIGMA, T_MIN_SIGMA = 11, 12
MIN_DET, T_MIN_DET = 13, 14
FINITE, T_DIVERGED = 15, 16
MAX_LIN_SPEED, MAX_LIN_SPEED_JOINT = 17, 18
LIMIT_JOINT, T_LIMIT, LIMIT_EXCESS = 19, 20, 21
BASE_ROT_MAX, BASE_ROT_FINAL = 22, 23
MAX_TORQUE, MAX_TORQUE_JOINT, MAX_FORCE, MAX_FORCE_JOINT = 24, 25, 26, 27
EFFORT_JOINT, T_EFFORT, EFFORT_PEAK, DYNAMICS = 28, 29, 30, 31
MIN_CLEARANCE, T_MIN_CLEARANCE, CLEARANCE_PAIR = 32, 33, 34
COLLISION_PAIR, T_COLLISION, COLLISION_DISTANCE, GEOMETRY = 35, 36, 37, 38
N_METRICS = 39
#: Bisections of a step, at most, in the clearance check between samples (1/64 of a step).
MAX_BISECTIONS = 6

#: A position limit's rate bound is shrunk by this factor so that ``q + qd dt`` (two roundings)
#: cannot pass the limit: rounding is monotone, so ``fl(q + fl(qd dt))`` stays on the limit's
#: side once ``qd dt`` is below the gap by more than a few ulps.
LIMIT_SHRINK = 1.0 - 8.0 * 2.220446049250313e-16


@kernel
def _body_rate(ch, q, qd, kin, g, eye, zero, out):
    """``out = Omega_b(q) qd``: the base angular velocity in the base frame."""
    kinematics(ch, q, eye, zero, np.bool_(True), kin)
    angular_map(ch, kin, g)
    Omega = g[2]
    for r in range(3):
        acc = 0.0
        for j in range(qd.shape[0]):
            acc += Omega[r, j] * qd[j]
        out[r] = acc


@kernel
def advance_buffers(n):
    """Scratch for :func:`advance`: ``(q_sub (n,), w_a, w_m, w_b, phi (3,), R, A_tmp (3, 3),
    eye (3, 3), zero (3,))``."""
    return (
        np.empty(n),
        np.empty(3),
        np.empty(3),
        np.empty(3),
        np.empty(3),
        np.empty((3, 3)),
        np.empty((3, 3)),
        np.eye(3),
        np.zeros(3),
    )


@kernel
def advance(ch, q, qd, dt, A0, kin, g, kin_m, g_m, q_next, work):
    """One planner step from ``q (n,)``: ``q_next = q + qd dt``, whose base-frame kinematics
    and GJM go to ``kin`` and ``g`` (which on entry hold those of ``q``), and the base attitude
    ``A0 (3, 3)`` advanced in place along the joint line ``q + (t - t_k) qd`` by fourth-order
    Magnus on Simpson's nodes over sub-steps of at most ``SUBSTEP_ANGLE`` (revolute) or
    ``SUBSTEP_LENGTH`` (prismatic) joint travel.

    ``dA_0/dt = A_0 [w_b]x`` with the base-frame rate ``w_b = Omega_b(q(t)) qd`` (it does not
    depend on ``A_0``); over a sub-step ``h`` from ``w_a`` via ``w_m`` to ``w_b``:
    ``A_0 <- A_0 exp(h/6 (w_a + 4 w_m + w_b) + h^2/12 w_a x w_b)``.
    """
    q_sub, wa, wm, wb, phi, R, A_tmp, eye, zero = work
    n = q.shape[0]
    Omega = g[2]
    travel = 0.0  # in sub-steps
    for j in range(n):
        per_substep = 1.0 / SUBSTEP_ANGLE + ch.joints[j, SLIDE] * (1.0 / SUBSTEP_LENGTH - 1.0 / SUBSTEP_ANGLE)
        travel = max(travel, abs(qd[j]) * dt * per_substep)
    S = min(MAX_SUBSTEPS, max(1, int(np.ceil(travel))))
    h = dt / S
    for r in range(3):
        acc = 0.0
        for j in range(n):
            acc += Omega[r, j] * qd[j]
        wa[r] = acc
    for sub in range(S):
        ta = sub * h
        for j in range(n):
            q_sub[j] = q[j] + qd[j] * (ta + 0.5 * h)
        _body_rate(ch, q_sub, qd, kin_m, g_m, eye, zero, wm)
        if sub == S - 1:
            for j in range(n):
                q_next[j] = q[j] + qd[j] * dt
            kinematics(ch, q_next, eye, zero, np.bool_(True), kin)
            gjm(ch, kin, g)
            for r in range(3):
                acc = 0.0
                for j in range(n):
                    acc += Omega[r, j] * qd[j]
                wb[r] = acc
        else:
            for j in range(n):
                q_sub[j] = q[j] + qd[j] * (ta + h)
            _body_rate(ch, q_sub, qd, kin_m, g_m, eye, zero, wb)
        h6 = h / 6.0
        h12 = h * h / 12.0
        phi[0] = h6 * (wa[0] + 4.0 * wm[0] + wb[0]) + h12 * (wa[1] * wb[2] - wa[2] * wb[1])
        phi[1] = h6 * (wa[1] + 4.0 * wm[1] + wb[1]) + h12 * (wa[2] * wb[0] - wa[0] * wb[2])
        phi[2] = h6 * (wa[2] + 4.0 * wm[2] + wb[2]) + h12 * (wa[0] * wb[1] - wa[1] * wb[0])
        exp_so3(phi, R)
        for r in range(3):
            for c in range(3):
                A_tmp[r, c] = A0[r, 0] * R[0, c] + A0[r, 1] * R[1, c] + A0[r, 2] * R[2, c]
        for r in range(3):
            for c in range(3):
                A0[r, c] = A_tmp[r, c]
        for r in range(3):
            wa[r] = wb[r]


@kernel
def base_attitude_step(ch, q, qd, dt, A0):
    """The base attitude after one planner step of ``dt`` from ``q`` with ``qd`` (for tests)."""
    n = q.shape[0]
    kin = kinematics_buffers(n)
    g = gjm_buffers(n)
    kinematics(ch, q, np.eye(3), np.zeros(3), np.bool_(True), kin)
    gjm(ch, kin, g)
    A = A0.copy()
    advance(ch, q, qd, dt, A, kin, g, kinematics_buffers(n), gjm_buffers(n), np.empty(n), advance_buffers(n))
    return A


@kernel(inline=True)
def _secondary(objective, objective_gain, sv, g, q, centre, qd, null_work):
    null_space_step(objective, objective_gain, sv[3], g[2], q, centre, qd, null_work)


@kernel
def rate_box(ch, q, dt, speed_limit, lo, hi):
    """The box of the joint rates over the next step: ``|qd_j| <= speed_limit[j]`` and
    ``lower_j <= q_j + qd_j dt <= upper_j`` (shrunk by :data:`LIMIT_SHRINK`). The speed limit
    has priority: a joint already past a position limit gets back at most at its speed limit
    (``lo = hi = ±speed_limit`` when it is further out than one step at that speed)."""
    for j in range(q.shape[0]):
        v = speed_limit[j]
        low = -v
        high = v
        lower = ch.joints[j, LOWER]
        upper = ch.joints[j, UPPER]
        if lower > -np.inf:
            low = max(low, (lower - q[j]) / dt * LIMIT_SHRINK)
        if upper < np.inf:
            high = min(high, (upper - q[j]) / dt * LIMIT_SHRINK)
        lo[j] = min(low, v)
        hi[j] = max(high, -v)


@kernel(inline=True)
def bound_rates(ch, q, dt, speed_limit, U, s, V, damping, lam, xdot, qd, shift, box, qp_buf, C, d, m_rows, d_shifted):
    """The ``bounded`` inverse's step: ``qd (n,)`` holds the damped least-squares rates (plus
    the null-space motion ``shift (n,)`` of a secondary objective, zero without one). If they
    leave the box of :func:`rate_box` or break one of the first ``m_rows`` rows ``C qd <= d``
    (the velocity dampers of close pairs), replace them by the exact minimiser of ``|J x -
    xdot|^2 + lam^2 |x - shift|^2`` subject to both (the QP of
    :func:`engine.kernels.qp.dls_qp` on the thin SVD ``U``, ``s``, ``V`` with ``damping (m,)``;
    ``J shift = 0``, so this is the DLS problem in ``x - shift`` over the shifted box and rows),
    clipped to the box against rounding: the box holds bitwise. Returns False if the QP found
    its input invalid (``qd`` is then NaN). ``box (2, n)``, ``qp_buf``:
    :func:`engine.kernels.qp.qp_buffers` ``(n, >= m_rows)``, ``d_shifted (>= m_rows,)`` scratch."""
    n = q.shape[0]
    lo = box[0]
    hi = box[1]
    rate_box(ch, q, dt, speed_limit, lo, hi)
    inside = True
    for j in range(n):
        if not (lo[j] <= qd[j] <= hi[j]):
            inside = False
    for r in range(m_rows):
        acc = 0.0
        for j in range(n):
            acc += C[r, j] * qd[j]
        if not acc <= d[r]:
            inside = False
    if inside:
        return True
    for j in range(n):
        lo[j] -= shift[j]
        hi[j] -= shift[j]
    for r in range(m_rows):
        acc = d[r]
        for j in range(n):
            acc -= C[r, j] * shift[j]
        d_shifted[r] = acc
    status, _ = unlinked(dls_qp, (U, s, V, damping, lam, xdot, lo, hi, C[:m_rows], d_shifted[:m_rows], 0, qp_buf))
    rate_box(ch, q, dt, speed_limit, lo, hi)
    solution = qp_buf[2][V_QD]
    for j in range(n):
        qd[j] = min(max(solution[j] + shift[j], lo[j]), hi[j])
    return status != INVALID


@kernel
def clearance_work(ch, n):
    """Scratch of :func:`distance_at`: kinematics and GJM buffers (twice), ``q_s (n,)``, the
    advance buffers, ``A_s (3, 3)``, ``slide (n,)`` (1.0 for a prismatic joint), and a pair's
    reach ``(2, n + 1)``, indices ``(1, 2)`` and speed ``(1,)``."""
    slide = np.empty(n)
    for j in range(n):
        slide[j] = ch.joints[j, SLIDE]
    one_pair = np.zeros((1, 2), dtype=np.int64)
    one_pair[0, 1] = 1
    return (
        kinematics_buffers(n),
        gjm_buffers(n),
        kinematics_buffers(n),
        gjm_buffers(n),
        np.empty(n),
        advance_buffers(n),
        np.empty((3, 3)),
        slide,
        np.empty((2, n + 1)),
        one_pair,
        np.empty(1),
    )


@kernel(inline=True)
def distance_at(ch, shapes, vertices, a, b, q0, qd, A0, com_w, s, cbuf, work):
    """The distance of shapes ``a`` and ``b`` at ``s`` s into a step that starts at joints
    ``q0`` and base attitude ``A0`` with rates ``qd`` (the planner's joint line and Magnus base
    step, :func:`advance`), and the bound of its rate of change there. Uses ``cbuf``'s pair
    buffers."""
    kin, g, kin_m, g_m, q_s, adv, A_s, slide, reach, one_pair, speed = work
    posed2, witness2, gjk = cbuf[10], cbuf[11], cbuf[8]
    eye = adv[7]
    zero = adv[8]
    kinematics(ch, q0, eye, zero, np.bool_(True), kin)
    gjm(ch, kin, g)
    for r in range(3):
        for c in range(3):
            A_s[r, c] = A0[r, c]
    if s > 0.0:
        advance(ch, q0, qd, s, A_s, kin, g, kin_m, g_m, q_s, adv)  # kin and g now of q0 + s qd
    pose_into(shapes, a, kin[0], kin[1], A_s, com_w, posed2, np.int64(0))
    pose_into(shapes, b, kin[0], kin[1], A_s, com_w, posed2, np.int64(1))
    d = unlinked(shape_distance, (posed2[0], posed2[1], vertices, gjk, witness2))
    joint_reach(posed2, slide, kin, reach)
    pair_speeds(posed2, one_pair, reach, g[1], qd, speed)
    return d, speed[0]


@kernel(inline=True)
def check_interval(ch, shapes, vertices, a, b, pair, t0, dt, q0, qd, A0, com_w, d0, d1, speed, clearance, cbuf, work):
    """Whether pair ``pair`` (shapes ``a``, ``b``) stays at least ``clearance`` apart over the
    step ``[t0, t0 + dt]`` whose ends are ``d0`` and ``d1`` apart (exact, or lower bounds) and
    whose distance changes at most at ``speed`` m/s: bisected where the Lipschitz bound cannot
    tell, down to 1/2^MAX_BISECTIONS of the step. Distances found go into the stats (the
    smallest, and the first below the clearance; a bound below it at the finest level counts as
    a contact at that sub-interval's middle)."""
    stats, stack = cbuf[9], cbuf[12]
    stack[0, 0] = 0.0
    stack[0, 1] = dt
    stack[0, 2] = d0
    stack[0, 3] = d1
    stack[0, 4] = speed
    stack[0, 5] = 0.0
    top = 1
    while top > 0:
        top -= 1
        s0 = stack[top, 0]
        s1 = stack[top, 1]
        da = stack[top, 2]
        db = stack[top, 3]
        v = stack[top, 4]
        depth = stack[top, 5]
        bound = 0.5 * (da + db - v * (s1 - s0))
        if bound >= clearance:
            continue
        sm = 0.5 * (s0 + s1)
        if depth >= MAX_BISECTIONS:
            note_distance(stats, bound, t0 + sm, pair, clearance)
            return
        dm, vm = distance_at(ch, shapes, vertices, a, b, q0, qd, A0, com_w, sm, cbuf, work)
        note_distance(stats, dm, t0 + sm, pair, clearance)
        if dm < clearance:
            return
        v = max(v, vm)
        for half in range(2):
            stack[top, 0] = s0 if half == 0 else sm
            stack[top, 1] = sm if half == 0 else s1
            stack[top, 2] = da if half == 0 else dm
            stack[top, 3] = dm if half == 0 else db
            stack[top, 4] = v
            stack[top, 5] = depth + 1.0
            top += 1


@kernel
def same_chain(a, b):
    """Whether chains ``a`` and ``b`` have the same masses, inertias and CoM offsets (their
    joints, axes and end-effector frame are shared by construction)."""
    if a.total_mass != b.total_mass or a.masses.shape[0] != b.masses.shape[0]:
        return False
    for i in range(a.masses.shape[0]):
        if a.masses[i] != b.masses[i]:
            return False
        for r in range(3):
            if a.b[i, r] != b.b[i, r]:
                return False
            if i > 0 and a.a[i - 1, r] != b.a[i - 1, r]:
                return False
            for c in range(3):
                if a.inertias[i, r, c] != b.inertias[i, r, c]:
                    return False
    return True


@kernel(inline=True)
def _dynamics_metrics(ch, dt, N, run, end_rate, dyn, record, metrics):
    """The executed trajectory's dynamics of a finite plan (``run``) into ``dyn`` and their
    peaks into ``metrics``; without ``run`` the recorded rows are NaN and the peaks unknown."""
    if run and N >= 1:
        ok, peak, peak_joint, peak_lin, peak_lin_joint, over, t_over, over_peak = unlinked(
            trajectory_dynamics, (ch, dt, N + 1, end_rate, dyn, record)
        )
        metrics[MAX_TORQUE] = peak if ok else np.nan
        metrics[MAX_TORQUE_JOINT] = peak_joint
        metrics[MAX_FORCE] = peak_lin if ok else np.nan
        metrics[MAX_FORCE_JOINT] = peak_lin_joint
        metrics[EFFORT_JOINT] = over
        metrics[T_EFFORT] = t_over
        metrics[EFFORT_PEAK] = over_peak
        metrics[DYNAMICS] = 1.0
        return
    if record:
        dyn[3][:] = np.nan
        dyn[4][:] = np.nan
        dyn[5][:] = np.nan
        dyn[6][:] = np.nan
    metrics[MAX_TORQUE] = np.nan
    metrics[MAX_TORQUE_JOINT] = -1
    metrics[MAX_FORCE] = np.nan
    metrics[MAX_FORCE_JOINT] = -1
    metrics[EFFORT_JOINT] = -1
    metrics[T_EFFORT] = np.nan
    metrics[EFFORT_PEAK] = np.nan
    metrics[DYNAMICS] = 0.0


@kernel
def simulate(
    ch,
    plant,
    q0,
    twists,
    p_des,
    A_des,
    dt,
    gain,
    method,
    params,
    rows,
    objective,
    objective_gain,
    centre,
    speed_limit,
    dynamics,
    geo,
    given,
    trace,
    dyn,
    start,
    stop,
    out,
):
    """Plan the parameter sets ``params[b] (B, P)`` for ``b`` in ``[start, stop)`` into their
    metrics rows ``out[b] (N_METRICS,)``. The one step loop of the engine: a single plan is a range
    of one. (One function, not a loop over an inlined plan-one kernel: numba copies an inlined
    function's IR block by block, each copy with the whole scope, 4.4 s of a cold compilation.)

    ``twists (N+1, 6)`` commanded path twists and ``p_des (N+1, 3)``, ``A_des (N+1, 3, 3)``
    desired poses (world); ``gain`` the pose feedback gain (1/s); ``rows`` = 6 tracks the pose, 3
    the position only; ``objective``, ``objective_gain`` and ``centre (n,)`` the secondary
    objective (:mod:`engine.kernels.redundancy`); ``speed_limit (n,)`` each joint's speed limit
    (rad/s or m/s; the ``bounded`` inverse's box); ``geo`` the collision geometry ``(shapes,
    vertices, pairs, (clearance, influence distance, avoidance gain))`` (no pairs: none).

    ``ch`` is the controller's model and ``plant`` the robot that moves (the same chain for a plan;
    a sampled robot of :mod:`engine.uncertainty` for a closed loop under uncertainty): the
    inverse uses the controller's GJM at the measured joints and carrier attitude, while the
    carrier turns by the plant's momentum balance and the pose error, clearance and torques are
    the plant's. ``given (N+1, n)`` (or ``(0, n)``: none) replaces the inverse's joint rates (an
    open-loop replay of a plan's joint motion).

    ``trace`` and ``dyn``: the samples of the range's one plan, kept, or arrays of no rows
    (``engine.planner._no_samples``): only metrics are kept, and memory does not grow with the
    number of steps, except with ``dynamics`` (the effort peaks), whose spline needs the joint
    samples of one plan at a time (``3 (N+1) n`` floats, reused by the plans of the range; the
    kernel's own unless ``dyn`` has them). A kept ``trace`` is a tuple of ``q (N+1, n)``, ``qd``,
    ``base_p (N+1, 3)``, ``base_A (N+1, 3, 3)``, ``ee_p``, ``ee_A``, ``sv (N+1, m)``, ``det
    (N+1,)``, ``damping (N+1, m)``, ``pos_err (N+1,)``, ``att_err``, ``clearance (N+1,)`` the
    smallest distance of any pair, ``clearance_pair (N+1,)`` its pair; it receives every sample,
    and samples after a divergence are NaN. With ``dynamics``, ``dyn``
    (:func:`engine.kernels.dynamics.trajectory_buffers` of ``N+1`` samples, with ``N+1`` rows
    when the trace is kept, else 1) receives the executed trajectory's accelerations, torques and
    mount wrench of a finite plan (NaN otherwise), and their peaks go into the metrics."""
    n = q0.shape[0]
    samples = twists.shape[0]
    record = trace[0].shape[0] > 0
    if record and (stop - start != 1 or trace[0].shape[0] != samples or dyn[1].shape[0] != samples):
        raise ValueError("a kept trace holds one plan, all its samples: one parameter set, N+1 rows")
    if not record and dyn[1].shape[0] == 0:
        # the sizes at run time, not literals: a literal argument would compile another signature
        dyn = trajectory_buffers(samples if dynamics else 0, n, 1 if dynamics else 0)
    elif dynamics and dyn[1].shape[0] < samples:
        raise ValueError("the dynamics buffers hold fewer than the plan's N+1 samples")
    for b in range(start, stop):
        params_b = params[b]
        metrics = out[b]
        tr_q, tr_qd, tr_bp, tr_bA, tr_ep, tr_eA, tr_sv, tr_det, tr_damp, tr_perr, tr_aerr, tr_clear, tr_cpair = trace
        dyn_q = dyn[1]
        m = min(rows, n)
        N = twists.shape[0] - 1
        eye = np.eye(3)
        zero = np.zeros(3)
        kin = kinematics_buffers(n)  # the plant's (the controller's too when they are the same)
        g = gjm_buffers(n)
        separate = not same_chain(ch, plant)
        kin_c = kin
        g_c = g
        if separate:
            kin_c = kinematics_buffers(n)
            g_c = gjm_buffers(n)
        replaying = given.shape[0] > 0
        kin_m = kinematics_buffers(n)
        g_m = gjm_buffers(n)
        sv = svd_buffers(n, rows)
        q = q0.copy()
        q_next = np.empty(n)
        qd = np.empty(n)
        damping = np.empty(m)
        peak = np.zeros(n)
        work = advance_buffers(n)
        null_work = (np.empty((3, n)), np.empty((3, 6)), np.empty(6), np.empty(n), np.empty((3, 3)), np.empty(3), np.empty(3))
        redundant = objective != NONE and n > m
        A0 = np.eye(3)
        ee_p = np.empty(3)
        ee_A = np.empty((3, 3))
        base_p = np.empty(3)
        D = np.empty((3, 3))
        dphi = np.empty(3)
        xdot_w = np.empty(6)
        xdot_b = np.empty(6)
        inv_scratch = np.empty((2, 6))
        det_scratch = np.empty((6, 6))
        bounded = method == BOUNDED
        shift = np.zeros(n)
        box = np.empty((2, n))
        shapes, vertices, pairs, geo_set = geo
        n_pairs = pairs.shape[0]
        checking = n_pairs > 0
        clearance = geo_set[0]
        influence = geo_set[1]
        avoid_gain = geo_set[2]
        avoid_rows = checking and bounded
        avoid_null = checking and redundant and objective == CLEARANCE
        cbuf = clearance_buffers(n, shapes.shape[0], n_pairs)
        cwork = clearance_work(plant, n)
        slide = cwork[7]
        stats = cbuf[9]
        reset_stats(stats)
        cbuf[5][:] = 0.0
        speed_now = np.empty(n_pairs)
        q_prev = np.empty(n)
        qd_prev = np.empty(n)
        A_prev = np.empty((3, 3))
        m_rows = 0
        qp_buf = qp_buffers(n, n_pairs)

        kinematics(plant, q, eye, zero, np.bool_(True), kin)
        gjm(plant, kin, g)
        if separate:
            kinematics(ch, q, eye, zero, np.bool_(True), kin_c)
            gjm(ch, kin_c, g_c)
        _, com_b, _, _, ee_p_b, ee_A_b = kin
        J_b = g_c[0] if rows == 6 else g_c[0][:3]  # the tracked rows of the GJM (a view: gjm writes in place)
        com_w = np.empty(3)
        for r in range(3):
            com_w[r] = -com_b[0, r]  # the base starts at the world origin with the identity attitude

        pos_max = 0.0
        att_max = 0.0
        cpl_max = 0.0
        pos_sq = 0.0
        att_sq = 0.0
        cpl_sq = 0.0
        pos_e = 0.0
        att_e = 0.0
        cpl_e = 0.0
        min_sigma = np.inf
        t_min_sigma = np.nan
        min_det = np.inf
        t_min_det = np.nan
        limit_joint = -1
        t_limit = np.nan
        limit_excess = 0.0
        rot_key = 0.0
        finite = True
        t_div = np.nan
        last = N
        for k in range(N + 1):
            t_k = k * dt
            # World pose: A_0 times the base-frame pose, shifted by the fixed system CoM.
            for r in range(3):
                base_p[r] = com_w[r] + A0[r, 0] * com_b[0, 0] + A0[r, 1] * com_b[0, 1] + A0[r, 2] * com_b[0, 2]
                ee_p[r] = com_w[r] + A0[r, 0] * ee_p_b[0] + A0[r, 1] * ee_p_b[1] + A0[r, 2] * ee_p_b[2]
                for c in range(3):
                    ee_A[r, c] = A0[r, 0] * ee_A_b[0, c] + A0[r, 1] * ee_A_b[1, c] + A0[r, 2] * ee_A_b[2, c]
            # Tracking errors: dp = p - p_d, dphi = log(A A_d^T) (world axes).
            for r in range(3):
                for c in range(3):
                    D[r, c] = ee_A[r, 0] * A_des[k, c, 0] + ee_A[r, 1] * A_des[k, c, 1] + ee_A[r, 2] * A_des[k, c, 2]
            log_so3(D, dphi)
            sq_p = 0.0
            sq_a = 0.0
            sq_c = 0.0
            for r in range(3):
                dp = ee_p[r] - p_des[k, r]
                sq_p += dp * dp
                sq_a += dphi[r] * dphi[r]
                sq_c += (dp * dphi[r]) * (dp * dphi[r])
                xdot_w[r] = twists[k, r] + gain * (-dp)
                xdot_w[r + 3] = twists[k, r + 3] + gain * (-dphi[r])
            pos_e = np.sqrt(sq_p)
            att_e = np.sqrt(sq_a)
            cpl_e = np.sqrt(sq_c)
            pos_max = max(pos_max, pos_e)
            att_max = max(att_max, att_e)
            cpl_max = max(cpl_max, cpl_e)
            pos_sq += pos_e * pos_e
            att_sq += att_e * att_e
            cpl_sq += cpl_e * cpl_e
            # The carrier's rotation from its start, tracked as 3 - trace A_0 = 4 sin^2(angle / 2)
            # (increasing in the angle; converted once at the end).
            rot_key = max(rot_key, 3.0 - (A0[0, 0] + A0[1, 1] + A0[2, 2]))
            for j in range(n):
                excess = max(ch.joints[j, LOWER] - q[j], q[j] - ch.joints[j, UPPER])
                if excess > 0.0:
                    if limit_joint < 0:
                        limit_joint = j
                        t_limit = t_k
                    if j == limit_joint:
                        limit_excess = max(limit_excess, excess)
            if checking:
                pose_all(shapes, kin[0], kin[1], A0, com_w, cbuf[0])
                prev_dist, prev_speed, step_speed = cbuf[4], cbuf[5], cbuf[14]
                joint_reach(cbuf[0], slide, kin, cbuf[15])
                if k > 0:  # the speed bound of the step that just ended: its rates at either end
                    pair_speeds(cbuf[0], pairs, cbuf[15], g[1], qd_prev, speed_now)
                    for p in range(n_pairs):
                        step_speed[p] = max(prev_speed[p], speed_now[p])
                # exact distances for the pairs that may be the smallest (of the sample when the trace
                # is kept, else of the plan), that constrain the step, or that the check between
                # samples may need; lower bounds for the others
                cutoff = max(stats[MIN_D], influence if (avoid_rows or avoid_null) else -np.inf)
                best, best_pair = sample_distances(pairs, vertices, cutoff, clearance, dt, k == 0, record, cbuf)
                if record:
                    tr_clear[k] = best
                    tr_cpair[k] = best_pair
                dist, exact = cbuf[1], cbuf[2]
                for p in range(n_pairs):
                    if exact[p] != 0.0:
                        note_distance(stats, dist[p], t_k, p, clearance)
                if k > 0:  # the step that just ended, between samples
                    for p in range(n_pairs):
                        # (the call only where the Lipschitz bound cannot tell: it takes the buffers)
                        if (
                            prev_dist[p] >= clearance
                            and dist[p] >= clearance
                            and (0.5 * (prev_dist[p] + dist[p] - step_speed[p] * dt) < clearance)
                        ):
                            check_interval(
                                plant,
                                shapes,
                                vertices,
                                pairs[p, 0],
                                pairs[p, 1],
                                p,
                                t_k - dt,
                                dt,
                                q_prev,
                                qd_prev,
                                A_prev,
                                com_w,
                                prev_dist[p],
                                dist[p],
                                step_speed[p],
                                clearance,
                                cbuf,
                                cwork,
                            )
                if avoid_rows:
                    m_rows = avoidance_rows(cbuf[0], pairs, cbuf, slide, kin, g_c[1], influence, clearance, avoid_gain, dt)
            for r in range(3):
                xdot_b[r] = A0[0, r] * xdot_w[0] + A0[1, r] * xdot_w[1] + A0[2, r] * xdot_w[2]
                xdot_b[r + 3] = A0[0, r] * xdot_w[3] + A0[1, r] * xdot_w[4] + A0[2, r] * xdot_w[5]
            ok, _ = unlinked(jacobi_svd, (J_b, sv, k % REFRESH_EVERY == 0))
            s = sv[2]
            if replaying:
                ok = True
                for j in range(n):
                    qd[j] = given[k, j]
                    ok = ok and np.isfinite(qd[j])
                damping[:] = np.nan
            elif ok:
                apply_inverse(method, params_b, J_b, sv[1], s, sv[3], xdot_b, qd, damping, inv_scratch)
                if redundant:
                    if bounded:
                        for j in range(n):
                            shift[j] = qd[j]
                    if avoid_null:
                        clearance_push(cbuf[0], pairs, cbuf, slide, kin, g_c[1], influence, objective_gain, null_work[3])
                    elif objective == CLEARANCE:
                        null_work[3][:] = 0.0  # no geometry: nothing to push apart
                    _secondary(objective, objective_gain, sv, g_c, q, centre, qd, null_work)
                    if bounded:
                        for j in range(n):
                            shift[j] = qd[j] - shift[j]
                if bounded:
                    ok = bound_rates(
                        ch,
                        q,
                        dt,
                        speed_limit,
                        sv[1],
                        s,
                        sv[3],
                        damping,
                        params_b[0],
                        xdot_b,
                        qd,
                        shift,
                        box,
                        qp_buf,
                        cbuf[6],
                        cbuf[7],
                        m_rows,
                        speed_now,
                    )
                for j in range(n):
                    if not np.isfinite(qd[j]):
                        ok = False
            else:
                qd[:] = np.nan
                damping[:] = np.nan
            ok = ok and np.isfinite(pos_e) and np.isfinite(att_e)
            det = np.nan
            if n == rows and np.isfinite(s[0]):
                det = det6(J_b, det_scratch) if rows == 6 else det3(J_b)
            if dynamics:
                for j in range(n):
                    dyn_q[k, j] = q[j]
            if record:
                for j in range(n):
                    tr_q[k, j] = q[j]
                    tr_qd[k, j] = qd[j]
                for r in range(3):
                    tr_bp[k, r] = base_p[r]
                    tr_ep[k, r] = ee_p[r]
                    for c in range(3):
                        tr_bA[k, r, c] = A0[r, c]
                        tr_eA[k, r, c] = ee_A[r, c]
                for i in range(m):
                    tr_sv[k, i] = s[i]
                    tr_damp[k, i] = damping[i]
                tr_det[k] = det
                tr_perr[k] = pos_e
                tr_aerr[k] = att_e
            for j in range(n):
                v = abs(qd[j])
                if not v <= peak[j]:  # NaN counts as exceeding
                    peak[j] = v if np.isfinite(v) else np.inf
            if s[m - 1] < min_sigma:
                min_sigma = s[m - 1]
                t_min_sigma = t_k
            if abs(det) < min_det:
                min_det = abs(det)
                t_min_det = t_k
            if not ok:
                finite = False
                t_div = t_k
                last = k
                break
            if k == N:
                break
            if checking:  # what the check of the coming step needs from its start
                pair_speeds(cbuf[0], pairs, cbuf[15], g[1], qd, cbuf[5])
                for p in range(n_pairs):
                    cbuf[4][p] = cbuf[1][p]
                for j in range(n):
                    q_prev[j] = q[j]
                    qd_prev[j] = qd[j]
                for r in range(3):
                    for c in range(3):
                        A_prev[r, c] = A0[r, c]
            # Joints: the paper's explicit update. Base attitude: Magnus along the joint line.
            advance(plant, q, qd, dt, A0, kin, g, kin_m, g_m, q_next, work)
            for j in range(n):
                q[j] = q_next[j]
            if separate:
                kinematics(ch, q, eye, zero, np.bool_(True), kin_c)
                gjm(ch, kin_c, g_c)
            _, com_b, _, _, ee_p_b, ee_A_b = kin

        if record:
            for k in range(last + 1, N + 1):
                tr_q[k] = np.nan
                tr_qd[k] = np.nan
                tr_bp[k] = np.nan
                tr_bA[k] = np.nan
                tr_ep[k] = np.nan
                tr_eA[k] = np.nan
                tr_sv[k] = np.nan
                tr_det[k] = np.nan
                tr_damp[k] = np.nan
                tr_perr[k] = np.nan
                tr_aerr[k] = np.nan
                tr_clear[k] = np.nan
                tr_cpair[k] = -1.0
        count = N + 1
        if finite:
            metrics[POS_MAX] = pos_max
            metrics[POS_RMS] = np.sqrt(pos_sq / count)
            metrics[POS_FINAL] = pos_e
            metrics[ATT_MAX] = att_max
            metrics[ATT_RMS] = np.sqrt(att_sq / count)
            metrics[ATT_FINAL] = att_e
            metrics[CPL_MAX] = cpl_max
            metrics[CPL_RMS] = np.sqrt(cpl_sq / count)
            metrics[CPL_FINAL] = cpl_e
            metrics[BASE_ROT_MAX] = 2.0 * np.arcsin(min(1.0, np.sqrt(max(rot_key, 0.0) / 4.0)))
            metrics[BASE_ROT_FINAL] = rotation_angle(A0)
        else:
            for i in range(CPL_FINAL + 1):
                metrics[i] = np.nan
            metrics[BASE_ROT_MAX] = np.nan
            metrics[BASE_ROT_FINAL] = np.nan
        best, best_lin = fastest_joints(ch.joints, peak)
        metrics[MAX_SPEED] = peak[best] if best >= 0 else 0.0
        metrics[MAX_SPEED_JOINT] = best
        metrics[MAX_LIN_SPEED] = peak[best_lin] if best_lin >= 0 else 0.0
        metrics[MAX_LIN_SPEED_JOINT] = best_lin
        metrics[MIN_SIGMA] = min_sigma
        metrics[T_MIN_SIGMA] = t_min_sigma
        metrics[MIN_DET] = min_det if n == rows else np.nan
        metrics[T_MIN_DET] = t_min_det if n == rows else np.nan
        metrics[FINITE] = 1.0 if finite else 0.0
        metrics[T_DIVERGED] = t_div
        metrics[LIMIT_JOINT] = limit_joint
        metrics[T_LIMIT] = t_limit
        metrics[LIMIT_EXCESS] = limit_excess if limit_joint >= 0 else np.nan
        metrics[MIN_CLEARANCE] = stats[MIN_D] if checking else np.nan
        metrics[T_MIN_CLEARANCE] = stats[T_MIN_D]
        metrics[CLEARANCE_PAIR] = stats[MIN_PAIR]
        metrics[COLLISION_PAIR] = stats[HIT_PAIR]
        metrics[T_COLLISION] = stats[T_HIT]
        metrics[COLLISION_DISTANCE] = stats[HIT_D]
        metrics[GEOMETRY] = 1.0 if checking else 0.0
        _dynamics_metrics(plant, dt, N, finite and dynamics, qd, dyn, record, metrics)

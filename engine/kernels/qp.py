"""Exact solver of the small strictly convex QP of a bounded inverse (issues 18 and 19):

    min  1/2 x^T H x - g^T x   subject to   lo <= x <= hi   and   C x <= d,

``x (n,)`` (n <= 12 joint rates), ``C (m, n)`` general rows (velocity dampers; m may be 0),
``lo``/``hi`` may hold -inf/inf. For a bounded damped inverse ``H = J^T J + lambda^2 I`` and
``g = J^T xdot``; :func:`dls_qp` takes the thin SVD of ``J`` instead (the planner has it), with a
damping per singular direction, so every filter of :mod:`engine.kernels.inverse` has a bounded
version: ``H = V diag(sigma_i^2 + lambda_i^2) V^T + lambda_0^2 (I - V V^T)``, whose unconstrained
minimiser is the filter's ``qd = sum_i sigma_i / (sigma_i^2 + lambda_i^2) v_i u_i^T xdot``.
:func:`dense_qp` takes ``H`` and ``g``.

Method: the dual active-set method of Goldfarb and Idnani (1983), as in quadprog (Turlach) and
eiquadprog. It starts at the unconstrained minimiser (dual feasible), adds the most violated
constraint (largest violation over the row norm; lowest index on ties), and moves primal and dual
variables together keeping the multipliers >= 0, dropping a constraint whose multiplier reaches 0.
It works with a factor ``Z`` of ``H^-1 = Z Z^T`` rotated by Givens steps so that ``Z^T N_A = [R; 0]``
(``N_A`` the active normals, ``R`` upper triangular): no linear system is formed or solved anew.
A simple bound is a constraint with normal ``e_i``: its products with ``Z`` are a row of ``Z``.

- Common case first: when the unconstrained minimiser satisfies every constraint (to the
  tolerance below), it is returned after O(n (m + p)) work and no factor is built.
- The factor from the SVD is ``Z = [V diag(1/sqrt(sigma_i^2 + lambda_i^2)), V_perp / lambda_0]``
  (``V_perp`` an orthonormal completion): every column is a unit vector scaled once, so small
  damping costs no accuracy to cancellation. Hessian eigenvalues are floored at ``(LAM_FLOOR
  s)^2``, ``s`` the largest of ``sigma_1``, the dampings and ``lambda_0``: damping below ``1e-8
  sigma_1`` is raised to that (a relative change of ``H`` below 1e-16); with ``J = 0`` and no
  damping ``H = 0`` and the status is ``INVALID``. Accuracy: the KKT residual is within 1e-12 of
  the terms' size for ``lambda >= 1e-3 sigma_1`` and 1e-11 down to the floor (the forward error
  grows like eps cond(H) = eps (sigma_1 / lambda)^2, as for any backward-stable method).
- Dependent constraints: a constraint whose normal is (to ``DEP_TOL |Z| |n|``) in the span of the
  active ones gives no primal direction; the multipliers then move alone and an active
  constraint is dropped, or, when none can be, the problem is infeasible (Goldfarb-Idnani's test).
- Termination: the dual objective increases at every step with a positive step length; a
  degenerate cycle of zero steps is cut by the iteration limit (``max_iter``, default
  ``8 (2 n + m) + 16``; a solve takes about one iteration per active constraint).
- Feasibility: a constraint counts as violated when ``a^T x - b > FEAS_TOL (|b| + |a| |x|)``.
  After each addition one step of iterative refinement puts the active constraints back on
  their boundaries (the steps' rounding is relative to the path from the unconstrained
  minimiser, not to ``x``). On exit the active bounds are set exactly and ``x`` is clipped to
  the box, so the simple bounds hold exactly (bitwise ``lo <= qd <= hi``); general rows hold to
  ``FEAS_TOL`` relative (active ones to rounding). The multipliers are recomputed at the end
  from stationarity (``u = R^-1 Z_1^T (H x - g)``) rather than accumulated over the steps.

Status and the returned ``qd``:

- ``SOLVED``: the minimiser.
- ``INFEASIBLE`` (the rows and the box have no common point, or ``lo_i > hi_i``): ``qd`` is the
  exact minimiser over the box of the elastic problem
  ``1/2 x^T H x - g^T x + rho/2 sum_j max(0, (c_j x - d_j) / |c_j|)^2`` with
  ``rho = RELAX_WEIGHT * lambda_max(H)`` (:func:`dense_qp`: the largest diagonal entry of ``H``;
  ``rho`` is reported in the info vector): the rows are violated by about the least amount in the
  least-squares sense (up to ~1/RELAX_WEIGHT of the task's own pull) and the box still holds
  exactly; a joint with ``lo_i > hi_i`` is held at the midpoint (or the finite bound).
  Its multipliers are the elastic problem's: ``mu_j = rho max(0, ...) / |c_j|`` (0 for a zero
  row, which cannot be relaxed towards).
- ``ITER_LIMIT``: the last iterate clipped to the box (the box holds, rows may not).
- ``INVALID``: non-finite input, NaN or empty-side bounds (``lo = inf`` or ``hi = -inf``), or a
  Hessian that is not positive definite; ``qd`` is NaN.

Multipliers: ``H qd - g + C^T mu + z = 0`` with ``mu (m,) >= 0`` and the signed box multipliers
``z (n,)`` (``z_i > 0`` at the upper bound, ``< 0`` at the lower one). Active constraints are
reported as codes: ``i`` the upper bound of joint ``i``, ``n + i`` its lower bound, ``2 n + j``
row ``j``.
"""

from __future__ import annotations

import numpy as np

from engine.kernels.jit import kernel

SOLVED, INFEASIBLE, ITER_LIMIT, INVALID = 0, 1, 2, 3
FEAS_TOL = 1e-13  # relative violation that counts as a violated constraint
DEP_TOL = 64.0 * 2.220446049250313e-16  # |Z_2^T n| below DEP_TOL |Z|_F |n|: n depends on the active normals
LAM_FLOOR = 1e-8  # Hessian eigenvalues are floored at (LAM_FLOOR * sigma_1)^2
RELAX_WEIGHT = 1e6  # weight of the squared row violations, relative to lambda_max(H), when infeasible

# The buffers (see qp_buffers) are four arrays, so that a call passes four array references
# (a tuple of twenty arrays costs ~0.3 µs of reference counting per call, more than the common
# case's whole solve): matrices, rows, vectors as rows of one array, integer vectors likewise.
MAT_Z, MAT_R, MAT_Z0 = 0, 1, 2
V_X0, V_X, V_LO, V_HI, V_B, V_ROW_NORM, V_ELASTIC_NORM, V_D, V_STEP, V_DUAL_STEP = 0, 1, 2, 3, 4, 5, 6, 7, 8, 9
V_GRAD, V_EIG, V_PROJ, V_U, V_QD, V_BOX, V_ROWS, V_INFO = 10, 11, 12, 13, 14, 15, 16, 17
N_VEC = 18
I_ACT, I_FLAG, I_ACTIVE = 0, 1, 2
# Layout of the info vector: number of active constraints, the elastic weight rho (0 unless infeasible).
INFO_ACTIVE, INFO_RHO = 0, 1


@kernel
def qp_buffers(n, m):
    """Work buffers for a QP with ``n`` variables and ``m`` general rows (``N = n + m``, the
    elastic problem's size): ``(mats (3, N, N), A (m, N), vecs (N_VEC, N + 1), ints (3, 2 N + m +
    1) int64)``. ``mats`` holds the factor ``Z``, the triangle ``R`` and the initial factor ``Z0``;
    ``vecs`` and ``ints`` hold vectors as rows (``V_*``, ``I_*``). The outputs: ``qd =
    vecs[V_QD, :n]``, box multipliers ``vecs[V_BOX, :n]``, row multipliers ``vecs[V_ROWS, :m]``,
    active codes ``ints[I_ACTIVE, :count]`` with ``count = vecs[V_INFO, INFO_ACTIVE]``, the
    elastic weight ``vecs[V_INFO, INFO_RHO]``."""
    N = n + m
    return (np.zeros((3, N, N)), np.zeros((m, N)), np.zeros((N_VEC, N + 1)), np.zeros((3, 2 * N + m + 1), dtype=np.int64))


@kernel
def default_max_iter(n, m):
    """The default iteration limit for ``n`` variables and ``m`` rows."""
    return 8 * (2 * n + m) + 16


@kernel
def _dual_active_set(N, M, Z, R, x, lo, hi, A, b, row_norm, u, act, flag, d, z, r, max_iter):
    """Goldfarb-Idnani from the unconstrained minimiser ``x (N,)`` and a factor ``Z (N, N)`` of
    ``H^-1`` (both updated in place) for the box ``lo``/``hi (N,)`` and the rows ``A[:M, :N] x <=
    b``. Returns ``(status, iterations, q)``: the active codes are ``act[:q]`` with multipliers
    ``u[:q]`` (codes: ``i`` upper bound of ``x_i``, ``N + i`` lower bound, ``2 N + j`` row ``j``).

    Internally a constraint ``k`` is ``n_k^T x >= r_k`` with the inward normal ``n_k = -a_k``
    (so the slack ``n_k^T x - r_k = b_k - a_k^T x``), the stationarity ``H x - g = N_A u``, and
    ``Z^T N_A = [R; 0]`` with ``R (q, q)`` upper triangular. The small steps (slacks, ``Z^T n``,
    the Givens updates) are written out in place: a call of a helper costs an atomic reference
    count per array argument, which at this size is more than its arithmetic.
    """
    z_norm = 0.0
    for i in range(N):
        for c in range(N):
            z_norm += Z[i, c] * Z[i, c]
    z_norm = np.sqrt(z_norm)
    for k in range(2 * N + M):
        flag[k] = 0
    q = 0
    iters = 0
    while True:
        # Step 1: the most violated constraint (violation over the row norm), if any.
        x_norm = 0.0
        for i in range(N):
            x_norm += x[i] * x[i]
        x_norm = np.sqrt(x_norm)
        p = -1
        worst = 0.0
        for i in range(N):
            if flag[i] == 0 and hi[i] < np.inf:
                sl = hi[i] - x[i]
                if sl < -FEAS_TOL * (abs(hi[i]) + x_norm) and sl < worst:
                    worst = sl
                    p = i
            if flag[N + i] == 0 and lo[i] > -np.inf:
                sl = x[i] - lo[i]
                if sl < -FEAS_TOL * (abs(lo[i]) + x_norm) and sl < worst:
                    worst = sl
                    p = N + i
        for j in range(M):
            if flag[2 * N + j] != 0:
                continue
            sl = b[j]
            for c in range(N):
                sl -= A[j, c] * x[c]
            if sl < -FEAS_TOL * (abs(b[j]) + row_norm[j] * x_norm):
                if row_norm[j] == 0.0:  # 0 <= b_j < 0
                    return INFEASIBLE, iters, q
                if sl / row_norm[j] < worst:
                    worst = sl / row_norm[j]
                    p = 2 * N + j
        if p < 0:
            return SOLVED, iters, q
        if p < N:
            s_p = hi[p] - x[p]
            n_norm = 1.0
        elif p < 2 * N:
            s_p = x[p - N] - lo[p - N]
            n_norm = 1.0
        else:
            s_p = worst * row_norm[p - 2 * N]
            n_norm = row_norm[p - 2 * N]
        u_plus = 0.0
        # Step 2: move towards satisfying p, dropping constraints whose multiplier reaches 0.
        while True:
            iters += 1
            if iters > max_iter:
                return ITER_LIMIT, iters, q
            # d = Z^T n_p
            if p < N:
                for c in range(N):
                    d[c] = -Z[p, c]
            elif p < 2 * N:
                for c in range(N):
                    d[c] = Z[p - N, c]
            else:
                j = p - 2 * N
                for c in range(N):
                    acc = 0.0
                    for i in range(N):
                        acc -= Z[i, c] * A[j, i]
                    d[c] = acc
            d2 = 0.0
            for c in range(q, N):
                d2 += d[c] * d[c]
            dependent = d2 <= (DEP_TOL * z_norm * n_norm) ** 2
            # r = R^-1 d[:q]: how the active multipliers change per unit of u_plus
            for k in range(q - 1, -1, -1):
                acc = d[k]
                for c in range(k + 1, q):
                    acc -= R[k, c] * r[c]
                r[k] = acc / R[k, k]
            t1 = np.inf
            pos = -1
            for k in range(q):
                if r[k] > 0.0:
                    t = u[k] / r[k]
                    if t < t1:
                        t1 = t
                        pos = k
            t2 = np.inf if dependent else -s_p / d2
            if t1 == np.inf and t2 == np.inf:
                return INFEASIBLE, iters, q
            if not dependent:
                # the primal step z = Z_2 Z_2^T n_p (Z_2: the columns after q)
                for i in range(N):
                    acc = 0.0
                    for c in range(q, N):
                        acc += Z[i, c] * d[c]
                    z[i] = acc
            if t2 <= t1:
                # Full step: p becomes active.
                for i in range(N):
                    x[i] += t2 * z[i]
                for k in range(q):
                    u[k] = max(u[k] - t2 * r[k], 0.0)
                # Rotate columns q..N-1 of Z so that d has zeros below entry q; append d[:q+1] to R.
                for jj in range(N - 1, q, -1):
                    da = d[jj - 1]
                    db = d[jj]
                    if db == 0.0:
                        continue
                    h = np.hypot(da, db)
                    cc = da / h
                    ss = db / h
                    d[jj - 1] = h
                    d[jj] = 0.0
                    for i in range(N):
                        t_a = Z[i, jj - 1]
                        t_b = Z[i, jj]
                        Z[i, jj - 1] = cc * t_a + ss * t_b
                        Z[i, jj] = ss * t_a - cc * t_b
                for i in range(q + 1):
                    R[i, q] = d[i]
                u[q] = u_plus + t2
                act[q] = p
                flag[p] = 1
                q += 1
                # Refinement: x came from x0 by steps, so its rounding is relative to the path, not
                # to x. x -= Z_1 R^-T s_A zeroes the active slacks s_A to rounding (u is recomputed
                # from stationarity at the end).
                for k in range(q):
                    code = act[k]
                    if code < N:
                        acc = hi[code] - x[code]
                    elif code < 2 * N:
                        acc = x[code - N] - lo[code - N]
                    else:
                        j = code - 2 * N
                        acc = b[j]
                        for c in range(N):
                            acc -= A[j, c] * x[c]
                    for c in range(k):
                        acc -= R[c, k] * d[c]
                    d[k] = acc / R[k, k]
                for i in range(N):
                    acc = 0.0
                    for k in range(q):
                        acc += Z[i, k] * d[k]
                    x[i] -= acc
                break
            # Partial step: the multiplier of act[pos] reaches 0 and it leaves the active set.
            if not dependent:
                for i in range(N):
                    x[i] += t1 * z[i]
                s_p += t1 * d2
            for k in range(q):
                u[k] = max(u[k] - t1 * r[k], 0.0)
            u_plus += t1
            flag[act[pos]] = 0
            # Remove column pos of R, then restore its triangle with Givens rotations (applied to
            # the same columns of Z).
            for k in range(pos, q - 1):
                act[k] = act[k + 1]
                u[k] = u[k + 1]
                for i in range(k + 2):
                    R[i, k] = R[i, k + 1]
            for i in range(q):
                R[i, q - 1] = 0.0
            q -= 1
            for jj in range(pos, q):
                ra = R[jj, jj]
                rb = R[jj + 1, jj]
                if rb == 0.0:
                    continue
                h = np.hypot(ra, rb)
                cc = ra / h
                ss = rb / h
                R[jj, jj] = h
                R[jj + 1, jj] = 0.0
                for k in range(jj + 1, q):
                    t_a = R[jj, k]
                    t_b = R[jj + 1, k]
                    R[jj, k] = cc * t_a + ss * t_b
                    R[jj + 1, k] = ss * t_a - cc * t_b
                for i in range(N):
                    t_a = Z[i, jj]
                    t_b = Z[i, jj + 1]
                    Z[i, jj] = cc * t_a + ss * t_b
                    Z[i, jj + 1] = ss * t_a - cc * t_b


@kernel
def _screen(n, x0, lo, hi, C, d, row_norm):
    """One pass over the inputs at the unconstrained minimiser ``x0[:n]``: ``(valid, box_ok,
    violated)``: every entry finite (bounds may be -inf/inf on their own side), ``lo <= hi``, and
    whether ``x0`` violates a bound or a row by the solver's tolerance. Writes ``row_norm``."""
    valid = True
    box_ok = True
    violated = False
    x_norm = 0.0
    for i in range(n):
        if not np.isfinite(x0[i]):
            valid = False
        x_norm += x0[i] * x0[i]
    x_norm = np.sqrt(x_norm)
    for i in range(n):
        if np.isnan(lo[i]) or np.isnan(hi[i]) or lo[i] == np.inf or hi[i] == -np.inf:
            valid = False
        elif lo[i] > hi[i]:
            box_ok = False
        if x0[i] - hi[i] > FEAS_TOL * (abs(hi[i]) + x_norm) or lo[i] - x0[i] > FEAS_TOL * (abs(lo[i]) + x_norm):
            violated = True
    for j in range(C.shape[0]):
        if not np.isfinite(d[j]):
            valid = False
        sq = 0.0
        acc = -d[j]
        for c in range(n):
            if not np.isfinite(C[j, c]):
                valid = False
            sq += C[j, c] * C[j, c]
            acc += C[j, c] * x0[c]
        row_norm[j] = np.sqrt(sq)
        if acc > FEAS_TOL * (abs(d[j]) + row_norm[j] * x_norm):
            violated = True
    return valid, box_ok, violated


@kernel
def _write_outputs(n, m, N, status, q, buf):
    """Snap the active bounds, clip to the box and write ``qd``, the multipliers and the active
    codes (in the caller's layout) from the solver state of an ``N``-variable problem (``N > n``:
    the elastic one, whose rows are those of ``C`` over their norms)."""
    vecs = buf[2]
    ints = buf[3]
    x = vecs[V_X]
    lo = vecs[V_LO]
    hi = vecs[V_HI]
    row_norm = vecs[V_ROW_NORM]
    u = vecs[V_U]
    act = ints[I_ACT]
    qd = vecs[V_QD]
    box = vecs[V_BOX]
    rows = vecs[V_ROWS]
    active = ints[I_ACTIVE]
    for i in range(n):
        box[i] = 0.0
    for j in range(m):
        rows[j] = 0.0
    count = 0
    for k in range(q):
        code = act[k]
        if code < N:
            if code < n:
                x[code] = hi[code]
                box[code] = u[k]
                active[count] = code
                count += 1
        elif code < 2 * N:
            i = code - N
            if i < n:
                x[i] = lo[i]
                box[i] = -u[k]
                active[count] = n + i
                count += 1
        else:
            j = code - 2 * N
            if n == N:
                rows[j] = u[k]
            elif row_norm[j] > 0.0:
                rows[j] = u[k] / row_norm[j]
            active[count] = 2 * n + j
            count += 1
    for i in range(n):
        qd[i] = min(max(x[i], lo[i]), hi[i])
    vecs[V_INFO, INFO_ACTIVE] = count


@kernel
def _multipliers(N, q, Z, R, grad, u, w):
    """Recompute the active multipliers from stationarity, ``N_A u = H x - g`` with ``grad = H x
    - g (N,)``: ``u = R^-1 Z_1^T grad`` (clamped at 0). The multipliers the steps accumulate carry
    the rounding of every step; these are as accurate as ``x``."""
    for k in range(q):
        acc = 0.0
        for i in range(N):
            acc += Z[i, k] * grad[i]
        w[k] = acc
    for k in range(q - 1, -1, -1):
        acc = w[k]
        for c in range(k + 1, q):
            acc -= R[k, c] * w[c]
        w[k] = acc / R[k, k]
        u[k] = max(w[k], 0.0)


@kernel
def _solve_from_start(n, m, lo, hi, C, d, h_max, max_iter, box_ok, buf):
    """Run the solver from ``Z0 (n, n)`` and ``x0 (n,)`` in ``buf`` (the factor of ``H^-1`` and
    the unconstrained minimiser); on infeasibility solve the elastic problem. ``h_max`` the largest
    eigenvalue of ``H``. Returns ``(status, iterations, q, N)``: the solver state is left in
    ``buf`` for :func:`_finish`, ``N = n`` for the problem itself, ``n + m`` for the elastic one."""
    mats, A, vecs, ints = buf
    Z = mats[MAT_Z]
    R = mats[MAT_R]
    Z0 = mats[MAT_Z0]
    x0 = vecs[V_X0]
    x = vecs[V_X]
    lo_w = vecs[V_LO]
    hi_w = vecs[V_HI]
    b = vecs[V_B]
    row_norm = vecs[V_ROW_NORM]
    elastic_norm = vecs[V_ELASTIC_NORM]
    u = vecs[V_U]
    act = ints[I_ACT]
    flag = ints[I_FLAG]
    dv = vecs[V_D]
    zv = vecs[V_STEP]
    rv = vecs[V_DUAL_STEP]
    info = vecs[V_INFO]
    info[INFO_RHO] = 0.0
    if max_iter <= 0:
        max_iter = default_max_iter(n, m)
    iters = 0
    if box_ok:
        for i in range(n):
            x[i] = x0[i]
            lo_w[i] = lo[i]
            hi_w[i] = hi[i]
            for c in range(n):
                Z[i, c] = Z0[i, c]
        for j in range(m):
            b[j] = d[j]
            for c in range(n):
                A[j, c] = C[j, c]
        status, iters, q = _dual_active_set(n, m, Z, R, x, lo_w, hi_w, A, b, row_norm, u, act, flag, dv, zv, rv, max_iter)
        if status != INFEASIBLE:
            return status, iters, q, n
    # Elastic problem in (x, s): min f(x) + rho/2 |s|^2, box on x, c_j x / |c_j| - s_j <= d_j / |c_j|.
    N = n + m
    rho = RELAX_WEIGHT * h_max
    info[INFO_RHO] = rho
    for i in range(N):
        for c in range(N):
            Z[i, c] = 0.0
        x[i] = 0.0
        lo_w[i] = -np.inf
        hi_w[i] = np.inf
    for i in range(n):
        x[i] = x0[i]
        for c in range(n):
            Z[i, c] = Z0[i, c]
        lo_w[i] = lo[i]
        hi_w[i] = hi[i]
        if lo[i] > hi[i]:  # an empty interval: hold the joint at its middle (or the finite end)
            if lo[i] == -np.inf:
                mid = hi[i]
            elif hi[i] == np.inf:
                mid = lo[i]
            else:
                mid = 0.5 * (lo[i] + hi[i])
            lo_w[i] = mid
            hi_w[i] = mid
    for j in range(m):
        Z[n + j, n + j] = 1.0 / np.sqrt(rho)
        inv = 1.0 / row_norm[j] if row_norm[j] > 0.0 else 1.0
        for c in range(N):
            A[j, c] = 0.0
        for c in range(n):
            A[j, c] = C[j, c] * inv
        A[j, n + j] = -1.0
        b[j] = d[j] * inv
        elastic_norm[j] = np.sqrt(2.0) if row_norm[j] > 0.0 else 1.0
    status, more, q = _dual_active_set(N, m, Z, R, x, lo_w, hi_w, A, b, elastic_norm, u, act, flag, dv, zv, rv, max_iter)
    return (INFEASIBLE if status == SOLVED else status), iters + more, q, N


@kernel
def _finish(n, m, status, q, N, buf):
    """Multipliers from the gradient ``H x - g`` that the entry point left in ``vecs[V_GRAD, :n]``
    (the elastic part is added here), then the outputs."""
    if status != ITER_LIMIT and q > 0:
        mats = buf[0]
        vecs = buf[2]
        grad = vecs[V_GRAD]
        x = vecs[V_X]
        rho = vecs[V_INFO, INFO_RHO]
        for j in range(n, N):
            grad[j] = rho * x[j]
        _multipliers(N, q, mats[MAT_Z], mats[MAT_R], grad, vecs[V_U], vecs[V_D])
    _write_outputs(n, m, N, status, q, buf)


@kernel
def _set_outputs(n, m, vecs, qd_value, multiplier):
    """``qd`` to ``x0`` (or ``qd_value`` when it is NaN), the multipliers to ``multiplier``, no
    active constraint (explicit loops: slice assignment costs more than the solve here)."""
    for i in range(n):
        vecs[V_QD, i] = qd_value if np.isnan(qd_value) else vecs[V_X0, i]
        vecs[V_BOX, i] = multiplier
    for j in range(m):
        vecs[V_ROWS, j] = multiplier
    vecs[V_INFO, INFO_ACTIVE] = 0
    vecs[V_INFO, INFO_RHO] = 0.0


@kernel
def _invalid(n, m, vecs):
    _set_outputs(n, m, vecs, np.nan, np.nan)
    return INVALID, 0


@kernel
def _unconstrained(n, m, vecs):
    _set_outputs(n, m, vecs, 0.0, 0.0)
    return SOLVED, 0


@kernel
def dls_qp(U, s, V, damping, lam_null, xdot, lo, hi, C, d, max_iter, buf):
    """Bounded damped inverse from the thin SVD ``J = U diag(s) V^T`` (``U (p, k)``, ``s (k,)``,
    ``V (n, k)``, as :func:`engine.kernels.svd.jacobi_svd` gives): minimise
    ``|J x - xdot|^2 + sum_i damping_i^2 (v_i^T x)^2 + lam_null^2 |x - V V^T x|^2`` subject to
    ``lo <= x <= hi (n,)`` and ``C (m, n) x <= d (m,)``. ``xdot``: its first ``p`` entries.
    For DLS, ``damping[:] = lam_null = lambda``. ``max_iter`` 0 for the default. Outputs in
    ``buf`` (:func:`qp_buffers`). Returns ``(status, iterations)``."""
    p = U.shape[0]
    n = V.shape[0]
    k = s.shape[0]
    m = C.shape[0]
    vecs = buf[2]
    x0 = vecs[V_X0]
    eig = vecs[V_EIG]
    proj = vecs[V_PROJ]
    row_norm = vecs[V_ROW_NORM]
    valid = np.isfinite(lam_null)
    scale = lam_null if n > k else 0.0
    for i in range(k):
        if not (np.isfinite(s[i]) and np.isfinite(damping[i])):
            valid = False
        scale = max(scale, s[i], abs(damping[i]))
    if not (valid and scale > 0.0):
        return _invalid(n, m, vecs)
    floor_sq = (LAM_FLOOR * scale) ** 2
    h_max = 0.0
    for i in range(k):
        eig[i] = max(s[i] * s[i] + damping[i] * damping[i], floor_sq)
        h_max = max(h_max, eig[i])
    lam0_sq = max(lam_null * lam_null, floor_sq)
    if n > k:
        h_max = max(h_max, lam0_sq)
    for j in range(n):
        x0[j] = 0.0
    for i in range(k):
        acc = 0.0
        for r in range(p):
            acc += U[r, i] * xdot[r]
        proj[i] = acc
        coef = s[i] * acc / eig[i]
        for j in range(n):
            x0[j] += V[j, i] * coef
    valid, box_ok, violated = _screen(n, x0, lo, hi, C, d, row_norm)
    if not valid:
        return _invalid(n, m, vecs)
    if box_ok and not violated:
        return _unconstrained(n, m, vecs)
    _svd_factor(V, eig, np.sqrt(lam0_sq), buf[0][MAT_Z0])
    status, iters, q, N = _solve_from_start(n, m, lo, hi, C, d, h_max, max_iter, box_ok, buf)
    # H x - g = V (diag(eig) V^T x - diag(s) U^T xdot) + lam0^2 (x - V V^T x)
    x = vecs[V_X]
    grad = vecs[V_GRAD]
    for j in range(n):
        grad[j] = lam0_sq * x[j]
    for i in range(k):
        acc = 0.0
        for j in range(n):
            acc += V[j, i] * x[j]
        coef = (eig[i] - lam0_sq) * acc - s[i] * proj[i]
        for j in range(n):
            grad[j] += V[j, i] * coef
    _finish(n, m, status, q, N, buf)
    return status, iters


@kernel
def _svd_factor(V, eig, lam0, Z0):
    """``Z0 = [V diag(eig^-1/2), V_perp / lam0]`` with ``V_perp (n, n - k)`` an orthonormal
    completion of ``V (n, k)``: ``Z0 Z0^T = H^-1``."""
    n = V.shape[0]
    k = V.shape[1]
    for c in range(k):
        w = 1.0 / np.sqrt(eig[c])
        for r in range(n):
            Z0[r, c] = V[r, c] * w
    for c in range(k, n):
        # The standard basis vector with the largest part outside the columns so far.
        best = -1.0
        pick = 0
        for t in range(n):
            res = 1.0
            for i in range(k):
                res -= V[t, i] * V[t, i]
            for i in range(k, c):
                res -= Z0[t, i] * Z0[t, i]
            if res > best:
                best = res
                pick = t
        for r in range(n):
            Z0[r, c] = 1.0 if r == pick else 0.0
        for _ in range(2):  # Gram-Schmidt twice is enough (Giraud et al. 2005)
            for i in range(k):
                dot = 0.0
                for r in range(n):
                    dot += V[r, i] * Z0[r, c]
                for r in range(n):
                    Z0[r, c] -= dot * V[r, i]
            for i in range(k, c):
                dot = 0.0
                for r in range(n):
                    dot += Z0[r, i] * Z0[r, c]
                for r in range(n):
                    Z0[r, c] -= dot * Z0[r, i]
        norm = 0.0
        for r in range(n):
            norm += Z0[r, c] * Z0[r, c]
        norm = np.sqrt(norm)
        for r in range(n):
            Z0[r, c] /= norm
    for c in range(k, n):
        for r in range(n):
            Z0[r, c] /= lam0


@kernel
def dense_qp(H, g, lo, hi, C, d, max_iter, buf):
    """The QP with an explicit symmetric positive definite ``H (n, n)`` and ``g (n,)`` (Cholesky
    ``H = L L^T``, ``Z0 = L^-T``); otherwise as :func:`dls_qp`. A Hessian that is not positive
    definite gives ``INVALID``."""
    n = H.shape[0]
    m = C.shape[0]
    R = buf[0][MAT_R]
    Z0 = buf[0][MAT_Z0]
    vecs = buf[2]
    x0 = vecs[V_X0]
    row_norm = vecs[V_ROW_NORM]
    valid = True
    h_max = 0.0
    for i in range(n):
        if not np.isfinite(g[i]):
            valid = False
        for j in range(n):
            if not np.isfinite(H[i, j]):
                valid = False
        h_max = max(h_max, H[i, i])
    if not valid:
        return _invalid(n, m, vecs)
    # Cholesky into the lower triangle of R (free until the solver runs).
    for j in range(n):
        acc = H[j, j]
        for c in range(j):
            acc -= R[j, c] * R[j, c]
        if not acc > 0.0:
            return _invalid(n, m, vecs)
        ljj = np.sqrt(acc)
        R[j, j] = ljj
        for i in range(j + 1, n):
            acc = H[i, j]
            for c in range(j):
                acc -= R[i, c] * R[j, c]
            R[i, j] = acc / ljj
    # x0 = L^-T L^-1 g
    for i in range(n):
        acc = g[i]
        for c in range(i):
            acc -= R[i, c] * x0[c]
        x0[i] = acc / R[i, i]
    for i in range(n - 1, -1, -1):
        acc = x0[i]
        for c in range(i + 1, n):
            acc -= R[c, i] * x0[c]
        x0[i] = acc / R[i, i]
    valid, box_ok, violated = _screen(n, x0, lo, hi, C, d, row_norm)
    if not valid:
        return _invalid(n, m, vecs)
    if box_ok and not violated:
        return _unconstrained(n, m, vecs)
    # Z0 = L^-T: column j solves L^T z = e_j (upper triangular, zero below j).
    for j in range(n):
        for i in range(n - 1, -1, -1):
            acc = 1.0 if i == j else 0.0
            for c in range(i + 1, j + 1):
                acc -= R[c, i] * Z0[c, j]
            Z0[i, j] = acc / R[i, i] if i <= j else 0.0
    for i in range(n):  # R is the solver's triangle from here on
        for j in range(n):
            R[i, j] = 0.0
    status, iters, q, N = _solve_from_start(n, m, lo, hi, C, d, h_max, max_iter, box_ok, buf)
    x = vecs[V_X]
    grad = vecs[V_GRAD]
    for i in range(n):
        acc = -g[i]
        for j in range(n):
            acc += H[i, j] * x[j]
        grad[i] = acc
    _finish(n, m, status, q, N, buf)
    return status, iters

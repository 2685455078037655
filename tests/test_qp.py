"""The bounded inverse's QP solver (engine.kernels.qp) against independent truth: the KKT
conditions (a certificate of the unique minimiser of a strictly convex QP, whatever the
algorithm), the damped least-squares solution by LAPACK's least squares on the stacked system
``[J; lambda I]``, and the ``quadprog`` package (Turlach's Fortran Goldfarb-Idnani: a different
implementation, exact to rounding, unlike interior-point or SLSQP solvers whose 1e-6..1e-8
tolerances could not check 1e-9)."""

from fractions import Fraction

import numpy as np
import pytest
import quadprog
from hypothesis import assume, given, note, settings
from hypothesis import strategies as st

from engine.kernels import inverse as inverse_kernels
from engine.kernels import qp as kernels
from engine.kernels import svd as svd_kernels
from engine.qp import QPResult, bounded_dls, result_from_buffers, solve_qp

SOLVED, INFEASIBLE, ITER_LIMIT, INVALID = kernels.SOLVED, kernels.INFEASIBLE, kernels.ITER_LIMIT, kernels.INVALID


def _jacobian(rng, p, n, rank_drop):
    J = rng.normal(size=(p, n)) * 10.0 ** rng.uniform(-1.0, 0.5)
    if rank_drop:
        U, s, Vt = np.linalg.svd(J, full_matrices=False)
        s[rng.integers(0, len(s)) :] = 0.0
        J = U @ np.diag(s) @ Vt
    return J


def _box(rng, n, kind):
    """Joint-rate bounds of several shapes (some containing 0, some not, fixed and free joints)."""
    around = (-rng.uniform(0.05, 1.0, n), rng.uniform(0.05, 1.0, n))
    centre = rng.choice([-1.0, 1.0], n) * rng.uniform(0.2, 1.0, n)
    half = rng.uniform(0.01, 0.3, n)
    shifted = (centre - half, centre + half)
    if kind == "around zero":
        return around
    if kind == "shifted":
        return shifted
    if kind == "unbounded":
        return np.full(n, -np.inf), np.full(n, np.inf)
    pick = rng.integers(0, 4, n)
    lo = np.where(pick == 0, around[0], np.where(pick == 1, shifted[0], np.where(pick == 2, -np.inf, around[0])))
    hi = np.where(pick == 0, around[1], np.where(pick == 1, shifted[1], np.where(pick == 2, rng.uniform(0.1, 1.0, n), np.inf)))
    if kind == "fixed joints":
        fixed = rng.random(n) < 0.3
        lo = np.where(fixed, shifted[0], lo)
        hi = np.where(fixed, shifted[0], hi)
    return lo, hi


def _rows(rng, n, m, kind, lo, hi):
    """``m`` rows ``C x <= d`` satisfied by a point of the box (some of them tight there)."""
    x_f = np.clip(rng.normal(size=n) * 0.3, lo, hi)
    C = rng.normal(size=(m, n))
    if m >= 2 and kind == "duplicates":
        C[1::2] = C[0::2][: m // 2]
    if m >= 2 and kind == "parallel":
        C[1:] = C[0] * rng.uniform(0.1, 10.0, (m - 1, 1)) + 1e-3 * rng.normal(size=(m - 1, n)) * (rng.random((m - 1, 1)) < 0.5)
    if kind == "box-like":
        for j in range(m):
            C[j] = 0.0
            C[j, rng.integers(0, n)] = rng.choice([-1.0, 1.0]) * rng.uniform(0.5, 2.0)
    slack = rng.uniform(0.0, 0.3, m) * (rng.random(m) < 0.7)
    return C, C @ x_f + slack


@st.composite
def problems(draw, lam_exp=(-3.0, 0.0), m_max=8, box_kinds=("around zero", "shifted", "mixed", "fixed joints", "unbounded")):
    """``(J (p, n), lam, xdot (p,), lo, hi (n,), C (m, n), d (m,))`` with a feasible set; ``lam``
    is ``10^lam_exp`` times the largest singular value of ``J`` (1 when ``J = 0``)."""
    n = draw(st.integers(1, 12))
    p = draw(st.sampled_from([3, 6]))
    m = draw(st.integers(0, m_max))
    box_kind = draw(st.sampled_from(box_kinds))
    row_kind = draw(st.sampled_from(["random", "duplicates", "parallel", "box-like"]))
    rank_drop = draw(st.booleans())
    lam_rel = 10.0 ** draw(st.floats(*lam_exp))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    J = _jacobian(rng, p, n, rank_drop)
    lam = lam_rel * (np.linalg.norm(J, 2) or 1.0)
    xdot = rng.normal(size=p) * 10.0 ** rng.uniform(-1.0, 1.0)
    lo, hi = _box(rng, n, box_kind)
    C, d = _rows(rng, n, m, row_kind, lo, hi)
    note(f"p={p} n={n} m={m} box={box_kind} rows={row_kind} rank_drop={rank_drop} lam/sigma_1={lam_rel:.3g} seed={seed}")
    return J, lam, xdot, lo, hi, C, d


def _exact_dls(J, lam, xdot):
    """``(J^T J + lam^2 I)^-1 J^T xdot`` in exact rational arithmetic (of the float inputs)."""
    p, n = J.shape
    Jq = [[Fraction(v) for v in row] for row in J]
    lam_sq = Fraction(lam) ** 2
    rows = [
        [sum(Jq[k][i] * Jq[k][j] for k in range(p)) + (lam_sq if i == j else 0) for j in range(n)]
        + [sum(Jq[k][i] * Fraction(xdot[k]) for k in range(p))]
        for i in range(n)
    ]
    for c in range(n):  # symmetric positive definite: no pivoting needed
        for r in range(c + 1, n):
            f = rows[r][c] / rows[c][c]
            rows[r] = [a - f * b for a, b in zip(rows[r], rows[c], strict=True)]
    x = [Fraction(0)] * n
    for r in range(n - 1, -1, -1):
        x[r] = (rows[r][n] - sum(rows[r][c] * x[c] for c in range(r + 1, n))) / rows[r][r]
    return np.array([float(v) for v in x])


def _hessian(J, lam, xdot):
    n = J.shape[1]
    return J.T @ J + lam**2 * np.eye(n), J.T @ xdot


def assert_kkt(res: QPResult, H, g, lo, hi, C, d, stationarity=1e-12):
    """The KKT conditions of ``min 1/2 x^T H x - g^T x`` s.t. ``lo <= x <= hi``, ``C x <= d``:
    box exactly, rows to 1e-12 relative, dual feasibility, complementarity, stationarity."""
    x, mu, z = res.qd, res.row_multipliers, res.box_multipliers
    assert np.all(np.isfinite(x))
    assert np.all(lo <= x) and np.all(x <= hi), "a bound is exceeded"
    row_scale = np.abs(d) + np.linalg.norm(C, axis=1) * np.linalg.norm(x)
    slack = d - C @ x
    assert np.all(slack >= -1e-12 * row_scale), "a row is violated"
    assert np.all(mu >= 0.0)
    assert np.all((z <= 0.0) | (x == hi)), "an upper multiplier at a joint off its upper bound"
    assert np.all((z >= 0.0) | (x == lo)), "a lower multiplier at a joint off its lower bound"
    assert np.all((mu == 0.0) | (np.abs(slack) <= 1e-12 * row_scale)), "a multiplier on a slack row"
    residual = H @ x - g + C.T @ mu + z
    scale = np.abs(H) @ np.abs(x) + np.abs(g) + np.abs(C.T) @ mu + np.abs(z)
    assert np.abs(residual).max() <= stationarity * max(scale.max(), np.finfo(float).tiny), (residual, scale)


def _quadprog(H, g, lo, hi, C, d):
    """``quadprog.solve_qp`` with the box as rows (fixed joints as equalities, first)."""
    n = H.shape[0]
    eye = np.eye(n)
    fixed = lo == hi
    upper = ~fixed & np.isfinite(hi)
    lower = ~fixed & np.isfinite(lo)
    A = np.vstack([eye[fixed], -eye[upper], eye[lower], -C]).T
    b = np.concatenate([lo[fixed], -hi[upper], lo[lower], -d])
    if b.size == 0:
        return np.linalg.solve(H, g)
    return quadprog.solve_qp(H, g, A, b, int(fixed.sum()))[0]


@settings(max_examples=300, deadline=None)
@given(problems(lam_exp=(-8.0, 0.5), m_max=32))
def test_kkt_conditions_hold(problem):
    J, lam, xdot, lo, hi, C, d = problem
    res = bounded_dls(J, lam, xdot, lo, hi, C, d)
    assert res.status == SOLVED, res
    H, g = _hessian(J, lam, xdot)
    # The backward error grows slowly with cond(H) = (sigma_1 / lam)^2 (to ~1e-12 at 1e16).
    ill = lam < 1e-3 * np.linalg.norm(J, 2)
    assert_kkt(res, H, g, lo, hi, C, d, stationarity=1e-11 if ill else 1e-12)
    assert res.iterations <= kernels.default_max_iter(J.shape[1], C.shape[0])


@settings(max_examples=300, deadline=None)
@given(problems(lam_exp=(-2.0, 0.5)))
def test_agrees_with_quadprog(problem):
    J, lam, xdot, lo, hi, C, d = problem
    H, g = _hessian(J, lam, xdot)
    try:
        ref = _quadprog(H, g, lo, hi, C, d)
    except ValueError:  # quadprog gives up on some degenerate (dependent, tight) sets: no truth to compare
        assume(False)
    scale = max(1.0, np.abs(ref).max())
    res = bounded_dls(J, lam, xdot, lo, hi, C, d)
    assert np.abs(res.qd - ref).max() <= 1e-9 * scale
    dense = solve_qp(H, g, lo, hi, C, d)
    assert np.abs(dense.qd - ref).max() <= 1e-9 * scale
    assert_kkt(dense, H, g, lo, hi, C, d)


@settings(max_examples=300, deadline=None)
@given(problems(lam_exp=(-1.3, 0.5), box_kinds=("around zero", "mixed", "unbounded")), st.booleans())
def test_equals_unconstrained_dls_when_nothing_is_active(problem, with_rows):
    """To 1e-12 of the largest rate ``|xdot|`` can ask for (``|xdot| max_i sigma_i / (sigma_i^2 +
    lam^2)``) for ``lam >= 0.05 sigma_1``: any backward-stable DLS is off by about eps (sigma_1 /
    lam)^2 of that, the price of the conditioning of ``H``, which smaller damping raises."""
    J, lam, xdot, lo, hi, C, d = problem
    ref = _exact_dls(J, lam, xdot)
    lo, hi = np.minimum(lo, -np.abs(ref) - 1.0), np.maximum(hi, np.abs(ref) + 1.0)
    C, d = (C, C @ ref + np.abs(C) @ np.abs(ref) + 0.1) if with_rows else (None, None)
    res = bounded_dls(J, lam, xdot, lo, hi, C, d)
    assert res.status == SOLVED and res.iterations == 0 and res.active == ()
    assert np.all(res.box_multipliers == 0.0) and np.all(res.row_multipliers == 0.0)
    s = np.linalg.svd(J, compute_uv=False)
    largest = np.linalg.norm(xdot) * np.max(s / (s**2 + lam**2))
    assert np.linalg.norm(res.qd - ref) <= 1e-12 * largest


@settings(max_examples=200, deadline=None)
@given(st.integers(1, 12), st.integers(0, 12), st.integers(0, 2**32 - 1))
def test_dense_hessian(n, m, seed):
    rng = np.random.default_rng(seed)
    B = rng.normal(size=(n, n))
    H = B @ B.T + 0.1 * np.eye(n)
    g = rng.normal(size=n) * 3.0
    lo, hi = _box(rng, n, "mixed")
    C, d = _rows(rng, n, m, "random", lo, hi)
    res = solve_qp(H, g, lo, hi, C, d)
    assert res.status == SOLVED
    assert_kkt(res, H, g, lo, hi, C, d)
    try:
        ref = _quadprog(H, g, lo, hi, C, d)
    except ValueError:  # quadprog gives up on some degenerate sets
        assume(False)
    assert np.abs(res.qd - ref).max() <= 1e-9 * max(1.0, np.abs(ref).max())


def _elastic_kkt(res, H, g, lo, hi, C, d, stationarity):
    """The infeasible case's documented answer: the minimiser over the box of ``1/2 x^T H x -
    g^T x + rho/2 sum_j max(0, (c_j x - d_j) / |c_j|)^2``."""
    x = res.qd
    assert np.all(lo <= x) and np.all(x <= hi)
    norms = np.linalg.norm(C, axis=1)
    expected_mu = res.relax_weight * np.maximum(0.0, (C @ x - d) / norms) / norms
    np.testing.assert_allclose(res.row_multipliers, expected_mu, rtol=1e-6, atol=1e-9 * max(1.0, expected_mu.max()))
    residual = H @ x - g + C.T @ res.row_multipliers + res.box_multipliers
    scale = np.abs(H) @ np.abs(x) + np.abs(g) + np.abs(C.T) @ res.row_multipliers + np.abs(res.box_multipliers)
    assert np.abs(residual).max() <= stationarity * scale.max()
    z = res.box_multipliers
    assert np.all((z <= 0.0) | (x == hi)) and np.all((z >= 0.0) | (x == lo))


@settings(max_examples=200, deadline=None)
@given(problems(lam_exp=(-2.0, 0.5), m_max=30), st.floats(0.01, 1.0), st.integers(0, 2**32 - 1))
def test_conflicting_rows_are_reported_and_relaxed(problem, gap, seed):
    J, lam, xdot, lo, hi, C, d = problem
    rng = np.random.default_rng(seed)
    n = J.shape[1]
    c = rng.normal(size=n)
    # c x <= -gap |c| and -c x <= -gap |c|: no common point, wherever the box is
    C = np.vstack([C, c, -c * rng.uniform(0.5, 2.0)])
    d = np.concatenate([d, [-gap * np.linalg.norm(c), -gap * np.linalg.norm(C[-1])]])
    res = bounded_dls(J, lam, xdot, lo, hi, C, d)
    assert res.status == INFEASIBLE
    assert res.iterations <= 2 * kernels.default_max_iter(n, C.shape[0])
    assert res.relax_weight > 0.0
    H, g = _hessian(J, lam, xdot)
    _elastic_kkt(res, H, g, lo, hi, C, d, stationarity=1e-9)
    # the minimum violation of the two rows is 2 gap (their distance): the elastic answer is close
    viol = np.maximum(0.0, (C[-2:] @ res.qd - d[-2:]) / np.linalg.norm(C[-2:], axis=1))
    assert viol.sum() >= 2 * gap * (1.0 - 1e-12)


def test_elastic_solution_matches_quadprog_on_the_slack_problem(rng):
    for _ in range(50):
        n, p, m = int(rng.integers(2, 9)), 6, int(rng.integers(1, 6))
        J = _jacobian(rng, p, n, False)
        lam = 0.1
        xdot = rng.normal(size=p)
        lo, hi = _box(rng, n, "around zero")
        C = rng.normal(size=(m + 1, n))
        d = np.concatenate([rng.uniform(0.0, 0.2, m), [0.0]])
        C[m] = C[0] * -1.0
        d[m] = -d[0] - 0.5 * np.linalg.norm(C[0])  # conflicts with row 0
        res = bounded_dls(J, lam, xdot, lo, hi, C, d)
        assert res.status == INFEASIBLE
        H, g = _hessian(J, lam, xdot)
        rho = res.relax_weight
        norms = np.linalg.norm(C, axis=1)
        k = C.shape[0]
        # the slacks scaled by sqrt(rho) keep quadprog's Hessian well conditioned
        H_aug = np.block([[H, np.zeros((n, k))], [np.zeros((k, n)), np.eye(k)]])
        box = np.hstack([np.eye(n), np.zeros((n, k))])
        A = np.vstack([-box, box, np.hstack([-C / norms[:, None], np.eye(k) / np.sqrt(rho)])]).T
        b = np.concatenate([-hi, lo, -d / norms])
        ref = quadprog.solve_qp(H_aug, np.concatenate([g, np.zeros(k)]), A, b)[0][:n]
        assert np.abs(res.qd - ref).max() <= 1e-7 * max(1.0, np.abs(ref).max())


def test_empty_box_and_box_conflicts_are_infeasible(rng):
    J = rng.normal(size=(6, 7))
    xdot = rng.normal(size=6)
    lo, hi = -np.ones(7), np.ones(7)
    lo[2], hi[2] = 0.5, 0.3  # an empty interval
    res = bounded_dls(J, 0.1, xdot, lo, hi)
    assert res.status == INFEASIBLE
    assert res.qd[2] == 0.4
    assert np.all(res.qd[[0, 1, 3, 4, 5, 6]] >= -1.0) and np.all(res.qd[[0, 1, 3, 4, 5, 6]] <= 1.0)
    # a row that needs qd_0 >= 2 against hi_0 = 1: the box holds, the row is violated least
    C = np.zeros((1, 7))
    C[0, 0] = -1.0
    res = bounded_dls(J, 0.1, xdot, -np.ones(7), np.ones(7), C, [-2.0])
    assert res.status == INFEASIBLE and res.qd[0] == 1.0
    # a zero row with a negative right-hand side: nothing to relax, the box-only solution
    res = bounded_dls(J, 0.1, xdot, -np.ones(7), np.ones(7), np.zeros((1, 7)), [-1.0])
    assert res.status == INFEASIBLE and res.row_multipliers[0] == 0.0
    H, g = _hessian(J, 0.1, xdot)
    box_only = QPResult(res.qd, res.box_multipliers, np.zeros(0), (), SOLVED, 0, 0.0)
    assert_kkt(box_only, H, g, -np.ones(7), np.ones(7), np.zeros((0, 7)), np.zeros(0))


def test_iteration_limit_is_reported_with_the_box_kept(rng):
    J = rng.normal(size=(6, 8))
    xdot = rng.normal(size=6) * 10.0
    lo, hi = -0.1 * np.ones(8), 0.1 * np.ones(8)
    full = bounded_dls(J, 0.05, xdot, lo, hi)
    assert full.status == SOLVED and full.iterations >= 2
    res = bounded_dls(J, 0.05, xdot, lo, hi, max_iter=1)
    assert res.status == ITER_LIMIT and res.iterations == 2
    assert np.all(lo <= res.qd) and np.all(res.qd <= hi)


def test_invalid_inputs(rng):
    J = rng.normal(size=(6, 6))
    xdot = rng.normal(size=6)
    bad = J.copy()
    bad[0, 0] = np.nan
    assert bounded_dls(bad, 0.1, xdot, -1.0, 1.0).status == INVALID
    assert np.all(np.isnan(bounded_dls(bad, 0.1, xdot, -1.0, 1.0).qd))
    assert bounded_dls(J, 0.1, xdot * np.nan, -1.0, 1.0).status == INVALID
    assert bounded_dls(J, 0.1, xdot, np.inf, 1.0).status == INVALID
    assert bounded_dls(J, 0.1, xdot, -1.0, 1.0, np.full((1, 6), np.nan), [0.0]).status == INVALID
    assert bounded_dls(np.zeros((6, 6)), 0.0, xdot, -1.0, 1.0).status == INVALID
    assert solve_qp(-np.eye(3), np.ones(3), -1.0, 1.0).status == INVALID


@pytest.mark.parametrize("lam", [1e-12, 1e-9, 1e-8, 1e-6])
def test_tiny_damping(rng, lam):
    """Damping below LAM_FLOOR sigma_1 is raised to it; above it, the KKT conditions of the
    caller's problem hold (a redundant arm: a 4-dimensional null space weighted by lam^2)."""
    for _ in range(50):
        J = rng.normal(size=(6, 10))
        xdot = rng.normal(size=6)
        lo, hi = _box(rng, 10, "mixed")
        C, d = _rows(rng, 10, 4, "random", lo, hi)
        res = bounded_dls(J, lam, xdot, lo, hi, C, d)
        assert res.status == SOLVED
        lam_eff = max(lam, kernels.LAM_FLOOR * np.linalg.norm(J, 2))
        H, g = _hessian(J, lam_eff, xdot)
        assert_kkt(res, H, g, lo, hi, C, d)


def test_dependent_and_degenerate_constraints(rng):
    n = 6
    J = rng.normal(size=(6, n))
    xdot = rng.normal(size=6) * 5.0
    lo, hi = -0.2 * np.ones(n), 0.2 * np.ones(n)
    lo[1] = hi[1] = 0.05  # a fixed joint
    # rows that repeat the bounds, duplicate each other and pass through the same vertex
    C = np.array([np.eye(n)[0], np.eye(n)[0], 2.0 * np.eye(n)[0], -np.eye(n)[3], np.ones(n), np.ones(n)])
    d = np.array([0.2, 0.2, 0.4, 0.2, 0.1, 0.1])
    res = bounded_dls(J, 0.05, xdot, lo, hi, C, d)
    assert res.status == SOLVED
    assert res.qd[1] == 0.05
    H, g = _hessian(J, 0.05, xdot)
    assert_kkt(res, H, g, lo, hi, C, d)
    np.testing.assert_allclose(res.qd, _quadprog(H, g, lo, hi, C[[0, 3, 4]], d[[0, 3, 4]]), atol=1e-9)


def test_per_direction_damping_from_the_planner_svd(rng):
    """dls_qp on the planner's SVD with a filter's effective damping: unconstrained it returns the
    filter's own rates (here the paper's adaptive damping); bounded, the KKT conditions hold for
    ``H = V diag(sigma^2 + lambda_i^2) V^T + lambda_0^2 (I - V V^T)``."""
    for n in (3, 6, 7, 12):
        for _ in range(20):
            J = _jacobian(rng, 6, n, rng.random() < 0.5)
            xdot = rng.normal(size=6)
            sv = svd_kernels.svd_buffers(n, 6)
            svd_kernels.jacobi_svd(J, sv, False)
            _, U, s, V, _, _ = sv
            k = s.shape[0]
            params = np.array([0.06, 10.0 ** rng.uniform(-1.0, 0.5)])
            qd_ref, damping = np.empty(n), np.empty(k)
            inverse_kernels.apply_inverse(inverse_kernels.ADAPTIVE, params, J, U, s, V, xdot, qd_ref, damping, np.empty((2, 6)))
            buf = kernels.qp_buffers(n, 0)
            free = np.full(n, np.inf)
            status, _ = kernels.dls_qp(U, s, V, damping, 0.06, xdot, -free, free, np.zeros((0, n)), np.zeros(0), 0, buf)
            assert status == SOLVED
            np.testing.assert_allclose(
                result_from_buffers(buf, n, 0, status, 0).qd, qd_ref, rtol=1e-13, atol=1e-13 * np.abs(qd_ref).max()
            )
            lo, hi = -0.5 * np.abs(qd_ref).max() * np.ones(n), 0.3 * np.abs(qd_ref).max() * np.ones(n)
            status, _ = kernels.dls_qp(U, s, V, damping, 0.06, xdot, lo, hi, np.zeros((0, n)), np.zeros(0), 0, buf)
            assert status == SOLVED
            eig = np.maximum(s**2 + damping**2, (kernels.LAM_FLOOR * s[0]) ** 2)
            H = V @ np.diag(eig) @ V.T + 0.06**2 * (np.eye(n) - V @ V.T)
            g = V @ (s * (U.T @ xdot))
            res = result_from_buffers(buf, n, 0, status, 0)
            assert_kkt(res, H, g, lo, hi, np.zeros((0, n)), np.zeros(0))


def test_buffers_are_reused_without_memory_of_the_last_solve(rng):
    problems_ = []
    for m in (0, 3, 6):
        J = rng.normal(size=(6, 7))
        lo, hi = _box(rng, 7, "mixed")
        C, d = _rows(rng, 7, 6, "random", lo, hi)
        if m < 6:  # rows that never bind
            d[m:] = 1e3
        problems_.append((J, rng.normal(size=6) * 5.0, lo, hi, C, d))
    buf = kernels.qp_buffers(7, 6)
    outputs = []
    for J, xdot, lo, hi, C, d in problems_ + problems_[::-1]:
        sv = svd_kernels.svd_buffers(7, 6)
        svd_kernels.jacobi_svd(J, sv, False)
        _, U, s, V, _, _ = sv
        status, iters = kernels.dls_qp(U, s, V, np.full(6, 0.1), 0.1, xdot, lo, hi, C, d, 0, buf)
        res = result_from_buffers(buf, 7, 6, status, iters)
        outputs.append((status, iters, res.qd, res.row_multipliers))
    for a, b in zip(outputs[:3], outputs[3:][::-1], strict=True):
        assert a[:2] == b[:2]
        assert np.array_equal(a[2], b[2]) and np.array_equal(a[3], b[3])

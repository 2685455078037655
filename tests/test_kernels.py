"""The compiled core against independent truth: the SVD against LAPACK, the inverses and the
whole planner against the numpy implementation kept as an oracle (``tests/oracle``)."""

import math

import numpy as np
import pytest
from oracle import inverses as oracle_inverses
from oracle import planner as oracle_planner
from robots import random_robot

from engine import CartesianTask, make_inverse, make_secondary, method_names, plan, plan_batch
from engine.inverses import thin_svd
from engine.kernels import dynamics as dynamics_kernels
from engine.kernels import plan as plan_kernels
from engine.kernels import svd as svd_kernels
from engine.kinematics import as_state, forward_kinematics
from engine.planner import _no_samples
from engine.spatial import exp_so3

EPS = np.finfo(float).eps


def _with_singular_values(rng, n, s):
    U, _ = np.linalg.qr(rng.normal(size=(6, 6)))
    V, _ = np.linalg.qr(rng.normal(size=(n, n)))
    S = np.zeros((6, n))
    S[: len(s), : len(s)] = np.diag(s)
    return U @ S @ V.T


def _matrices(rng, n):
    m = min(6, n)
    yield "random", rng.normal(size=(6, n))
    s = np.sort(rng.uniform(0.1, 2.0, m))[::-1]
    s[rng.integers(0, m) :] = 0.0
    yield "rank-deficient", _with_singular_values(rng, n, s)
    s = np.full(m, 1.3)
    s[m // 2 :] = 0.7
    yield "repeated", _with_singular_values(rng, n, s)
    yield "badly scaled", rng.normal(size=(6, n)) * 10.0 ** rng.uniform(-8, 8, (1, n)) * 10.0 ** rng.uniform(-4, 4, (6, 1))
    yield "graded", _with_singular_values(rng, n, 10.0 ** -np.arange(0, 3 * m, 3.0))


@pytest.mark.parametrize("n", range(1, 13))
def test_svd_matches_lapack_to_a_few_ulps(rng, n):
    worst = {"s": 0.0, "rec": 0.0, "orth": 0.0}
    for _ in range(12):
        for kind, J in _matrices(rng, n):
            U, s, Vt = thin_svd(J)
            ref = np.linalg.svd(J, compute_uv=False)
            scale = max(ref[0], np.finfo(float).tiny)
            m = min(6, n)
            worst["s"] = max(worst["s"], np.abs(s - ref).max() / (EPS * scale))
            worst["rec"] = max(worst["rec"], np.abs(U @ np.diag(s) @ Vt - J).max() / (EPS * scale))
            worst["orth"] = max(worst["orth"], np.abs(U.T @ U - np.eye(m)).max() / EPS, np.abs(Vt @ Vt.T - np.eye(m)).max() / EPS)
            assert np.all(np.diff(s) <= 0.0), kind
            if kind == "random":  # distinct singular values: the vectors too, up to sign
                Ur, _, Vtr = np.linalg.svd(J, full_matrices=False)
                gaps = np.minimum(np.abs(np.diff(ref, prepend=np.inf)), np.abs(np.diff(ref, append=-np.inf)))
                ok = gaps > 1e-3 * ref[0]
                np.testing.assert_allclose(np.abs(np.sum(U * Ur, axis=0))[ok], 1.0, atol=1e-12)
                np.testing.assert_allclose(np.abs(np.sum(Vt * Vtr, axis=1))[ok], 1.0, atol=1e-12)
            if kind == "repeated":  # only the subspaces are unique: compare the projectors
                Ur, _, _ = np.linalg.svd(J, full_matrices=False)
                k = m // 2  # the first k singular values are 1.3, the rest 0.7
                np.testing.assert_allclose(U[:, :k] @ U[:, :k].T, Ur[:, :k] @ Ur[:, :k].T, atol=1e-13)
                np.testing.assert_allclose(U @ U.T, Ur @ Ur.T, atol=1e-13)
    # "A few ulps" of the largest singular value (LAPACK's own error is of that size).
    assert worst["s"] <= 16.0, worst
    assert worst["rec"] <= 24.0, worst
    assert worst["orth"] <= 32.0, worst


def test_svd_of_zero_and_non_finite_matrices():
    U, s, _Vt = thin_svd(np.zeros((6, 4)))
    assert np.all(s == 0.0)
    np.testing.assert_allclose(U.T @ U, np.eye(4), atol=1e-15)
    buf = svd_kernels.svd_buffers(6)
    J = np.eye(6)
    J[2, 3] = np.nan
    finite, sweeps = svd_kernels.jacobi_svd(J, buf, True)
    assert not finite and sweeps == 0 and np.all(np.isnan(buf[2]))
    J[2, 3] = np.inf
    assert not svd_kernels.jacobi_svd(J, buf, True)[0]


def test_warm_started_svd_equals_a_cold_one(rng):
    """Along a slowly turning sequence the warm start changes nothing but the work."""
    J0 = rng.normal(size=(6, 7))
    D = rng.normal(size=(6, 7))
    buf = svd_kernels.svd_buffers(7)
    total = 0
    for k in range(200):
        J = J0 + 0.02 * k * D
        _finite, sweeps = svd_kernels.jacobi_svd(J, buf, k % 16 == 0)
        total += sweeps
        _, s_cold, _ = thin_svd(J)
        np.testing.assert_allclose(buf[2], s_cold, rtol=0, atol=32 * EPS * s_cold[0])
        U, s, V = buf[1], buf[2], buf[3]
        np.testing.assert_allclose(U @ np.diag(s) @ V.T, J, atol=32 * EPS * s[0])
    assert total < 200 * 5


def test_inverses_match_the_numpy_oracle(rng):
    """Full rank, nearly singular, and exactly singular GJMs. At an exact singularity of a
    non-square GJM the left singular vectors of the zero singular values are not unique, so only
    the methods whose gain vanishes there (everything but the undamped inverse, SVF and SDLS)
    have a unique answer to compare."""
    for n in (3, 6, 7, 12):
        for smallest in (None, 1e-7, 0.0):
            s = np.sort(rng.uniform(0.005, 2.0, min(6, n)))[::-1]
            if smallest is not None:
                s[-1] = smallest
            J = _with_singular_values(rng, n, s)
            x = rng.normal(size=6)
            for name in method_names():
                if smallest == 0.0 and name in ("inverse", "svf", "sdls"):
                    continue
                ours = make_inverse(name).solve(J, x)
                theirs = oracle_inverses.make_inverse(name).solve(J, x)
                scale = max(1.0, float(np.abs(theirs.qd).max()))
                np.testing.assert_allclose(ours.qd, theirs.qd, atol=1e-11 * scale, err_msg=f"{name} n={n} smallest={smallest}")
                # lambda = sqrt(sigma / g - sigma^2) is ill-conditioned near 0: compare lambda^2, and
                # not at all for the rounding-level singular values of a singular GJM.
                real = s > 1e-9 * s[0]
                np.testing.assert_allclose(ours.damping[real] ** 2, theirs.damping[real] ** 2, atol=1e-13, err_msg=name)


def _random_task(rng, robot, **options):
    q0 = rng.uniform(-np.pi, np.pi, robot.n_joints)
    fk = forward_kinematics(robot, as_state(robot, q0))
    return CartesianTask.from_q0(
        robot, q0, fk.ee_position + rng.normal(size=3) * 0.1, exp_so3(rng.normal(size=3) * 0.2) @ fk.ee_attitude, **options
    )


def _assert_plans_agree(ours, theirs, label):
    assert ours.metrics.finite == theirs.metrics.finite, label
    np.testing.assert_allclose(ours.q, theirs.q, atol=1e-9, err_msg=label)
    np.testing.assert_allclose(ours.base_attitude, theirs.base_attitude, atol=1e-9, err_msg=label)
    np.testing.assert_allclose(ours.ee_position, theirs.ee_position, atol=1e-9, err_msg=label)
    np.testing.assert_allclose(ours.singular_values, theirs.singular_values, atol=1e-9, err_msg=label)
    np.testing.assert_allclose(ours.det_J_g, theirs.det_J_g, rtol=1e-7, atol=1e-12, err_msg=label)
    assert ours.metrics.position_error_max == pytest.approx(theirs.metrics.position_error_max, rel=1e-6, abs=1e-12)


@pytest.mark.parametrize("method", ["dls", "adaptive", "wdls", "sdls", "svf"])
def test_planner_matches_the_numpy_oracle(robot, task, rng, method):
    """The compiled planner and the numpy planner (LAPACK SVD, the same Magnus step) agree on
    the paper's task and on random 3- to 12-joint robots, pose tasks (6 joints or more) and
    position tasks (3 or more), with and without feedback."""
    cases = [(robot, task)]
    for n, tracks in ((3, "position"), (5, "position"), (8, "position"), (7, "pose"), (9, "pose"), (12, "pose")):
        r = random_robot(rng, n)
        cases.append((r, _random_task(rng, r, duration=4.0, ramp_time=0.5, dt=0.1, tracks=tracks)))
    for model, t in cases:
        for gain in (0.0, 2.0):
            ours = plan(model, t, make_inverse(method), feedback_gain=gain)
            theirs = oracle_planner.plan(model, t, oracle_inverses.make_inverse(method), feedback_gain=gain)
            _assert_plans_agree(ours, theirs, f"{method} n={model.n_joints} {t.tracks} gain={gain}")


@pytest.mark.parametrize("objective", ["min_base_rotation", "joint_centering"])
def test_secondary_objectives_match_the_numpy_oracle(rng, objective):
    """The null-space step of the kernel (loops, a 3x3 Cholesky) against the oracle's numpy
    matrices (the projector I - V V^T, np.linalg.solve), on redundant pose and position tasks."""
    for n, tracks, gain in ((7, "pose", 1.0), (9, "pose", 0.5), (5, "position", 0.8)):
        model = random_robot(rng, n)
        t = _random_task(rng, model, duration=3.0, ramp_time=0.5, dt=0.1, tracks=tracks)
        secondary = make_secondary(objective, gain)
        for method in ("adaptive", "sdls"):
            ours = plan(model, t, make_inverse(method), feedback_gain=1.0, secondary=secondary)
            theirs = oracle_planner.plan(model, t, oracle_inverses.make_inverse(method), feedback_gain=1.0, secondary=secondary)
            _assert_plans_agree(ours, theirs, f"{objective} {method} n={n} {tracks}")
            plain = plan(model, t, make_inverse(method), feedback_gain=1.0)
            assert np.abs(ours.q - plain.q).max() > 1e-6  # the objective does move the joints


def test_plain_inverse_plan_matches_the_oracle_away_from_singularities(rng):
    r = random_robot(rng, 6)
    t = _random_task(rng, r, duration=2.0, ramp_time=0.5, dt=0.1)
    ours = plan(r, t, make_inverse("inverse"))
    theirs = oracle_planner.plan(r, t, oracle_inverses.make_inverse("inverse"))
    assert ours.metrics.min_singular_value > 1e-3
    np.testing.assert_allclose(ours.q, theirs.q, atol=1e-9)


def test_batches_are_bit_identical_to_single_plans(robot, task):
    params = {"lambda_max": np.linspace(0.01, 0.2, 13), "epsilon": np.linspace(0.3, 0.02, 13)}
    reference = plan_batch(robot, task, "adaptive", params, threads=1).metrics
    for threads, size in ((2, None), (2, 1), (3, 5)):
        other = plan_batch(robot, task, "adaptive", params, threads=threads, batch_size=size).metrics
        for name in ("objective_b", "position_error_rms", "max_joint_speed", "min_abs_det_J_g"):
            np.testing.assert_array_equal(getattr(other, name), getattr(reference, name))
    for i in (0, 6, 12):
        single = plan(robot, task, make_inverse("adaptive", lambda_max=params["lambda_max"][i], epsilon=params["epsilon"][i]))
        assert single.metrics.position_error_rms == reference.position_error_rms[i]
        assert single.metrics.max_joint_speed == reference.max_joint_speed[i]


def test_a_diverging_plan_stops_with_a_message(robot, task):
    """Feedback of 1e300/s blows the joint rates up after the first step: the plan ends as
    diverged at that sample, the rest of the arrays are NaN, and nothing hangs."""
    r = plan(robot, task, make_inverse("dls"), feedback_gain=1e300)
    assert not r.success and not r.metrics.finite
    assert "diverged at t = " in r.message
    k = round(r.metrics.time_diverged / task.dt)
    assert 0 < k < task.n_steps
    assert np.all(np.isnan(r.q[k + 1 :])) and np.all(np.isfinite(r.q[: k + 1]))
    assert math.isinf(r.metrics.objective_b) and math.isinf(r.metrics.max_joint_speed)
    batch = plan_batch(robot, task, "dls", {"lambda": [0.05]}, feedback_gain=1e300)
    assert not batch.metrics.finite[0] and batch.metrics.time_diverged[0] == r.metrics.time_diverged


def test_kernel_stops_at_a_non_finite_twist(robot, task):
    samples = task.samples
    twists = samples.twists.copy()
    twists[7, 2] = np.nan
    metrics = np.empty(plan_kernels.N_METRICS)
    trace = _no_samples(6, 6)[0]  # metrics only
    args = (
        samples.p_des,
        samples.A_des,
        task.dt,
        0.0,
        1,
        np.array([[0.05, 0.0]]),
        6,
        0,
        0.0,
        task.q0.copy(),
        np.full(6, task.joint_speed_limit),
        True,
        (np.zeros((0, 19)), np.zeros((1, 3)), np.zeros((0, 2), dtype=np.int64), np.array([0.0, 0.1, 0.5])),  # no geometry
        np.empty((0, 6)),  # no given rates
        trace,
        dynamics_kernels.trajectory_buffers(task.n_steps + 1, 6, 1),
        0,
        1,
        metrics[None],
    )
    plan_kernels.simulate(robot.chain, robot.chain, task.q0.copy(), twists, *args)
    assert metrics[plan_kernels.FINITE] == 0.0 and metrics[plan_kernels.T_DIVERGED] == 7 * task.dt
    assert math.isnan(metrics[plan_kernels.POS_MAX]) and math.isinf(metrics[plan_kernels.MAX_SPEED])
    assert metrics[plan_kernels.DYNAMICS] == 0.0 and math.isnan(metrics[plan_kernels.MAX_TORQUE])  # none for a diverged plan


def test_the_replay_uses_scipy_dop853_tableau():
    """The compiled replay loads scipy's DOP853 coefficients from their file (not through
    scipy.integrate's package import): the same numbers as scipy's own module."""
    from scipy.integrate._ivp import dop853_coefficients as scipy_dop

    from engine.kernels import replay as replay_kernels

    assert replay_kernels.N_STAGES == scipy_dop.N_STAGES
    n = scipy_dop.N_STAGES
    np.testing.assert_array_equal(replay_kernels.A, scipy_dop.A[:n, :n])
    for name in ("B", "E3", "E5"):
        np.testing.assert_array_equal(getattr(replay_kernels, name), getattr(scipy_dop, name))
    np.testing.assert_array_equal(replay_kernels.C, scipy_dop.C[:n])

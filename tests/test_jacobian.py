import numpy as np
import pytest
from oracle.kinematics import kinematics_batch as oracle_kinematics
from oracle.replay import momentum
from pinocchio_oracle import build_pinocchio_model, pinocchio_configuration, pinocchio_gjm
from robots import random_robot, random_robot_dict

from engine import RobotModel, State, generalized_jacobian, make_inverse, plan
from engine.bounds import MAX_MASS_KG
from engine.jacobian import fixed_base_jacobian_batch, gjm_batch
from engine.kinematics import kinematics_about_com, kinematics_batch, state_kinematics, system_com
from engine.model import urdf_robot
from engine.spatial import exp_so3, log_so3


def _random_state(rng, n):
    return State(rng.uniform(-np.pi, np.pi, n), rng.normal(size=3), exp_so3(rng.normal(size=3)))


def _max_gap_to_pinocchio(model, rng, count):
    pm, fid = build_pinocchio_model(model)
    worst = 0.0
    for _ in range(count):
        s = _random_state(rng, model.n_joints)
        J_pin, _, _ = pinocchio_gjm(pm, fid, pinocchio_configuration(s.q, s.base_position, s.base_attitude))
        worst = max(worst, float(np.abs(generalized_jacobian(model, s).J_g - J_pin).max()))
    return worst


def test_gjm_matches_pinocchio_table1(robot, rng):
    assert _max_gap_to_pinocchio(robot, rng, 60) < 1e-9


@pytest.mark.parametrize("prismatic", [0.0, 0.5])
def test_gjm_matches_pinocchio_random_robots(rng, prismatic):
    for n in (3, 4, 5, 6, 7, 12):
        for _ in range(2):
            assert _max_gap_to_pinocchio(random_robot(rng, n, prismatic=prismatic), rng, 25) < 1e-9


@pytest.mark.parametrize("prismatic", [False, True])
def test_gjm_is_derivative_of_momentum_conserving_motion(robot, rng, prismatic):
    """Move a tiny step forwards and backwards with the base reacting (angular momentum via
    the base map, CoM fixed) and compare the end-effector displacement with J_g qd (the
    Table-1 robot, and a random robot with prismatic joints)."""
    if prismatic:
        robot = random_robot(rng, 6, prismatic=0.5)
        assert robot.prismatic.any()
    q = rng.uniform(-np.pi, np.pi, 6)
    qd = rng.normal(size=6)
    A0 = exp_so3(rng.normal(size=3))
    J_g, base_map = gjm_batch(robot, q[None], A0[None], np.zeros((1, 3)), about_com=True)
    w0 = base_map[0, 3:] @ qd
    h = 1e-6
    plus = kinematics_about_com(robot, (q + h * qd)[None], (exp_so3(w0 * h) @ A0)[None], np.zeros((1, 3)))
    minus = kinematics_about_com(robot, (q - h * qd)[None], (exp_so3(-w0 * h) @ A0)[None], np.zeros((1, 3)))
    v_fd = (plus.ee_position[0] - minus.ee_position[0]) / (2 * h)
    w_fd = log_so3(plus.ee_attitude[0] @ minus.ee_attitude[0].T) / (2 * h)
    np.testing.assert_allclose(J_g[0] @ qd, np.concatenate([v_fd, w_fd]), atol=1e-7)
    # And the base linear velocity agrees with the finite difference of the base position.
    v0_fd = (plus.body_com[0, 0] - minus.body_com[0, 0]) / (2 * h)
    np.testing.assert_allclose(base_map[0, :3] @ qd, v0_fd, atol=1e-7)


@pytest.mark.parametrize("prismatic", [0.0, 0.5])
def test_infinite_base_mass_gives_fixed_base_jacobian(rng, prismatic):
    """As the base's mass and inertia grow the GJM tends to the fixed-base Jacobian, the gap
    shrinking as 1 / M (the base's reaction is the arm's momentum over the base's inertia)."""
    d = random_robot_dict(rng, 6, prismatic)
    s = _random_state(rng, 6)
    gaps = []
    for scale in (MAX_MASS_KG / 10, MAX_MASS_KG):  # the heaviest base a model may have (engine.bounds)
        d["base"]["mass"] = scale
        d["base"]["inertia"] = (np.eye(3) * scale).tolist()
        model = RobotModel.from_dict(d)
        J_fixed = fixed_base_jacobian_batch(state_kinematics(model, s), model.prismatic)[0]
        gaps.append(np.abs(generalized_jacobian(model, s).J_g - J_fixed).max())
    assert gaps[1] < 1e-5, gaps
    assert 5.0 < gaps[0] / gaps[1] < 20.0, gaps  # first order in 1 / M
    # With a light base the two differ: the test can fail.
    assert np.abs(generalized_jacobian(random_robot(rng, 6), s).J_g - J_fixed).max() > 1e-3


def test_gjm_result_fields(robot):
    s = State(np.radians([175.0, -60.0, -60.0, 0.0, 210.0, 5.0]))
    g = generalized_jacobian(robot, s)
    sv = np.linalg.svd(g.J_g, compute_uv=False)
    np.testing.assert_allclose(g.singular_values, sv)
    np.testing.assert_allclose(abs(g.determinant), np.prod(sv), rtol=1e-10)
    np.testing.assert_allclose(g.manipulability, np.prod(sv))
    assert g.success


def test_a_gjm_singular_to_working_precision_has_no_condition_number():
    """arm7 at zero angles (stretched out) is singular: its smallest singular value is a
    rounding residue, which numpy's rank (to max(m, n) eps sigma_max) does not count; the
    condition number is then infinite (null in the API), not sigma_max over the residue. A
    state merely near the singularity keeps its finite one."""
    arm7 = urdf_robot("arm7")
    stretched = generalized_jacobian(arm7, State(np.zeros(7)))
    assert np.linalg.matrix_rank(stretched.J_g) < 6
    assert stretched.condition_number == np.inf
    near = generalized_jacobian(arm7, State(np.full(7, 1e-4)))
    assert np.linalg.matrix_rank(near.J_g) == 6
    sv = np.linalg.svd(near.J_g, compute_uv=False)
    assert near.condition_number == pytest.approx(sv[0] / sv[-1], rel=1e-6)


def test_non_square_gjm_has_no_determinant(rng):
    model = random_robot(rng, 4)
    g = generalized_jacobian(model, _random_state(rng, 4))
    assert g.J_g.shape == (6, 4) and g.determinant is None and g.singular_values.shape == (4,)


def test_momentum_stays_zero_along_a_plan(robot, task):
    """Body-by-body momentum (the numpy oracle's) of the planned motion (stored base pose, base
    twist from the kernel's base map) is zero, and the system CoM does not move."""
    result = plan(robot, task, make_inverse("adaptive"))
    com0 = None
    for k in range(0, result.t.shape[0], 3):
        args = result.q[k][None], result.base_attitude[k][None], result.base_position[k][None]
        kin = kinematics_batch(robot, *args)
        _, base_map = gjm_batch(robot, *args)
        P, L = momentum(robot, oracle_kinematics(robot, *args), result.qd[k], base_map[0] @ result.qd[k])
        assert np.linalg.norm(P) < 1e-10 and np.linalg.norm(L) < 1e-10
        com = system_com(robot, kin)[0]
        com0 = com if com0 is None else com0
        np.testing.assert_allclose(com, com0, atol=1e-12)

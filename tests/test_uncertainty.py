"""Plans and tuning under mass-property uncertainty (issue 20): the samples, the plan's open- and
closed-loop robustness checked against the plan itself (no perturbation, gain 0) and against an
independent integration (the DOP853 replay on each sampled robot), robust tuning's statistic
against plans of the sampled robots, and the refinement after the GA against a 256 x 256 grid."""

from __future__ import annotations

import math

import numpy as np
import pytest

from engine import make_inverse, paper_task, replay, run_plan, table1_robot
from engine.errors import ParameterError
from engine.kernels import plan as plan_kernels
from engine.landscape import landscape
from engine.planner import PlanOptions, PlanSetup
from engine.robustness import robustness, sampled_setups, statistic
from engine.trajectory import PAPER_TASK_PARAMS
from engine.tuning import TuningProblem, check_bounds, tune
from engine.uncertainty import Uncertainty, draw, sampled_model

MODEL = table1_robot()
TASK = paper_task(MODEL)
INVERSE = make_inverse("adaptive", **PAPER_TASK_PARAMS["adaptive"])
TEN_PERCENT = Uncertainty(carrier_mass_rel=0.1, carrier_inertia_rel=0.1, samples=16, seed=3)


def _setup(gain: float = 0.0) -> PlanSetup:
    return PlanSetup(MODEL, TASK, PlanOptions(feedback_gain=gain))


def test_samples_stay_within_their_bounds_and_repeat_with_their_seed() -> None:
    u = Uncertainty(carrier_mass_rel=0.1, link_inertia_rel=0.2, link_com_m=0.01, q0_rad=math.radians(1.0), samples=200, seed=7)
    samples = draw(u, MODEL)
    masses = np.array([s.carrier_mass_factor for s in samples])
    inertias = np.array([s.link_inertia_factors for s in samples])
    offsets = np.array([s.link_com_offsets for s in samples])
    q0 = np.array([s.q0_offset for s in samples])
    assert np.all(np.abs(masses - 1.0) <= 0.1) and np.ptp(masses) > 0.19  # the bounds, and (Halton) nearly all of them
    assert np.all(np.abs(inertias - 1.0) <= 0.2) and np.all(np.array([s.carrier_inertia_factor for s in samples]) == 1.0)
    assert np.all(np.linalg.norm(offsets, axis=2) <= 0.01 + 1e-15) and np.max(np.linalg.norm(offsets, axis=2)) > 0.009
    assert np.all(np.abs(q0) <= math.radians(1.0))
    again = draw(u, MODEL)
    assert all(np.array_equal(a.link_com_offsets, b.link_com_offsets) for a, b in zip(samples, again, strict=True))
    other = draw(Uncertainty(carrier_mass_rel=0.1, samples=200, seed=8), MODEL)
    assert not np.array_equal(masses, [s.carrier_mass_factor for s in other])
    normal = draw(Uncertainty(link_mass_rel=0.1, distribution="normal", samples=500), MODEL)
    factors = np.array([s.link_mass_factors for s in normal])
    assert np.all(np.abs(factors - 1.0) <= 0.3 + 1e-12) and 0.08 < np.std(factors) < 0.11  # truncated at 3 sigma


@pytest.mark.parametrize(
    ("fields", "field"),
    [
        ({"carrier_mass_rel": 1.0}, "carrier_mass_rel"),  # a factor 1 - 1 = 0: zero mass
        ({"link_inertia_rel": 0.34, "distribution": "normal"}, "link_inertia_rel"),  # 1 - 3 x 0.34 < 0
        ({"link_mass_rel": -0.1}, "link_mass_rel"),
        ({"samples": 0}, "samples"),
        ({"samples": 1025}, "samples"),
        ({"distribution": "cauchy"}, "distribution"),
        ({"link_com_m": math.nan}, "link_com_m"),
    ],
)
def test_an_invalid_uncertainty_names_its_field(fields: dict[str, object], field: str) -> None:
    with pytest.raises(ParameterError) as err:
        Uncertainty(**fields)  # type: ignore[arg-type]
    assert err.value.field == field


def test_a_sampled_robot_keeps_its_joints_and_shapes_where_they_are() -> None:
    """Moving a link's CoM moves a and b oppositely: the kinematics of the joints and the end
    effector are those of the nominal robot (at the same base CoM placement)."""
    from engine.model import table1_with_geometry

    model = table1_with_geometry()
    sample = draw(Uncertainty(link_com_m=0.05, samples=3, seed=1), model)[2]
    moved = sampled_model(model, sample)
    for link, nominal in zip(moved.links, model.links, strict=True):
        assert np.allclose(link.a + link.b, nominal.a + nominal.b, rtol=0, atol=1e-15)
        for ours, theirs in zip(link.shapes, nominal.shapes, strict=True):  # the same shape about the joint
            assert np.allclose(ours.position + link.a, theirs.position + nominal.a, rtol=0, atol=1e-15)


def test_without_perturbation_both_loops_reproduce_the_plan_bit_for_bit() -> None:
    for gain in (0.0, 1.0):
        setup = _setup(gain)
        nominal = run_plan(setup, INVERSE)
        r = robustness(setup, INVERSE, nominal, Uncertainty(samples=3))
        for loop in (r.open_loop, r.closed_loop):
            assert np.array_equal(loop.position_error_band[:, 2], nominal.position_error)
            assert np.array_equal(loop.attitude_error_band[:, 0], nominal.attitude_error)
            assert loop.position_error_max.max == nominal.metrics.position_error_max
            assert loop.limit_broken_fraction == (0.0 if nominal.success else 1.0)


def test_the_closed_loop_with_gain_zero_and_the_exact_model_is_the_plan() -> None:
    """A sampled robot planned with its own model in the controller is simply its plan."""
    sample = draw(TEN_PERCENT, MODEL)[5]
    robot = sampled_model(MODEL, sample)
    own = run_plan(PlanSetup(robot, TASK), INVERSE)
    same = PlanSetup(robot, TASK).under(robot, TASK.q0)
    from engine.planner import evaluate_traced

    _, position, attitude = evaluate_traced([same], INVERSE)
    assert np.array_equal(position[0], own.position_error) and np.array_equal(attitude[0], own.attitude_error)
    # the task's q0 is read-only, a type of its own to numba: the start is copied, so the step
    # loop is the one already compiled, not a second compilation of it
    assert len(plan_kernels.simulate.signatures) == 1, plan_kernels.simulate.signatures


def test_the_open_loop_matches_an_independent_integration_on_each_sampled_robot() -> None:
    """Open loop: the plan's joint motion on the sampled robot. The DOP853 replay (rtol 1e-12)
    integrates the same joint motion through that robot's momentum equations independently."""
    setup = _setup()
    nominal = run_plan(setup, INVERSE)
    r = robustness(setup, INVERSE, nominal, TEN_PERCENT)
    assert r.open_loop.position_error_max.max > 2.0 * nominal.metrics.position_error_max  # the uncertainty matters
    errors = []
    for sample in r.samples:
        replayed = replay(sampled_model(MODEL, sample), nominal)
        errors.append(replayed.path_position_error_max)
    ours = r.open_loop
    assert ours.position_error_max.max == pytest.approx(max(errors), abs=2e-6)
    assert ours.position_error_max.mean == pytest.approx(float(np.mean(errors)), abs=2e-6)
    assert r.samples[ours.worst_index] is ours.worst
    assert errors[ours.worst_index] == pytest.approx(max(errors), abs=2e-6)


def test_robust_b_is_the_statistic_of_the_sampled_robots_plans() -> None:
    uncertainty = Uncertainty(carrier_mass_rel=0.2, carrier_inertia_rel=0.2, link_mass_rel=0.1, samples=6, seed=2)
    params = {"lambda_max": 0.05, "epsilon": 0.3}
    per_sample = [
        run_plan(s, make_inverse("adaptive", **params)).metrics.objective_b
        for s in sampled_setups(_setup(), draw(uncertainty, MODEL))
    ]
    for name, expected in (("mean", np.mean(per_sample)), ("max", np.max(per_sample)), ("p95", np.percentile(per_sample, 95))):
        problem = TuningProblem.build(MODEL, TASK, "adaptive", uncertainty=uncertainty, robust_statistic=name)
        assert problem.objective_b(params) == pytest.approx(expected, rel=1e-12)
    assert statistic(np.array([[1.0, np.inf, 2.0]]), "p95")[0] == math.inf  # a sample over a limit: infeasible
    with pytest.raises(ParameterError, match="robust_statistic"):
        TuningProblem.build(MODEL, TASK, "adaptive", uncertainty=uncertainty, robust_statistic="median")


def test_robust_tuning_reports_the_nominal_b_of_its_parameters() -> None:
    uncertainty = Uncertainty(carrier_mass_rel=0.1, carrier_inertia_rel=0.1, samples=4)
    result = tune(MODEL, TASK, "adaptive", population=6, generations=2, uncertainty=uncertainty, refine=False)
    nominal = TuningProblem.build(MODEL, TASK, "adaptive").objective_b(result.best_params)
    assert result.success and result.nominal_objective_b == nominal
    assert result.evaluations % 4 == 0 and result.evaluations > 0  # plans: each parameter set on each sample


def test_the_tuner_finds_the_grid_optimum() -> None:
    """The README's job (paper task, default bounds, seed 1): the GA then the refinement reach a B
    within 0.5 % of the best feasible cell of a 256 x 256 grid over the same bounds (below it, in
    fact: the optimum lies between cells, on the joint speed limit); the GA alone does not."""
    bounds = check_bounds("adaptive", None)
    grid = landscape(
        MODEL,
        TASK,
        "adaptive",
        ("lambda_max", np.linspace(*bounds["lambda_max"], 256)),
        ("epsilon", np.linspace(*bounds["epsilon"], 256)),
    )
    tuned = tune(MODEL, TASK, "adaptive", seed=1)
    assert tuned.best_objective_b <= grid.best_objective_b * 1.005
    assert {r.phase for r in tuned.history} == {"ga", "refine"}
    assert tuned.history[-1].best == tuned.best_objective_b < tuned.ga_objective_b
    refined = tuned.history[51:]
    assert all(r.phase == "refine" for r in refined) and [r.generation for r in refined] == list(range(51, 51 + len(refined)))
    confirmed = run_plan(_setup(), make_inverse("adaptive", **tuned.best_params))
    assert confirmed.success and confirmed.metrics.objective_b == tuned.best_objective_b
    alone = tune(MODEL, TASK, "adaptive", seed=1, refine=False)
    assert alone.best_objective_b == tuned.ga_objective_b > grid.best_objective_b * 1.005
    assert all(r.phase == "ga" for r in alone.history) and len(alone.history) == 51


def test_the_refinements_nelder_mead_is_scipys() -> None:
    """Point by point the same search as ``scipy.optimize.minimize(method="Nelder-Mead")`` with
    bounds: on a bent valley and on the paper task's B (with its infeasible region)."""
    from scipy.optimize import minimize

    from engine.tuning.refine import nelder_mead

    problem = TuningProblem.build(MODEL, TASK, "adaptive")
    lo, hi = np.array([1e-4, 1e-4]), np.array([0.2, 1.0])

    def paper_b(u: np.ndarray) -> float:
        x = lo + np.clip(u, 0.0, 1.0) * (hi - lo)
        return problem.objective_b({"lambda_max": float(x[0]), "epsilon": float(x[1])})

    def valley(u: np.ndarray) -> float:
        return float((u[0] - 0.3) ** 2 + 10.0 * (u[1] - u[0] ** 2) ** 2)

    for f, start in ((valley, [0.9, 0.1]), (paper_b, [0.188, 0.558])):
        simplex = np.array([start, [start[0] + 0.05, start[1]], [start[0], start[1] + 0.05]])
        ours_calls: list[tuple[float, ...]] = []
        theirs_calls: list[tuple[float, ...]] = []

        def counted(calls: list[tuple[float, ...]], f=f):  # type: ignore[no-untyped-def]
            def g(u: np.ndarray) -> float:
                calls.append(tuple(u))
                return float(f(u))

            return g

        ours_f, theirs_f = counted(ours_calls), counted(theirs_calls)
        x, fx = nelder_mead(ours_f, simplex, xatol=1e-7, fatol=1e-12, maxfev=300)
        found = minimize(
            theirs_f,
            simplex[0],
            method="Nelder-Mead",
            bounds=[(0.0, 1.0)] * 2,
            options={"initial_simplex": simplex, "xatol": 1e-7, "fatol": 1e-12, "maxfev": 300},
        )
        assert ours_calls == theirs_calls and fx == found.fun and np.array_equal(x, found.x)


def test_the_open_loop_matches_a_pinocchio_monte_carlo() -> None:
    """An independent Monte Carlo on Pinocchio: each sampled robot as a free-flyer model, the
    plan's joint motion applied, the carrier's twist from zero centroidal momentum (Pinocchio's
    centroidal map), the configuration integrated on the Lie group (``pin.integrate``, explicit
    midpoint, 40 sub-steps per planner step), the end effector's placement from Pinocchio's
    frame kinematics: each sample's largest position and attitude error against the path."""
    pin = pytest.importorskip("pinocchio")
    from tests.pinocchio_oracle import build_pinocchio_model

    setup = _setup()
    nominal = run_plan(setup, INVERSE)
    uncertainty = Uncertainty(carrier_mass_rel=0.1, carrier_inertia_rel=0.1, link_mass_rel=0.1, link_com_m=0.02, samples=5)
    r = robustness(setup, INVERSE, nominal, uncertainty)
    samples = TASK.samples
    substeps = 40
    position, attitude = [], []
    for sample in r.samples:
        pm, frame = build_pinocchio_model(sampled_model(MODEL, sample))
        data = pm.createData()

        def rate(q_pin: np.ndarray, qd: np.ndarray, pm=pm, data=data) -> np.ndarray:  # type: ignore[no-untyped-def]
            Ag = pin.computeCentroidalMap(pm, data, q_pin)
            return np.concatenate([-np.linalg.solve(Ag[:, :6], Ag[:, 6:] @ qd), qd])

        q_pin = np.concatenate([np.zeros(3), [0.0, 0.0, 0.0, 1.0], TASK.q0])
        worst_p = worst_a = 0.0
        for k in range(TASK.n_steps + 1):
            pin.framesForwardKinematics(pm, data, q_pin)
            placement = data.oMf[frame]
            worst_p = max(worst_p, float(np.linalg.norm(placement.translation - samples.p_des[k])))
            worst_a = max(worst_a, float(np.linalg.norm(pin.log3(placement.rotation @ samples.A_des[k].T))))
            if k == TASK.n_steps:
                break
            h = TASK.dt / substeps
            for _ in range(substeps):
                half = pin.integrate(pm, q_pin, rate(q_pin, nominal.qd[k]) * (0.5 * h))
                q_pin = pin.integrate(pm, q_pin, rate(half, nominal.qd[k]) * h)
        position.append(worst_p)
        attitude.append(worst_a)
    assert r.open_loop.position_error_max.max == pytest.approx(max(position), abs=1e-7)
    assert r.open_loop.position_error_max.mean == pytest.approx(float(np.mean(position)), abs=1e-7)
    assert r.open_loop.attitude_error_max.max == pytest.approx(max(attitude), abs=1e-8)
    assert r.open_loop.worst_index == int(np.argmax(position))


def test_the_halton_points_are_as_even_as_scipys() -> None:
    """The scrambled Halton points (computed in the engine: scipy.stats costs a process 60 MiB)
    cover the cube as evenly as ``scipy.stats.qmc.Halton``'s and much more evenly than random
    points (centred L2 discrepancy); the normal quantiles are scipy's."""
    from scipy.special import ndtri
    from scipy.stats import qmc

    from engine.uncertainty import _unit, halton

    for n, d in ((64, 2), (256, 38), (1024, 8)):
        ours = halton(n, d, np.random.default_rng(1))
        assert ours.shape == (n, d) and np.all((ours >= 0.0) & (ours < 1.0))
        theirs = qmc.discrepancy(qmc.Halton(d=d, scramble=True, seed=1).random(n))
        random = qmc.discrepancy(np.random.default_rng(2).random((n, d)))
        assert qmc.discrepancy(ours) <= 1.05 * theirs and qmc.discrepancy(ours) < 0.95 * random
    assert not np.array_equal(halton(64, 3, np.random.default_rng(1)), halton(64, 3, np.random.default_rng(2)))
    u = np.linspace(0.0, 1.0, 101)
    lo = 0.5 * math.erfc(3.0 / math.sqrt(2.0))
    assert np.allclose(_unit(u, "normal"), np.clip(ndtri(lo + u * (1.0 - 2.0 * lo)), -3.0, 3.0), rtol=0, atol=1e-12)

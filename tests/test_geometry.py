"""Collision geometry (issue 19) against independent truth: distances against coal (hpp-fcl's
successor, Pinocchio's collision library) on random poses of every pair of primitive types, and
against a general-purpose constrained minimiser for cylinders; the distance's rate along the
joint rates (with the carrier's reaction) against finite differences of a momentum-conserving
motion; the clearance of a plan against coal at every sample; the check between samples on a
motion that passes through an obstacle between two samples; avoidance in the bounded inverse
and the null space; the objective's P_l; refusals naming the field."""

from __future__ import annotations

import dataclasses
import math
import zlib

import numpy as np
import pytest
from scipy.optimize import minimize

from engine import CartesianTask, RobotModel, State, make_inverse, make_secondary, paper_task, plan, plan_batch, table1_robot
from engine.errors import ParameterError
from engine.geometry import Scene, Shape, build_geometry, distance, posed, shape_from_dict
from engine.kernels import chain as chain_kernels
from engine.kernels import geometry as geometry_kernels
from engine.kinematics import as_state, forward_kinematics
from engine.model import table1_with_geometry
from engine.spatial import exp_so3, log_so3, quaternion_to_matrix
from engine.trajectory import PAPER_TASK_PARAMS

coal = pytest.importorskip("coal")


def _rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    return quaternion_to_matrix(q / np.linalg.norm(q))


def _random_shape(rng: np.random.Generator, kind: str) -> tuple[Shape, object]:
    """A random shape at a random pose, and coal's geometry of it (at the identity)."""
    R, p = _rotation(rng), rng.normal(size=3) * 0.6
    w, x, y, z = rng.normal(size=4)
    quaternion = (np.array([w, x, y, z]) / math.hypot(w, x, y, z)).tolist()
    if kind == "sphere":
        r = rng.uniform(0.01, 0.3)
        return shape_from_dict({"type": "sphere", "radius_m": r, "position_m": p.tolist()}), coal.Sphere(r)
    if kind == "capsule":
        r, h = rng.uniform(0.01, 0.2), rng.uniform(0.05, 0.5)
        a, b = p - h * R[:, 2], p + h * R[:, 2]
        return shape_from_dict({"type": "capsule", "radius_m": r, "from_m": a.tolist(), "to_m": b.tolist()}), coal.Capsule(
            r, 2 * h
        )
    if kind == "box":
        size = rng.uniform(0.04, 1.0, 3)
        shape = shape_from_dict({"type": "box", "size_m": size.tolist(), "position_m": p.tolist(), "quaternion": quaternion})
        return shape, coal.Box(*size)
    if kind == "cylinder":
        r, length = rng.uniform(0.02, 0.4), rng.uniform(0.04, 0.8)
        data = {"type": "cylinder", "radius_m": r, "length_m": length, "position_m": p.tolist(), "quaternion": quaternion}
        return shape_from_dict(data), coal.Cylinder(r, length)
    points = rng.normal(size=(12, 3)) * rng.uniform(0.05, 0.4)
    shape = shape_from_dict({"type": "convex", "vertices_m": points.tolist(), "position_m": p.tolist(), "quaternion": quaternion})
    vertices = coal.StdVec_Vec3s()
    for v in shape.vertices:
        vertices.append(np.asarray(v, dtype=float))
    return shape, coal.Convex.convexHull(vertices, False, "")


def _coal_distance(a: Shape, ga: object, b: Shape, gb: object) -> float:
    def placed(shape: Shape) -> object:
        return coal.Transform3s(shape.rotation, shape.position)

    request, result = coal.DistanceRequest(), coal.DistanceResult()
    request.gjk_tolerance = 1e-13
    request.epa_tolerance = 1e-13  # overlapping pairs: coal's penetration depth (its EPA)
    request.epa_max_iterations = 1000
    return float(coal.distance(ga, placed(a), gb, placed(b), request, result))


POLYTOPES_AND_ROUND = ("sphere", "capsule", "box", "convex")


@pytest.mark.parametrize("kind_a", POLYTOPES_AND_ROUND)
@pytest.mark.parametrize("kind_b", POLYTOPES_AND_ROUND)
def test_distances_equal_coal_to_1e_9(kind_a: str, kind_b: str) -> None:
    """Random poses, apart and overlapping: the signed distance equals coal's (its penetration
    depth where they overlap), and the closest (deepest) points of the cores are the distance
    less (plus) the radii apart. coal's own polytope distances agree with an exact QP to about
    1e-11, so 1e-9 is the test's margin."""
    rng = np.random.default_rng(zlib.crc32(f"{kind_a} {kind_b}".encode()))  # not hash(): it changes per process
    apart = overlapping = 0
    for _ in range(300):
        a, ga = _random_shape(rng, kind_a)
        b, gb = _random_shape(rng, kind_b)
        theirs = _coal_distance(a, ga, b, gb)
        ours = distance(a, b)
        assert ours.distance == pytest.approx(theirs, abs=1e-9), (kind_a, kind_b)
        gap = float(np.linalg.norm(ours.points[0] - ours.points[1]))
        core = ours.distance + a.radius + b.radius
        assert gap == pytest.approx(abs(core), abs=1e-12)
        apart += theirs > 0.0
        overlapping += core < 0.0  # the cores too, not only the swept spheres: EPA's depth
    assert apart >= 100
    assert overlapping >= 1 or (kind_a in ("sphere", "capsule") and kind_b in ("sphere", "capsule"))


ALL_KINDS = (*POLYTOPES_AND_ROUND, "cylinder")


@pytest.mark.parametrize("kind_a", ALL_KINDS)
@pytest.mark.parametrize("kind_b", ("box", "convex", "cylinder"))
def test_an_overlaps_depth_is_the_shortest_way_out(kind_a: str, kind_b: str) -> None:
    """Overlapping cores (cylinders too, where coal's EPA is no oracle): moving ``b`` along the
    way out (from ``a``'s deepest point to ``b``'s) by the depth +- 0.1 mm leaves them 0.1 mm
    apart or overlapping by 0.1 mm, to 1e-8 m, so the depth is attained; and no direction gets
    out sooner (the depth is the least): moving ``b`` by 99 % of the depth along 200 random
    directions never separates them. The same for pairs just apart (GJK near contact). With a
    cylinder EPA ends within its tolerance (1e-7 of the shapes' size) instead of exactly."""
    rng = np.random.default_rng(zlib.crc32(f"way out {kind_a} {kind_b}".encode()))
    tolerance = 1e-8 if "cylinder" not in (kind_a, kind_b) else 1e-6
    checked = 0
    for _ in range(600):
        a, _ = _random_shape(rng, kind_a)
        b, _ = _random_shape(rng, kind_b)
        ours = distance(a, b)
        depth = -(ours.distance + a.radius + b.radius)
        if depth <= 1e-3:
            continue
        checked += 1
        out = (ours.points[0] - ours.points[1]) / depth

        def core_distance(shift: np.ndarray, a: Shape = a, b: Shape = b) -> float:
            return distance(a, dataclasses.replace(b, position=b.position + shift)).distance + a.radius + b.radius

        assert core_distance((depth + 1e-4) * out) == pytest.approx(1e-4, abs=tolerance)
        assert core_distance((depth - 1e-4) * out) == pytest.approx(-1e-4, abs=tolerance)
        for direction in rng.normal(size=(200, 3)):
            assert core_distance(0.99 * depth * direction / np.linalg.norm(direction)) < 0.0
    assert checked >= 5


@pytest.mark.parametrize(("kind_a", "kind_b"), [("cylinder", "cylinder"), ("cylinder", "box"), ("box", "box")])
def test_epas_polytope_stays_closed_with_every_neighbour_known(kind_a: str, kind_b: str) -> None:
    """After EPA on overlapping cores, its polytope's faces (those still on it) form a closed
    surface (Euler: points - edges + faces = 2) and each face knows the face across each of its
    edges, which runs that edge the other way and knows it back: the bookkeeping that lets the
    search for the faces a new point sees walk from neighbour to neighbour. (Not convex to the
    last bit: a face the new point sees by less than EPA's tolerance stays.)"""
    rng = np.random.default_rng(zlib.crc32(f"epa polytope {kind_a} {kind_b}".encode()))
    buf = geometry_kernels.gjk_buffers()
    checked = 0
    for _ in range(400):
        a, _ = _random_shape(rng, kind_a)
        b, _ = _random_shape(rng, kind_b)
        witness = np.empty((2, 3))
        buf[8][:] = 0  # no face from the last call
        d = geometry_kernels.shape_distance(posed(a, None, None), posed(b, None, None), np.zeros((1, 3)), buf, witness)
        if d + a.radius + b.radius > -1e-3:
            continue
        checked += 1
        faces = buf[8]
        live = [f for f in range(faces.shape[0]) if faces[f, 3] == 1]
        used = sorted({int(p) for f in live for p in faces[f, :3]})
        assert len(used) - 3 * len(live) // 2 + len(live) == 2
        for f in live:
            for e in range(3):
                g, eg = divmod(int(faces[f, 4 + e]), 3)
                assert faces[g, 3] == 1 and faces[g, 4 + eg] == 3 * f + e
                assert (faces[g, eg], faces[g, (eg + 1) % 3]) == (faces[f, (e + 1) % 3], faces[f, e])
    assert checked >= 10


def _cylinder_oracle(cyl: Shape, other_points: np.ndarray, rng: np.random.Generator) -> float:
    """The distance from a cylinder to the convex hull of ``other_points`` by SLSQP (a convex
    problem: the best of several starts)."""
    rc, h = cyl.dims[0], cyl.dims[1]
    k = other_points.shape[0]

    def gap(z: np.ndarray) -> float:
        return float(np.sum((z[:k] @ other_points - (cyl.position + cyl.rotation @ z[k:])) ** 2))

    constraints = [
        {"type": "eq", "fun": lambda z: z[:k].sum() - 1.0},
        {"type": "ineq", "fun": lambda z: rc**2 - z[k] ** 2 - z[k + 1] ** 2},
        {"type": "ineq", "fun": lambda z: h - abs(z[k + 2])},
    ]
    best = math.inf
    for _ in range(12):
        start = np.concatenate([rng.dirichlet(np.ones(k)), rng.uniform(-0.5, 0.5, 3) * [rc, rc, h]])
        found = minimize(
            gap,
            start,
            method="SLSQP",
            bounds=[(0, 1)] * k + [(None, None)] * 3,
            constraints=constraints,
            options={"ftol": 1e-18, "maxiter": 2000},
        )
        best = min(best, math.sqrt(max(found.fun, 0.0)))
    return best


def test_cylinder_distances_equal_a_constrained_minimiser() -> None:
    """Cylinders against boxes and hulls. coal is not the oracle here: on curved shapes its GJK
    stops early (its distances run up to millimetres above the true one on these poses), while
    GJK's iterates only ever overestimate. The oracle is SLSQP on the convex problem."""
    rng = np.random.default_rng(19)
    compared = 0
    for _ in range(40):
        cyl, _ = _random_shape(rng, "cylinder")
        other, _ = _random_shape(rng, "convex" if compared % 2 else "box")
        if other.type == "box":
            corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * other.dims
        else:
            assert other.vertices is not None
            corners = other.vertices
        points = other.position + corners @ other.rotation.T
        ours = distance(cyl, other).distance
        if ours <= 1e-3:
            continue
        assert ours == pytest.approx(_cylinder_oracle(cyl, points, rng), abs=2e-8)
        compared += 1
    assert compared >= 15


def _geometry(model: RobotModel, scene: Scene):
    links = model.links
    return build_geometry([link.shapes for link in links], model.base.shapes, [link.name for link in links], scene)


def _armed_table1(radius: float = 0.05) -> RobotModel:
    data = table1_robot().to_dict()
    for link in data["links"]:
        link["collision_radius_m"] = radius
    data["base"]["collision_box"] = {"size_m": [1.0, 1.0, 1.4], "center_m": [0.0, 0.0, 0.0]}
    return RobotModel.from_dict(data)


def test_geometry_round_trips_and_the_pairs_follow_the_rules() -> None:
    model = _armed_table1()
    data = model.to_dict()
    data["links"][3]["collision_shapes"] = [
        {"type": "box", "size_m": [0.1, 0.2, 0.3], "position_m": [0.1, 0.0, 0.0], "quaternion": [0.5, 0.5, 0.5, 0.5]}
    ]
    again = RobotModel.from_dict(RobotModel.from_dict(data).to_dict())
    assert again.to_dict() == RobotModel.from_dict(data).to_dict()
    assert [len(link.shapes) for link in again.links] == [1, 1, 1, 2, 1, 1]
    scene = Scene((shape_from_dict({"type": "sphere", "radius_m": 0.1, "position_m": [2.0, 0.0, 0.0]}),), clearance=0.01)
    geometry = _geometry(again, scene)
    names = {geometry.pair_names(p) for p in range(geometry.pairs.shape[0])}
    assert ("carrier", "link1") not in names and ("carrier", "link2") in names  # link 1 is mounted on the carrier
    assert ("link1", "link2") not in names and ("link1", "link3") in names  # adjacent links share a joint
    assert ("link4", "link4") not in names and ("link2", "link4") in names
    assert ("carrier", "obstacle0") in names and ("link6", "obstacle0") in names
    # by shape: the carrier against 6 shapes of links 2-6 (link 4 has two), 13 between links, the carrier and 7 link
    # shapes against the obstacle; 22 pairs of names
    assert geometry.pairs.shape[0] == 6 + 13 + 1 + 7 and len(names) == 22


NAN_SPHERE = {"type": "sphere", "radius_m": 0.1, "position_m": [0, float("nan"), 0]}
FLAT_HULL = {"type": "convex", "vertices_m": [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]}
ZERO_QUATERNION_BOX = {"type": "box", "size_m": [1, 1, 1], "quaternion": [0, 0, 0, 0]}


@pytest.mark.parametrize(
    ("change", "field"),
    [
        (lambda d: d["links"][2].update(collision_radius_m=-0.1), "links[2].collision_radius_m"),
        (lambda d: d["links"][0].update(collision_shapes=[NAN_SPHERE]), "links[0].collision_shapes[0].position_m"),
        (lambda d: d["base"].update(collision_box={"size_m": [1.0, 0.0, 1.0]}), "base.collision_box.size_m[1]"),
        (lambda d: d["links"][1].update(collision_shapes=[FLAT_HULL]), "links[1].collision_shapes[0].vertices_m"),
        (lambda d: d["links"][1].update(collision_shapes=[ZERO_QUATERNION_BOX]), "links[1].collision_shapes[0].quaternion"),
        (lambda d: d["links"][1].update(collision_shapes=[{"type": "cone"}]), "links[1].collision_shapes[0].type"),
    ],
)
def test_bad_geometry_names_its_field(change, field) -> None:
    data = _armed_table1().to_dict()
    change(data)
    with pytest.raises(ParameterError) as info:
        RobotModel.from_dict(data)
    assert info.value.field == field, info.value


def _world_shapes(
    model: RobotModel, q: np.ndarray, base_position: np.ndarray, base_attitude: np.ndarray
) -> list[tuple[int, Shape]]:
    """Every body's shapes in the world at a state with their body (0 the carrier, i link i),
    through the engine's forward kinematics (the bodies' CoMs and attitudes)."""
    fk = forward_kinematics(model, State(q, base_position, base_attitude))
    centres = [fk.base_position, *fk.link_com_positions]
    attitudes = [fk.base_attitude, *fk.link_attitudes]
    out = []
    for body, shapes in enumerate([model.base.shapes] + [link.shapes for link in model.links]):
        R, c = attitudes[body], centres[body]
        for s in shapes:
            out.append((body, Shape(s.type, s.radius, c + R @ s.position, R @ s.rotation, s.dims, s.vertices)))
    return out


def _coal_of(shape: Shape) -> object:
    if shape.type == "capsule":
        return coal.Capsule(shape.radius, 2 * shape.dims[0])
    return coal.Box(*(2 * shape.dims))


def test_a_plans_clearance_equals_coal_at_every_sample() -> None:
    """The paper plan of a Table-1 robot with capsule links, a carrier box and a box obstacle:
    the planner's smallest distance at each sample equals coal's over the same pairs (links and
    the obstacle, links and the carrier but link 1, links two or more apart, the carrier and the
    obstacle), placed by the plan's own joint angles and base pose and the engine's forward
    kinematics."""
    model = _armed_table1()
    box = {"type": "box", "size_m": [0.3, 0.3, 0.3], "position_m": [1.45, 0.35, 0.45]}
    base = paper_task(table1_robot())
    task = CartesianTask(q0=base.q0, path=base.path, dt=base.dt, scene=Scene((shape_from_dict(box),)))
    result = plan(model, task, make_inverse("adaptive", **PAPER_TASK_PARAMS["adaptive"]))
    obstacle = shape_from_dict(box)
    for k in range(0, result.t.shape[0], 3):
        world = _world_shapes(model, result.q[k], result.base_position[k], result.base_attitude[k])
        best = min(_coal_distance(s, _coal_of(s), obstacle, _coal_of(obstacle)) for _, s in world)
        for i, (body_a, a) in enumerate(world):
            for body_b, b in world[i + 1 :]:
                if body_b - body_a >= 2 or (body_a == 0 and body_b >= 2):
                    best = min(best, _coal_distance(a, _coal_of(a), b, _coal_of(b)))
        assert result.clearance[k] == pytest.approx(best, abs=1e-9), k
    # the metric also counts the motion between samples: never above the samples' smallest
    assert result.metrics.min_clearance <= np.nanmin(result.clearance)
    assert result.metrics.clearance_respected and result.success


def test_a_pass_through_an_obstacle_between_two_samples_is_caught() -> None:
    """A 2 mm sphere where the middle of link 2 (a 5 mm capsule, 1 m long) is halfway between two
    samples of a coarse plan (1 s steps: it sweeps 5 cm sideways a step): clear of it at every
    sample, through it between two. The mid-step pose is placed independently of the planner (its
    joints halfway, the carrier's attitude and position interpolated between the samples)."""
    data = table1_robot().to_dict()
    for link in data["links"]:
        link["collision_radius_m"] = 0.005
    model = RobotModel.from_dict(data)
    base = paper_task(table1_robot())
    coarse = CartesianTask(q0=base.q0, path=base.path, dt=1.0)
    free = plan(model, coarse, make_inverse("dls", **{"lambda": 0.035}))
    k = 7
    q_mid = free.q[k] + 0.5 * coarse.dt * free.qd[k]
    turn = log_so3(free.base_attitude[k + 1] @ free.base_attitude[k].T)
    A_mid = exp_so3(0.5 * turn) @ free.base_attitude[k]
    p_mid = 0.5 * (free.base_position[k] + free.base_position[k + 1])
    fk = forward_kinematics(model, State(q_mid, p_mid, A_mid))
    point = fk.joint_positions[1] + 0.8 * (fk.joint_positions[2] - fk.joint_positions[1])
    sphere = {"type": "sphere", "radius_m": 0.002, "position_m": point.tolist()}
    task = CartesianTask(q0=coarse.q0, path=coarse.path, dt=coarse.dt, scene=Scene((shape_from_dict(sphere),)))
    hit = plan(model, task, make_inverse("dls", **{"lambda": 0.035}))
    assert np.nanmin(hit.clearance) > 0.005  # no sample sees it
    assert not hit.success and not hit.metrics.clearance_respected
    assert hit.metrics.clearance_broken_pair == ("link2", "obstacle0")
    assert k * coarse.dt < hit.metrics.time_collision < (k + 1) * coarse.dt
    assert hit.metrics.min_clearance < 0.0  # found by bisection: they overlap
    assert "clearance broken: link2 and obstacle0" in hit.message


def _fd_state(model: RobotModel, q: np.ndarray, A0: np.ndarray) -> tuple:
    n = model.n_joints
    kin, g = chain_kernels.kinematics_buffers(n), chain_kernels.gjm_buffers(n)
    chain_kernels.kinematics(model.chain, q, A0, np.zeros(3), True, kin)  # system CoM fixed at the origin
    chain_kernels.gjm(model.chain, kin, g)
    return kin, g


def test_the_distance_rate_equals_finite_differences_with_the_carriers_reaction() -> None:
    """``d_dot = row . qd`` (the velocity dampers' rows) against the central difference of the
    distance along a momentum-conserving motion (joints on a line, the carrier turning by its
    reaction, the system CoM fixed), for every pair on random states."""
    model = _armed_table1()
    scene = Scene((shape_from_dict({"type": "box", "size_m": [0.3, 0.2, 0.4], "position_m": [1.2, 0.3, 0.5]}),))
    geometry = build_geometry(
        [link.shapes for link in model.links], model.base.shapes, [link.name for link in model.links], scene
    )
    rng = np.random.default_rng(5)
    slide = np.ascontiguousarray(model.chain.joints[:, 0])
    buf = geometry_kernels.gjk_buffers()

    def distances(q, A0):
        kin, g = _fd_state(model, q, A0)
        posed = np.empty((geometry.shapes.shape[0], geometry_kernels.SHAPE_WIDTH))
        geometry_kernels.pose_all(geometry.shapes, kin[0], kin[1], np.eye(3), np.zeros(3), posed)  # kin is in world axes
        out, witness = [], []
        for a, b in geometry.pairs:
            w = np.empty((2, 3))
            out.append(geometry_kernels.shape_distance(posed[a], posed[b], geometry.vertices, buf, w))
            witness.append(w)
        return np.array(out), witness, posed, kin, g

    checked = overlapping = 0
    for _ in range(10):
        q, qd, A0 = rng.uniform(-2, 2, 6), rng.normal(size=6) * 0.3, exp_so3(rng.normal(size=3))
        d, witness, posed, kin, g = distances(q, A0)
        w0 = g[1][3:] @ qd
        h = 1e-6
        plus = distances(q + h * qd, exp_so3(w0 * h) @ A0)[0]
        minus = distances(q - h * qd, exp_so3(-w0 * h) @ A0)[0]
        for p, (a, b) in enumerate(geometry.pairs):
            row = np.empty(6)
            if not geometry_kernels.distance_rate_row(posed[a], posed[b], witness[p], d[p], slide, kin, g[1], row):
                continue  # capsules whose segments cross: no normal
            assert row @ qd == pytest.approx((plus[p] - minus[p]) / (2 * h), abs=1e-8)
            checked += 1
            overlapping += d[p] < -(posed[a, geometry_kernels.RADIUS] + posed[b, geometry_kernels.RADIUS])
    assert checked > 100
    assert overlapping > 5  # the way out of an overlap (EPA's normal) is checked too


def _raster_near_a_panel() -> tuple[RobotModel, CartesianTask, dict]:
    """The paper's line with a panel just below its middle: the unavoided plan hits it."""
    model = _armed_table1(radius=0.04)
    base = paper_task(table1_robot())
    free = plan(model, base, make_inverse("bounded", **{"lambda": 0.03}))
    k = base.n_steps // 2
    panel = {"type": "box", "size_m": [0.6, 0.6, 0.05], "position_m": (free.ee_position[k] + [0.0, 0.0, -0.09]).tolist()}
    return model, base, panel


def test_bounded_avoidance_keeps_the_clearance_where_the_plain_plan_breaks_it() -> None:
    model, base, panel = _raster_near_a_panel()
    scene = Scene((shape_from_dict(panel),), clearance=0.02, influence_distance=0.12, avoidance_gain=0.5)
    task = CartesianTask(q0=base.q0, path=base.path, dt=base.dt, scene=scene)
    plain = plan(model, task, make_inverse("dls", **{"lambda": 0.03}))
    assert not plain.metrics.clearance_respected and plain.metrics.min_clearance < 0.02
    avoided = plan(model, task, make_inverse("bounded", **{"lambda": 0.03}))
    assert avoided.metrics.clearance_respected, avoided.message
    assert avoided.metrics.min_clearance >= 0.02
    assert np.all(np.abs(avoided.qd) <= task.joint_speed_limit)  # the box still holds with the dampers
    # the price: the panel pushes the tool off the path (reported, not hidden)
    assert avoided.metrics.position_error_max > plain.metrics.position_error_max


def test_p_l_counts_the_clearance_in_batches_as_in_single_plans() -> None:
    model, base, panel = _raster_near_a_panel()
    task = CartesianTask(q0=base.q0, path=base.path, dt=base.dt, scene=Scene((shape_from_dict(panel),), clearance=0.02))
    lambdas = np.array([0.01, 0.03, 0.08])
    batch = plan_batch(model, task, "dls", {"lambda": lambdas})
    for i, lam in enumerate(lambdas):
        single = plan(model, task, make_inverse("dls", **{"lambda": float(lam)}))
        assert batch.metrics.clearance_respected[i] == single.metrics.clearance_respected
        assert batch.metrics.min_clearance[i] == pytest.approx(single.metrics.min_clearance, abs=1e-12)
        if not single.metrics.clearance_respected:
            assert math.isinf(batch.objective_b[i]) and math.isinf(single.metrics.objective_b)


def test_the_clearance_objective_pushes_a_redundant_arm_away_in_the_null_space() -> None:
    """On the 7-joint arm with capsule links: an obstacle near the elbow's path; the clearance
    objective raises the smallest distance, the end effector's path unchanged to the tolerance."""
    from engine import urdf_robot

    arm = urdf_robot("arm7")
    data = arm.to_dict()
    for link in data["links"]:
        link["collision_radius_m"] = 0.03
    arm = RobotModel.from_dict(data)
    q0 = np.radians([0.0, 40.0, 0.0, 80.0, 0.0, 50.0, 0.0])
    fk = forward_kinematics(arm, as_state(arm, q0))
    line = CartesianTask.from_q0(arm, q0, fk.ee_position + [0.1, 0.1, -0.05], fk.ee_attitude, duration=6.0, ramp_time=1.0, dt=0.1)
    free = plan(arm, line, make_inverse("dls", **{"lambda": 0.02}))
    wrist = forward_kinematics(arm, as_state(arm, free.q[30])).joint_positions[4]
    sphere = {"type": "sphere", "radius_m": 0.05, "position_m": (wrist + [0.0, 0.12, 0.0]).tolist()}
    task = CartesianTask(q0=line.q0, path=line.path, dt=line.dt, scene=Scene((shape_from_dict(sphere),), influence_distance=0.15))
    without = plan(arm, task, make_inverse("dls", **{"lambda": 0.02}))
    pushed = plan(arm, task, make_inverse("dls", **{"lambda": 0.02}), secondary=make_secondary("clearance", 2.0))
    assert without.success and pushed.success, pushed.message
    assert pushed.metrics.min_clearance > without.metrics.min_clearance + 0.02  # 17 mm -> 44 mm
    assert pushed.metrics.position_error_max < 1e-3  # the end effector's path is the primary inverse's
    with pytest.raises(ParameterError, match="clearance objective needs collision geometry"):
        plan(urdf_robot("arm7"), line, make_inverse("dls"), secondary=make_secondary("clearance"))


def test_obstacles_for_a_robot_without_shapes_say_so() -> None:
    base = paper_task(table1_robot())
    task = CartesianTask(q0=base.q0, path=base.path, scene=Scene((shape_from_dict({"type": "sphere", "radius_m": 0.1}),)))
    with pytest.raises(ParameterError, match="no collision shapes") as info:
        plan(table1_robot(), task, make_inverse("dls"))
    assert info.value.field == "task.scene.obstacles"


def test_overlaps_have_their_depth_and_fail_a_plan_at_the_default_clearance() -> None:
    """Cores that intersect report minus their penetration depth, not 0 (a 20 cm box inside the
    carrier's 1.5 m cube read 0.0, "within 7e-14 mm", so a plan whose obstacle sat inside the
    carrier respected the default clearance of 0): the analytic depths of a sphere at the cube's
    centre and of a box inside it, and a paper plan with that box in its scene fails at t = 0."""
    cube = shape_from_dict({"type": "box", "size_m": [1.5, 1.5, 1.5]})
    sphere = shape_from_dict({"type": "sphere", "radius_m": 0.1})
    box = shape_from_dict({"type": "box", "size_m": [0.2, 0.2, 0.2], "position_m": [0.1, 0.0, 0.0]})
    assert distance(cube, sphere).distance == pytest.approx(-0.85, abs=1e-12)  # out through a face: 0.75 + 0.1
    assert distance(sphere, cube).distance == pytest.approx(-0.85, abs=1e-12)
    assert distance(cube, box).distance == pytest.approx(-0.75, abs=1e-12)  # its face at x = 0 to the cube's at 0.75
    model = table1_with_geometry()
    base = paper_task(table1_robot())
    carrier = forward_kinematics(model, as_state(model, base.q0)).base_position
    inside = {"type": "box", "size_m": [0.2, 0.2, 0.2], "position_m": (carrier + [0.1, 0.0, 0.0]).tolist()}
    task = CartesianTask(q0=base.q0, path=base.path, dt=base.dt, scene=Scene((shape_from_dict(inside),)))
    assert task.scene.clearance == 0.0
    result = plan(model, task, make_inverse("adaptive", lambda_max=0.06, epsilon=0.12))
    assert not result.success and not result.metrics.clearance_respected
    assert result.metrics.clearance_broken_pair == ("carrier", "obstacle0") and result.metrics.time_collision == 0.0
    assert result.clearance[0] == pytest.approx(-0.75, abs=1e-12)  # at the start, as the analytic case
    assert result.metrics.min_clearance <= result.clearance[0]


def test_touching_shapes_are_at_distance_zero() -> None:
    """Contact exactly, where GJK ends on the boundary of the cores' difference (the EPA entry that
    tells touching from overlapping): a box on a box face to face, a box edge on a face, a point on
    a face, a capsule lying on a box; each at 0 (less the radii), not a depth."""
    box = shape_from_dict({"type": "box", "size_m": [1.0, 1.0, 1.0]})
    on_top = shape_from_dict({"type": "box", "size_m": [0.4, 0.4, 0.4], "position_m": [0.1, -0.2, 0.7]})
    turned = {"type": "box", "size_m": [0.4, 0.4, 0.4], "quaternion": [math.cos(math.pi / 8), math.sin(math.pi / 8), 0.0, 0.0]}
    edge = shape_from_dict({**turned, "position_m": [0.0, 0.0, 0.5 + 0.2 * math.sqrt(2.0)]})
    point = shape_from_dict({"type": "sphere", "radius_m": 0.05, "position_m": [0.2, 0.3, 0.5]})
    lying = shape_from_dict({"type": "capsule", "radius_m": 0.05, "from_m": [-0.3, 0.0, 0.55], "to_m": [0.3, 0.0, 0.55]})
    assert distance(box, on_top).distance == pytest.approx(0.0, abs=1e-12)
    assert distance(box, edge).distance == pytest.approx(0.0, abs=1e-12)
    assert distance(box, point).distance == pytest.approx(-0.05, abs=1e-12)
    assert distance(point, box).distance == pytest.approx(-0.05, abs=1e-12)
    assert distance(box, lying).distance == pytest.approx(0.0, abs=1e-12)

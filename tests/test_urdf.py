"""URDF import and export against Pinocchio's own URDF reader (free-flyer root joint): forward
kinematics and the GJM of the example robots and of random URDFs (fixed joints with and without
mass, rotated inertial frames, prismatic and continuous joints, revolute joints without limits),
merged inertias against Pinocchio's fixed-joint merging, round trips, and every refusal."""

import math

import numpy as np
import pytest
from robots import random_robot
from urdf_robots import chain_urdf, pinocchio_from_urdf, pinocchio_gjm_and_pose, pinocchio_state, random_urdf

from engine import RobotModel, State, generalized_jacobian, make_inverse, paper_task, plan, table1_robot, urdf_robot
from engine.kinematics import forward_kinematics
from engine.model import URDF_PRESETS, table1_with_geometry, urdf_preset_text
from engine.spatial import exp_so3, matrix_to_quaternion
from engine.urdf import MAX_URDF_BYTES, UrdfError


def _random_state(rng, model):
    lower = np.where(np.isfinite(model.lower_limits), model.lower_limits, -math.pi)
    upper = np.where(np.isfinite(model.upper_limits), model.upper_limits, math.pi)
    return State(rng.uniform(lower, upper), rng.normal(size=3), exp_so3(rng.normal(size=3)))


def _max_gaps(model, text, frame, rng, count):
    """Largest differences of the GJM, the end-effector position and attitude to Pinocchio's."""
    pm = pinocchio_from_urdf(text)
    worst = np.zeros(3)
    for _ in range(count):
        state = _random_state(rng, model)
        J_pin, p_pin, A_pin = pinocchio_gjm_and_pose(pm, frame, pinocchio_state(pm, model, state))
        ours = generalized_jacobian(model, state)
        gaps = [np.abs(ours.J_g - J_pin).max(), np.abs(ours.ee_position - p_pin).max(), np.abs(ours.ee_attitude - A_pin).max()]
        worst = np.maximum(worst, gaps)
    return worst


@pytest.mark.parametrize("preset", sorted(URDF_PRESETS))
def test_example_robots_match_pinocchio(rng, preset):
    model = urdf_robot(preset)
    assert np.all(_max_gaps(model, urdf_preset_text(preset), "tool0", rng, 40) < 1e-9)


def test_example_robots():
    arm7, arm3 = urdf_robot("arm7"), urdf_robot("arm3")
    assert arm7.n_joints == 7 and arm7.joint_types == ("revolute",) * 7
    assert arm7.base.name == "spacecraft" and arm7.base.mass == 483.0  # the mounting plate is merged
    assert arm7.end_effector_name == "tool0" and np.all(np.isfinite(arm7.lower_limits))
    assert arm3.joint_types == ("revolute", "revolute", "prismatic")
    assert arm3.joint_names == ("yaw", "pitch", "boom_extension")
    assert math.isinf(arm3.lower_limits[0]) and math.isinf(arm3.upper_limits[0])  # continuous
    np.testing.assert_allclose(arm3.lower_limits[1:], [math.radians(-90.0), 0.0])
    # The default end effector is the only leaf after the last moving joint.
    assert RobotModel.from_urdf(urdf_preset_text("arm7")).end_effector_name == "tool0"


@pytest.mark.parametrize("n", [3, 6, 7, 12])
def test_random_urdfs_match_pinocchio(rng, n):
    for _ in range(3):
        text = random_urdf(rng, n)
        model = RobotModel.from_urdf(text, end_effector_link="tool0")
        assert model.n_joints == n
        assert np.all(_max_gaps(model, text, "tool0", rng, 8) < 1e-9)


def test_merged_inertias_match_pinocchio(rng):
    """Mass, CoM and inertia of every body (fixed links merged) equal Pinocchio's, turned into
    the model's frames (parallel to the base at q = 0)."""
    for n in (3, 7):
        for _ in range(3):
            text = random_urdf(rng, n)
            model = RobotModel.from_urdf(text, end_effector_link="tool0")
            pm = pinocchio_from_urdf(text)
            data = pm.createData()
            import pinocchio as pin

            pin.forwardKinematics(pm, data, pin.neutral(pm))
            root = data.oMi[1].rotation
            bodies = [(model.base.mass, np.zeros(3), model.base.inertia)] + [
                (link.mass, link.a, link.inertia) for link in model.links
            ]
            for j, (mass, a, inertia) in enumerate(bodies):
                U = root.T @ data.oMi[j + 1].rotation  # the URDF frame at q = 0 in the base frame
                theirs = pm.inertias[j + 1]
                assert mass == pytest.approx(theirs.mass, rel=1e-12)
                np.testing.assert_allclose(U @ theirs.inertia @ U.T, inertia, atol=1e-10)
                if j > 0:
                    np.testing.assert_allclose(U @ theirs.lever, a, atol=1e-12)
            np.testing.assert_allclose(model.base.b + pm.inertias[1].lever, pm.jointPlacements[2].translation, atol=1e-12)


def _assert_same_model(a, b, tol=1e-12):
    assert a.n_joints == b.n_joints and a.joint_types == b.joint_types
    np.testing.assert_allclose(a.masses, b.masses, rtol=tol)
    np.testing.assert_allclose(a.inertias, b.inertias, atol=tol * np.abs(a.inertias).max())
    np.testing.assert_allclose(a.joint_axes, b.joint_axes, atol=tol)
    np.testing.assert_allclose(a.a_vectors, b.a_vectors, atol=tol)
    np.testing.assert_allclose(a.b_vectors, b.b_vectors, atol=tol)
    np.testing.assert_allclose(a.C_e, b.C_e, atol=tol)
    np.testing.assert_array_equal(a.lower_limits, b.lower_limits)
    np.testing.assert_array_equal(a.upper_limits, b.upper_limits)
    np.testing.assert_array_equal(a.effort_limits, b.effort_limits)


def test_round_trips(rng):
    models = [table1_robot(), urdf_robot("arm7"), urdf_robot("arm3")]
    models += [RobotModel.from_urdf(random_urdf(rng, n), end_effector_link="tool0") for n in (3, 8)]
    limited = random_robot(rng, 7, prismatic=0.5).to_dict()
    limited["links"][1]["limits"] = {"lower": -1.0, "upper": None}  # one-sided
    limited["links"][2]["limits"] = {"lower": -0.2, "upper": 0.4}
    for link in limited["links"][3:6]:  # effort limits on limited, unlimited (continuous) and prismatic joints
        link["force_limit_n" if link["joint_type"] == "prismatic" else "torque_limit_n_m"] = float(rng.uniform(0.1, 100.0))
    limited["links"][2]["force_limit_n" if limited["links"][2]["joint_type"] == "prismatic" else "torque_limit_n_m"] = 0.7
    models.append(RobotModel.from_dict(limited))
    for model in models:
        again = RobotModel.from_urdf(model.to_urdf())
        _assert_same_model(model, again)
        assert again.joint_names == model.joint_names and again.end_effector_name == model.end_effector_name
        # Pinocchio reads the export to the same robot.
        assert np.all(_max_gaps(model, model.to_urdf(), model.end_effector_name, rng, 5) < 1e-9)


def test_table1_export_gives_the_same_paper_plan(robot, task):
    again = RobotModel.from_urdf(robot.to_urdf())
    inverse = make_inverse("adaptive", lambda_max=0.06, epsilon=0.12)
    ours, theirs = plan(robot, task, inverse), plan(again, paper_task(again), inverse)
    np.testing.assert_allclose(theirs.q, ours.q, atol=1e-10)
    np.testing.assert_allclose(theirs.ee_position, ours.ee_position, atol=1e-10)
    assert theirs.metrics.objective_b == pytest.approx(ours.metrics.objective_b, rel=1e-9)


def test_tool_offset_moves_the_end_effector(rng):
    text = urdf_preset_text("arm7")
    offset = np.array([0.01, -0.02, 0.15])
    R = exp_so3(np.array([0.3, -0.2, 0.5]))
    plain = RobotModel.from_urdf(text, end_effector_link="tool0")
    tool = RobotModel.from_urdf(text, end_effector_link="tool0", tool_offset=(offset, R))
    for _ in range(5):
        state = _random_state(rng, plain)
        a, b = forward_kinematics(plain, state), forward_kinematics(tool, state)
        np.testing.assert_allclose(b.ee_position, a.ee_position + a.ee_attitude @ offset, atol=1e-12)
        np.testing.assert_allclose(b.ee_attitude, a.ee_attitude @ R, atol=1e-12)
    with pytest.raises(UrdfError, match="tool"):
        RobotModel.from_urdf(text, end_effector_link="tool0", tool_offset=(offset, 2.0 * R))


def test_effort_limits_are_read_from_limit_effort():
    """A positive ``<limit effort>`` is the torque (N m) or force (N, prismatic) limit, on a
    continuous joint too; URDF's placeholder 0 (what exports write when unknown) is none."""
    text = _arm(
        _joint("j3", "prismatic", "l2", "l3", "<axis xyz='1 0 0'/><limit lower='0' upper='0.5' effort='80' velocity='1'/>"),
        _link("l3"),
    )
    text = text.replace('<axis xyz="0 0 1"/>', "<axis xyz=\"0 0 1\"/><limit effort='12.5' velocity='0'/>")
    text = text.replace('<axis xyz="0 1 0"/>', "<axis xyz=\"0 1 0\"/><limit lower='-1' upper='1' effort='0' velocity='0'/>")
    model = RobotModel.from_urdf(text.replace('type="revolute"><parent link="base"', 'type="continuous"><parent link="base"'))
    np.testing.assert_array_equal(model.effort_limits, [12.5, np.inf, 80.0])
    entries = model.to_dict()["links"]
    assert entries[0]["torque_limit_n_m"] == 12.5 and entries[2]["force_limit_n"] == 80.0 and "torque_limit_n_m" not in entries[1]
    assert not model.links[0].limited  # continuous: no position limit, though its <limit> has an effort


def test_massless_frames_and_missing_limits_are_accepted():
    text = """<robot name="r">
      <link name="world"/>
      <link name="body"><inertial><mass value="100"/>
        <inertia ixx="10" ixy="0" ixz="0" iyy="10" iyz="0" izz="10"/></inertial></link>
      <joint name="world_body" type="fixed"><parent link="world"/><child link="body"/></joint>
      <link name="arm"><inertial><origin xyz="0.2 0 0"/><mass value="2"/>
        <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.02" iyz="0" izz="0.02"/></inertial></link>
      <joint name="shoulder" type="revolute"><parent link="body"/><child link="arm"/><axis xyz="0 0 1"/></joint>
      <link name="flange"/>
      <joint name="flange_joint" type="fixed"><parent link="arm"/><child link="flange"/><origin xyz="0.4 0 0"/></joint>
    </robot>"""
    model = RobotModel.from_urdf(text)
    assert model.n_joints == 1 and model.base.name == "world" and model.end_effector_name == "flange"
    assert not model.links[0].limited  # revolute without <limit>: unlimited
    np.testing.assert_allclose(model.links[0].b, [0.2, 0.0, 0.0])


INERTIA = '<inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/>'


def _link(name, inertial=f'<inertial><mass value="1"/>{INERTIA}</inertial>'):
    return f'<link name="{name}">{inertial}</link>'


def _joint(name, kind, parent, child, extra=""):
    return f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>{extra}</joint>'


def _arm(joints: str = "", links: str = "", name: str = 'name="r"') -> str:
    """A two-joint arm, with extra joints and links."""
    return f"""<robot {name}>
      <link name="base"><inertial><mass value="100"/>{INERTIA}</inertial></link>{_link("l1")}{_link("l2")}
      {_joint("j1", "revolute", "base", "l1", '<axis xyz="0 0 1"/>')}
      {_joint("j2", "revolute", "l1", "l2", '<origin xyz="0 0 1"/><axis xyz="0 1 0"/>')}
      {links}{joints}
    </robot>"""


def _third(kind, extra="", link=_link("l3")):
    """The arm with a third joint ``j3`` from l2 to l3."""
    return _arm(_joint("j3", kind, "l2", "l3", extra), link)


def _inertia(values):
    attrs = " ".join(f'{k}="{v}"' for k, v in zip(("ixx", "ixy", "ixz", "iyy", "iyz", "izz"), values, strict=True))
    return _link("l3", f'<inertial><mass value="1"/><inertia {attrs}/></inertial>')


J3 = '<joint name="j3">'
L3 = '<link name="l3">'


@pytest.mark.parametrize(
    ("text", "options", "element", "reason"),
    [
        ("<robot name='r'><link name='a'>", {}, "<robot>", "not well-formed"),
        ('<?xml version="1.0"?><!DOCTYPE r [<!ENTITY a "aaaa">]><robot name="r">&a;</robot>', {}, "<robot>", "DTD"),
        ('<!DOCTYPE r [<!ENTITY x SYSTEM "file:///etc/passwd">]><robot name="x">&x;</robot>', {}, "<robot>", "DTD"),
        ("<model name='r'/>", {}, "<model>", "must be <robot>"),
        (_arm(name=""), {}, "<robot>", "name"),
        (_third("floating", link="<link name='l3'/>"), {}, J3, "floating"),
        (_third("planar", link="<link name='l3'/>"), {}, J3, "planar"),
        (_third("spherical", link="<link name='l3'/>"), {}, J3, "unknown joint type"),
        (_third("revolute", "<mimic joint='j2'/>"), {}, J3, "mimic"),
        (_arm(_joint("j3", "fixed", "l2", "nowhere")), {}, J3, "does not exist"),
        (_arm(), {"end_effector_link": "nowhere"}, '<link name="nowhere">', "no such link"),
        (_arm(_joint("j3", "revolute", "l1", "l3", "<axis xyz='1 0 0'/>"), _link("l3")), {}, J3, "second moving branch"),
        (_arm(), {"end_effector_link": "l1"}, '<joint name="j2">', "off the chain"),
        (_third("prismatic", link="<link name='l3'/>"), {}, L3, "zero mass"),
        (_third("fixed", link=_inertia((1, 0, 0, -1, 0, 1))), {}, L3, "non-physical inertia"),
        (_third("fixed", link=_inertia((1, 0, 0, 1, 0, 5))), {}, L3, "triangle inequality"),
        (_arm(links="<link name='l3'><inertial><mass value='-1'/></inertial></link>"), {}, L3, "negative mass"),
        (_arm(links="<link name='l3'><inertial><mass value='1'/></inertial></link>"), {}, L3, "<inertia>"),
        (_third("fixed", "<origin xyz='${a} 0 0'/>"), {}, J3, "xacro"),
        (_third("revolute", "<axis xyz='0 0 0'/>"), {}, J3, "axis is zero"),
        (_arm(links="<link name='l1'/>"), {}, '<link name="l1">', "two <link>"),
        (_arm(_joint("j3", "fixed", "l2", "l1")), {}, '<link name="l1">', "child of two joints"),
        (_third("revolute", "<limit lower='1' upper='-1'/>"), {}, J3, "lower"),
        # issue 22: an empty robot says so; numbers are XML Schema doubles
        ('<robot name="a"/>', {}, "<robot>", "no <link>"),
        (_third("fixed", link=_inertia((1, 0, 0, 1, 0, 1)).replace('"1"', '"1_000"', 1)), {}, L3, "'1_000' is not 1 number"),
        (_third("fixed", link=_inertia((1, 0, 0, 1, 0, 1)).replace('<mass value="1"', '<mass value="inf"')), {}, L3, "number"),
        (_third("revolute", "<origin xyz='0x10 0 0'/>"), {}, J3, "number"),
        (_third("revolute", "<limit lower='-1' upper='1' effort='-5' velocity='1'/>"), {}, J3, "negative"),
        (_third("continuous", "<limit effort='nan' velocity='1'/>"), {}, J3, "number"),  # no inf or nan (engine.urdf.NUMBER)
    ],
)
def test_refusals_name_the_element(text, options, element, reason):
    with pytest.raises(UrdfError) as info:
        RobotModel.from_urdf(text, **options)
    assert info.value.element == element, info.value
    assert reason in info.value.reason, info.value


def test_size_and_depth_limits():
    with pytest.raises(UrdfError, match="bytes"):
        RobotModel.from_urdf("<robot name='r'>" + " " * MAX_URDF_BYTES + "</robot>")
    with pytest.raises(UrdfError, match="nested"):
        RobotModel.from_urdf("<robot name='r'>" + "<a>" * 40 + "</a>" * 40 + "</robot>")
    # A billion-laughs document is refused before any expansion.
    bomb = (
        '<!DOCTYPE r [<!ENTITY a "aaaaaaaaaa">'
        + "".join(f'<!ENTITY a{i} "{("&a;" if i == 0 else f"&a{i - 1};") * 10}">' for i in range(9))
        + ']><robot name="r">&a8;</robot>'
    )
    with pytest.raises(UrdfError, match="DTD"):
        RobotModel.from_urdf(bomb)


def test_geometry_and_unknown_elements_are_ignored():
    link = "<link name='l3'><visual><geometry><box size='not numbers'/></geometry></visual></link>"
    text = _third("fixed", link=link).replace("</robot>", "<gazebo>anything</gazebo></robot>")
    model = RobotModel.from_urdf(text)
    assert model.n_joints == 2 and model.end_effector_name == "l3"


@pytest.mark.parametrize("kind", ["revolute", "fixed"])
def test_a_megabyte_of_joints_is_refused_before_the_tree_is_walked(kind):
    """Issue 22: the joint and link counts are checked first, and reading is linear in the
    document (a 10,000-joint chain took 9 s of CPU when the chain walk came first)."""
    import time

    text = chain_urdf(10_000, kind)
    assert 1_000_000 < len(text.encode()) <= MAX_URDF_BYTES
    start = time.process_time()
    with pytest.raises(UrdfError, match="at most") as info:
        RobotModel.from_urdf(text)
    print(f"\n{kind}: {len(text)} bytes, 10,000 joints refused in {time.process_time() - start:.3f} s of CPU: {info.value}")
    assert info.value.element == "<robot>"
    moving = chain_urdf(13)
    with pytest.raises(UrdfError, match="13 moving joints"):
        RobotModel.from_urdf(moving)


@pytest.mark.parametrize(
    ("change", "field"),
    [
        (('<mass value="1"/>', '<mass value="1e308"/>'), "mass"),
        ((INERTIA, INERTIA.replace('"1"', '"1e308"')), "inertia"),
        (('<origin xyz="0 0 1"/>', '<origin xyz="1e200 0 1"/>'), ".b"),
        (("<axis xyz='0 0 1'/>", "<axis xyz='0 0 1'/><limit lower='-1e308' upper='1e308'/>"), "limits"),
    ],
)
def test_huge_numbers_are_refused_with_the_parameter_sets_bounds(change, field):
    """Issue 22: a URDF's numbers are finite but may be huge; the model built from it has the
    bounds of any parameter set (engine.bounds), and nothing overflows on the way (no LinAlgError)."""
    text = _third("revolute", "<axis xyz='0 0 1'/>").replace(*change)
    assert text != _third("revolute", "<axis xyz='0 0 1'/>")
    with pytest.raises(UrdfError) as info:
        RobotModel.from_urdf(text)
    assert field in info.value.field + str(info.value), info.value


COLLIDING = f"""<robot name="c">
  <link name="base"><inertial><origin xyz="0.1 0 0"/><mass value="100"/>{INERTIA}</inertial>
    <collision><origin xyz="0.1 0.2 -0.3" rpy="0.1 0.2 0.3"/><geometry><box size="0.8 0.6 0.4"/></geometry></collision></link>
  <link name="l1"><inertial><origin xyz="0 0 0.2"/><mass value="2"/>{INERTIA}</inertial>
    <collision><origin xyz="0 0 0.25" rpy="0.3 -0.2 0.5"/>
      <geometry><cylinder radius="0.05" length="0.5"/></geometry></collision></link>
  <link name="l2"><inertial><origin xyz="0.3 0 0" rpy="0 0.4 0"/><mass value="1.5"/>{INERTIA}</inertial>
    <collision><origin xyz="0.3 0 0" rpy="0 1.5707963267948966 0"/>
      <geometry><capsule radius="0.04" length="0.6"/></geometry></collision></link>
  <link name="tip"><collision><origin xyz="0.05 0 0"/><geometry><sphere radius="0.03"/></geometry></collision></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="0.4 0 0.2" rpy="0 0 0.3"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="0" velocity="0"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0 0 0.5" rpy="0.2 0 0"/>
    <axis xyz="0 1 0"/><limit lower="-3" upper="3" effort="0" velocity="0"/></joint>
  <joint name="j3" type="revolute"><parent link="l2"/><child link="l3"/><origin xyz="0.6 0 0"/><axis xyz="1 0 0"/>
    <limit lower="-3" upper="3" effort="0" velocity="0"/></joint>
  <link name="l3"><inertial><mass value="0.5"/>{INERTIA}</inertial></link>
  <joint name="tip_mount" type="fixed"><parent link="l3"/><child link="tip"/><origin xyz="0.1 0 0" rpy="0 0 0.7"/></joint>
</robot>"""


def test_collision_geometry_is_placed_as_pinocchio_places_it(rng):
    """Every <collision> of the URDF (a box on the base, a cylinder, a capsule along its origin's
    z, a sphere on a fixed link merged into the last body), placed by our forward kinematics,
    against Pinocchio's own collision model of the URDF (pin.buildGeomFromUrdfString, placed by
    pin.updateGeometryPlacements): centres and axes to 1e-12 on random states. (urdfdom reads no
    <capsule>: Pinocchio gets a cylinder at the same origin.)"""
    import pinocchio as pin

    model = RobotModel.from_urdf(COLLIDING, end_effector_link="tip")
    assert [len(model.base.shapes)] + [len(link.shapes) for link in model.links] == [1, 1, 1, 1]
    for_pinocchio = COLLIDING.replace("<capsule", "<cylinder")
    pm = pinocchio_from_urdf(for_pinocchio)
    gm = pin.buildGeomFromUrdfString(pm, for_pinocchio, pin.GeometryType.COLLISION)
    theirs = {obj.name.rsplit("_", 1)[0]: i for i, obj in enumerate(gm.geometryObjects)}
    for _ in range(10):
        state = _random_state(rng, model)
        fk = forward_kinematics(model, state)
        centres = [fk.base_position, *fk.link_com_positions]
        attitudes = [fk.base_attitude, *fk.link_attitudes]
        data, gdata = pm.createData(), gm.createData()
        pin.updateGeometryPlacements(pm, data, gm, gdata, pinocchio_state(pm, model, state))
        for body, owner in enumerate(("base", "l1", "l2", "tip")):
            (shape,) = model.base.shapes if body == 0 else model.links[body - 1].shapes
            R, c = attitudes[body], centres[body]
            placement = gdata.oMg[theirs[owner]]
            np.testing.assert_allclose(c + R @ shape.position, placement.translation, atol=1e-12)
            ours_axes = R @ shape.rotation
            if shape.type == "box":
                np.testing.assert_allclose(ours_axes, placement.rotation, atol=1e-12)
            elif shape.type in ("cylinder", "capsule"):
                np.testing.assert_allclose(
                    ours_axes[:, 2] * np.sign(ours_axes[:, 2] @ placement.rotation[:, 2]), placement.rotation[:, 2], atol=1e-12
                )
    (box,) = model.base.shapes
    (cylinder,), (capsule,), (sphere,) = (link.shapes for link in model.links)
    np.testing.assert_allclose(2 * box.dims, [0.8, 0.6, 0.4])
    assert (cylinder.dims[0], 2 * cylinder.dims[1]) == pytest.approx((0.05, 0.5))
    assert (capsule.radius, 2 * capsule.dims[0]) == pytest.approx((0.04, 0.6))
    assert sphere.radius == pytest.approx(0.03)


@pytest.mark.parametrize(
    ("geometry", "reason"),
    [
        ("<box size='1 0 1'/>", "must be > 0"),
        ("<cylinder radius='0.1'/>", "length"),
        ("<mesh filename='package://arm/meshes/l3.stl'/>", "mesh://"),
        ("<cone radius='1'/>", "one <geometry>"),
    ],
)
def test_bad_collision_geometry_names_the_link(geometry, reason):
    link = _link("l3", f'<inertial><mass value="1"/>{INERTIA}</inertial><collision><geometry>{geometry}</geometry></collision>')
    with pytest.raises(UrdfError) as info:
        RobotModel.from_urdf(_third("revolute", "<axis xyz='1 0 0'/>", link))
    assert info.value.element == '<link name="l3">' and reason in info.value.reason, info.value


def test_a_mesh_collision_is_the_hull_the_caller_gives():
    cube = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
    link = _link(
        "l3",
        f'<inertial><mass value="1"/>{INERTIA}</inertial><collision><geometry>'
        "<mesh filename='mesh://abc' scale='0.1 0.2 0.3'/></geometry></collision>",
    )
    model = RobotModel.from_urdf(_third("revolute", "<axis xyz='1 0 0'/>", link), mesh_hulls={"mesh://abc": cube}.get)
    (shape,) = model.links[2].shapes
    assert shape.type == "convex"
    np.testing.assert_allclose(np.abs(shape.vertices).max(axis=0), [0.1, 0.2, 0.3])


def _assert_same_shapes(ours, theirs):
    assert [s.type for s in ours] == [s.type for s in theirs]
    for a, b in zip(ours, theirs, strict=True):
        assert a.radius == pytest.approx(b.radius, abs=1e-15)
        np.testing.assert_allclose(a.position, b.position, atol=1e-12)
        np.testing.assert_allclose(a.dims, b.dims, atol=1e-12)
        if a.type == "box":
            np.testing.assert_allclose(a.rotation, b.rotation, atol=1e-12)
        elif a.type in ("cylinder", "capsule"):  # symmetric about their axis, and end for end
            np.testing.assert_allclose(
                a.rotation[:, 2] * np.sign(a.rotation[:, 2] @ b.rotation[:, 2]), b.rotation[:, 2], atol=1e-12
            )


def _every_shape(rng):
    """A random 4-joint robot whose bodies carry every shape type, turned at random (a box with
    its x axis straight up too, where roll and yaw are one angle), and a capsule link."""
    data = random_robot(rng, 4).to_dict()
    turned = [exp_so3(rng.normal(size=3)) for _ in range(3)] + [exp_so3([0.0, math.pi / 2, 0.0]) @ exp_so3([0.3, 0, 0])]
    quaternion = [matrix_to_quaternion(R).tolist() for R in turned]
    data["base"]["collision_box"] = {"size_m": [0.8, 0.6, 0.5], "center_m": [0.0, 0.1, -0.05]}
    data["base"]["collision_shapes"] = [
        {"type": "box", "size_m": [0.1, 0.2, 0.3], "position_m": [0.2, 0, 0.4], "quaternion": quaternion[3]}
    ]
    data["links"][0]["collision_shapes"] = [
        {"type": "cylinder", "radius_m": 0.05, "length_m": 0.3, "position_m": [0.01, 0.02, 0.03], "quaternion": quaternion[0]},
        {"type": "sphere", "radius_m": 0.04, "position_m": [0.1, -0.1, 0.0]},
    ]
    data["links"][1]["collision_radius_m"] = 0.03
    data["links"][2]["collision_shapes"] = [
        {"type": "capsule", "radius_m": 0.02, "from_m": [0.0, 0.0, 0.0], "to_m": [0.1, 0.2, -0.1]},
        {"type": "box", "size_m": [0.05, 0.1, 0.2], "position_m": [0.0, 0.05, 0.0], "quaternion": quaternion[1]},
    ]
    data["links"][3]["collision_shapes"] = [
        {
            "type": "convex",
            "vertices_m": [[x, y, z] for x in (0, 0.1) for y in (0, 0.1) for z in (0, 0.1)],
            "quaternion": quaternion[2],
        }
    ]
    return RobotModel.from_dict(data)


def test_collision_geometry_round_trips_through_the_export(rng):
    """The export writes every body's collision shapes as standard URDF: reading it back gives the
    same shapes (a capsule, written as a cylinder and two end spheres, merged again), and
    Pinocchio's own collision model of the export (urdfdom, placed by
    pin.updateGeometryPlacements) puts each written primitive where our forward kinematics puts
    it. A convex shape is left out with a comment (URDF carries meshes as files only)."""
    import pinocchio as pin

    for model in (table1_with_geometry(), RobotModel.from_urdf(COLLIDING, end_effector_link="tip"), _every_shape(rng)):
        text = model.to_urdf()
        again = RobotModel.from_urdf(text, end_effector_link=model.end_effector_name)
        _assert_same_model(model, again)
        bodies = [model.base, *model.links]
        for ours, theirs in zip(bodies, [again.base, *again.links], strict=True):
            _assert_same_shapes([s for s in ours.shapes if s.type != "convex"], theirs.shapes)
        convex = [s for body in bodies for s in body.shapes if s.type == "convex"]
        assert text.count("a convex collision shape of 8 vertices is not written") == len(convex)

        # Pinocchio: a capsule is three primitives, every other written shape one
        written = [(j, s) for j, body in enumerate(bodies) for s in body.shapes if s.type != "convex"]
        pm = pinocchio_from_urdf(text)
        gm = pin.buildGeomFromUrdfString(pm, text, pin.GeometryType.COLLISION)
        assert gm.ngeoms == sum(3 if s.type == "capsule" else 1 for _, s in written)
        state = _random_state(rng, model)
        fk = forward_kinematics(model, state)
        centres, attitudes = [fk.base_position, *fk.link_com_positions], [fk.base_attitude, *fk.link_attitudes]
        data, gdata = pm.createData(), gm.createData()
        pin.updateGeometryPlacements(pm, data, gm, gdata, pinocchio_state(pm, model, state))
        placed = iter(range(gm.ngeoms))  # urdfdom keeps each link's collisions in document order
        for j, shape in written:
            R, c = attitudes[j], centres[j]
            half = shape.dims[0] * shape.rotation[:, 2] if shape.type == "capsule" else np.zeros(3)
            for offset in (0.0, -1.0, 1.0) if shape.type == "capsule" else (0.0,):
                obj = gm.geometryObjects[next(placed)]
                placement = gdata.oMg[gm.getGeometryId(obj.name)]
                assert obj.parentJoint == (1 if j == 0 else j + 1)
                np.testing.assert_allclose(c + R @ (shape.position + offset * half), placement.translation, atol=1e-12)
                if shape.type == "box":
                    np.testing.assert_allclose(R @ shape.rotation, placement.rotation, atol=1e-12)
                    np.testing.assert_allclose(obj.geometry.halfSide, shape.dims, atol=1e-15)
                elif offset == 0.0 and shape.type in ("cylinder", "capsule"):
                    axis = (R @ shape.rotation)[:, 2]
                    np.testing.assert_allclose(
                        axis * np.sign(axis @ placement.rotation[:, 2]), placement.rotation[:, 2], atol=1e-12
                    )
                    assert obj.geometry.radius == pytest.approx(shape.dims[0] if shape.type == "cylinder" else shape.radius)


def test_only_a_cylinder_with_a_sphere_of_its_radius_on_each_end_is_a_capsule():
    """The reader merges a capsule as the export writes it, and nothing else: a sphere of another
    radius, one off the end face's centre, or one end only stay as they are; two cylinders sharing
    an end sphere take it once."""

    def link_with(geometries):
        body = "".join(
            f'<collision><origin xyz="{xyz}" rpy="0 0 0"/><geometry>{g}</geometry></collision>' for xyz, g in geometries
        )
        return RobotModel.from_urdf(
            _third("revolute", "<axis xyz='1 0 0'/>", _link("l3", f'<inertial><mass value="1"/>{INERTIA}</inertial>{body}'))
        )

    cylinder = ("0 0 0", "<cylinder radius='0.1' length='0.4'/>")
    end = ("0 0 0.2", "<sphere radius='0.1'/>")
    other_end = ("0 0 -0.2", "<sphere radius='0.1'/>")
    cases = {
        "merged": ([cylinder, end, other_end], ["capsule"]),
        "radius": ([cylinder, end, ("0 0 -0.2", "<sphere radius='0.09'/>")], ["cylinder", "sphere", "sphere"]),
        "off centre": ([cylinder, end, ("0.01 0 -0.2", "<sphere radius='0.1'/>")], ["cylinder", "sphere", "sphere"]),
        "one end": ([cylinder, end], ["cylinder", "sphere"]),
        "shared": ([cylinder, end, other_end, ("0 0 0.4", "<cylinder radius='0.1' length='0.4'/>")], ["capsule", "cylinder"]),
    }
    for name, (geometries, types) in cases.items():
        assert [s.type for s in link_with(geometries).links[2].collision_shapes] == types, name


def test_a_tool_frame_gets_a_name_no_link_of_the_file_has():
    """With a tool offset the end effector is named ``<link>_tool``; a link of the file already
    called so makes it ``<link>_tool_2``, so that no two frames of the robot share a name (the API
    refuses a parameter set whose frames do, and the export would rename one)."""
    text = table1_robot().to_urdf().replace('"link3"', '"link6_tool"')
    model = RobotModel.from_urdf(text, end_effector_link="link6", tool_offset=([0.1, 0.0, 0.0], np.eye(3)))
    names = [model.base.name, *(link.name for link in model.links)]
    assert "link6_tool" in names and model.end_effector_name == "link6_tool_2"
    plain = RobotModel.from_urdf(table1_robot().to_urdf(), end_effector_link="link6", tool_offset=([0.1, 0.0, 0.0], np.eye(3)))
    assert plain.end_effector_name == "link6_tool"

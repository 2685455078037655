"""The task presets: the paper's detection line and variants, and two inspection paths on the
Table-1 robot (a raster scan of a patch in front of it and a waypoint inspection), each with the
method and parameters it is meant to be planned with, and lines for the URDF example robots.

The inspection presets' adaptive-damping parameters were tuned with the paper's GA
(:func:`engine.tuning.tune`: population 16, 10 generations, seed 1, B with w = (0.5, 0.5) and
the max aggregation) and rounded to four digits; ``bench/tune_presets.py`` reruns that tuning
and plans and replays both. The
waypoint attitudes are the start attitude at the paper's q0, ``[0, -0.0872, -0.9962, 0]``,
turned about world axes (15 deg about z, 10 deg about y, then back).
"""

from __future__ import annotations

from engine.trajectory import PAPER_Q0_DEG, PAPER_TASK_PARAMS
from service.errors import NotFoundError
from service.schemas.common import PAPER_TASK_EXAMPLE
from service.schemas.geometry import BoxIn, SceneIn
from service.schemas.methods import MethodIn
from service.schemas.paths import PoseIn, RasterPathIn, WaypointsPathIn
from service.schemas.tasks import TaskIn, TaskPreset, TaskPresetList

#: The paper's start attitude turned 15 deg about world z, and 10 deg about world y.
_TURNED_Z15 = [0.0, 0.043619387, -0.999048222, 0.0]
_TILTED_Y10 = [0.086824089, -0.086824089, -0.992403877, 0.007596123]
_START_ATTITUDE = [0.0, -0.087155743, -0.996194698, 0.0]

RASTER_PATCH = RasterPathIn(
    type="raster",
    corner_m=[1.35, -0.15, 0.0],
    scan_edge_m=[0.2, 0.0, 0.0],
    step_edge_m=[0.0, 0.3, 0.0],
    line_spacing_m=0.05,
    standoff_m=0.15,
    scan_speed_m_s=0.02,
    scan_acceleration_m_s2=0.01,
)

WAYPOINT_INSPECTION = WaypointsPathIn(
    type="waypoints",
    waypoints=[
        PoseIn(position_m=[1.30, 0.10, 0.45], attitude_quaternion=_TURNED_Z15),
        PoseIn(position_m=[1.50, 0.10, 0.30], attitude_quaternion=_TILTED_Y10),
        PoseIn(position_m=[1.50, -0.10, 0.15], attitude_quaternion=_TILTED_Y10),
        PoseIn(position_m=[1.35, -0.10, 0.05], attitude_quaternion=_START_ATTITUDE),
    ],
    max_speed_m_s=0.03,
    max_angular_speed_deg_s=3.0,
    max_acceleration_m_s2=0.01,
    max_angular_acceleration_deg_s2=1.0,
)

#: The raster patch as the top face of a target spacecraft (a 0.6 m x 0.8 m x 0.3 m box), with a
#: fixture beyond its far edge (a plate 4 cm thick, 40 cm wide, 10 cm tall) under the scan's turns.
TARGET_SCENE = SceneIn(
    obstacles=[
        BoxIn(type="box", size_m=[0.6, 0.8, 0.3], position_m=[1.45, 0.0, -0.15]),
        BoxIn(type="box", size_m=[0.04, 0.4, 0.1], position_m=[1.58, 0.0, 0.05]),
    ],
    influence_distance_m=0.1,
    avoidance_gain=0.5,
)

#: The paper line's method: adaptive damping at the GA optimum for the Table-1 robot.
PAPER_METHOD = MethodIn.model_validate({"name": "adaptive", "params": PAPER_TASK_PARAMS["adaptive"]})

PRESETS: dict[str, TaskPreset] = {
    "paper-line": TaskPreset(
        name="paper-line",
        description="The paper's detection line on the Table-1 robot: 15 s, trapezoidal, dt 0.25 s, 6 deg/s limit; its "
        "method is the GA optimum for this robot (the paper's own lambda_max 0.0571, epsilon 0.0677 reach 8.54 deg/s "
        "here: they were tuned for the paper's exact robot)",
        robot_id="table1",
        task=TaskIn(**PAPER_TASK_EXAMPLE),
        method=PAPER_METHOD,
    ),
    "paper-line-quintic": TaskPreset(
        name="paper-line-quintic",
        description="The paper's detection line with a quintic time profile, and paper-line's method: the quintic "
        "profile's higher peak speed takes joint 2 to 8.9 deg/s, past the 6 deg/s limit (no adaptive damping between "
        "0.04 and 0.2 keeps it), so the plan fails where the trapezoidal one succeeds",
        robot_id="table1",
        task=TaskIn(**{**PAPER_TASK_EXAMPLE, "profile": "quintic"}),
        method=PAPER_METHOD,
    ),
    "paper-line-fine": TaskPreset(
        name="paper-line-fine",
        description="The paper's detection line with dt 0.05 s, and paper-line's method",
        robot_id="table1",
        task=TaskIn(**{**PAPER_TASK_EXAMPLE, "dt_s": 0.05}),
        method=PAPER_METHOD,
    ),
    "raster-patch": TaskPreset(
        name="raster-patch",
        description="Raster scan of a 0.2 m x 0.3 m horizontal patch at z = 0 in front of the Table-1 robot: 7 passes "
        "0.05 m apart at 2 cm/s, sensor (end-effector z axis) 0.15 m above it pointing down; about 114 s. The scan "
        "passes near the GJM's singularity (the plain inverse breaks the 6 deg/s limit); tuned adaptive damping",
        robot_id="table1",
        task=TaskIn(q0_deg=list(PAPER_Q0_DEG), path=RASTER_PATCH),
        method=MethodIn.model_validate({"name": "adaptive", "params": {"lambda_max": 0.02038, "epsilon": 0.1200}}),
    ),
    "raster-target": TaskPreset(
        name="raster-target",
        description="The raster-patch scan over the top face of a target spacecraft (a 0.6 m x 0.8 m x 0.3 m box) with "
        "a fixture 10 cm tall beyond the face's far edge, under the scan's turns; robot table1-geometry (capsule links, "
        "carrier cube), 20 mm clearance. Planned without avoidance (adaptive damping) the sensor link touches the "
        "fixture at a turn; the bounded inverse's velocity dampers keep 20 mm, lifting the sensor over it (a few cm of "
        "tracking error at the turns)",
        robot_id="table1-geometry",
        task=TaskIn(q0_deg=list(PAPER_Q0_DEG), path=RASTER_PATCH, clearance_m=0.02, scene=TARGET_SCENE),
        method=MethodIn.model_validate({"name": "bounded", "params": {"lambda": 0.02}}),
    ),
    "waypoint-inspection": TaskPreset(
        name="waypoint-inspection",
        description="Four inspection poses in front of the Table-1 robot, the sensor turned and tilted by up to 15 deg, "
        "visited rest to rest at up to 3 cm/s and 3 deg/s; about 59 s. The last pose is near the GJM's singularity "
        "(the plain inverse breaks the 6 deg/s limit); tuned adaptive damping",
        robot_id="table1",
        task=TaskIn(q0_deg=list(PAPER_Q0_DEG), path=WAYPOINT_INSPECTION),
        method=MethodIn.model_validate({"name": "adaptive", "params": {"lambda_max": 0.02753, "epsilon": 0.1736}}),
    ),
    "arm7-line": TaskPreset(
        name="arm7-line",
        description="The 7-joint arm on its spacecraft (URDF example): a 0.37 m line with a 20 deg turn in 20 s, "
        "6 deg/s limit, adaptive damping 0.05/0.05; plan it with and without the secondary objective "
        "min_base_rotation",
        robot_id="arm7",
        task=TaskIn(
            q0_deg=[0.0, 40.0, 0.0, 80.0, 0.0, 50.0, 0.0],
            target_position_m=[0.8878, 0.3099, -0.5009],
            target_attitude_quaternion=[0.482759, -0.411213, -0.51896, 0.573173],
            duration_s=20.0,
            ramp_time_s=2.0,
            dt_s=0.25,
            joint_speed_limit_deg_s=6.0,
        ),
        method=MethodIn.model_validate({"name": "adaptive", "params": {"lambda_max": 0.05, "epsilon": 0.05}}),
    ),
    "arm3-position": TaskPreset(
        name="arm3-position",
        description="The 3-joint arm (yaw, pitch, telescopic boom; URDF example) moves its tool 0.33 m in 20 s, "
        "tracking the position only; 6 deg/s and 0.05 m/s limits; DLS",
        robot_id="arm3",
        task=TaskIn(
            q0_deg=[0.0, 20.0, None],
            q0_m=[None, None, 0.2],
            tracks="position",
            target_position_m=[1.5156, 0.3, 1.2288],
            duration_s=20.0,
            ramp_time_s=2.0,
            dt_s=0.25,
            joint_speed_limit_deg_s=6.0,
            joint_speed_limit_m_s=0.05,
        ),
        method=MethodIn.model_validate({"name": "dls"}),
    ),
}


def listing() -> TaskPresetList:
    return TaskPresetList(items=list(PRESETS.values()), total=len(PRESETS))


def get(name: str) -> TaskPreset:
    if name not in PRESETS:
        raise NotFoundError("task preset", name)
    return PRESETS[name]

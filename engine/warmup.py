"""Load (or compile) every compiled kernel before the first real request.

numba compiles a kernel on its first call and keeps the machine code in its on-disk cache
(``NUMBA_CACHE_DIR``, or ``__pycache__`` beside the kernels); a process that starts with a warm
cache loads the kernels in about a second, a cold one compiles them (tens of seconds). The API
and the workers call :func:`warm_up` at start-up so that no user request pays for it.
"""

from __future__ import annotations

import math
import time

import numpy as np

from engine.inverses import make_inverse, method_names
from engine.jacobian import generalized_jacobian
from engine.kinematics import State, forward_kinematics
from engine.model import table1_robot
from engine.planner import plan, plan_batch
from engine.replay import replay
from engine.spatial import exp_so3, log_so3, matrix_to_quaternion, quaternion_to_matrix, rotation_angle
from engine.trajectory import CartesianTask


def warm_up() -> float:
    """Run every kernel once on a two-step task of the Table-1 robot (every inverse method,
    plans with and without traces, the replay, the GJM and the SO(3) helpers). Returns the
    seconds it took."""
    start = time.perf_counter()
    robot = table1_robot()
    q0 = np.radians([175.0, -60.0, -60.0, 0.0, 210.0, 5.0])
    fk = forward_kinematics(robot, State(q0))
    task = CartesianTask.from_q0(
        robot,
        q0,
        fk.ee_position + 0.001,
        fk.ee_attitude,
        duration=0.5,
        ramp_time=0.1,
        dt=0.25,
        joint_speed_limit=math.radians(6.0),
    )
    for name in method_names():
        result = plan(robot, task, make_inverse(name), feedback_gain=0.5)
        make_inverse(name).solve(generalized_jacobian(robot, State(q0)).J_g, np.ones(6))
    replay(robot, result)
    plan_batch(robot, task, "adaptive", {"lambda_max": [0.05, 0.06], "epsilon": [0.06, 0.07]}, threads=2)
    R = exp_so3(np.array([0.1, 0.2, 0.3]))
    log_so3(R)
    rotation_angle(R)
    quaternion_to_matrix(matrix_to_quaternion(R))
    return time.perf_counter() - start

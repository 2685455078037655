"""Numerical core: free-floating space robot kinematics, the generalized Jacobian,
singularity-robust inverses, path types, the Cartesian planner, the shortest feasible duration,
replay, GA tuning and objective landscapes.

numpy and scipy, numba for the compiled kernels (:mod:`engine.kernels`), DEAP for the GA; no web
or database code. SI units and radians throughout.
"""

from engine.inverses import METHODS, Inverse, InverseStep, Method, Param, make_inverse, method_names
from engine.jacobian import GJMResult, generalized_jacobian
from engine.kinematics import ForwardKinematics, State, forward_kinematics
from engine.landscape import Landscape, axis_values, landscape
from engine.metrics import Metrics, Objective
from engine.model import RobotModel, table1_robot, urdf_robot
from engine.paths import PATH_TYPES, ArcPath, LinePath, Path, RasterPath, WaypointPath, make_path
from engine.planner import BatchResult, PlanOptions, PlanResult, PlanSetup, plan, plan_batch, run_plan
from engine.redundancy import JointCentering, MinBaseRotation, make_secondary
from engine.replay import ReplayResult, replay
from engine.robustness import Robustness, robustness
from engine.shortest import DurationSearch, shortest_duration
from engine.trajectory import CartesianTask, paper_task
from engine.tuning import Comparison, TuneProgress, TuneResult, compare, tune
from engine.uncertainty import Uncertainty
from engine.warmup import warm_up

__all__ = [
    "METHODS",
    "PATH_TYPES",
    "ArcPath",
    "BatchResult",
    "CartesianTask",
    "Comparison",
    "DurationSearch",
    "ForwardKinematics",
    "GJMResult",
    "Inverse",
    "InverseStep",
    "JointCentering",
    "Landscape",
    "LinePath",
    "Method",
    "Metrics",
    "MinBaseRotation",
    "Objective",
    "Param",
    "Path",
    "PlanOptions",
    "PlanResult",
    "PlanSetup",
    "RasterPath",
    "ReplayResult",
    "RobotModel",
    "Robustness",
    "State",
    "TuneProgress",
    "TuneResult",
    "Uncertainty",
    "WaypointPath",
    "axis_values",
    "compare",
    "forward_kinematics",
    "generalized_jacobian",
    "landscape",
    "make_inverse",
    "make_path",
    "make_secondary",
    "method_names",
    "paper_task",
    "plan",
    "plan_batch",
    "replay",
    "robustness",
    "run_plan",
    "shortest_duration",
    "table1_robot",
    "tune",
    "urdf_robot",
    "warm_up",
]

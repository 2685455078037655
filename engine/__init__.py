"""Numerical core: free-floating space robot kinematics, the generalized Jacobian,
singularity-robust inverses, path types, the Cartesian planner, the shortest feasible duration,
replay, GA tuning and objective landscapes.

numpy and scipy, numba for the compiled kernels (:mod:`engine.kernels`), DEAP for the GA; no web
or database code. SI units and radians throughout.
"""

from engine.inverses import (
    METHODS,
    AdaptiveDamping,
    DampedLeastSquares,
    InverseStep,
    PlainInverse,
    RobustInverse,
    SelectivelyDampedLS,
    SingularValueFiltering,
    WeightedDLS,
    make_inverse,
    method_names,
)
from engine.jacobian import GJMResult, generalized_jacobian
from engine.kinematics import ForwardKinematics, State, forward_kinematics
from engine.landscape import Landscape, axis_values, landscape
from engine.metrics import BatchMetrics, Metrics
from engine.model import RobotModel, table1_robot, urdf_robot
from engine.paths import PATH_TYPES, ArcPath, LinePath, Path, RasterPath, WaypointPath, make_path
from engine.planner import BatchResult, PlanResult, plan, plan_batch
from engine.redundancy import JointCentering, MinBaseRotation, make_secondary
from engine.replay import ReplayResult, replay
from engine.shortest import DurationSearch, shortest_duration
from engine.trajectory import CartesianTask, paper_task
from engine.tuning import Comparison, TuneProgress, TuneResult, compare, tune
from engine.warmup import warm_up

__all__ = [
    "METHODS",
    "PATH_TYPES",
    "AdaptiveDamping",
    "ArcPath",
    "BatchMetrics",
    "BatchResult",
    "CartesianTask",
    "Comparison",
    "DampedLeastSquares",
    "DurationSearch",
    "ForwardKinematics",
    "GJMResult",
    "InverseStep",
    "JointCentering",
    "Landscape",
    "LinePath",
    "Metrics",
    "MinBaseRotation",
    "Path",
    "PlainInverse",
    "PlanResult",
    "RasterPath",
    "ReplayResult",
    "RobotModel",
    "RobustInverse",
    "SelectivelyDampedLS",
    "SingularValueFiltering",
    "State",
    "TuneProgress",
    "TuneResult",
    "WaypointPath",
    "WeightedDLS",
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
    "shortest_duration",
    "table1_robot",
    "tune",
    "urdf_robot",
    "warm_up",
]

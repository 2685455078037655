"""Numerical core: free-floating space robot kinematics, the generalized Jacobian,
singularity-robust inverses, the Cartesian planner, replay and GA tuning.

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
from engine.metrics import BatchMetrics, Metrics
from engine.model import RobotModel, table1_robot, urdf_robot
from engine.planner import BatchResult, PlanResult, plan, plan_batch
from engine.redundancy import JointCentering, MinBaseRotation, make_secondary
from engine.replay import ReplayResult, replay
from engine.trajectory import CartesianTask, paper_task
from engine.tuning import Comparison, TuneProgress, TuneResult, compare, tune
from engine.warmup import warm_up

__all__ = [
    "METHODS",
    "AdaptiveDamping",
    "BatchMetrics",
    "BatchResult",
    "CartesianTask",
    "Comparison",
    "DampedLeastSquares",
    "ForwardKinematics",
    "GJMResult",
    "InverseStep",
    "JointCentering",
    "Metrics",
    "MinBaseRotation",
    "PlainInverse",
    "PlanResult",
    "ReplayResult",
    "RobotModel",
    "RobustInverse",
    "SelectivelyDampedLS",
    "SingularValueFiltering",
    "State",
    "TuneProgress",
    "TuneResult",
    "WeightedDLS",
    "compare",
    "forward_kinematics",
    "generalized_jacobian",
    "make_inverse",
    "make_secondary",
    "method_names",
    "paper_task",
    "plan",
    "plan_batch",
    "replay",
    "table1_robot",
    "tune",
    "urdf_robot",
    "warm_up",
]

"""Singularity-robust inverses of the GJM: one protocol, small frozen strategies.

Every strategy maps a Jacobian ``J (..., p, n)`` and a task velocity ``xdot (..., p)`` to joint
rates ``qd (..., n)``: ``p = 6`` rows for a twist ``[v; w]``, ``p = 3`` for a linear velocity (a
task that tracks the position only). Parameters may be scalars or arrays of shape ``(B,)`` matching a leading
batch axis, so one strategy object evaluates a whole GA population at once.

The strategies are descriptions (a method number and its parameters); the mathematics lives
once, in the compiled kernels of :mod:`engine.kernels.inverse` (the filters of the singular
values, ``qd = sum_i f(sigma_i) v_i u_i^T xdot``) and :mod:`engine.kernels.svd` (the thin SVD),
which the planner runs too. Each reports an *effective damping* per singular direction,
``lambda_i = sqrt(sigma_i / f_i - sigma_i^2)``: the constant-damping value that would give the
same gain (0 means undamped; for DLS it is the damping itself).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar, NamedTuple, Protocol

import numpy as np
from numpy.typing import ArrayLike

from engine.errors import ParameterError
from engine.kernels import inverse as inverse_kernels
from engine.kernels import svd as svd_kernels
from engine.spatial import FloatArray


class SVD(NamedTuple):
    """Thin SVD ``J = U diag(s) Vt``: ``U (..., p, m)``, ``s (..., m)`` descending, ``Vt (..., m, n)``."""

    U: FloatArray
    s: FloatArray
    Vt: FloatArray


def _jacobians(J: ArrayLike) -> tuple[FloatArray, tuple[int, ...]]:
    arr = np.asarray(J, dtype=float)
    if arr.ndim < 2 or arr.shape[-2] not in (3, 6) or not 1 <= arr.shape[-1] <= 12:
        raise ValueError(f"expected Jacobians of shape (..., 6, n) or (..., 3, n) with 1 <= n <= 12, got {arr.shape}")
    lead = arr.shape[:-2]
    flat: FloatArray = np.require(arr.reshape((-1,) + arr.shape[-2:]), np.float64, ["C", "W"])
    return flat, lead


def thin_svd(J: ArrayLike) -> SVD:
    """Thin SVD of ``J (..., p, n)`` (p = 6 or 3, n = 1..12, ``m = min(p, n)``) by the compiled
    one-sided Jacobi kernel, each member cold-started; see :mod:`engine.kernels.svd`."""
    flat, lead = _jacobians(J)
    batch, p, n = flat.shape
    m = min(p, n)
    U, s, V = np.empty((batch, p, m)), np.empty((batch, m)), np.empty((batch, n, m))
    svd_kernels.svd_many(flat, U, s, V)
    return SVD(U.reshape(lead + (p, m)), s.reshape(lead + (m,)), np.swapaxes(V, -1, -2).reshape(lead + (m, n)))


class InverseStep(NamedTuple):
    """Result of one inverse: ``qd (..., n)`` rad/s and effective ``damping (..., m)``."""

    qd: FloatArray
    damping: FloatArray


class RobustInverse(Protocol):
    """A strategy mapping an end-effector twist to joint rates."""

    name: ClassVar[str]
    method_id: ClassVar[int]

    def solve(self, J: FloatArray, xdot: FloatArray) -> InverseStep:
        """Joint rates for ``J (..., p, n)``, ``xdot (..., p)``."""
        ...

    def params(self) -> dict[str, Any]:
        """Public parameter names (as accepted by :func:`make_inverse`) and values."""
        ...

    def kernel_params(self) -> tuple[FloatArray | float, ...]:
        """Parameter values in the kernel's order (scalars or ``(B,)`` arrays)."""
        ...


def kernel_param_rows(inverse: RobustInverse, batch: int) -> FloatArray:
    """The strategy's parameters as the kernel's ``(batch, MAX_PARAMS)`` rows."""
    rows = np.zeros((batch, inverse_kernels.MAX_PARAMS))
    for i, value in enumerate(inverse.kernel_params()):
        rows[:, i] = value if isinstance(value, float) else np.broadcast_to(np.asarray(value, dtype=float), (batch,))
    return rows


def solve(inverse: RobustInverse, J: ArrayLike, xdot: ArrayLike) -> InverseStep:
    """``inverse`` applied to ``J (..., p, n)`` and ``xdot (..., p)`` (leading axes broadcast;
    array parameters run along the flattened leading axes)."""
    J_arr = np.asarray(J, dtype=float)
    x_arr = np.asarray(xdot, dtype=float)
    lead = np.broadcast_shapes(J_arr.shape[:-2], x_arr.shape[:-1])
    flat, _ = _jacobians(np.broadcast_to(J_arr, lead + J_arr.shape[-2:]))
    batch, p, n = flat.shape
    x_flat = np.require(np.broadcast_to(x_arr, lead + (p,)).reshape(-1, p), np.float64, ["C", "W"])
    m = min(p, n)
    qd, damping, s = np.empty((batch, n)), np.empty((batch, m)), np.empty((batch, m))
    inverse_kernels.solve_many(inverse.method_id, kernel_param_rows(inverse, batch), flat, x_flat, qd, damping, s)
    return InverseStep(qd.reshape(lead + (n,)), damping.reshape(lead + (m,)))


@dataclass(frozen=True)
class PlainInverse:
    """Undamped inverse (paper eq. 3): ``qd = J^-1 xdot`` for a square GJM, the Moore-Penrose
    pseudo-inverse otherwise, both from the SVD (singular values below ``rcond sigma_1`` are
    dropped). Joint rates are unbounded near singularities."""

    name: ClassVar[str] = "inverse"
    method_id: ClassVar[int] = inverse_kernels.PLAIN
    rcond: float = 1e-12

    def solve(self, J: FloatArray, xdot: FloatArray) -> InverseStep:
        return solve(self, J, xdot)

    def params(self) -> dict[str, Any]:
        return {}

    def kernel_params(self) -> tuple[FloatArray | float, ...]:
        return (self.rcond,)


@dataclass(frozen=True)
class DampedLeastSquares:
    """Constant-damping least squares (Wampler 1986; Nakamura and Hanafusa 1986), paper eq. 6:
    ``qd = J^T (J J^T + lambda^2 I)^-1 xdot = sum_i sigma_i / (sigma_i^2 + lambda^2) v_i u_i^T xdot``
    (eq. 10). ``lam`` in the units of the singular values."""

    name: ClassVar[str] = "dls"
    method_id: ClassVar[int] = inverse_kernels.DLS
    lam: FloatArray | float = 0.05

    def solve(self, J: FloatArray, xdot: FloatArray) -> InverseStep:
        return solve(self, J, xdot)

    def params(self) -> dict[str, Any]:
        return {"lambda": self.lam}

    def kernel_params(self) -> tuple[FloatArray | float, ...]:
        return (self.lam,)


@dataclass(frozen=True)
class AdaptiveDamping:
    """The paper's adaptive damping (eq. 16), a separate damping per singular value:
    ``lambda_i = lambda_max (1 + cos(pi sigma_i / epsilon)) / 2`` if ``sigma_i < epsilon``,
    else 0; then ``qd = sum_i sigma_i / (sigma_i^2 + lambda_i^2) v_i u_i^T xdot``.
    Continuous at ``sigma_i = epsilon``; equal to the plain inverse when all
    ``sigma_i >= epsilon``."""

    name: ClassVar[str] = "adaptive"
    method_id: ClassVar[int] = inverse_kernels.ADAPTIVE
    lam_max: FloatArray | float = 0.0571
    epsilon: FloatArray | float = 0.0677

    def solve(self, J: FloatArray, xdot: FloatArray) -> InverseStep:
        return solve(self, J, xdot)

    def params(self) -> dict[str, Any]:
        return {"lambda_max": self.lam_max, "epsilon": self.epsilon}

    def kernel_params(self) -> tuple[FloatArray | float, ...]:
        return (self.lam_max, self.epsilon)


@dataclass(frozen=True)
class WeightedDLS:
    """Variable damping driven by the smallest singular value, applied to all directions
    (Maciejewski and Klein 1988; Chiaverini, Siciliano and Egeland 1994; as in Orocos KDL's
    ``ChainIkSolverVel_wdls``): ``lambda = lambda_max sqrt(1 - (sigma_min / epsilon)^2)`` if
    ``sigma_min < epsilon``, else 0."""

    name: ClassVar[str] = "wdls"
    method_id: ClassVar[int] = inverse_kernels.WDLS
    lam_max: FloatArray | float = 0.05
    epsilon: FloatArray | float = 0.1

    def solve(self, J: FloatArray, xdot: FloatArray) -> InverseStep:
        return solve(self, J, xdot)

    def params(self) -> dict[str, Any]:
        return {"lambda_max": self.lam_max, "epsilon": self.epsilon}

    def kernel_params(self) -> tuple[FloatArray | float, ...]:
        return (self.lam_max, self.epsilon)


@dataclass(frozen=True)
class SelectivelyDampedLS:
    """Selectively damped least squares (Buss and Kim 2005, J. Graphics Tools 10(3)), at the
    velocity level. The twist is split into its linear and angular 3-blocks (the "end
    effectors" of the original). Per singular direction i:
    ``N_i = sum_l ||u_{l,i}||``, ``M_i = sigma_i^-1 sum_j |v_{j,i}| sum_l ||J_{l,j}||``,
    ``gamma_i = min(1, N_i / M_i) gamma_max``,
    ``phi_i = ClampMaxAbs(sigma_i^-1 (u_i^T xdot) v_i, gamma_i)``; finally
    ``qd = ClampMaxAbs(sum_i phi_i, gamma_max)``. ``gamma_max`` in rad/s bounds every joint
    rate."""

    name: ClassVar[str] = "sdls"
    method_id: ClassVar[int] = inverse_kernels.SDLS
    gamma_max: FloatArray | float = 1.0

    def solve(self, J: FloatArray, xdot: FloatArray) -> InverseStep:
        return solve(self, J, xdot)

    def params(self) -> dict[str, Any]:
        return {"gamma_max": self.gamma_max}

    def kernel_params(self) -> tuple[FloatArray | float, ...]:
        return (self.gamma_max,)


@dataclass(frozen=True)
class SingularValueFiltering:
    """Singular value filtering (Colome and Torras 2015, IEEE/ASME Trans. Mechatronics
    20(2)): each singular value is replaced by
    ``sigma_hat = (sigma^3 + nu sigma^2 + 2 sigma + 2 sigma_0) / (sigma^2 + nu sigma + 2)``,
    which is >= ``sigma_0`` and tends to ``sigma`` for large ``sigma``; then
    ``qd = sum_i sigma_hat_i^-1 v_i u_i^T xdot``."""

    name: ClassVar[str] = "svf"
    method_id: ClassVar[int] = inverse_kernels.SVF
    sigma0: FloatArray | float = 0.01
    nu: FloatArray | float = 10.0

    def solve(self, J: FloatArray, xdot: FloatArray) -> InverseStep:
        return solve(self, J, xdot)

    def params(self) -> dict[str, Any]:
        return {"sigma0": self.sigma0, "nu": self.nu}

    def kernel_params(self) -> tuple[FloatArray | float, ...]:
        return (self.sigma0, self.nu)


@dataclass(frozen=True)
class ParamSpec:
    """A public parameter of an inverse: valid range and default GA search bounds."""

    name: str  # public name (API, make_inverse keyword)
    field: str  # dataclass field
    default: float
    low: float  # valid range, low inclusive unless low_open
    high: float
    tune_bounds: tuple[float, float]
    low_open: bool = False
    unit: str = ""


@dataclass(frozen=True)
class MethodSpec:
    cls: type
    params: tuple[ParamSpec, ...]
    description: str


# Default GA search bounds (``tune_bounds``), from the Table-1 robot on the paper's path: the
# best constant damping is lambda = 0.035 and B grows steadily above 0.1, so damping searches
# [1e-4, 0.2]. The GJM's smallest singular value runs from 7e-4 (the singular point) to 0.27
# along the path and the next two lie in [0.36, 0.75], so epsilon searches [1e-4, 1.0]: from
# "damp only at the singularity" to "damp the three weakest directions everywhere". Beyond
# about 0.25 the objective is nearly flat in epsilon (eq. 18: 0.00187 at 0.26, 0.00183 at
# 0.75), so tuned values anywhere there are equally good; an upper bound of 0.3 used to put
# the optimum on the bound. A tuning result warns when its optimum sits on a bound.
METHODS: dict[str, MethodSpec] = {
    "inverse": MethodSpec(PlainInverse, (), "plain inverse / pseudo-inverse, no damping (paper eq. 3)"),
    "dls": MethodSpec(
        DampedLeastSquares,
        (ParamSpec("lambda", "lam", 0.05, 0.0, 10.0, (1e-4, 0.2)),),
        "damped least squares with constant damping (paper eq. 6)",
    ),
    "adaptive": MethodSpec(
        AdaptiveDamping,
        (
            ParamSpec("lambda_max", "lam_max", 0.0571, 0.0, 10.0, (1e-4, 0.2)),
            ParamSpec("epsilon", "epsilon", 0.0677, 0.0, 10.0, (1e-4, 1.0), low_open=True),
        ),
        "per-singular-value adaptive damping (paper eq. 16)",
    ),
    "wdls": MethodSpec(
        WeightedDLS,
        (
            ParamSpec("lambda_max", "lam_max", 0.05, 0.0, 10.0, (1e-4, 0.2)),
            ParamSpec("epsilon", "epsilon", 0.1, 0.0, 10.0, (1e-4, 1.0), low_open=True),
        ),
        "damping from the smallest singular value, all directions (KDL wdls)",
    ),
    "sdls": MethodSpec(
        SelectivelyDampedLS,
        (ParamSpec("gamma_max", "gamma_max", 1.0, 0.0, 100.0, (1e-3, 2.0), low_open=True, unit="rad/s"),),
        "selectively damped least squares (Buss and Kim 2005)",
    ),
    "svf": MethodSpec(
        SingularValueFiltering,
        (
            ParamSpec("sigma0", "sigma0", 0.01, 0.0, 10.0, (1e-4, 0.2), low_open=True),
            ParamSpec("nu", "nu", 10.0, 0.0, 1000.0, (0.1, 100.0)),
        ),
        "singular value filtering (Colome and Torras 2015)",
    ),
}


def method_names() -> list[str]:
    return list(METHODS)


def method_spec(name: str) -> MethodSpec:
    try:
        return METHODS[name]
    except KeyError:
        raise ParameterError("method", f"unknown inverse method {name!r}; valid methods: {', '.join(METHODS)}") from None


def check_param(spec: ParamSpec, value: ArrayLike, field: str | None = None) -> FloatArray:
    """Validate a parameter value (scalar or array) against its range; returns it as float array."""
    label = field or spec.name
    arr = np.asarray(value, dtype=float)
    if not np.all(np.isfinite(arr)):
        raise ParameterError(label, "must be finite")
    below = arr <= spec.low if spec.low_open else arr < spec.low
    if np.any(below) or np.any(arr > spec.high):
        bracket = "(" if spec.low_open else "["
        raise ParameterError(label, f"must be in {bracket}{spec.low}, {spec.high}], got {arr.tolist()}")
    return arr


def make_inverse(name: str, **params: Any) -> RobustInverse:
    """Build the strategy ``name`` (one of :data:`METHODS`) from public parameter names.

    Missing parameters take their defaults; unknown names and out-of-range values raise
    ``ValueError``. Values may be scalars or ``(B,)`` arrays for batched evaluation.
    """
    spec = method_spec(name)
    known = {p.name: p for p in spec.params}
    unknown = set(params) - set(known)
    if unknown:
        valid = ", ".join(known) or "none"
        raise ParameterError(min(unknown), f"unknown parameter(s) {', '.join(sorted(unknown))} for {name}; valid: {valid}")
    kwargs: dict[str, Any] = {}
    for pname, p in known.items():
        value = params.get(pname, p.default)
        arr = check_param(p, value, pname)
        kwargs[p.field] = float(arr) if arr.ndim == 0 else arr
    inverse: RobustInverse = spec.cls(**kwargs)
    return inverse


def inverse_params(inverse: RobustInverse) -> dict[str, float]:
    """Scalar public parameters of an unbatched strategy (for reports)."""
    out: dict[str, float] = {}
    for key, value in inverse.params().items():
        arr = np.asarray(value, dtype=float)
        out[key] = float(arr) if arr.ndim == 0 else math.nan
    return out

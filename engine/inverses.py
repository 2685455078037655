"""Singularity-robust inverses of the GJM: methods declared as data, one generic strategy.

Every strategy maps a Jacobian ``J (..., p, n)`` and a task velocity ``xdot (..., p)`` to joint
rates ``qd (..., n)``: ``p = 6`` rows for a twist ``[v; w]``, ``p = 3`` for a linear velocity (a
task that tracks the position only). Parameters may be scalars or arrays of shape ``(B,)``
matching a leading batch axis, so one strategy object evaluates a whole GA population at once.

A method is a row of :data:`REGISTRY` (in the style of mink's ``Task``: a name, the kernel's
filter number, its parameters with defaults, valid ranges, GA search bounds and units); the API's
method names, parameter models and search bounds, the figures' singular-region threshold and the
README's table are all derived from it, so a new method is its kernel filter and its row here.
The mathematics lives once, in the compiled kernels of :mod:`engine.kernels.inverse` (the filters
of the singular values, ``qd = sum_i f(sigma_i) v_i u_i^T xdot``) and :mod:`engine.kernels.svd`
(the thin SVD), which the planner runs too. Each reports an *effective damping* per singular
direction, ``lambda_i = sqrt(sigma_i / f_i - sigma_i^2)``: the constant-damping value that would
give the same gain (0 means undamped; for DLS it is the damping itself).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from engine.errors import ParameterError
from engine.kernels import inverse as kernels
from engine.kernels import svd as svd_kernels
from engine.spatial import FloatArray

#: The unit of damping parameters and singular-value thresholds: that of the GJM's singular values
#: (the GJM maps joint rates in rad/s to [v (m/s); w (rad/s)]).
SINGULAR = "singular-value units"


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


def kernel_param_rows(inverse: Inverse, batch: int) -> FloatArray:
    """The strategy's parameters as the kernel's ``(batch, MAX_PARAMS)`` rows."""
    rows = np.zeros((batch, kernels.MAX_PARAMS))
    for i, value in enumerate(inverse.kernel_params()):
        rows[:, i] = value if isinstance(value, float) else np.broadcast_to(np.asarray(value, dtype=float), (batch,))
    return rows


def solve(inverse: Inverse, J: ArrayLike, xdot: ArrayLike) -> InverseStep:
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
    kernels.solve_many(inverse.method_id, kernel_param_rows(inverse, batch), flat, x_flat, qd, damping, s)
    return InverseStep(qd.reshape(lead + (n,)), damping.reshape(lead + (m,)))


@dataclass(frozen=True)
class Param:
    """A public parameter of an inverse method: its valid range, default, GA search bounds and
    unit (``SINGULAR`` for the units of the GJM's singular values)."""

    name: str  # public name (API field, make_inverse keyword)
    default: float
    low: float  # valid range, low inclusive unless low_open
    high: float
    tune_bounds: tuple[float, float]  # default GA search interval
    meaning: str  # what it is, for a person
    low_open: bool = False
    unit: str = SINGULAR

    def check(self, value: ArrayLike, field: str | None = None) -> FloatArray:
        """``value`` (scalar or array) as a float array within the valid range; else ParameterError."""
        # a request's scalar within range: no numpy reductions (0.05 ms a plan)
        if (
            type(value) is float
            and math.isfinite(value)
            and (value > self.low if self.low_open else value >= self.low)
            and value <= self.high
        ):
            return np.asarray(value)
        label = field or self.name
        arr = np.asarray(value, dtype=float)
        if not np.all(np.isfinite(arr)):
            raise ParameterError(label, "must be finite")
        outside = (arr <= self.low if self.low_open else arr < self.low) | (arr > self.high)
        if np.any(outside):
            bracket = "(" if self.low_open else "["
            bad = arr[outside]
            # the first offending value, not the whole array (a landscape axis has up to 128); as a
            # float, since numpy's own repr reads np.float64(...)
            got = repr(float(bad.flat[0]))
            if bad.size > 1:
                got += f" and {bad.size - 1} more of {arr.size}"
            raise ParameterError(label, f"must be in {bracket}{self.low}, {self.high}], got {got}")
        return arr


@dataclass(frozen=True)
class Method:
    """An inverse method as data: its kernel filter (``kernel_id``, :mod:`engine.kernels.inverse`)
    and its parameters in the kernel's order. Calling it builds the strategy."""

    name: str
    kernel_id: int
    params: tuple[Param, ...]
    description: str  # one line, for lists
    doc: str  # the formula and its source
    threshold: str | None = None  # the parameter that bounds the singular region (figures), if any

    @property
    def tunable(self) -> bool:
        """Whether the GA can tune it (it has parameters)."""
        return bool(self.params)

    def param(self, name: str) -> Param:
        for p in self.params:
            if p.name == name:
                return p
        valid = ", ".join(p.name for p in self.params) or "none"
        raise ParameterError(name, f"unknown parameter {name!r} for {self.name}; valid: {valid}")

    def __call__(self, **values: ArrayLike) -> Inverse:
        """The strategy with ``values`` by public name (scalars or ``(B,)`` arrays); missing ones take
        their defaults; unknown names and values out of range raise ``ParameterError``."""
        unknown = set(values) - {p.name for p in self.params}
        if unknown:
            valid = ", ".join(p.name for p in self.params) or "none"
            raise ParameterError(
                min(unknown), f"unknown parameter(s) {', '.join(sorted(unknown))} for {self.name}; valid: {valid}"
            )
        checked = []
        for p in self.params:
            arr = p.check(values.get(p.name, p.default))
            checked.append(float(arr) if arr.ndim == 0 else arr)
        return Inverse(self, tuple(checked))


@dataclass(frozen=True)
class Inverse:
    """The one strategy: a :class:`Method` and its parameter values (kernel order; scalars, or
    ``(B,)`` arrays for a batch of parameter sets evaluated at once)."""

    method: Method
    values: tuple[FloatArray | float, ...]

    @property
    def name(self) -> str:
        return self.method.name

    @property
    def method_id(self) -> int:
        return self.method.kernel_id

    def solve(self, J: FloatArray, xdot: FloatArray) -> InverseStep:
        """Joint rates for ``J (..., p, n)``, ``xdot (..., p)``."""
        return solve(self, J, xdot)

    def params(self) -> dict[str, FloatArray | float]:
        """Public parameter names and values."""
        return {p.name: v for p, v in zip(self.method.params, self.values, strict=True)}

    def kernel_params(self) -> tuple[FloatArray | float, ...]:
        return self.values

    def scalar_params(self) -> dict[str, float]:
        """The public parameters of an unbatched strategy (nan for an array)."""
        return {k: float(v) if np.ndim(v) == 0 else math.nan for k, v in self.params().items()}


def _lam(default: float) -> Param:
    return Param("lambda", default, 0.0, 10.0, (1e-4, 0.2), "the constant damping lambda")


def _lam_max(default: float) -> Param:
    return Param("lambda_max", default, 0.0, 10.0, (1e-4, 0.2), "the largest damping lambda_max (at a zero singular value)")


def _epsilon(default: float) -> Param:
    return Param("epsilon", default, 0.0, 10.0, (1e-4, 1.0), "the singular value epsilon below which damping starts", True)


# Default GA search bounds (``tune_bounds``), from the Table-1 robot on the paper's path: the
# best constant damping is lambda = 0.035 and B grows steadily above 0.1, so damping searches
# [1e-4, 0.2]. The GJM's smallest singular value runs from 7e-4 (the singular point) to 0.27
# along the path and the next two lie in [0.36, 0.75], so epsilon searches [1e-4, 1.0]: from
# "damp only at the singularity" to "damp the three weakest directions everywhere". Beyond
# about 0.25 the objective is nearly flat in epsilon (eq. 18: 0.00187 at 0.26, 0.00183 at
# 0.75), so tuned values anywhere there are equally good; an upper bound of 0.3 used to put
# the optimum on the bound. A tuning result warns when its optimum sits on a bound.
REGISTRY: tuple[Method, ...] = (
    Method(
        "inverse",
        kernels.PLAIN,
        (),
        "plain inverse / pseudo-inverse, no damping (paper eq. 3)",
        "Undamped inverse (paper eq. 3): ``qd = J^-1 xdot`` for a square GJM, the Moore-Penrose pseudo-inverse "
        "otherwise, both from the SVD (singular values below 1e-12 sigma_1 dropped). Joint rates are unbounded near "
        "singularities.",
    ),
    Method(
        "dls",
        kernels.DLS,
        (_lam(0.05),),
        "damped least squares with constant damping (paper eq. 6)",
        "Constant-damping least squares (Wampler 1986; Nakamura and Hanafusa 1986), paper eq. 6: "
        "``qd = J^T (J J^T + lambda^2 I)^-1 xdot = sum_i sigma_i / (sigma_i^2 + lambda^2) v_i u_i^T xdot`` (eq. 10).",
    ),
    Method(
        "adaptive",
        kernels.ADAPTIVE,
        (_lam_max(0.0571), _epsilon(0.0677)),
        "per-singular-value adaptive damping (paper eq. 16)",
        "The paper's adaptive damping (eq. 16), a separate damping per singular value: ``lambda_i = lambda_max "
        "(1 + cos(pi sigma_i / epsilon)) / 2`` if ``sigma_i < epsilon``, else 0; then ``qd = sum_i sigma_i / "
        "(sigma_i^2 + lambda_i^2) v_i u_i^T xdot``. Continuous at ``sigma_i = epsilon``; the plain inverse when all "
        "``sigma_i >= epsilon``.",
        threshold="epsilon",
    ),
    Method(
        "wdls",
        kernels.WDLS,
        (_lam_max(0.05), _epsilon(0.1)),
        "damping from the smallest singular value, all directions (KDL wdls)",
        "Variable damping driven by the smallest singular value, applied to all directions (Maciejewski and Klein "
        "1988; Chiaverini, Siciliano and Egeland 1994; Orocos KDL's ``ChainIkSolverVel_wdls``): ``lambda = "
        "lambda_max sqrt(1 - (sigma_min / epsilon)^2)`` if ``sigma_min < epsilon``, else 0.",
        threshold="epsilon",
    ),
    Method(
        "sdls",
        kernels.SDLS,
        (Param("gamma_max", 1.0, 0.0, 100.0, (1e-3, 2.0), "the largest joint rate gamma_max", True, "rad/s"),),
        "selectively damped least squares (Buss and Kim 2005)",
        "Selectively damped least squares (Buss and Kim 2005, J. Graphics Tools 10(3)), at the velocity level, the "
        "twist split into its linear and angular 3-blocks: per singular direction ``gamma_i = min(1, N_i / M_i) "
        "gamma_max`` clamps that direction's joint motion, and ``gamma_max`` (rad/s) bounds every joint rate.",
    ),
    Method(
        "svf",
        kernels.SVF,
        (
            Param("sigma0", 0.01, 0.0, 10.0, (1e-4, 0.2), "the smallest filtered singular value sigma_0", True),
            Param("nu", 10.0, 0.0, 1000.0, (0.1, 100.0), "the shape factor nu of the filter", unit=""),
        ),
        "singular value filtering (Colome and Torras 2015)",
        "Singular value filtering (Colome and Torras 2015, IEEE/ASME Trans. Mechatronics 20(2)): each singular value "
        "is replaced by ``sigma_hat = (sigma^3 + nu sigma^2 + 2 sigma + 2 sigma_0) / (sigma^2 + nu sigma + 2)`` "
        "(>= sigma_0, tending to sigma for large sigma); then ``qd = sum_i sigma_hat_i^-1 v_i u_i^T xdot``.",
        threshold="sigma0",
    ),
    Method(
        "bounded",
        kernels.BOUNDED,
        (_lam(0.03),),
        "damped least squares held within the joint speed and position limits by a QP at each step",
        "Bounded damped least squares, the small QP of each step of mink, pink and Drake's differential inverse "
        "kinematics (Drake's ``DoDifferentialInverseKinematics``; mink 0.0.5, 2024) on the free-floating GJM: "
        "``min |J qd - xdot|^2 + lambda^2 |qd|^2`` subject to ``|qd_i| <= v_i`` (the task's speed limits) and "
        "``q_min <= q_k + qd dt <= q_max``, solved exactly by the dual active-set method of Goldfarb and Idnani "
        "(1983) on the GJM's thin SVD (:mod:`engine.kernels.qp`). It equals DLS where no bound is active and meets "
        "the speed and position limits by construction; a secondary objective's null-space motion enters the QP "
        "(``lambda^2 |qd - z|^2``, which is DLS plus ``z`` when nothing binds). Outside the planner (no joint "
        "state) it is DLS.",
    ),
)
METHODS: dict[str, Method] = {m.name: m for m in REGISTRY}


def method_names() -> list[str]:
    return list(METHODS)


def method_spec(name: str) -> Method:
    """The registered method ``name``; an unknown name raises ``ParameterError`` naming ``method``."""
    try:
        return METHODS[name]
    except KeyError:
        raise ParameterError("method", f"unknown inverse method {name!r}; valid methods: {', '.join(METHODS)}") from None


def make_inverse(name: str, **params: Any) -> Inverse:
    """Build the strategy ``name`` (one of :data:`METHODS`) from public parameter names.

    Missing parameters take their defaults; unknown names and out-of-range values raise
    ``ParameterError`` (a ``ValueError``). Values may be scalars or ``(B,)`` arrays for batched
    evaluation.
    """
    return method_spec(name)(**params)


def method_table() -> str:
    """The README's table of the methods (markdown), from the registry."""
    rows = ["| method | parameters (default; GA search bounds) | what it is |", "|---|---|---|"]
    for m in REGISTRY:
        params = "; ".join(
            f"`{p.name}` {p.default:g}{' ' + p.unit if p.unit and p.unit != SINGULAR else ''} "
            f"([{p.tune_bounds[0]:g}, {p.tune_bounds[1]:g}])"
            for p in m.params
        )
        rows.append(f"| `{m.name}` | {params or 'none'} | {m.description} |")
    return "\n".join(rows)

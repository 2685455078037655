"""Robust inverses, their parameters and search bounds, and null-space objectives."""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import (
    ConfigDict,
    Field,
)

from engine.inverses import METHODS, ParamSpec
from engine.redundancy import MAX_CENTERING_GAIN
from service.schemas.common import (
    SINGULAR_VALUE_UNITS,
    Input,
    Magnitude,
    MethodName,
    Output,
    SecondaryObjective,
    _not_required,
    _omitted_when_none,
    _without_default,
)


def _param_specs(name: str) -> list[tuple[str, ParamSpec]]:
    """The methods that have a parameter ``name``, and its spec in each."""
    return [(method, p) for method, spec in METHODS.items() for p in spec.params if p.name == name]


def _method_param(name: str, meaning: str) -> Any:
    """A method parameter: optional, never null (left out when not given), its valid range the
    engine's (one range per name, whichever method uses it), its default per method."""
    specs = _param_specs(name)
    ranges = {(p.low, p.high, p.low_open) for _, p in specs}
    assert len(ranges) == 1, f"{name}: one valid range for every method that uses it"
    low, high, low_open = ranges.pop()
    defaults = ", ".join(f"{p.default:g} ({method})" for method, p in specs)
    return Field(
        default=None,
        alias=name,
        gt=low if low_open else None,
        ge=None if low_open else low,
        le=high,
        exclude_if=_omitted_when_none,
        json_schema_extra=_without_default,
        description=f"{meaning}; default {defaults}",
    )


def _param_bounds(name: str, unit: str) -> Any:
    """The GA's search interval of a method parameter: optional, never null."""
    defaults = ", ".join(f"[{p.tune_bounds[0]:g}, {p.tune_bounds[1]:g}] ({method})" for method, p in _param_specs(name))
    return Field(
        default=None,
        alias=name,
        exclude_if=_omitted_when_none,
        json_schema_extra=_without_default,
        description=f"[lo, hi] of `{name}`, {unit}, lo < hi within its valid range; default {defaults}",
    )


#: Parameter sets by their API names. A name no method has is refused by the document
#: (``additionalProperties: false``) but let through validation here: the engine's check then
#: names the parameters of the method chosen (``valid: lambda_max, epsilon``), which a schema
#: error ("extra inputs are not permitted") could not.
PARAMETER_NAMES_CONFIG = ConfigDict(
    serialize_by_alias=True,
    validate_by_alias=True,
    validate_by_name=False,
    extra="allow",
    json_schema_extra={"additionalProperties": False},
)


class MethodParams(Input):
    """Parameters of the robust inverse; give only those of the method named (each method's
    own: `dls`: `lambda`; `adaptive` and `wdls`: `lambda_max`, `epsilon`; `sdls`: `gamma_max`;
    `svf`: `sigma0`, `nu`; `inverse`: none). Missing ones take the method's defaults; a parameter
    of another method is a 422 naming it. Damping and singular-value thresholds are in the units
    of the GJM's singular values (the GJM maps joint rates in rad/s to [v (m/s); w (rad/s)])."""

    model_config = PARAMETER_NAMES_CONFIG

    lambda_: float = _method_param("lambda", f"dls: the constant damping lambda, {SINGULAR_VALUE_UNITS}")
    lambda_max: float = _method_param(
        "lambda_max", f"adaptive, wdls: the largest damping lambda_max (at a zero singular value), {SINGULAR_VALUE_UNITS}"
    )
    epsilon: float = _method_param(
        "epsilon", f"adaptive, wdls: the singular value epsilon below which damping starts, {SINGULAR_VALUE_UNITS}"
    )
    gamma_max: float = _method_param("gamma_max", "sdls: the largest joint rate gamma_max, rad/s")
    sigma0: float = _method_param("sigma0", f"svf: the smallest filtered singular value sigma_0, {SINGULAR_VALUE_UNITS}")
    nu: float = _method_param("nu", "svf: the shape factor nu of the filter (dimensionless)")

    def given(self) -> dict[str, float]:
        """The parameters given, by their API names."""
        return self.model_dump(exclude_none=True)


Interval = Annotated[list[Magnitude], Field(min_length=2, max_length=2)]


class MethodBounds(Input):
    """Search intervals of the GA, per parameter of the tuned method (the names of
    `MethodParams`); missing parameters take the default bounds, a parameter of another method
    is a 422 naming it."""

    model_config = PARAMETER_NAMES_CONFIG

    lambda_: Interval = _param_bounds("lambda", SINGULAR_VALUE_UNITS)
    lambda_max: Interval = _param_bounds("lambda_max", SINGULAR_VALUE_UNITS)
    epsilon: Interval = _param_bounds("epsilon", SINGULAR_VALUE_UNITS)
    gamma_max: Interval = _param_bounds("gamma_max", "rad/s")
    sigma0: Interval = _param_bounds("sigma0", SINGULAR_VALUE_UNITS)
    nu: Interval = _param_bounds("nu", "dimensionless")

    def given(self) -> dict[str, list[float]]:
        """The intervals given, by their API names."""
        return self.model_dump(exclude_none=True)


_PARAM_NAMES = {p.name for spec in METHODS.values() for p in spec.params}
for _model in (MethodParams, MethodBounds):
    assert {f.alias or name for name, f in _model.model_fields.items()} == _PARAM_NAMES, _model


class MethodIn(Input):
    """A robust inverse of the GJM and its parameters."""

    name: MethodName = Field(
        default="adaptive",
        description="`inverse` (plain, paper eq. 3), `dls` (constant damping, eq. 6), `adaptive` (the paper's "
        "per-singular-value damping, eq. 16), `wdls` (damping from the smallest singular value), `sdls` (selectively "
        "damped, Buss and Kim 2005), `svf` (singular value filtering, Colome and Torras 2015)",
    )
    params: MethodParams = Field(
        default_factory=MethodParams, description="the method's parameters; missing ones take the method's defaults"
    )


class SecondaryOut(Output):
    """The null-space objective a plan used, its gain filled in."""

    objective: SecondaryObjective = Field(description="the objective (see `SecondaryIn`)")
    gain: float = Field(description="min_base_rotation: in [0, 1], dimensionless; joint_centering: 1/s")


class MethodOut(Output):
    """The robust inverse a plan used, with every parameter of the method (defaults filled in),
    and the null-space objective if the plan had one."""

    model_config = ConfigDict(json_schema_extra=_not_required("secondary"))

    name: MethodName = Field(description="the method")
    params: MethodParams = Field(description="the method's parameters, every one of them")
    secondary: SecondaryOut | None = Field(
        default=None, exclude_if=_omitted_when_none, description="the null-space objective (left out when none)"
    )


class SecondaryIn(Input):
    """A secondary objective in the null space of a redundant arm (more joints than the task
    tracks: 7+ for a pose, 4+ for a position)."""

    objective: SecondaryObjective = Field(
        description="`min_base_rotation`: keep the carrier's attitude still (reaction null space); "
        "`joint_centering`: pull the joints towards the middle of their limits"
    )
    gain: float | None = Field(
        default=None,
        ge=0,
        le=MAX_CENTERING_GAIN,
        description="min_base_rotation: in [0, 1], dimensionless (1 = the full minimiser, default 1); joint_centering: 1/s "
        "(default 0.5)",
    )

"""Robust inverses, their parameters and search bounds, and null-space objectives.

Everything about the methods is derived from the engine's registry (:data:`engine.inverses.
REGISTRY`): the method names, the parameter models (one optional field per parameter name, its
valid range and defaults the engine's), the search bounds, and the conversions both ways."""

from __future__ import annotations

import keyword
from collections.abc import Mapping
from typing import TYPE_CHECKING, Annotated, Any

from pydantic import ConfigDict, Field, create_model

from engine.errors import ParameterError
from engine.inverses import METHODS, REGISTRY, SINGULAR, Inverse, Param
from engine.redundancy import MAX_CENTERING_GAIN, SecondaryObjective, make_secondary
from service.schemas.common import (
    SINGULAR_VALUE_UNITS,
    Input,
    Magnitude,
    Output,
    SecondaryObjectiveName,
    _not_required,
    _omitted_when_none,
    _without_default,
    vocabulary,
)

if TYPE_CHECKING:
    MethodName = str
    TunableMethodName = str
else:
    MethodName = vocabulary("MethodName", METHODS)
    TunableMethodName = vocabulary("TunableMethodName", [m.name for m in REGISTRY if m.tunable])


def _unit(p: Param) -> str:
    return SINGULAR_VALUE_UNITS if p.unit == SINGULAR else p.unit or "dimensionless"


def _uses(name: str) -> list[tuple[str, Param]]:
    """The methods that have a parameter ``name``, and the parameter in each."""
    return [(m.name, p) for m in REGISTRY for p in m.params if p.name == name]


#: Every parameter name of every method, in the registry's order.
PARAM_NAMES: tuple[str, ...] = tuple(dict.fromkeys(p.name for m in REGISTRY for p in m.params))


def _attr(name: str) -> str:
    return f"{name}_" if keyword.iskeyword(name) else name


def _param_field(name: str) -> Any:
    """A method parameter: optional, never null (left out when not given), its valid range the
    engine's (one range per name, whichever method uses it), its default per method."""
    uses = _uses(name)
    ranges = {(p.low, p.high, p.low_open) for _, p in uses}
    assert len(ranges) == 1, f"{name}: one valid range for every method that uses it"
    low, high, low_open = ranges.pop()
    p = uses[0][1]
    methods = ", ".join(method for method, _ in uses)
    defaults = ", ".join(f"{q.default:g} ({method})" for method, q in uses)
    return (
        float,
        Field(
            default=None,
            alias=name,
            gt=low if low_open else None,
            ge=None if low_open else low,
            le=high,
            exclude_if=_omitted_when_none,
            json_schema_extra=_without_default,
            description=f"{methods}: {p.meaning}, {_unit(p)}; default {defaults}",
        ),
    )


Interval = Annotated[list[Magnitude], Field(min_length=2, max_length=2)]


def _bounds_field(name: str) -> Any:
    """The GA's search interval of a method parameter: optional, never null."""
    uses = _uses(name)
    defaults = ", ".join(f"[{p.tune_bounds[0]:g}, {p.tune_bounds[1]:g}] ({method})" for method, p in uses)
    return (
        Interval,
        Field(
            default=None,
            alias=name,
            exclude_if=_omitted_when_none,
            json_schema_extra=_without_default,
            description=f"[lo, hi] of `{name}`, {_unit(uses[0][1])}, lo < hi within its valid range; default {defaults}",
        ),
    )


class _ByName(Input):
    """Values by parameter name. A name no method has is refused by the document
    (``additionalProperties: false``) but let through validation here: the engine's check then
    names the parameters of the method chosen (``valid: lambda_max, epsilon``), which a schema
    error ("extra inputs are not permitted") could not."""

    model_config = ConfigDict(
        serialize_by_alias=True,
        validate_by_alias=True,
        validate_by_name=False,
        extra="allow",
        json_schema_extra={"additionalProperties": False},
    )

    def given(self) -> dict[str, Any]:
        """The values given, by their API names."""
        return self.model_dump(exclude_none=True)


def _own_parameters() -> str:
    return "; ".join(f"`{m.name}`: {', '.join(f'`{p.name}`' for p in m.params) or 'none'}" for m in REGISTRY)


if TYPE_CHECKING:
    MethodParams = _ByName
    MethodBounds = _ByName
else:
    MethodParams = create_model(
        "MethodParams",
        __base__=_ByName,
        __doc__="Parameters of the robust inverse; give only those of the method named (each method's own: "
        f"{_own_parameters()}). Missing ones take the method's defaults; a parameter of another method is a 422 "
        "naming it. Damping and singular-value thresholds are in the units of the GJM's singular values (the GJM "
        "maps joint rates in rad/s to [v (m/s); w (rad/s)]).",
        **{_attr(name): _param_field(name) for name in PARAM_NAMES},
    )
    MethodBounds = create_model(
        "MethodBounds",
        __base__=_ByName,
        __doc__="Search intervals of the GA, per parameter of the tuned method (the names of `MethodParams`); "
        "missing parameters take the default bounds, a parameter of another method is a 422 naming it.",
        **{_attr(name): _bounds_field(name) for name in PARAM_NAMES},
    )


def params_out(values: Mapping[str, float]) -> Any:
    """A :data:`MethodParams` of parameter values by name (a tuned or used set)."""
    return MethodParams.model_validate(dict(values))


class MethodIn(Input):
    """A robust inverse of the GJM and its parameters."""

    name: MethodName = Field(
        default="adaptive",
        description=", ".join(f"`{m.name}` ({m.description})" for m in REGISTRY),
    )
    params: MethodParams = Field(
        default_factory=MethodParams, description="the method's parameters; missing ones take the method's defaults"
    )

    def to_engine(self) -> Inverse:
        """The engine's strategy (its parameters checked by the engine: errors name ``params.<name>``)."""
        try:
            return METHODS[self.name](**self.params.given())
        except ParameterError as exc:
            raise exc.within("params") from None


class SecondaryOut(Output):
    """The null-space objective a plan used, its gain filled in."""

    objective: SecondaryObjectiveName = Field(description="the objective (see `SecondaryIn`)")
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

    @classmethod
    def from_engine(cls, inverse: Inverse, secondary: SecondaryObjective | None) -> MethodOut:
        return cls(
            name=inverse.name,
            params=params_out(inverse.scalar_params()),
            secondary=SecondaryOut(objective=secondary.name, gain=secondary.gain) if secondary is not None else None,
        )


class SecondaryIn(Input):
    """A secondary objective in the null space of a redundant arm (more joints than the task
    tracks: 7+ for a pose, 4+ for a position)."""

    objective: SecondaryObjectiveName = Field(
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

    def to_engine(self) -> SecondaryObjective:
        return make_secondary(self.objective, self.gain)

"""Mass-property uncertainty: the request's ``uncertainty`` and a plan's ``robustness``."""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

from pydantic import Field
from typing_extensions import TypeAliasType

from engine.robustness import LoopRobustness, Robustness, Spread
from engine.uncertainty import MAX_COM_OFFSET_M, MAX_SAMPLES, Uncertainty
from service.schemas.common import EngineName, Input, Output

DistributionName = TypeAliasType("DistributionName", Literal["uniform", "normal"])


class UncertaintyIn(Input):
    """How roughly the robot's mass properties and start are known. `uniform`: each factor is
    1 + rel u with u uniform in [-1, 1] (a CoM offset uniform in the ball of radius `link_com_m`,
    a q0 error uniform in [-q0_deg, q0_deg]); `normal`: the values are one standard deviation,
    truncated at 3. Inertia matrices are scaled as a whole. Samples come from a scrambled Halton
    sequence (low discrepancy) seeded by `seed`."""

    carrier_mass_rel: float = Field(default=0.0, ge=0, lt=1, description="relative bound of the carrier's mass")
    carrier_inertia_rel: float = Field(default=0.0, ge=0, lt=1, description="relative bound of the carrier's inertia")
    link_mass_rel: float = Field(default=0.0, ge=0, lt=1, description="relative bound of each link's mass")
    link_inertia_rel: float = Field(default=0.0, ge=0, lt=1, description="relative bound of each link's inertia")
    link_com_m: float = Field(default=0.0, ge=0, le=MAX_COM_OFFSET_M, description="bound of each link's CoM offset, m")
    q0_deg: Annotated[float, EngineName("q0_rad")] = Field(
        default=0.0, ge=0, le=60, description="bound of each revolute joint's start error, deg"
    )
    distribution: DistributionName = Field(default="uniform", description="`uniform` (bounds) or `normal` (standard deviations)")
    samples: int = Field(default=64, ge=1, le=MAX_SAMPLES, description="the count of sampled robots")
    seed: int = Field(default=0, ge=0, le=2**63 - 1, description="the samples' seed")

    def to_engine(self) -> Uncertainty:
        return Uncertainty(
            carrier_mass_rel=self.carrier_mass_rel,
            carrier_inertia_rel=self.carrier_inertia_rel,
            link_mass_rel=self.link_mass_rel,
            link_inertia_rel=self.link_inertia_rel,
            link_com_m=self.link_com_m,
            q0_rad=math.radians(self.q0_deg),
            distribution=self.distribution,
            samples=self.samples,
            seed=self.seed,
        )


def _number(value: float) -> float | None:
    return value if math.isfinite(value) else None


class SpreadOut(Output):
    """A quantity over the samples; null where a sample diverged and the statistic reaches it."""

    mean: float | None = Field(description="mean over the samples (m or deg, as the field holding it says)")
    p50: float | None = Field(description="median (m or deg)")
    p95: float | None = Field(description="95th percentile (m or deg)")
    max: float | None = Field(description="largest (m or deg)")

    @classmethod
    def of(cls, spread: Spread, scale: float = 1.0) -> SpreadOut:
        return cls(**{k: _number(v * scale) for k, v in spread.as_dict().items()})


class SampleOut(Output):
    """One sampled robot: the factors of the carrier's and each link's mass and inertia, each link's CoM offset (link
    frame) and each joint's start error."""

    index: int = Field(description="the sample's index (0-based)")
    carrier_mass_factor: float = Field(description="the carrier's mass over the nominal one (dimensionless)")
    carrier_inertia_factor: float = Field(description="the carrier's inertia over the nominal one (dimensionless)")
    link_mass_factors: list[float] = Field(description="each link's mass over the nominal one (dimensionless)")
    link_inertia_factors: list[float] = Field(description="each link's inertia over the nominal one (dimensionless)")
    link_com_offsets_m: list[list[float]] = Field(description="each link's CoM offset [x, y, z] in its link frame, m")
    q0_offset_deg: list[float] = Field(description="each joint's start error, deg (0 for prismatic joints)")
    position_error_max_m: float | None = Field(description="its largest position error, m (null: diverged)")
    attitude_error_max_deg: float | None = Field(description="its largest attitude error, deg (null: diverged)")


class LoopOut(Output):
    position_error_max_m: SpreadOut = Field(description="each sample's largest end-effector position error, m")
    attitude_error_max_deg: SpreadOut = Field(description="each sample's largest attitude error, deg")
    limit_broken_fraction: float = Field(
        description="the fraction of samples (0 to 1) that break a limit (joint speed, position or torque, clearance) or diverge"
    )
    diverged: int = Field(description="the count of samples whose plan diverged")
    worst_sample: SampleOut = Field(description="the sample with the largest position error")

    @classmethod
    def from_engine(cls, loop: LoopRobustness) -> LoopOut:
        worst: dict[str, Any] = loop.worst.as_dict()
        worst["q0_offset_deg"] = [math.degrees(x) for x in worst.pop("q0_offset_rad")]
        return cls.model_validate(
            {
                "position_error_max_m": SpreadOut.of(loop.position_error_max),
                "attitude_error_max_deg": SpreadOut.of(loop.attitude_error_max, math.degrees(1.0)),
                "limit_broken_fraction": loop.limit_broken_fraction,
                "diverged": loop.diverged,
                "worst_sample": {
                    "index": loop.worst_index,
                    **worst,
                    "position_error_max_m": _number(loop.worst_position_error_max),
                    "attitude_error_max_deg": _number(math.degrees(loop.worst_attitude_error_max)),
                },
            }
        )


class RobustnessOut(Output):
    """The plan under uncertainty: open loop (its joint motion on each sampled robot) and closed loop (the planner on
    each sampled robot with the nominal model in the controller, the pose error measured on the sampled robot)."""

    samples: int = Field(description="the count of sampled robots")
    success: bool = Field(description="no sample breaks a limit in closed loop")
    message: str = Field(description="the verdict, for a person")
    open_loop: LoopOut = Field(description="the plan's joint motion on each sampled robot")
    closed_loop: LoopOut = Field(description="the planner on each sampled robot, the nominal model in the controller")

    @classmethod
    def from_engine(cls, r: Robustness) -> RobustnessOut:
        return cls(
            samples=len(r.samples),
            success=r.success,
            message=r.message,
            open_loop=LoopOut.from_engine(r.open_loop),
            closed_loop=LoopOut.from_engine(r.closed_loop),
        )

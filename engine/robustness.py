"""A plan under mass-property uncertainty: how far its end effector strays on the sampled robots
of :mod:`engine.uncertainty`.

- **Open loop**: the plan's joint motion (its commanded rates, from the sampled start) on each
  sampled robot, whose carrier turns and shifts by that robot's own momentum balance. The same
  compiled step loop and base step as the plan (:func:`engine.kernels.plan.simulate` with given
  rates), so a sample without perturbation reproduces the plan bit for bit.
- **Closed loop**: the planner run on each sampled robot with the nominal model in the
  controller: the GJM of the nominal masses at the measured joints and carrier attitude, the
  pose error measured on the sampled robot and fed back with the plan's ``feedback_gain``.

Each loop gives the spread over the samples of the largest position and attitude errors (mean,
median, 95th percentile, max; a sample that diverged counts as an infinite error), the fraction
of samples that break a limit (eq. 19's ``P_l``: joint speed, position or torque limit,
clearance, divergence), the worst sample (largest position error) and the band of the errors
over time (smallest, median and largest over the samples at each sample time).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from engine.inverses import Inverse
from engine.planner import PlanResult, PlanSetup, evaluate_traced
from engine.spatial import FloatArray
from engine.uncertainty import Sample, Uncertainty, draw, sampled_model

STATISTICS = ("mean", "p50", "p95", "max")


@dataclass(frozen=True)
class Spread:
    """A quantity over the samples (inf when a sample diverged and the statistic reaches it)."""

    mean: float
    p50: float
    p95: float
    max: float

    @classmethod
    def of(cls, values: FloatArray) -> Spread:
        v = np.where(np.isfinite(values), values, np.inf)
        mean = float(np.mean(v)) if np.all(np.isfinite(v)) else math.inf
        p50, p95 = (float(x) for x in np.percentile(v, [50.0, 95.0]))
        return cls(mean, p50, p95, float(np.max(v)))

    def as_dict(self) -> dict[str, float]:
        return {name: getattr(self, name) for name in STATISTICS}


def statistic(values: FloatArray, name: str, *, axis: int = -1) -> FloatArray:
    """``mean``, ``p50``, ``p95`` or ``max`` of ``values`` along ``axis``; inf where any value
    is not finite (a sample that breaks a limit makes the whole statistic infeasible)."""
    v = np.asarray(values, dtype=float)
    bad = ~np.all(np.isfinite(v), axis=axis)
    safe = np.where(np.isfinite(v), v, 0.0)
    if name == "mean":
        out = np.mean(safe, axis=axis)
    elif name == "max":
        out = np.max(safe, axis=axis)
    elif name in ("p50", "p95"):
        out = np.percentile(safe, 50.0 if name == "p50" else 95.0, axis=axis)
    else:
        raise ValueError(f"unknown statistic {name!r}")
    return np.where(bad, np.inf, out)


@dataclass(frozen=True)
class LoopRobustness:
    """One loop's (open or closed) statistics over the samples."""

    position_error_max: Spread  # m, each sample's largest position error
    attitude_error_max: Spread  # rad
    limit_broken_fraction: float  # samples whose plan breaks a limit (or diverges), 0..1
    diverged: int  # samples whose plan diverged
    worst_index: int  # the sample with the largest position error
    worst: Sample
    worst_position_error_max: float  # m (inf: diverged)
    worst_attitude_error_max: float  # rad
    position_error_band: FloatArray  # (N+1, 3) m: smallest, median, largest over the samples
    attitude_error_band: FloatArray  # (N+1, 3) rad


@dataclass(frozen=True)
class Robustness:
    """A plan's robustness: ``open_loop`` and ``closed_loop`` over the same ``samples``.
    ``success``: no sample breaks a limit in closed loop."""

    uncertainty: Uncertainty
    samples: list[Sample]
    open_loop: LoopRobustness
    closed_loop: LoopRobustness
    success: bool
    message: str


def _band(errors: FloatArray) -> FloatArray:
    e = np.where(np.isfinite(errors), errors, np.inf)
    return np.stack([np.min(e, axis=0), np.median(e, axis=0), np.max(e, axis=0)], axis=1)


def _loop(
    setups: list[PlanSetup], inverse: Inverse, samples: list[Sample], given: FloatArray | None, threads: int | None
) -> LoopRobustness:
    raw, position, attitude = evaluate_traced(setups, inverse, given=given, threads=threads)
    metrics = setups[0].metrics(raw)
    finite = np.asarray(metrics.finite, dtype=bool)
    pos_max = np.where(finite, np.asarray(metrics.position_error_max, dtype=float), np.inf)
    att_max = np.where(finite, np.asarray(metrics.attitude_error_max, dtype=float), np.inf)
    broken = ~np.isfinite(np.asarray(metrics.objective_b, dtype=float))
    worst = int(np.argmax(pos_max))  # a diverged sample's inf first
    return LoopRobustness(
        position_error_max=Spread.of(pos_max),
        attitude_error_max=Spread.of(att_max),
        limit_broken_fraction=float(np.mean(broken)),
        diverged=int(np.sum(~finite)),
        worst_index=worst,
        worst=samples[worst],
        worst_position_error_max=float(pos_max[worst]),
        worst_attitude_error_max=float(att_max[worst]),
        position_error_band=_band(position),
        attitude_error_band=_band(attitude),
    )


def sampled_setups(setup: PlanSetup, samples: list[Sample]) -> list[PlanSetup]:
    """The setup run on each sample's robot from its start (the controller keeps the model)."""
    q0 = np.asarray(setup.task.q0, dtype=float)
    return [setup.under(sampled_model(setup.model, s), q0 + s.q0_offset) for s in samples]


def robustness(
    setup: PlanSetup, inverse: Inverse, plan: PlanResult, uncertainty: Uncertainty, *, threads: int | None = None
) -> Robustness:
    """The robustness of ``plan`` (planned with ``inverse`` on ``setup``) under ``uncertainty``:
    ``2 x samples`` plans of the task, spread over ``threads``."""
    samples = draw(uncertainty, setup.model)
    setups = sampled_setups(setup, samples)
    open_loop = _loop(setups, inverse, samples, plan.qd, threads)
    closed_loop = _loop(setups, inverse, samples, None, threads)
    broken = closed_loop.limit_broken_fraction
    if broken == 0.0:
        message = f"no sample of {len(samples)} breaks a limit in closed loop"
    else:
        message = (
            f"{round(broken * len(samples))} of {len(samples)} samples break a limit in closed loop "
            f"(the worst, sample {closed_loop.worst_index}, strays up to {closed_loop.worst_position_error_max:.4g} m)"
        )
    return Robustness(uncertainty, samples, open_loop, closed_loop, broken == 0.0, message)

"""GA tuning jobs: the request, progress, phases and result."""

from __future__ import annotations

import math
from datetime import datetime
from typing import TYPE_CHECKING, Any, Literal

from pydantic import (
    ConfigDict,
    Field,
    ValidationInfo,
    field_validator,
)
from typing_extensions import TypeAliasType

from engine import Objective, PlanOptions, RobotModel
from engine.inverses import REGISTRY
from engine.tuning import (
    MAX_BITS_PER_GENE,
    MAX_GENERATIONS,
    MAX_POPULATION,
    GenerationRecord,
    TuneResult,
    TuningProblem,
    ga,
    improvement_percent,
)
from service.schemas.common import (
    AGGREGATION_DESCRIPTION,
    MAX_MAGNITUDE,
    PAPER_TASK_EXAMPLE,
    SINGULAR_VALUE_UNITS,
    AggregationName,
    AttitudeTerm,
    Input,
    JobStatus,
    Output,
    TaskAggregationName,
    Weights,
    located,
    vocabulary,
)
from service.schemas.methods import MethodBounds, MethodParams, TunableMethodName, params_out
from service.schemas.plans import PlanMetrics, metrics_out
from service.schemas.robots import OneRobot
from service.schemas.tasks import TaskIn
from service.schemas.uncertainty import UncertaintyIn

RobustStatistic = TypeAliasType("RobustStatistic", Literal["mean", "p95", "max"])

# --- tuning jobs --------------------------------------------------------------------------


class GASettings(Input):
    """The paper's binary-coded genetic algorithm (DEAP)."""

    population: int = Field(default=40, ge=2, le=MAX_POPULATION, description="individuals per generation")
    generations: int = Field(default=50, ge=1, le=MAX_GENERATIONS, description="generations after the initial population")
    crossover_probability: float = Field(default=0.8, ge=0, le=1, description="probability that a pair is crossed over")
    mutation_probability: float = Field(default=0.02, ge=0, le=1, description="per-bit flip probability")
    bits_per_gene: int = Field(
        default=16, ge=2, le=MAX_BITS_PER_GENE, description="bits coding each parameter over its search interval"
    )
    elitism: int = Field(default=1, ge=0, description="best individuals kept unchanged; < population")
    seed: int | None = Field(
        default=0,
        ge=0,
        le=2**63 - 1,
        description="null for a random seed: drawn once per job (from its id), so a job given back to the queue runs "
        "the same GA again; the result's `seed` says which",
    )

    def to_engine(self) -> ga.GASettings:
        return ga.GASettings(
            self.population,
            self.generations,
            self.crossover_probability,
            self.mutation_probability,
            self.bits_per_gene,
            self.elitism,
        )

    @field_validator("elitism")
    @classmethod
    def _elitism_below_population(cls, value: int, info: ValidationInfo) -> int:
        population = info.data.get("population")
        if population is not None and value >= population:
            raise ValueError(f"must be smaller than population ({population})")
        return value


class ObjectiveSettings(Input):
    """The objective B the GA minimises (paper eq. 18), per task, then over the tasks."""

    weights: Weights = [0.5, 0.5]  # noqa: RUF012 (a pydantic field: copied per instance)
    aggregation: AggregationName = Field(default="max", description=AGGREGATION_DESCRIPTION)
    attitude_term: AttitudeTerm = "eq18"
    task_aggregation: TaskAggregationName = Field(
        default="mean", description="how the tasks' B combine: `mean` or `max` (the worst task)"
    )

    def to_engine(self) -> Objective:
        return Objective((self.weights[0], self.weights[1]), self.aggregation, self.attitude_term)


class TuningJobRequest(OneRobot):
    model_config = ConfigDict(
        allow_inf_nan=False,
        json_schema_extra={
            "examples": [
                {
                    "robot_id": "table1",
                    "tasks": [PAPER_TASK_EXAMPLE],
                    "method": "adaptive",
                    "bounds": {"lambda_max": [0.0001, 0.2], "epsilon": [0.0001, 1.0]},
                    "ga": {
                        "population": 40,
                        "generations": 50,
                        "crossover_probability": 0.8,
                        "mutation_probability": 0.02,
                        "bits_per_gene": 16,
                        "elitism": 1,
                        "seed": 1,
                    },
                    "objective": {"weights": [0.5, 0.5], "aggregation": "max", "attitude_term": "eq18"},
                    "compare_with_dls": True,
                }
            ]
        },
    )

    tasks: list[TaskIn] = Field(min_length=1, max_length=20, description="the tasks B is evaluated on")
    method: TunableMethodName = Field(default="adaptive", description="the inverse to tune (a method with parameters)")
    bounds: MethodBounds | None = Field(
        default=None, description="search interval [lo, hi] per parameter; missing parameters take the default bounds"
    )
    ga: GASettings = Field(default_factory=GASettings, description="the genetic algorithm's settings")
    objective: ObjectiveSettings = Field(default_factory=ObjectiveSettings, description="the objective B")
    feedback_gain: float = Field(default=0.0, ge=0, le=MAX_MAGNITUDE, description="1/s, pose-error feedback")
    compare_with_dls: bool = Field(default=True, description="also tune constant-damping DLS with the same GA settings")
    compare_with_bounded: bool = Field(
        default=False,
        description="also tune the `bounded` inverse (DLS held within the joint speed and position limits by an exact "
        "QP) with the same GA settings: the comparison's third row (ignored when `method` is `bounded`)",
    )
    refine: bool = Field(
        default=True,
        description="after the GA, refine its best by Nelder-Mead (records with `stage` `refine` in the history); "
        "false: the paper's GA alone",
    )
    uncertainty: UncertaintyIn | None = Field(
        default=None,
        description="robust tuning: B is `robust_statistic` of B over robots sampled within these bounds, each planned "
        "in closed loop with the nominal model in the controller (infinite if any sample breaks a limit); the job also "
        "tunes the method on the nominal robot alone, to report what robust tuning gains on the same samples",
    )
    robust_statistic: RobustStatistic = Field(
        default="mean",
        description="what robust tuning minimises over the samples' B: `mean`, `p95` or `max` (only with `uncertainty`)",
    )

    @field_validator("robust_statistic")
    @classmethod
    def _with_uncertainty(cls, value: str, info: ValidationInfo) -> str:
        # `mean`, the default, also comes back in every stored request; another without samples is a mistake
        if value != "mean" and "uncertainty" in info.data and info.data["uncertainty"] is None:
            raise ValueError(f"{value!r} needs `uncertainty`: robust tuning takes it over the samples of the uncertain robot")
        return value

    def phases(self) -> list[tuple[str, str, dict[str, list[float]] | None]]:
        """The GA runs of the job: ``(method, role, bounds)``, the tuned method then (with
        ``compare_with_dls``) the DLS baseline and (with ``compare_with_bounded``) the bounded
        inverse, each with its default bounds."""
        bounds = self.bounds.given() if self.bounds else None
        phases = [(self.method, "tuned", bounds)]
        if self.compare_with_dls:
            phases.append(("dls", "dls_baseline", None))
        if self.compare_with_bounded and self.method != "bounded":
            phases.append(("bounded", "bounded_baseline", None))
        if self.uncertainty is not None:
            phases.append((self.method, "nominal_tuned", bounds))
        return phases

    def problems(self, model: RobotModel) -> list[TuningProblem]:
        """The engine's problem of each phase (its tasks and bounds checked once: errors name the
        API field)."""
        tasks = []
        for i, task in enumerate(self.tasks):
            with located(task, "body", "tasks", i):
                tasks.append(task.to_engine(model))
        options = PlanOptions(feedback_gain=self.feedback_gain, objective=self.objective.to_engine())
        uncertainty = None
        if self.uncertainty is not None:
            with located(self.uncertainty, "body", "uncertainty"):
                uncertainty = self.uncertainty.to_engine()
        with located(self, "body"):
            return [
                TuningProblem.build(
                    model,
                    tasks,
                    method,
                    bounds=bounds,
                    options=options,
                    task_aggregation=self.objective.task_aggregation,
                    uncertainty=None if role == "nominal_tuned" else uncertainty,
                    robust_statistic=self.robust_statistic,
                )
                for method, role, bounds in self.phases()
            ]


Stage = TypeAliasType("Stage", Literal["ga", "refine"])


class HistoryRecord(Output):
    generation: int = Field(description="the generation (0: the initial population)")
    best: float | None = Field(description="best objective B so far (null while nothing is feasible)")
    mean: float | None = Field(description="mean B of this generation's feasible individuals (null if none)")
    feasible: int = Field(description="feasible individuals in this generation (within the joint speed limit)")
    stage: Stage = Field(
        default="ga",
        description="`ga`: a generation of the GA; `refine`: a record of the Nelder-Mead refinement after it (its plans "
        "since the previous record; `generation` continues the GA's numbering)",
    )


def history_record(record: GenerationRecord) -> dict[str, Any]:
    """A generation of the engine's GA (or a record of its refinement) as the API's history
    record (JSON-ready)."""
    return {
        "generation": record.generation,
        "best": record.best if math.isfinite(record.best) else None,
        "mean": record.mean if math.isfinite(record.mean) else None,
        "feasible": record.feasible,
        "stage": record.phase,
    }


PhaseRole = TypeAliasType("PhaseRole", Literal["tuned", "dls_baseline", "bounded_baseline", "nominal_tuned"])
if TYPE_CHECKING:
    PhaseName = str
else:
    PhaseName = vocabulary("PhaseName", [*(m.name for m in REGISTRY if m.tunable), "done"])


class JobPhase(Output):
    """One GA run of a job: the tuned method, then (with ``compare_with_dls``) the DLS baseline and
    (with ``compare_with_bounded``) the bounded inverse."""

    name: TunableMethodName = Field(description="the method this GA tunes")
    role: PhaseRole = Field(
        description="`tuned` (the job's method), `dls_baseline`, `bounded_baseline`, or `nominal_tuned` (a robust job's "
        "method tuned on the nominal robot alone)"
    )
    generations: int = Field(description="generations of this GA (after the initial population)")
    completed: int = Field(description="generations of this GA finished so far (0 to `generations`)")
    history: list[HistoryRecord] = Field(description="one record per finished generation, from the initial population (0)")


class JobProgress(Output):
    generation: int = Field(default=0, description="generations finished, summed over the phases")
    generations: int = Field(default=0, description="generations of the whole job, summed over the phases")
    evaluations: int = Field(default=0, description="plans run so far (repeated genomes are not planned again)")
    best_objective_b: float | None = Field(default=None, description="best B of the running phase so far")
    best_params: MethodParams | None = Field(default=None, description="parameters of that best B (null before the first)")
    phase: PhaseName | None = Field(
        default=None, description="the running phase's method, `done` once finished; null while queued"
    )
    phases: list[JobPhase] = Field(default_factory=list, description="each GA of the job with its history")


class JobLinks(Output):
    model_config = ConfigDict(populate_by_name=True)

    self_: str = Field(alias="self", description="this job")
    result: str = Field(description="its result (409 until it succeeded; a cancelled job's best so far)")
    events: str = Field(description="its Server-Sent Events (status changes and generations, live)")
    convergence_figure: str = Field(description="its convergence figure (paper Fig. 7), SVG; `?format=png` for PNG")


class TuningJobOut(Output):
    id: str = Field(description="the job's id (32 hex digits)")
    status: JobStatus = Field(description="queued, then running, then succeeded, failed or cancelled")
    robot_id: str | None = Field(description="the stored robot tuned for; null for an inline robot")
    method: TunableMethodName = Field(description="the method being tuned")
    progress: JobProgress = Field(description="how far the GA is")
    attempts: int = Field(description="times a worker claimed the job")
    worker_id: str | None = Field(
        description="the worker that claimed the job last (`host:pid:random`, as in its log and the "
        "`spacearm_worker_heartbeat_age_seconds` metric); null while it was never claimed"
    )
    max_attempts: int = Field(description="claims before the job is failed for good")
    cancel_requested: bool = Field(description="a cancellation was asked for")
    error: str | None = Field(description="why the job failed; null otherwise")
    created_at: datetime = Field(description="when it was submitted (UTC)")
    started_at: datetime | None = Field(description="when a worker last claimed it (UTC); null while queued")
    finished_at: datetime | None = Field(description="when it ended (UTC); null until then")
    links: JobLinks = Field(description="where the job's result, events and figure are")


class TuningJobList(Output):
    items: list[TuningJobOut] = Field(description="this page of jobs, newest first")
    total: int = Field(description="number of jobs (with the status asked for)")


class DLSBaseline(Output):
    lambda_: float | None = Field(
        alias="lambda", serialization_alias="lambda", description=f"the tuned DLS damping, {SINGULAR_VALUE_UNITS}"
    )
    objective_b: float | None = Field(description="B of the tuned DLS")
    warnings: list[str] = Field(default_factory=list, description="e.g. the tuned lambda on a search bound")

    model_config = ConfigDict(populate_by_name=True)


class BoundedBaseline(Output):
    lambda_: float | None = Field(
        alias="lambda",
        serialization_alias="lambda",
        description=f"the tuned damping of the bounded inverse, {SINGULAR_VALUE_UNITS}",
    )
    objective_b: float | None = Field(description="B of the tuned bounded inverse")
    warnings: list[str] = Field(default_factory=list, description="e.g. the tuned lambda on a search bound")

    model_config = ConfigDict(populate_by_name=True)


class RobustPair(Output):
    objective_b: float | None = Field(description="B over the samples (the job's `robust_statistic`); null if infeasible")
    nominal_objective_b: float | None = Field(description="B of the same parameters on the nominal robot")


class NominalTuning(Output):
    best_params: MethodParams = Field(description="the method tuned on the nominal robot alone (same GA settings)")
    objective_b: float | None = Field(description="their B over the samples (as the robust tuning measures it)")
    nominal_objective_b: float | None = Field(description="their B on the nominal robot")


class RobustTuningOut(Output):
    """What robust tuning found, against tuning on the nominal robot, on the same samples."""

    samples: int = Field(description="the count of sampled robots")
    statistic: RobustStatistic = Field(description="what was minimised over the samples' B")
    tuned: RobustPair = Field(description="the robust-tuned parameters (`best_params`)")
    dls_baseline: RobustPair | None = Field(description="the robust-tuned DLS; null without `compare_with_dls`")
    nominal_tuning: NominalTuning | None = Field(
        description="the method tuned on the nominal robot; null if it found nothing feasible"
    )
    improvement_over_nominal_tuning_percent: float | None = Field(
        description="how much lower the robust-tuned B over the samples is than the nominal-tuned parameters' B over the "
        "same samples, percent; null if either is infeasible"
    )


ResultStatus = TypeAliasType("ResultStatus", Literal["succeeded", "cancelled"])


class TuningJobResult(Output):
    """A job's result: the GA's best parameters, complete (`status` `succeeded`) or the best found
    before the job was cancelled (`status` `cancelled`)."""

    status: ResultStatus = Field(
        default="succeeded",
        description="`succeeded`: every generation ran; `cancelled`: the best found before the job was cancelled",
    )
    message: str = Field(default="", description="how far the GA got, for a person")
    best_params: MethodParams = Field(description="the tuned parameters (those of the method)")
    best_objective_b: float | None = Field(description="their B; null if no individual was feasible")
    best_metrics: list[PlanMetrics] = Field(description="metrics of the best parameters, one per task")
    history: list[HistoryRecord] = Field(description="one row per generation of the tuned method")
    evaluations: int = Field(description="plans evaluated")
    elapsed_s: float = Field(description="time the GA took, s")
    dls_baseline: DLSBaseline | None = Field(description="DLS tuned with the same GA settings; null without `compare_with_dls`")
    improvement_over_dls_percent: float | None = Field(
        description="how much lower B is than the tuned DLS's, percent; null without a baseline"
    )
    bounded_baseline: BoundedBaseline | None = Field(
        default=None,
        description="the bounded inverse tuned with the same GA settings (the third row); null without `compare_with_bounded`",
    )
    bounded_improvement_over_dls_percent: float | None = Field(
        default=None,
        description="how much lower the bounded inverse's B is than the tuned DLS's, percent (negative: higher); "
        "null without both baselines",
    )
    warnings: list[str] = Field(
        default_factory=list,
        description="e.g. a tuned parameter on a search bound, where the optimum may lie beyond it: widen that bound",
    )
    ga_objective_b: float | None = Field(
        default=None, description="the GA's own best B, before the refinement (equal to `best_objective_b` without it)"
    )
    robust: RobustTuningOut | None = Field(
        default=None, description="robust tuning's figures (a job with `uncertainty`); null otherwise"
    )
    seed: int | None = Field(
        default=None,
        description="the GA's seed: the request's, or the one drawn for `ga.seed` null (send it to run the same GA "
        "again); null in results stored before it was recorded",
    )

    @classmethod
    def from_engine(
        cls,
        tuned: TuneResult,
        baseline: TuneResult | None,
        evaluations: int,
        elapsed_s: float,
        status: Literal["succeeded", "cancelled"] = "succeeded",
        message: str = "every generation ran",
        bounded: TuneResult | None = None,
        robust: tuple[TuneResult, float] | None = None,
        body: TuningJobRequest | None = None,
    ) -> TuningJobResult:
        """The result of a job's GA runs (the tuned method, and the DLS baseline and the bounded
        inverse if any), complete or (``status`` cancelled) as far as they got."""

        def number(value: float) -> float | None:
            return value if math.isfinite(value) else None

        robust_out = None
        if body is not None and body.uncertainty is not None:
            nominal, nominal_robust_b = robust if robust is not None else (None, math.inf)

            def pair(result: TuneResult) -> dict[str, float | None]:
                return {"objective_b": number(result.best_objective_b), "nominal_objective_b": number(result.nominal_objective_b)}

            robust_out = {
                "samples": body.uncertainty.samples,
                "statistic": body.robust_statistic,
                "tuned": {
                    "objective_b": number(tuned.best_objective_b),
                    "nominal_objective_b": number(tuned.nominal_objective_b),
                },
                "dls_baseline": None
                if baseline is None
                else {
                    "objective_b": number(baseline.best_objective_b),
                    "nominal_objective_b": number(baseline.nominal_objective_b),
                },
                "nominal_tuning": None
                if nominal is None
                else {
                    "best_params": params_out(nominal.best_params),
                    "objective_b": number(nominal_robust_b),
                    "nominal_objective_b": number(nominal.best_objective_b),
                },
                "improvement_over_nominal_tuning_percent": number(improvement_percent(nominal_robust_b, tuned.best_objective_b)),
            }
        return cls.model_validate(
            {
                "status": status,
                "message": message,
                "seed": tuned.seed if isinstance(tuned.seed, int) else None,
                "best_params": params_out(tuned.best_params),
                "best_objective_b": number(tuned.best_objective_b),
                "best_metrics": [metrics_out(m) for m in tuned.best_metrics],
                "history": [history_record(h) for h in tuned.history],
                "evaluations": evaluations,
                "elapsed_s": elapsed_s,
                "dls_baseline": None
                if baseline is None
                else {
                    "lambda": baseline.best_params.get("lambda"),
                    "objective_b": number(baseline.best_objective_b),
                    "warnings": baseline.warnings,
                },
                "improvement_over_dls_percent": None
                if baseline is None
                else number(improvement_percent(baseline.best_objective_b, tuned.best_objective_b)),
                "bounded_baseline": None
                if bounded is None
                else {
                    "lambda": bounded.best_params.get("lambda"),
                    "objective_b": number(bounded.best_objective_b),
                    "warnings": bounded.warnings,
                },
                "bounded_improvement_over_dls_percent": None
                if baseline is None or bounded is None
                else number(improvement_percent(baseline.best_objective_b, bounded.best_objective_b)),
                "warnings": tuned.warnings,
                "ga_objective_b": number(tuned.ga_objective_b),
                "robust": robust_out,
            }
        )

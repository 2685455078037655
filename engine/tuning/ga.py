"""The paper's binary GA (sections 3.2 and 4) with ask/tell, DEAP's operators inside.

Each parameter is a gene of ``bits_per_gene`` bits decoded linearly onto its bounds; roulette
selection, one-point crossover, bit-flip mutation, and a new population every generation that
keeps the best ``elitism`` individuals (so the best objective never gets worse, as in the
paper's Figure 7). :meth:`BinaryGA.ask` gives the parameter sets to evaluate (genomes seen
before are not asked for again: the objective is a deterministic function of the genome);
:meth:`BinaryGA.tell` takes their ``B`` and closes the generation.

Fitness. Roulette selection needs a positive fitness to maximise while the objective ``B``
(eqs. 17-19) is minimised and is +inf for an infeasible individual. We use ``fitness = 1 / B``
(``B`` floored at 1e-12) and give infeasible individuals the fitness ``1e-9``, so they are almost
never selected but roulette still works when every individual is infeasible. ``1 / (1 + B)``
would be nearly constant for ``B`` of a few millimetres, leaving roulette no selection pressure.

Randomness. DEAP's operators (``tools.selRoulette``, ``tools.cxOnePoint``, ``tools.mutFlipBit``)
draw from Python's global ``random`` module. Each generation draws a seed from the run's
``numpy.random.Generator`` and runs the operators under a lock with the global state seeded from
it, then restores the global state: same seed, same result, and runs in other threads do not
disturb each other.
"""

from __future__ import annotations

import math
import random
import threading
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np
from deap import base, creator, tools

from engine.errors import ParameterError
from engine.spatial import FloatArray

INFEASIBLE_FITNESS = 1e-9
MAX_POPULATION = 1000
MAX_GENERATIONS = 1000
MAX_BITS_PER_GENE = 52  # a float64 mantissa: more bits cannot be decoded exactly

_RANDOM_LOCK = threading.Lock()

if not hasattr(creator, "SpacearmFitness"):
    creator.create("SpacearmFitness", base.Fitness, weights=(1.0,))
if not hasattr(creator, "SpacearmIndividual"):
    creator.create("SpacearmIndividual", list, fitness=creator.SpacearmFitness)


@contextmanager
def _seeded_global_random(seed: int) -> Iterator[None]:
    """Run DEAP's operators on a global ``random`` state seeded from ``seed``; restore after."""
    with _RANDOM_LOCK:
        saved = random.getstate()
        random.seed(seed)
        try:
            yield
        finally:
            random.setstate(saved)


@dataclass(frozen=True)
class GASettings:
    """The binary GA's settings: individuals per generation, generations after the initial
    population, the chance a pair is crossed, the per-bit flip probability (DEAP's ``indpb``,
    applied to every offspring), bits per parameter, elites kept unchanged."""

    population: int = 40
    generations: int = 50
    crossover_probability: float = 0.8
    mutation_probability: float = 0.02
    bits_per_gene: int = 16
    elitism: int = 1

    def __post_init__(self) -> None:
        if not 2 <= self.population <= MAX_POPULATION:
            raise ParameterError("population", f"must be in [2, {MAX_POPULATION}]")
        if not 1 <= self.generations <= MAX_GENERATIONS:
            raise ParameterError("generations", f"must be in [1, {MAX_GENERATIONS}]")
        if not 0.0 <= self.crossover_probability <= 1.0:
            raise ParameterError("crossover_probability", "must be in [0, 1]")
        if not 0.0 <= self.mutation_probability <= 1.0:
            raise ParameterError("mutation_probability", "must be in [0, 1]")
        if not 2 <= self.bits_per_gene <= MAX_BITS_PER_GENE:
            raise ParameterError("bits_per_gene", f"must be in [2, {MAX_BITS_PER_GENE}]")
        if not 0 <= self.elitism < self.population:
            raise ParameterError("elitism", "must be in [0, population - 1]")


@dataclass(frozen=True)
class GenerationRecord:
    generation: int  # 0: the initial population
    best: float  # best B so far (inf while nothing is feasible)
    mean: float  # mean B of the feasible individuals of this generation (inf if none)
    feasible: int
    best_params: dict[str, float]
    phase: str = "ga"  # "ga", or "refine" for a round of the refinement after it


def decode(bits: np.ndarray, bounds: Mapping[str, tuple[float, float]], bits_per_gene: int) -> dict[str, FloatArray]:
    """Decode genomes ``bits (B, G * bits_per_gene)`` (0/1) to parameter arrays ``(B,)``:
    gene g's bits, most significant first, give an integer mapped linearly onto its bounds."""
    weights = 2.0 ** np.arange(bits_per_gene - 1, -1, -1)
    top = 2.0**bits_per_gene - 1.0
    out = {}
    for g, (name, (lo, hi)) in enumerate(bounds.items()):
        ints = bits[:, g * bits_per_gene : (g + 1) * bits_per_gene] @ weights
        out[name] = lo + (hi - lo) * ints / top
    return out


def _fitness(b: float) -> float:
    return 1.0 / max(b, 1e-12) if math.isfinite(b) else INFEASIBLE_FITNESS


class BinaryGA:
    """The paper's GA over ``bounds`` (``{name: (lo, hi)}``) with ask/tell: ``ask()`` the
    parameter sets of the next generation's new genomes (the initial population first), evaluate
    them, ``tell(B)``. ``seed``: an int, a ``numpy.random.Generator`` or None."""

    def __init__(
        self, bounds: Mapping[str, tuple[float, float]], settings: GASettings, seed: int | np.random.Generator | None = 0
    ) -> None:
        self.bounds = dict(bounds)
        self.settings = settings
        self.rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        self.toolbox = base.Toolbox()
        self.toolbox.register("select", tools.selRoulette)
        self.toolbox.register("mate", tools.cxOnePoint)
        self.toolbox.register("mutate", tools.mutFlipBit, indpb=settings.mutation_probability)
        self.known: dict[tuple[int, ...], float] = {}  # B of every genome seen
        self.generation = -1  # the last generation told (0: the initial population)
        self.planned = 0  # genomes evaluated (each once)
        self.cache_hits = 0  # individuals whose genome had been evaluated before
        self.history: list[GenerationRecord] = []
        self._population: list[Any] = []
        self._best: Any = None
        self._elite: list[Any] = []
        self._offspring: list[Any] = []
        self._fresh: list[tuple[int, ...]] = []

    def ask(self) -> dict[str, FloatArray]:
        """The parameter sets ``{name: (K,)}`` of the next generation's genomes not evaluated
        before (possibly none: ``K = 0``)."""
        s = self.settings
        if self.generation < 0:
            bits = self.rng.integers(0, 2, size=(s.population, s.bits_per_gene * len(self.bounds)))
            self._elite, self._offspring = [], [creator.SpacearmIndividual(row) for row in bits.tolist()]
        else:
            pop = self._population
            self._elite = [self.toolbox.clone(ind) for ind in tools.selBest(pop, s.elitism)] if s.elitism else []
            with _seeded_global_random(int(self.rng.integers(2**63 - 1))):
                offspring = [self.toolbox.clone(ind) for ind in self.toolbox.select(pop, s.population - len(self._elite))]
                for a, b in zip(offspring[::2], offspring[1::2], strict=False):
                    if random.random() < s.crossover_probability:
                        self.toolbox.mate(a, b)
                for ind in offspring:
                    self.toolbox.mutate(ind)
            self._offspring = offspring
        self._fresh = list(dict.fromkeys(tuple(ind) for ind in self._offspring if tuple(ind) not in self.known))
        bits = np.array(self._fresh, dtype=float).reshape(len(self._fresh), s.bits_per_gene * len(self.bounds))
        return decode(bits, self.bounds, s.bits_per_gene)

    def tell(self, objective_b: np.ndarray) -> GenerationRecord:
        """``B (K,)`` of the sets :meth:`ask` gave: the generation is closed and recorded."""
        values = np.asarray(objective_b, dtype=float).reshape(-1)
        if values.shape[0] != len(self._fresh):
            raise ValueError(f"expected {len(self._fresh)} objective values, got {values.shape[0]}")
        self.known.update(zip(self._fresh, (float(b) for b in values), strict=True))
        self.planned += len(self._fresh)
        self.cache_hits += len(self._offspring) - len(self._fresh)
        for ind in self._offspring:
            ind.objective_b = self.known[tuple(ind)]
            ind.fitness.values = (_fitness(ind.objective_b),)
        self._population = self._elite + self._offspring
        generation_best = min(self._population, key=lambda ind: ind.objective_b)
        if self._best is None or generation_best.objective_b < self._best.objective_b:
            self._best = self.toolbox.clone(generation_best)
            self._best.objective_b = generation_best.objective_b
        self.generation += 1
        feasible = [ind.objective_b for ind in self._population if math.isfinite(ind.objective_b)]
        record = GenerationRecord(
            self.generation,
            self.best_objective_b,
            float(np.mean(feasible)) if feasible else math.inf,
            len(feasible),
            self.best_params,
        )
        self.history.append(record)
        return record

    @property
    def best_objective_b(self) -> float:
        return float(self._best.objective_b) if self._best is not None else math.inf

    def evaluated(self) -> tuple[dict[str, FloatArray], FloatArray]:
        """Every parameter set evaluated so far ``{name: (K,)}`` and its ``B (K,)``."""
        width = self.settings.bits_per_gene * len(self.bounds)
        bits = np.array(list(self.known), dtype=float).reshape(len(self.known), width)
        return decode(bits, self.bounds, self.settings.bits_per_gene), np.array(list(self.known.values()), dtype=float)

    @property
    def best_params(self) -> dict[str, float]:
        """The best parameters so far (empty before the first :meth:`tell`)."""
        if self._best is None:
            return {}
        decoded = decode(np.array([self._best], dtype=float), self.bounds, self.settings.bits_per_gene)
        return {k: float(v[0]) for k, v in decoded.items()}

"""The refinement after the GA: bounded Nelder-Mead from the GA's best individuals.

The binary GA finds the basin of ``B`` but not its bottom: the paper task's feasible optimum
lies in a narrow valley along the joint speed limit, where ``B`` jumps to infinity, and a
population of 40 over 2^32 genomes lands near it only by chance. Nelder-Mead needs no
gradient, treats an infeasible point (``B = inf``) as worse than any feasible one, and its
simplex stretches along a valley. Measured on the paper task from the README GA's best
(``B`` 0.001863): Nelder-Mead reaches 0.001807 in 166 plans; DEAP's CMA-ES (12 per
generation) reaches the same with a first step of 5 % of the ranges in 1800 plans and ends at
0.001867 with 20 %; scipy's bounded Powell ends at 0.001867; a shrinking axis-aligned grid
search stalls at 0.001863 (its steps cannot follow the valley's slope of about 1:20).

``B`` has more than one valley: from some GA runs' best (seed 3 of the README job: 0.001867 at
lambda_max 0.0400, epsilon 0.381) every simplex size ends in a local minimum. So the search
starts from up to :data:`STARTS` of the GA's evaluated points: the best, then the best of those
at least :data:`START_SEPARATION` (scaled) from the points already chosen.

The search works in coordinates scaled to the bounds (``[0, 1]`` per parameter), starts from a
simplex of :data:`FIRST_STEP` of each range about a start, and restarts from its result
(a collapsed simplex can stop short on the limit's edge) until a restart gains nothing, at
most :data:`RESTARTS` times.

:func:`nelder_mead` is scipy's bounded Nelder-Mead (``scipy.optimize.minimize``,
``method="Nelder-Mead"``: the same coefficients, order of operations, clipping to the bounds and
stopping rules; the tests compare the two point by point). It is written out here because
importing ``scipy.optimize`` costs every worker process about 37 MiB of memory.

Every :data:`RECORD_EVERY` plans make one history record (``phase`` ``refine``), continuing the
GA's numbering.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from engine.planner import EvaluationStoppedError, Stop
from engine.spatial import FloatArray
from engine.tuning.ga import GenerationRecord

#: The first simplex's edge, as a fraction of each parameter's search range.
FIRST_STEP = 0.05
#: Simplex size (scaled) and ``B`` change at which a search has converged.
X_TOLERANCE = 1e-7
B_TOLERANCE = 1e-12
#: Plans per parameter, at most, per search; restarts after the first, at most.
EVALUATIONS_PER_PARAMETER = 150
RESTARTS = 2
#: Starting points, at most, and their least distance from each other (scaled coordinates).
STARTS = 4
START_SEPARATION = 0.1


def max_evaluations(dimensions: int) -> int:
    """The most plans a refinement of ``dimensions`` parameters runs (per task and sample)."""
    return STARTS * (1 + RESTARTS) * EVALUATIONS_PER_PARAMETER * dimensions


#: Plans per history record.
RECORD_EVERY = 50


@dataclass
class Refinement:
    """The refinement's outcome: its best point, its records and the plans it ran."""

    best_params: dict[str, float]
    best_objective_b: float
    history: list[GenerationRecord] = field(default_factory=list)
    planned: int = 0
    cache_hits: int = 0
    stopped: bool = False


def starting_points(
    bounds: Mapping[str, tuple[float, float]], evaluated: Mapping[str, FloatArray], objective_b: FloatArray
) -> list[int]:
    """Indices of the feasible ``evaluated`` points to start from: the best, then the best of
    those at least :data:`START_SEPARATION` (scaled) from every point chosen, :data:`STARTS` at
    most."""
    names = list(bounds)
    scaled = np.stack([(np.asarray(evaluated[n]) - bounds[n][0]) / (bounds[n][1] - bounds[n][0]) for n in names], axis=1).reshape(
        -1, len(names)
    )
    chosen: list[int] = []
    for i in np.argsort(objective_b, kind="stable"):
        if not math.isfinite(objective_b[i]) or len(chosen) >= STARTS:
            break
        if all(np.max(np.abs(scaled[i] - scaled[j])) >= START_SEPARATION for j in chosen):
            chosen.append(int(i))
    return chosen


def refine(
    bounds: Mapping[str, tuple[float, float]],
    starts: Sequence[tuple[Mapping[str, float], float]],
    first_generation: int,
    evaluate: Callable[[dict[str, FloatArray]], FloatArray],
    *,
    on_record: Callable[[GenerationRecord, int], None] | None = None,
    stop: Stop | None = None,
) -> Refinement:
    """Refine from each of ``starts`` (``(params, B)``, the best first) within ``bounds`` by Nelder-Mead, evaluating
    ``B`` of parameter sets with ``evaluate`` (``{name: (1,)}`` -> ``(1,)``). ``on_record(record,
    planned)`` after each record; ``stop`` ends the search early (the best so far is kept)."""
    names = list(bounds)
    lo = np.array([bounds[n][0] for n in names])
    span = np.array([bounds[n][1] - bounds[n][0] for n in names])
    out = Refinement({n: float(starts[0][0][n]) for n in names}, float(starts[0][1]))
    known: dict[tuple[float, ...], float] = {}
    pending: list[float] = []
    generation = first_generation

    def record() -> None:
        nonlocal generation
        feasible = [b for b in pending if math.isfinite(b)]
        entry = GenerationRecord(
            generation,
            out.best_objective_b,
            float(np.mean(feasible)) if feasible else math.inf,
            len(feasible),
            dict(out.best_params),
            phase="refine",
        )
        out.history.append(entry)
        pending.clear()
        generation += 1
        if on_record is not None:
            on_record(entry, out.planned)

    def objective(u: FloatArray) -> float:
        point = tuple(np.clip(u, 0.0, 1.0).tolist())
        if point in known:
            out.cache_hits += 1
            return known[point]
        if stop is not None and stop.is_set():
            raise EvaluationStoppedError("stopped during the refinement")
        values = lo + np.array(point) * span
        b = float(evaluate({n: values[i : i + 1] for i, n in enumerate(names)})[0])
        known[point] = b
        out.planned += 1
        pending.append(b)
        if b < out.best_objective_b:
            out.best_objective_b = b
            out.best_params = {n: float(values[i]) for i, n in enumerate(names)}
        if len(pending) >= RECORD_EVERY:
            record()
        return b

    def scaled(params: Mapping[str, float]) -> FloatArray:
        return np.clip((np.array([params[n] for n in names]) - lo) / span, 0.0, 1.0)

    for params, b in starts:
        known[tuple(scaled(params).tolist())] = float(b)
    try:
        for params, b in starts:
            search_from(scaled(params), float(b), objective, len(names))
    except EvaluationStoppedError:
        out.stopped = True
    if pending or not out.history:
        record()
    return out


def nelder_mead(
    f: Callable[[FloatArray], float], simplex: FloatArray, *, xatol: float, fatol: float, maxfev: int
) -> tuple[FloatArray, float]:
    """Minimise ``f`` over the unit box from ``simplex (d+1, d)``: scipy's bounded Nelder-Mead
    (reflection 1, expansion 2, contraction 1/2, shrink 1/2; every new point clipped to the box;
    done when the simplex is within ``xatol`` and its values within ``fatol`` of its best, or after
    ``maxfev`` calls of ``f``). Returns the best point and its value."""
    rho, chi, psi, sigma = 1.0, 2.0, 0.5, 0.5
    sim = np.clip(np.array(simplex, dtype=float), 0.0, 1.0)
    d = sim.shape[1]
    calls = 0

    def call(x: FloatArray) -> float:
        nonlocal calls
        if calls >= maxfev:
            raise _ExhaustedError
        calls += 1
        return f(x)

    fsim = np.full(d + 1, np.inf)
    try:
        for k in range(d + 1):
            fsim[k] = call(sim[k])
    except _ExhaustedError:
        pass
    order = np.argsort(fsim)
    sim, fsim = sim[order], fsim[order]
    while calls < maxfev:
        try:
            if np.max(np.abs(sim[1:] - sim[0])) <= xatol and np.max(np.abs(fsim[0] - fsim[1:])) <= fatol:
                break
            xbar = np.add.reduce(sim[:-1], 0) / d
            xr = np.clip((1 + rho) * xbar - rho * sim[-1], 0.0, 1.0)
            fxr = call(xr)
            if fxr < fsim[0]:
                xe = np.clip((1 + rho * chi) * xbar - rho * chi * sim[-1], 0.0, 1.0)
                fxe = call(xe)
                sim[-1], fsim[-1] = (xe, fxe) if fxe < fxr else (xr, fxr)
            elif fxr < fsim[-2]:
                sim[-1], fsim[-1] = xr, fxr
            else:
                shrink = False
                if fxr < fsim[-1]:  # outside contraction
                    xc = np.clip((1 + psi * rho) * xbar - psi * rho * sim[-1], 0.0, 1.0)
                    fxc = call(xc)
                    if fxc <= fxr:
                        sim[-1], fsim[-1] = xc, fxc
                    else:
                        shrink = True
                else:  # inside contraction
                    xcc = np.clip((1 - psi) * xbar + psi * sim[-1], 0.0, 1.0)
                    fxcc = call(xcc)
                    if fxcc < fsim[-1]:
                        sim[-1], fsim[-1] = xcc, fxcc
                    else:
                        shrink = True
                if shrink:
                    for j in range(1, d + 1):
                        sim[j] = np.clip(sim[0] + sigma * (sim[j] - sim[0]), 0.0, 1.0)
                        fsim[j] = call(sim[j])
        except _ExhaustedError:
            pass
        order = np.argsort(fsim)
        sim, fsim = sim[order], fsim[order]
    return sim[0], float(fsim[0])


class _ExhaustedError(Exception):
    """:func:`nelder_mead` ran out of calls."""


def search_from(start: FloatArray, start_b: float, objective: Callable[[FloatArray], float], d: int) -> None:
    """Nelder-Mead from ``start`` (scaled), restarted from its best until a restart gains nothing."""
    best, best_b = start, start_b
    for _ in range(1 + RESTARTS):
        centre = best
        simplex = [centre]
        for i in range(d):
            vertex = centre.copy()
            vertex[i] += FIRST_STEP if centre[i] + FIRST_STEP <= 1.0 else -FIRST_STEP
            simplex.append(vertex)
        x, fx = nelder_mead(
            objective, np.array(simplex), xatol=X_TOLERANCE, fatol=B_TOLERANCE, maxfev=EVALUATIONS_PER_PARAMETER * d
        )
        if not fx < best_b:
            break
        best, best_b = x, fx

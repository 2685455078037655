"""Mass properties known only roughly: an uncertainty model and the sampled robots it gives.

On orbit the carrier's and the links' masses and inertias (fuel burned, payloads, cabling) and
the links' centres of mass are known within bounds, and so is the start configuration. An
:class:`Uncertainty` gives those bounds and how they are spread; :func:`draw` turns it into
``samples`` perturbations from a scrambled Halton sequence (low discrepancy: an even cover of
the bounds with few samples, reproducible from ``seed``), and :func:`sampled_model` builds the
robot of one of them.

The Halton points (:func:`halton`: the radical inverse of the sample index in the first ``d``
primes, each digit position with its own random permutation, as ``scipy.stats.qmc.Halton``
scrambles them) and the normal quantiles (``statistics.NormalDist``) are computed here:
importing ``scipy.stats`` would add about 60 MiB to every API and worker process, ``scipy.special``
13 MiB. The tests compare the points' discrepancy with scipy's.

- ``uniform``: each scalar factor is ``1 + rel u`` with ``u ~ U[-1, 1]``, independently; a CoM
  offset is a vector uniform in the ball of radius ``link_com_m``; a q0 error ``q0 u``.
- ``normal``: ``rel`` (``link_com_m``, ``q0``) is one standard deviation, each scalar (each CoM
  coordinate) a normal truncated at :data:`TRUNCATION` standard deviations.

An inertia matrix is scaled as a whole (it stays physical). Moving a link's CoM by ``delta``
(link frame) moves ``a_i`` by ``delta`` and ``b_i`` by ``-delta``: the joints stay where they
are, and so do the link's collision shapes (their positions, given about the CoM, move by
``-delta``). The q0 error applies to revolute joints.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from statistics import NormalDist
from typing import Any

import numpy as np

from engine.errors import ParameterError
from engine.geometry import Shape
from engine.model import Link, RobotModel
from engine.spatial import FloatArray

DISTRIBUTIONS = ("uniform", "normal")
#: The most samples one request may ask for.
MAX_SAMPLES = 1024
#: A normal perturbation is truncated at this many standard deviations.
TRUNCATION = 3.0
#: The largest CoM offset (m) and q0 error (rad) accepted.
MAX_COM_OFFSET_M = 10.0
MAX_Q0_ERROR_RAD = math.pi

RELATIVE = ("carrier_mass_rel", "carrier_inertia_rel", "link_mass_rel", "link_inertia_rel")


@dataclass(frozen=True)
class Uncertainty:
    """Bounds (``uniform``) or standard deviations (``normal``) of the mass properties and of the
    start: relative for masses and inertias, ``link_com_m`` in m, ``q0_rad`` in rad; ``samples``
    drawn from ``seed``."""

    carrier_mass_rel: float = 0.0
    carrier_inertia_rel: float = 0.0
    link_mass_rel: float = 0.0
    link_inertia_rel: float = 0.0
    link_com_m: float = 0.0
    q0_rad: float = 0.0
    distribution: str = "uniform"
    samples: int = 64
    seed: int = 0

    def __post_init__(self) -> None:
        if self.distribution not in DISTRIBUTIONS:
            raise ParameterError("distribution", f"must be one of {', '.join(DISTRIBUTIONS)}")
        reach = self.reach
        for name in RELATIVE:
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ParameterError(name, f"must be finite and >= 0, got {value}")
            if reach * value >= 1.0:
                what = "mass" if "mass" in name else "inertia"
                raise ParameterError(
                    name,
                    f"{value:g} lets a factor 1 - {reach:g} x {value:g} reach zero or a negative {what}"
                    + (f" (a normal spread is truncated at {TRUNCATION:g} standard deviations)" if reach > 1.0 else "")
                    + f"; it must be below {1.0 / reach:.4g}",
                )
        for name, top in (("link_com_m", MAX_COM_OFFSET_M), ("q0_rad", MAX_Q0_ERROR_RAD)):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0.0 <= value * reach <= top):
                raise ParameterError(name, f"must be >= 0 and reach at most {top:g}, got {value}")
        if not 1 <= self.samples <= MAX_SAMPLES:
            raise ParameterError("samples", f"must be in [1, {MAX_SAMPLES}]")
        if self.seed < 0:
            raise ParameterError("seed", "must be >= 0")

    @property
    def reach(self) -> float:
        """The largest ``|u|`` a perturbation's unit variable takes: 1 (uniform) or the truncation."""
        return 1.0 if self.distribution == "uniform" else TRUNCATION

    @property
    def dimensions(self) -> dict[str, float]:
        """The spread of each perturbed quantity (0: not perturbed)."""
        return {name: float(getattr(self, name)) for name in (*RELATIVE, "link_com_m", "q0_rad")}


@dataclass(frozen=True)
class Sample:
    """One perturbation: factors of the carrier's and each link's mass and inertia, each link's
    CoM offset ``(n, 3)`` m (link frame) and the start's joint error ``(n,)`` rad."""

    carrier_mass_factor: float
    carrier_inertia_factor: float
    link_mass_factors: FloatArray  # (n,)
    link_inertia_factors: FloatArray  # (n,)
    link_com_offsets: FloatArray  # (n, 3) m
    q0_offset: FloatArray  # (n,) rad (0 for prismatic joints)

    def as_dict(self) -> dict[str, Any]:
        return {
            "carrier_mass_factor": self.carrier_mass_factor,
            "carrier_inertia_factor": self.carrier_inertia_factor,
            "link_mass_factors": self.link_mass_factors.tolist(),
            "link_inertia_factors": self.link_inertia_factors.tolist(),
            "link_com_offsets_m": self.link_com_offsets.tolist(),
            "q0_offset_rad": self.q0_offset.tolist(),
        }


def _primes(count: int) -> list[int]:
    primes: list[int] = []
    candidate = 2
    while len(primes) < count:
        if all(candidate % p for p in primes if p * p <= candidate):
            primes.append(candidate)
        candidate += 1
    return primes


def halton(n: int, d: int, rng: np.random.Generator) -> FloatArray:
    """``(n, d)`` points of the scrambled Halton sequence in ``[0, 1)``: coordinate ``j`` of point
    ``i`` is the radical inverse of ``i`` in the ``j``-th prime ``b``, each of its digits (to
    float64 resolution) sent through a random permutation of ``0..b-1`` drawn for that digit
    position (random-permutation scrambling, which keeps the sequence's low discrepancy and
    breaks the correlations of plain Halton between high dimensions)."""
    out = np.zeros((n, d))
    index = np.arange(n)
    for j, base in enumerate(_primes(d)):
        digits = math.ceil(53 * math.log(2.0) / math.log(base))
        rest = index.copy()
        scale = 1.0 / base
        for _ in range(digits):
            permutation = rng.permutation(base)
            out[:, j] += permutation[rest % base] * scale
            rest //= base
            scale /= base
    return np.minimum(out, np.nextafter(1.0, 0.0))


_NORMAL = NormalDist()


def _unit(u: FloatArray, distribution: str) -> FloatArray:
    """Points ``u`` of the unit cube mapped to the perturbations' unit variable: ``U[-1, 1]`` or
    the standard normal truncated at :data:`TRUNCATION` (its quantiles)."""
    if distribution == "uniform":
        return 2.0 * u - 1.0
    lo = _NORMAL.cdf(-TRUNCATION)
    p = lo + u * (1.0 - 2.0 * lo)
    quantiles = np.array([_NORMAL.inv_cdf(float(x)) for x in p.ravel()]).reshape(p.shape)
    return np.clip(quantiles, -TRUNCATION, TRUNCATION)


def draw(uncertainty: Uncertainty, model: RobotModel) -> list[Sample]:
    """``uncertainty.samples`` perturbations of ``model`` (scrambled Halton points from
    ``uncertainty.seed``; the same for the same seed, robot size and sample count)."""
    n = model.n_joints
    width = 2 + 2 * n + 3 * n + n
    points = halton(uncertainty.samples, width, np.random.default_rng(uncertainty.seed))
    z = _unit(points, uncertainty.distribution)
    u = uncertainty
    revolute = ~np.asarray(model.prismatic)
    col = 2 + 2 * n  # the CoM offsets' columns, then the q0 errors'
    out = []
    for row, unit in zip(points, z, strict=True):
        if u.distribution == "uniform":
            # a vector uniform in the ball: radius R u^(1/3), direction uniform on the sphere
            cube = row[col : col + 3 * n].reshape(n, 3)
            radius = u.link_com_m * np.cbrt(cube[:, 0])
            cos_t = 2.0 * cube[:, 1] - 1.0
            sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t * cos_t))
            phi = 2.0 * math.pi * cube[:, 2]
            offsets = radius[:, None] * np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t], axis=1)
        else:
            offsets = u.link_com_m * unit[col : col + 3 * n].reshape(n, 3)
        out.append(
            Sample(
                carrier_mass_factor=1.0 + u.carrier_mass_rel * float(unit[0]),
                carrier_inertia_factor=1.0 + u.carrier_inertia_rel * float(unit[1]),
                link_mass_factors=1.0 + u.link_mass_rel * unit[2 : 2 + n],
                link_inertia_factors=1.0 + u.link_inertia_rel * unit[2 + n : 2 + 2 * n],
                link_com_offsets=offsets,
                q0_offset=np.where(revolute, u.q0_rad * unit[col + 3 * n :], 0.0),
            )
        )
    return out


def _shifted(shape: Shape, delta: FloatArray) -> Shape:
    return replace(shape, position=np.asarray(shape.position, dtype=float) - delta)


def sampled_model(model: RobotModel, sample: Sample) -> RobotModel:
    """The robot of one perturbation (the same joints, axes, limits and shapes)."""
    base = replace(
        model.base, mass=model.base.mass * sample.carrier_mass_factor, inertia=model.base.inertia * sample.carrier_inertia_factor
    )
    links: list[Link] = []
    for i, link in enumerate(model.links):
        delta = sample.link_com_offsets[i]
        links.append(
            replace(
                link,
                mass=link.mass * float(sample.link_mass_factors[i]),
                inertia=link.inertia * float(sample.link_inertia_factors[i]),
                a=link.a + delta,
                b=link.b - delta,
                collision_shapes=tuple(_shifted(s, delta) for s in link.collision_shapes),
            )
        )
    return RobotModel(model.name, base, tuple(links), model.C_e, model.end_effector_name)

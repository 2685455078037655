"""µs per solve of the bounded inverse's QP (engine.kernels.qp.dls_qp) from a given thin SVD, as
the planner's step loop would call it (preallocated buffers, a compiled loop: no Python in the
timing), and through the Python wrapper ``engine.qp.bounded_dls`` (SVD, buffers and dispatch
included). Cases: n = 6 (pose task) with 0, 2 and 6 active joint-rate bounds; n = 7 with 8 general
rows (velocity dampers). Medians of several rounds.

Run: ``flock /tmp/spacearm-cpu.lock .venv/bin/python bench/bench_qp.py``
"""

from __future__ import annotations

import statistics
import sys
import time
from functools import partial
from pathlib import Path

import numpy as np
from numba import njit

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's engine

from engine.kernels import qp as kernels
from engine.kernels import svd as svd_kernels
from engine.qp import bounded_dls

LAM = 0.05
KERNEL_REPS = 20000
WRAPPER_REPS = 2000


@njit(nogil=True)
def _loop(U, s, V, damping, lam, xdot, lo, hi, C, d, buf, reps):
    iterations = 0
    for _ in range(reps):
        _, it = kernels.dls_qp(U, s, V, damping, lam, xdot, lo, hi, C, d, 0, buf)
        iterations += it
    return iterations


def _box_with_active(J, xdot, count):
    """A symmetric box ``|qd_i| <= b`` scaled so that exactly ``count`` bounds are active."""
    n = J.shape[1]
    free = bounded_dls(J, LAM, xdot).qd
    top = np.abs(free).max()
    for factor in np.geomspace(2.0, 1e-3, 4000):
        b = np.full(n, factor * top)
        if len(bounded_dls(J, LAM, xdot, -b, b).active) == count:
            return -b, b
    raise RuntimeError(f"no box with {count} active bounds")


def _cases(rng):
    J = rng.normal(size=(6, 6))
    xdot = rng.normal(size=6)
    for count in (0, 2, 6):
        lo, hi = _box_with_active(J, xdot, count)
        yield f"n=6, {count} active bounds", J, xdot, lo, hi, np.zeros((0, 6)), np.zeros(0)
    J = rng.normal(size=(6, 7))
    xdot = rng.normal(size=6)
    free = bounded_dls(J, LAM, xdot).qd
    C = rng.normal(size=(8, 7))
    d = C @ free - 0.3 * np.abs(C @ free) - 0.05  # every row violated by the unconstrained rates
    top = np.abs(free).max()
    yield "n=7, 8 rows", J, xdot, -2.0 * top * np.ones(7), 2.0 * top * np.ones(7), C, d


def _wrapped(J, xdot, lo, hi, C, d, reps):
    for _ in range(reps):
        bounded_dls(J, LAM, xdot, lo, hi, C, d)


def median_us(fn, reps, rounds=7):
    times = []
    for _ in range(rounds):
        start = time.perf_counter()
        fn()
        times.append((time.perf_counter() - start) / reps * 1e6)
    return statistics.median(times)


def main() -> None:
    rng = np.random.default_rng(18)
    print(f"{'case':28s} {'active':>6s} {'iters':>5s} {'kernel µs':>10s} {'wrapper µs':>11s}")
    for name, J, xdot, lo, hi, C, d in _cases(rng):
        n = J.shape[1]
        sv = svd_kernels.svd_buffers(n, 6)
        svd_kernels.jacobi_svd(J, sv, False)
        _, U, s, V, _, _ = sv
        damping = np.full(s.shape[0], LAM)
        buf = kernels.qp_buffers(n, C.shape[0])
        res = bounded_dls(J, LAM, xdot, lo, hi, C, d)
        _loop(U, s, V, damping, LAM, xdot, lo, hi, C, d, buf, 1)  # compile
        kernel = median_us(partial(_loop, U, s, V, damping, LAM, xdot, lo, hi, C, d, buf, KERNEL_REPS), KERNEL_REPS)
        wrapped = median_us(partial(_wrapped, J, xdot, lo, hi, C, d, WRAPPER_REPS), WRAPPER_REPS, rounds=3)
        print(f"{name:28s} {len(res.active):6d} {res.iterations:5d} {kernel:10.2f} {wrapped:11.1f}")


if __name__ == "__main__":
    main()

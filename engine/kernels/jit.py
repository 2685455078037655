"""The one decorator every compiled function uses, and where numba caches the machine code
(:mod:`engine.kernels.cache`)."""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

import numba
from numba import njit

from engine.kernels.cache import cache_dir, source_hash

__all__ = ["CACHE_DIR", "kernel", "source_hash"]

CACHE_DIR = cache_dir()
numba.config.CACHE_DIR = str(CACHE_DIR)  # type: ignore[attr-defined]  # read by each kernel's cache when decorated
# LLVM at -O1 unless NUMBA_OPT says otherwise: it compiles the kernels in about 15 % less time than
# numba's default -O3 and they run as fast (the paper plan and a batch of 64, measured alike).
# The compiler re-reads NUMBA_* variables before each compilation, so this holds even when numba
# was imported first.
os.environ.setdefault("NUMBA_OPT", "1")


def kernel(fn: Callable[..., Any]) -> Any:
    """``numba.njit`` with the on-disk cache, the GIL released and numpy's error model (a numba
    dispatcher: typed ``Any``, its signature is whatever numba compiles it for)."""
    return njit(cache=True, nogil=True, error_model="numpy")(fn)

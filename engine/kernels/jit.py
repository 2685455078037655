"""The one decorator every compiled function uses, and where numba caches the machine code.

numba keys a cached function by its own source file only, so a kernel whose callee in another
file changed would be loaded stale. The cache therefore lives in a directory named after a
hash of every kernel source (and the numba and Python versions): any change, or an upgrade,
starts a fresh cache. The directory is ``$NUMBA_CACHE_DIR/spacearm-<hash>`` when
``NUMBA_CACHE_DIR`` is set (the Docker image sets it), else ``engine/kernels/__pycache__/
numba-<hash>`` when that is writable, else ``~/.cache/spacearm/numba-<hash>``.
"""

from __future__ import annotations

import hashlib
import os
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numba
from numba import njit

HERE = Path(__file__).resolve().parent


def source_hash() -> str:
    """A short hash of the kernel sources, the numba version and the Python version."""
    digest = hashlib.sha256(f"{numba.__version__} {sys.version_info[:2]}".encode())
    for path in sorted(HERE.glob("*.py")):
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def _writable(directory: Path) -> bool:
    try:
        directory.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=directory):
            pass
    except OSError:
        return False
    return True


def cache_dir() -> Path:
    """The cache directory for this version of the kernels (created here)."""
    tag = source_hash()
    configured = os.environ.get("NUMBA_CACHE_DIR", "").strip()
    if configured:
        return Path(configured) / f"spacearm-{tag}"
    in_tree = HERE / "__pycache__" / f"numba-{tag}"
    if _writable(in_tree):
        return in_tree
    cache_home = Path(os.environ.get("XDG_CACHE_HOME", "") or Path.home() / ".cache")
    return cache_home / "spacearm" / f"numba-{tag}"


CACHE_DIR = cache_dir()
numba.config.CACHE_DIR = str(CACHE_DIR)  # type: ignore[attr-defined]  # read by each kernel's cache when decorated


def kernel(fn: Callable[..., Any]) -> Any:
    """``numba.njit`` with the on-disk cache, the GIL released and numpy's error model (a numba
    dispatcher: typed ``Any``, its signature is whatever numba compiles it for)."""
    return njit(cache=True, nogil=True, error_model="numpy")(fn)

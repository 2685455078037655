"""Where the compiled kernels are cached, and whether the cache is complete for this CPU, in the
standard library alone: ``spacearm run``'s launcher loads this file by its path (without the
``engine`` package, numpy or numba) to know whether the kernels need compiling.

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
import platform
import sys
import tempfile
from importlib.metadata import version
from pathlib import Path

HERE = Path(__file__).resolve().parent


def source_hash() -> str:
    """A short hash of the kernel sources, the numba version and the Python version."""
    digest = hashlib.sha256(f"{version('numba')} {sys.version_info[:2]}".encode())
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
    """The cache directory for this version of the kernels (created here when in the tree)."""
    tag = source_hash()
    configured = os.environ.get("NUMBA_CACHE_DIR", "").strip()
    if configured:
        return Path(configured) / f"spacearm-{tag}"
    in_tree = HERE / "__pycache__" / f"numba-{tag}"
    if _writable(in_tree):
        return in_tree
    cache_home = Path(os.environ.get("XDG_CACHE_HOME", "") or Path.home() / ".cache")
    return cache_home / "spacearm" / f"numba-{tag}"


def cpu_tag() -> str:
    """A short hash of what this machine's compiled code depends on: the CPU model and its
    features (``/proc/cpuinfo`` on Linux), and numba's ``NUMBA_CPU_NAME``/``NUMBA_CPU_FEATURES``
    overrides."""
    described = [platform.machine(), os.environ.get("NUMBA_CPU_NAME", ""), os.environ.get("NUMBA_CPU_FEATURES", "")]
    try:
        with open("/proc/cpuinfo") as cpuinfo:
            for line in cpuinfo:
                key = line.split(":", 1)[0].strip()
                if key in ("model name", "flags", "Features", "CPU part"):
                    described.append(line.strip())
                if not line.strip():
                    break  # the first processor describes them all
    except OSError:
        described.append(platform.processor())
    return hashlib.sha256("\n".join(described).encode()).hexdigest()[:16]


def marker_path(directory: Path) -> Path:
    """The file in ``directory`` (a :func:`cache_dir`) that says every kernel was compiled there
    for this CPU (numba's entries are per CPU: another host compiles its own)."""
    return directory / f"compiled-{cpu_tag()}"


def compiled() -> bool:
    """Whether the cache is complete for this version of the kernels and this CPU."""
    return marker_path(cache_dir()).exists()

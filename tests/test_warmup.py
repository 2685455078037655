"""The kernels' warm-up in parts: the parts compiled in separate processes (``spacearm compile``,
which ``make test`` runs before the suite) leave nothing for a full :func:`engine.warm_up` to
compile, and each kernel is compiled for one signature only (a literal argument would add one)."""

from __future__ import annotations

import gc
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from numba import types

from engine import make_inverse, paper_task, plan
from engine.executed import executed_trajectory
from engine.kernels import spline
from engine.kernels.cache import HERE as KERNELS_DIR
from engine.kernels.cache import marker_path, source_hash
from engine.kernels.jit import CACHE_DIR, KERNELS
from engine.model import table1_robot
from engine.warmup import (
    COMPILE_GC_THRESHOLDS,
    PARTS,
    _command,
    compile_kernels,
    compile_part,
    kernel_name,
    loop_callees,
    signatures_path,
    warm_up,
)

SCRIPT = """
import json
from numba.core import event

compiled = []

class Listener(event.Listener):
    def on_start(self, ev):
        compiled.append(ev.data["dispatcher"].py_func.__qualname__)

    def on_end(self, ev):
        pass

event.register("numba:compile", Listener())
import engine
from engine.kernels import plan, replay, svd
engine.warm_up()
signatures = {k.py_func.__qualname__: len(k.signatures) for k in (plan.simulate, replay.integrate)}
print(json.dumps({"compiled": compiled, "signatures": signatures}))
"""


def test_a_full_warm_up_after_the_parts_compiles_nothing_and_each_kernel_once() -> None:
    warm_up()  # the cache is complete (the suite's conftest warms it up too)
    done = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=600, check=True)
    found = json.loads(done.stdout.strip().splitlines()[-1])
    assert found["compiled"] == [], found
    assert found["signatures"] == {"simulate": 1, "integrate": 1}, found


def test_a_compiling_child_collects_garbage_less_often(monkeypatch: pytest.MonkeyPatch) -> None:
    """A child of ``spacearm compile`` runs :func:`compile_part`: the part's warm-up, recording its
    signatures, with the collector's thresholds raised, and what was there put back after."""
    import engine.warmup

    seen: list[tuple[tuple[str, ...], bool, tuple[int, ...]]] = []

    def fake(parts: list[str], *, record: bool = False) -> float:
        seen.append((tuple(parts), record, gc.get_threshold()))
        return 0.0

    monkeypatch.setattr(engine.warmup, "warm_up", fake)
    before = gc.get_threshold()
    assert before != COMPILE_GC_THRESHOLDS
    compile_part("tools")
    assert seen == [(("tools",), True, COMPILE_GC_THRESHOLDS)]
    assert gc.get_threshold() == before
    assert _command("tools")[-1] == "tools" and "compile_part(sys.argv[2])" in _command("tools")[3]


def test_unknown_parts_are_refused() -> None:
    assert set(PARTS) == {"planner", "tools"}
    with pytest.raises(ValueError, match="unknown kernel part"):
        warm_up(["planner", "gpu"])


def test_a_parked_kernel_links_again_into_a_new_compilation() -> None:
    """After the warm-up the loaded kernels' linking modules are parked as bitcode (about 40 MiB
    of a service process); a compilation that calls one of them parses it again and works."""
    import numba
    import numpy as np

    from engine.kernels import svd

    warm_up()
    library = next(iter(svd.svd_many.overloads.values())).library
    assert library._shared_module is None  # parked

    @numba.njit
    def singular_values(J: np.ndarray) -> np.ndarray:
        U, s, V = np.empty((1, 6, 6)), np.empty((1, 6)), np.empty((1, 6, 6))
        svd.svd_many(J, U, s, V)
        return s

    J = np.random.default_rng(3).normal(size=(1, 6, 6))
    expected = np.linalg.svd(J[0], compute_uv=False)
    np.testing.assert_allclose(singular_values(J)[0], expected, rtol=1e-12)
    assert library._shared_module is not None  # parsed again for the link


RELEASE_SCRIPT = """
import gc, json, re
gc.disable()  # a collection could dispose of an LLVM object, running its code, between two reads
import numba
import numpy as np
from engine import make_inverse, paper_task, plan, table1_robot, warm_up
from engine.kernels.jit import release_library_pages

def llvm_mappings():
    # (start, permissions, Rss KiB, Anonymous KiB) of each mapping of LLVM's library
    found, current = [], None
    for line in open("/proc/self/smaps").read().splitlines():
        head = re.match(r"^([0-9a-f]+)-[0-9a-f]+ (\\S{4}) \\S+ \\S+ \\S+ *(.*)$", line)
        if head:
            current = [head[1], head[2], 0, 0] if "libllvmlite" in head[3] else None
            if current:
                found.append(current)
        elif current and line.startswith(("Rss:", "Anonymous:")):
            current[2 if line.startswith("Rss:") else 3] = int(line.split()[1])
    return found

warm_up()
after_warm_up = llvm_mappings()

@numba.njit
def twice_root(x):
    return 2.0 * np.sqrt(x)

value = twice_root(4.0)  # a compilation: LLVM's code runs again
after_compiling = llvm_mappings()
released = release_library_pages("libllvmlite")
after_release = llvm_mappings()
model = table1_robot()
q_end = plan(model, paper_task(model), make_inverse("adaptive")).q[-1].tolist()
print(json.dumps(dict(after_warm_up=after_warm_up, after_compiling=after_compiling, released=released,
                      after_release=after_release, value=value, q_end=q_end)))
"""


@pytest.mark.skipif(not Path("/proc/self/smaps").exists(), reason="needs Linux's /proc/<pid>/smaps")
def test_llvms_library_pages_are_released_after_the_warm_up_and_come_back_when_needed() -> None:
    """The warm-up ends by unmapping the resident pages of LLVM's library that are the file's own
    (60-100 MiB of RSS on Linux 6.x, which maps the file in large folios): its read-only mappings
    without a copied-on-write page. The relocated ones keep their pages; a later compilation
    faults back what it runs, and the kernels and the compiler give the same results after."""
    run = subprocess.run([sys.executable, "-c", RELEASE_SCRIPT], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    out = json.loads(run.stdout.strip().splitlines()[-1])

    def clean(mappings: list[list]) -> int:
        return sum(rss for _, perms, rss, anonymous in mappings if "w" not in perms and perms.endswith("p") and anonymous == 0)

    assert any(anonymous for *_, anonymous in out["after_warm_up"])  # the relocated part, which must stay
    assert clean(out["after_warm_up"]) == 0
    assert clean(out["after_compiling"]) > 0  # the compilation ran LLVM's code from the file
    assert out["released"] >= clean(out["after_compiling"]) > 0
    assert clean(out["after_release"]) == 0
    kept = {start: rss for start, _, rss, anonymous in out["after_compiling"] if anonymous}
    assert kept and kept == {start: rss for start, _, rss, anonymous in out["after_release"] if anonymous}
    assert out["value"] == 4.0
    model = table1_robot()
    assert out["q_end"] == plan(model, paper_task(model), make_inverse("adaptive")).q[-1].tolist()


UNLINKED_SCRIPT = """
import itertools, json
import numba.core.bytecode
numba.core.bytecode.FunctionIdentity._unique_ids = itertools.count(10**6)  # symbols unlike the cache's
from engine import make_inverse, paper_task, plan, table1_robot
from engine.kernels import plan as plan_kernels, qp, svd
before = [len(k.overloads) for k in (svd.jacobi_svd, qp.dls_qp)]
model = table1_robot()
q_end = plan(model, paper_task(model), make_inverse("adaptive")).q[-1].tolist()
print(json.dumps(dict(before=before, svd_compiled=sum(svd.jacobi_svd.stats.cache_misses.values()),
                      loop_loaded=sum(plan_kernels.simulate.stats.cache_hits.values()), q_end=q_end)))
"""


def test_the_loop_loaded_from_the_cache_calls_its_unlinked_callees(tmp_path: Path) -> None:
    """The step loop calls its largest callees by symbol (``engine.kernels.jit.unlinked``). In a
    process that loads it from the cache and has loaded none of them, with the SVD's cache entry
    lost (compiled again there, under a symbol of that process), the loop loads them first and
    calls the SVD compiled there: the plan is the same (the call jumped to nothing, a segfault)."""
    warm_up()  # the cache is complete
    cache = tmp_path / "numba"
    shutil.copytree(CACHE_DIR, cache / f"spacearm-{source_hash()}")
    lost = [path for path in cache.rglob("svd.jacobi_svd-*") if path.is_file()]
    assert lost
    for path in lost:
        path.unlink()
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    run = subprocess.run([sys.executable, "-c", UNLINKED_SCRIPT], capture_output=True, text=True, timeout=600, env=env)
    assert run.returncode == 0, (run.returncode, run.stderr[-3000:])
    out = json.loads(run.stdout.strip().splitlines()[-1])
    assert out["before"] == [0, 0] and out["svd_compiled"] == 1 and out["loop_loaded"] == 1, out
    model = table1_robot()
    assert out["q_end"] == plan(model, paper_task(model), make_inverse("adaptive")).q[-1].tolist()


LINKED_KERNELS = """
import numpy as np
from engine.kernels.jit import kernel, unlinked

@kernel
def callee(a, k):
    s = 0.0
    for i in range(a.shape[0]):
        s += a[i] * k
    return s

@kernel
def middle(a):  # not inlined: a kernel that a caller links in
    return unlinked(callee, (a, 2.0)) + 1.0

@kernel
def outer(a):
    return middle(a) * 10.0
"""

LINKED_STEP = """
import itertools, json, sys
import numba.core.bytecode
numba.core.bytecode.FunctionIdentity._unique_ids = itertools.count(int(sys.argv[1]))  # symbols of this process
import numpy as np
import linked
a = np.arange(4.0)
if sys.argv[2] == "middle":
    value = linked.middle(a)
else:
    value = linked.outer(a)
loaded = {k.py_func.__name__: sum(k.stats.cache_hits.values()) for k in (linked.callee, linked.middle, linked.outer)}
print(json.dumps(dict(value=value, loaded=loaded)))
"""


def test_a_kernel_linked_in_after_a_cache_load_keeps_its_callees_loaders(tmp_path: Path) -> None:
    """A kernel that calls another :func:`~engine.kernels.jit.unlinked` and is linked into a caller
    compiled in a later process, which loaded it from the cache: numba gives a loaded library no
    ``reload_init``, so the caller's cache entry had no loader for the callee, and a third process
    that loaded the caller first (the callee's entry lost) called nothing (a segfault)."""
    (tmp_path / "linked.py").write_text(LINKED_KERNELS)
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba"), "PYTHONPATH": f"{tmp_path}{os.pathsep}{Path.cwd()}"}

    def step(first_uid: int, entry: str) -> dict[str, Any]:
        run = subprocess.run([sys.executable, "-c", LINKED_STEP, str(first_uid), entry], capture_output=True, text=True, env=env)
        assert run.returncode == 0, (entry, run.returncode, run.stderr[-3000:])
        return json.loads(run.stdout.strip().splitlines()[-1])

    assert step(1, "middle") == {"value": 13.0, "loaded": {"callee": 0, "middle": 0, "outer": 0}}
    assert step(10**5, "outer")["loaded"] == {"callee": 1, "middle": 1, "outer": 0}  # middle loaded, outer compiled
    for path in (tmp_path / "numba").rglob("linked.callee-*"):
        path.unlink()  # compiled again below, under a symbol of that process
    assert step(10**6, "outer") == {"value": 130.0, "loaded": {"callee": 0, "middle": 0, "outer": 1}}


def _records() -> dict[str, dict[str, list[str]]]:
    """The compile parts' signature records (``engine.warmup.signatures_path``), by part."""
    warm_up()  # the cache is complete
    records = {}
    for part in PARTS:
        recorded = signatures_path(part)
        if not recorded.exists():
            pytest.fail(f"{recorded} is missing: this version's kernels were not compiled in a fresh cache (delete {CACHE_DIR})")
        records[part] = json.loads(recorded.read_text())
    return records


def test_the_loops_largest_callees_were_compiled_ahead_for_the_loops_own_types() -> None:
    """``engine.warmup.loop_callees`` gives the argument types the step loop gives its largest
    callees, which the tools part compiles ahead: the part that compiled the loop held exactly
    those (other types, and the loop would have compiled its own beside them)."""
    planner = _records()["planner"]
    for kernel, argument_types in loop_callees(table1_robot()):
        assert planner.get(kernel_name(kernel)) == [str(argument_types)], kernel_name(kernel)


def test_every_kernel_was_compiled_for_one_signature() -> None:
    """A literal argument (``True``, ``0``) or a read-only array makes numba compile a kernel
    again for that type: callers pass runtime values (``np.bool_(True)``, ``np.int64(0)``) and
    writable arrays. The compile parts recorded the signatures their processes held; together,
    in a fresh cache, every signature compiled."""
    held: dict[str, set[str]] = {}
    for record in _records().values():
        for kernel, signatures in record.items():
            held.setdefault(kernel, set()).update(signatures)
    assert "engine.kernels.plan.simulate" in held
    assert {k: sorted(v) for k, v in held.items() if len(v) > 1} == {}


#: Kernels no part compiles: no service request calls them (the library's, and the tests').
NOT_WARMED = {
    "engine.kernels.dynamics.inverse_dynamics_many",  # engine.dynamics.inverse_dynamics, plan_dynamics
    "engine.kernels.qp.dense_qp",  # engine.qp.solve_qp
    "engine.kernels.plan.base_attitude_step",  # tests
}


def test_the_parts_compile_every_kernel_the_service_calls() -> None:
    """Every kernel but those inlined into their caller and :data:`NOT_WARMED` is in the parts'
    records: none is left for a request to compile (the clearance figure's distances were)."""
    held = {kernel for record in _records().values() for kernel in record}
    names = {kernel_name(k) for k in KERNELS if k.targetoptions["inline"] != "always"}
    assert names - held == NOT_WARMED


def test_read_only_inputs_compile_no_other_spline() -> None:
    """A stored plan's arrays are read-only, and so is the end rate ``from_plan`` broadcasts: the
    executed trajectory copies them, so it runs the spline compiled ahead instead of compiling
    another one (for read-only arrays) at run time."""
    warm_up()
    t = np.linspace(0.0, 1.0, 5)
    q = np.zeros((5, 6))
    for array in (t, q):
        array.setflags(write=False)
    executed_trajectory(t, q, None, np.broadcast_to(0.1, (6,)))
    arrays = [arg for signature in spline.clamped_spline.signatures for arg in signature if isinstance(arg, types.Array)]
    assert arrays and all(arg.mutable for arg in arrays), spline.clamped_spline.signatures


def test_compiling_removes_the_in_tree_caches_of_earlier_sources() -> None:
    if CACHE_DIR.parent != KERNELS_DIR / "__pycache__":
        pytest.skip(f"the kernel cache is not in the tree ({CACHE_DIR}): other installs may share it")
    stale = CACHE_DIR.parent / "numba-0123456789abcdef"
    (stale / "kernels").mkdir(parents=True, exist_ok=True)
    (stale / "kernels" / "entry.nbi").write_bytes(b"old")
    compile_kernels(lambda _: None)  # the cache is complete: the parts load, then the sweep
    assert not stale.exists()
    assert marker_path(CACHE_DIR).exists()

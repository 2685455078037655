"""The kernels' warm-up in parts: the parts compiled in separate processes (``spacearm compile``,
which ``make test`` runs before the suite) leave nothing for a full :func:`engine.warm_up` to
compile, and each kernel is compiled for one signature only (a literal argument would add one)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from engine.warmup import PARTS, warm_up

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
signatures = {k.py_func.__qualname__: len(k.signatures) for k in (plan.simulate, plan.evaluate_range, replay.integrate)}
print(json.dumps({"compiled": compiled, "signatures": signatures}))
"""


def test_a_full_warm_up_after_the_parts_compiles_nothing_and_each_kernel_once() -> None:
    warm_up()  # the cache is complete (the suite's conftest warms it up too)
    done = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=600, check=True)
    found = json.loads(done.stdout.strip().splitlines()[-1])
    assert found["compiled"] == [], found
    assert found["signatures"] == {"simulate": 1, "evaluate_range": 1, "integrate": 1}, found


def test_unknown_parts_are_refused() -> None:
    assert set(PARTS) == {"planner", "tools"}
    with pytest.raises(ValueError, match="unknown kernel part"):
        warm_up(["planner", "gpu"])

import sys
from pathlib import Path

import numpy as np
import pytest

# After the checkout: ``tests/service`` must not shadow the ``service`` package (helpers such as
# ``robots`` and ``oracle`` are imported from here).
sys.path.append(str(Path(__file__).parent))

from engine import paper_task, table1_robot, warm_up


@pytest.fixture(scope="session", autouse=True)
def kernels():
    """Compile (or load) the kernels once, first: numba's cache is then warm for every API and
    worker process the service tests start."""
    return warm_up()


@pytest.fixture(scope="session")
def robot():
    return table1_robot()


@pytest.fixture(scope="session")
def task(robot):
    return paper_task(robot)


@pytest.fixture
def rng():
    return np.random.default_rng(20261122)

"""What a plan request keeps between requests (:mod:`service.infra.lru`): robot models by their
parameters and engine tasks by model and task, so that planning one task again skips its
building, without ever answering with another task's or robot's."""

from __future__ import annotations

import numpy as np
import pytest

from engine import table1_robot
from engine.model import table1_with_geometry
from service.infra.lru import Lru
from service.schemas.common import PAPER_TASK_EXAMPLE
from service.schemas.robots import model_of
from service.schemas.tasks import TaskIn
from service.usecases import plans


def test_a_task_is_built_once_per_model_and_task() -> None:
    model = model_of(table1_robot().to_dict())
    assert model_of(table1_robot().to_dict()) is model  # a stored robot's model is kept
    task_in = TaskIn.model_validate(PAPER_TASK_EXAMPLE)
    task = plans.engine_task(task_in, model)
    assert plans.engine_task(TaskIn.model_validate(PAPER_TASK_EXAMPLE), model) is task
    slower = plans.engine_task(TaskIn.model_validate({**PAPER_TASK_EXAMPLE, "dt_s": 0.5}), model)
    assert slower is not task and slower.dt == 0.5 and task.dt == PAPER_TASK_EXAMPLE["dt_s"]
    other = model_of(table1_with_geometry().to_dict())
    on_other = plans.engine_task(task_in, other)
    assert on_other is not task
    fresh = task_in.to_engine(other)
    assert np.array_equal(on_other.q0, fresh.q0)
    assert np.allclose(on_other.path.start_position, fresh.path.start_position)


def test_a_reused_model_id_never_answers_with_another_models_task() -> None:
    task_in = TaskIn.model_validate({**PAPER_TASK_EXAMPLE, "dt_s": 0.125})
    kept, other = table1_robot(), table1_with_geometry()
    wrong = task_in.to_engine(kept)
    key = (id(other), task_in.model_dump_json())
    plans._TASKS.put(key, (kept, wrong))  # as if `other` had taken the id of a model no longer kept
    task = plans.engine_task(task_in, other)
    assert task is not wrong
    assert plans.engine_task(task_in, other) is task  # and the right one is kept from then on


def test_the_cache_keeps_the_last_values_and_no_failure() -> None:
    cache: Lru[int, str] = Lru(2)
    built: list[int] = []

    def build(k: int) -> str:
        built.append(k)
        return str(k)

    for k in (1, 2, 1, 3):  # 1 is used again, so 2 is the one dropped for 3
        assert cache.get(k, lambda k=k: build(k)) == str(k)
    assert built == [1, 2, 3]
    cache.get(1, lambda: build(1))
    cache.get(2, lambda: build(2))
    assert built == [1, 2, 3, 2]

    def fail() -> str:
        raise ValueError("no")

    with pytest.raises(ValueError):
        cache.get(9, fail)
    assert cache.get(9, lambda: "nine") == "nine"

"""What a plan request keeps between requests (:mod:`service.infra.lru`): robot models by their
parameters and engine tasks by model and task, so that planning one task again skips its
building, without ever answering with another task's or robot's."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from sqlalchemy import create_engine, text
from sqlalchemy.orm import Session

from engine import run_plan, table1_robot
from engine.model import table1_with_geometry
from service.errors import NotFoundError
from service.infra.db import Database
from service.infra.lru import Lru
from service.infra.settings import Settings
from service.models import Base, Robot
from service.schemas.common import PAPER_TASK_EXAMPLE
from service.schemas.plans import PlanRequest
from service.schemas.robots import model_of
from service.schemas.tasks import TaskIn
from service.usecases import plans, robots


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


def test_a_kept_robot_plans_without_the_database_and_its_deletion_is_caught_at_the_insert(tmp_path: Path) -> None:
    url = f"sqlite:///{tmp_path / 'kept.db'}"
    engine = create_engine(url)
    Base.metadata.create_all(engine)
    with Session(engine) as session:
        session.add(Robot(id="kept-arm", name="kept", parameters=table1_robot().to_dict(), preset=False))
        session.commit()
    db, settings = Database(url), Settings(database_url=url)
    body = PlanRequest.model_validate({"robot_id": "kept-arm", "task": PAPER_TASK_EXAMPLE, "replay": False})
    first = plans.prepare(db, body)  # read from the database, then kept
    assert robots.kept("kept-arm") is first.model
    with Session(engine) as session:  # as another API process deletes it
        session.execute(text("DELETE FROM robots WHERE id = 'kept-arm'"))
        session.commit()
    again = plans.prepare(db, body)  # no database read: the kept model
    assert again.model is first.model and again.robot_id == "kept-arm"
    planned = plans.finish(body, again, run_plan(again.setup, again.inverse), settings, 0.0, {})
    with pytest.raises(NotFoundError, match="kept-arm"):
        plans.store(db, settings, planned)  # the foreign key refuses it
    assert robots.kept("kept-arm") is None
    with pytest.raises(NotFoundError, match="kept-arm"):
        plans.prepare(db, body)  # read again: gone
    db.dispose()

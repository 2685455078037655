"""The README's tables say what the code has: every setting the service reads, every inverse method."""

from __future__ import annotations

import re
from pathlib import Path

from engine.inverses import method_table
from service.infra.settings import Settings

README = Path(__file__).resolve().parents[1] / "README.md"


def test_every_setting_is_in_the_configuration_table() -> None:
    rows = {
        m.group(1)
        for line in README.read_text().splitlines()
        if line.startswith("| `SPACEARM_")
        for m in re.finditer(r"`(SPACEARM_[A-Z0-9_]+)`", line.split("|")[1])
    }
    # the service's settings, and the one the engine reads itself (engine.planner.default_threads)
    expected = {f"SPACEARM_{name.upper()}" for name in Settings.model_fields} | {"SPACEARM_ENGINE_THREADS"}
    assert expected - rows == set(), "settings missing from the README's configuration table"
    assert rows - expected == set(), "README rows for settings the service does not read"


def test_the_method_table_is_the_registry() -> None:
    assert method_table() in README.read_text(), "regenerate the README's method table: engine.inverses.method_table()"

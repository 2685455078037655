"""The documentation says what the code has, and builds: the configuration table (docs/configuration.md)
lists every setting the service reads, the method table (docs/engine.md) is the registry's, MkDocs
builds the docs/ pages with ``--strict`` (a broken link or anchor fails), the README's links lead
to pages that exist, and the README stays a quick start (under 150 lines, examples on
``$SPACEARM_URL``, no hard-coded server address)."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from engine.inverses import method_table
from service.infra.settings import Settings

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
README = ROOT / "README.md"


def test_every_setting_is_in_the_configuration_table() -> None:
    rows = {
        m.group(1)
        for line in (DOCS / "configuration.md").read_text().splitlines()
        if line.startswith("| `SPACEARM_")
        for m in re.finditer(r"`(SPACEARM_[A-Z0-9_]+)`", line.split("|")[1])
    }
    # the service's settings, and the one the engine reads itself (engine.planner.default_threads)
    expected = {f"SPACEARM_{name.upper()}" for name in Settings.model_fields} | {"SPACEARM_ENGINE_THREADS"}
    assert expected - rows == set(), "settings missing from the configuration table (docs/configuration.md)"
    assert rows - expected == set(), "configuration table rows for settings the service does not read"


def test_the_method_table_is_the_registry() -> None:
    assert method_table() in (DOCS / "engine.md").read_text(), "regenerate docs/engine.md's method table: method_table()"


def mkdocs(config: Path) -> subprocess.CompletedProcess[str]:
    exe = Path(sys.executable).with_name("mkdocs")
    command = [str(exe)] if exe.exists() else [sys.executable, "-m", "mkdocs"]
    return subprocess.run(
        [*command, "build", "--strict", "--config-file", str(config), "--site-dir", str(config.parent / "site")],
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_the_docs_build_strictly_and_a_broken_link_fails(tmp_path: Path) -> None:
    pytest.importorskip("mkdocs", reason="MkDocs is in the test extras (pip install -e '.[test]')")
    shutil.copy(ROOT / "mkdocs.yml", tmp_path / "mkdocs.yml")
    shutil.copytree(DOCS, tmp_path / "docs")
    built = mkdocs(tmp_path / "mkdocs.yml")
    assert built.returncode == 0, built.stderr
    assert (tmp_path / "site" / "plans" / "index.html").exists()
    # the same build with one broken link, then one broken anchor: both fail
    for broken, named in (("[gone](nowhere.md)", "nowhere.md"), ("[gone](plans.md#no-such-section)", "no-such-section")):
        page = tmp_path / "docs" / "jobs.md"
        original = page.read_text()
        page.write_text(original + f"\nSee {broken}.\n")
        failed = mkdocs(tmp_path / "mkdocs.yml")
        assert failed.returncode != 0 and named in failed.stderr, (broken, failed.stderr)
        page.write_text(original)


def test_the_readme_is_a_quick_start_whose_links_exist() -> None:
    text = README.read_text()
    lines = text.splitlines()
    print(f"\nREADME: {len(lines)} lines")
    assert len(lines) < 150
    for target in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", text):
        assert (ROOT / target).exists(), target
    pages = {p.name for p in DOCS.glob("*.md")}
    assert {Path(t).name for t in re.findall(r"\]\((docs/[^)#]+)", text)} == pages - {"index.md"}
    for path in [README, *DOCS.glob("*.md")]:
        for block in re.findall(r"```sh\n(.*?)```", path.read_text(), re.S):
            assert "localhost:8000" not in block and "127.0.0.1:8000/v1" not in block, path.name
            assert "JOB_ID/" not in block.replace("$JOB_ID/", ""), path.name  # ids are captured, not placeholders
    assert not (ROOT / "arm7.urdf").exists() and not (ROOT / "wp.json").exists()


def test_nothing_cites_a_file_the_repository_does_not_have() -> None:
    """The API and the engine once cited ``robot-table1.yaml``; the robot's schema is ``engine/data/table1_robot.json``."""
    assert (ROOT / "engine" / "data" / "table1_robot.json").exists()
    for path in [*(ROOT / "service").rglob("*.py"), *(ROOT / "engine").rglob("*.py")]:
        assert "robot-table1" not in path.read_text(), path

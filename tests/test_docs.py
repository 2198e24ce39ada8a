"""The documentation site builds with ``mkdocs build --strict`` (a broken link, a missing page or an
unresolved API reference fails), and the CLI reference names every command."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from agentax.cli import COMMANDS

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


def _nav_files(nav) -> list[str]:
    files: list[str] = []
    for entry in nav:
        if isinstance(entry, str):
            files.append(entry)
        elif isinstance(entry, dict):
            for value in entry.values():
                files.extend(_nav_files(value) if isinstance(value, list) else [value])
    return files


def _mkdocs_config() -> dict:
    # mkdocs.yml may hold python tags in principle; this one is plain YAML
    return yaml.safe_load((ROOT / "mkdocs.yml").read_text())


def test_cli_reference_names_every_command():
    text = (DOCS / "cli.md").read_text()
    for command in COMMANDS:
        assert f"## agentax {command}" in text, f"docs/cli.md has no section for agentax {command}"
        assert f"<!-- agentax-help: {command} -->" in text, f"docs/cli.md does not generate {command}'s help"


def test_nav_holds_every_page():
    """Every Markdown page is in the nav (the tutorial's pages included), and every nav entry exists."""
    nav = _nav_files(_mkdocs_config()["nav"])
    for name in nav:
        assert (DOCS / name).is_file(), f"mkdocs.yml's nav names {name}, which is missing"
    pages = sorted(str(p.relative_to(DOCS)) for p in DOCS.rglob("*.md"))
    missing = [page for page in pages if page not in nav]
    assert not missing, f"pages not in mkdocs.yml's nav: {missing}"


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_site_builds_strict(tmp_path: Path):
    pytest.importorskip("mkdocs")
    pytest.importorskip("mkdocstrings_handlers.python")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1", "NO_COLOR": "1"}
    result = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-d", str(tmp_path / "site")],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=280,
    )
    output = result.stdout + result.stderr
    assert result.returncode == 0, output
    assert not re.search(r"^(WARNING|ERROR)\b", output, re.MULTILINE), output
    site = tmp_path / "site"
    assert (site / "index.html").is_file()
    cli = (site / "cli" / "index.html").read_text()
    for command in COMMANDS:
        assert f"usage: agentax {command}" in cli, f"the built CLI reference lacks agentax {command} --help"
    assert "agentax.agents.protocol" in (site / "api" / "index.html").read_text()

"""The documentation site builds with ``mkdocs build --strict`` (a broken link, a missing page or an
unresolved API reference fails), and the CLI reference names every command.

The README is the front door and mkdocs does not build it, so its checks are here: it stays short
and says how to install, its links and anchors resolve, its Python example runs, every ``agentax``
command it (or a docs page) shows is a real command with real flags, and its headline figures are
the ones on the pages it links to for how they were measured."""

from __future__ import annotations

import contextlib
import functools
import io
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
README = ROOT / "README.md"
README_MAX_LINES = 110  # a front door: the details are on the docs pages


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


def _markdown(path: Path) -> str:
    """A page's Markdown with its ``--8<-- "FILE"`` snippets (paths from the repository root) inlined."""
    text = path.read_text()
    return re.sub(r'^--8<-- "([^"]+)"$', lambda m: (ROOT / m.group(1)).read_text(), text, flags=re.MULTILINE)


def _anchors(path: Path) -> set[str]:
    """The ids that MkDocs' toc extension gives the headings of a Markdown page."""
    from markdown.extensions.toc import slugify

    text = re.sub(r"^```.*?^```", "", _markdown(path), flags=re.MULTILINE | re.DOTALL)
    headings = re.findall(r"^#{1,6} (.+?)\s*$", text, re.MULTILINE)
    return {slugify(re.sub(r"[`*_]", "", heading), "-") for heading in headings}


def _section(text: str, heading: str) -> str:
    match = re.search(rf"^## {re.escape(heading)}\n(.*?)(?=^## |\Z)", text, re.MULTILINE | re.DOTALL)
    assert match, f"README.md has no section '## {heading}'"
    return match.group(1)


def test_readme_is_a_front_door():
    lines = len(README.read_text().splitlines())
    assert lines <= README_MAX_LINES, f"README.md has {lines} lines; the details belong on a docs page"
    text = README.read_text()
    install = _section(text, "Install")
    for command in ("make demo", "make test", "pip install -e ."):
        assert command in install, f"README.md's Install section does not show {command}"
    extras = re.search(
        r"^\[project.optional-dependencies\]\n(.*?)^\[",
        (ROOT / "pyproject.toml").read_text(),
        re.MULTILINE | re.DOTALL,
    ).group(1)
    for extra in re.findall(r"^(\w+) = ", extras, re.MULTILINE):
        assert f"`{extra}`" in install or f"{extra}," in install or f"{extra}]" in install, (
            f"README.md's Install section does not name the extra {extra}"
        )
    for heading in ("In Python", "What works", "Headline figures", "Where to go next"):
        _section(text, heading)


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_the_readme_python_example_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """The README's Python example, run as shown but for a small budget (2,048 env steps a seed, as
    tests/test_api.py's run, whose stored program it loads) in a temporary folder: it trains,
    evaluates, plots, records and loads, and the loaded run evaluates as the trained one did."""
    import agentax

    code = re.search(r"^```python\n(.*?)^```", _section(README.read_text(), "In Python"), re.M | re.S).group(
        1
    )
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(agentax, "train", functools.partial(agentax.train, total_steps=2048, progress=False))
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        exec(compile(code, "README.md", "exec"), {"__name__": "readme"})
    trained, steps, loaded = printed.getvalue().splitlines()
    assert re.fullmatch(r"mean return \d+\.\d over 100 episodes", trained), trained
    assert 0 < float(steps.split()[0]) <= 2048, steps  # at most the budget
    assert loaded.split()[2] == trained.split()[2]  # the run from its folder plays as the trained one
    assert (tmp_path / "curve.png").stat().st_size > 0 and (tmp_path / "episode.gif").stat().st_size > 0


def test_readme_links_resolve():
    """Every relative link and image of the README names a file, and a #fragment one of its headings."""
    links = re.findall(r"\]\(([^)\s]+)\)", README.read_text())
    assert links
    for link in links:
        if "://" in link:
            continue
        target, _, anchor = link.partition("#")
        path = ROOT / target
        assert path.exists(), f"README.md links {link}: {target} is missing"
        if anchor:
            assert anchor in _anchors(path), f"README.md links {link}: {target} has no heading #{anchor}"


def _commands(text: str) -> list[str]:
    """The ``agentax ...`` commands a page shows: in inline code, and lines of its shell (or bare) code
    blocks, comments cut off."""
    found, prose, fence = [], [], None  # fence: the open block's language ("" for a bare one)
    for line in text.splitlines():
        if line.startswith("```"):
            fence = line[3:].strip() if fence is None else None
            prose.append("")
        elif fence is None:
            prose.append(line)
        elif fence in ("", "bash", "sh", "console") and line.startswith("agentax "):
            found.append(line.split(" #")[0])
    found += re.findall(r"`(agentax [^`]+)`", "\n".join(prose))
    return [command.strip() for command in found]


def test_the_commands_shown_exist(monkeypatch: pytest.MonkeyPatch):
    """Every ``agentax`` command in the README and the docs pages names a command of the CLI, and
    each of its flags is in that command's --help (``ppo|dqn``, ``play/evaluate``: the first)."""
    import importlib.util

    monkeypatch.setenv("COLUMNS", "100")  # command_help sets it; put it back after
    spec = importlib.util.spec_from_file_location("docs_hooks", DOCS / "hooks.py")
    hooks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hooks)
    helps: dict[tuple[str, ...], str] = {}

    def help_of(*args: str) -> str:
        if args not in helps:
            helps[args] = hooks.command_help(list(args))
        return helps[args]

    pages = [README, *sorted(p for p in DOCS.rglob("*.md") if p.name != "cli.md")]
    checked = 0
    for page in pages:
        for command in _commands(page.read_text()):
            words = command.split()
            name = re.split(r"[|/]", words[1])[0]
            if name.startswith("-") or any(word.endswith(":") for word in words[:3]):  # --version; a message
                continue
            where = f"{page.relative_to(ROOT)} shows `{command}`"
            assert name in COMMANDS, f"{where}: there is no agentax {name}"
            text = help_of(name)
            if name in ("train", "search") and len(words) > 2 and not words[2].startswith(("-", "[")):
                sub = re.split(r"[|/]", words[2])[0]
                if sub.isidentifier():
                    text += help_of(name, sub)
            for flag in re.findall(r"(?<![\w-])--[a-z][a-z0-9-]*", command):
                assert re.search(rf"{flag}\b", text), f"{where}: agentax {name} has no {flag}"
            checked += 1
    assert checked > 50


def test_readme_headline_figures_are_where_they_link():
    """Each headline figure of the README appears on the docs page its row links to (where the page
    says how it was measured): the front door repeats figures, it does not make them."""
    rows = [
        line
        for line in _section(README.read_text(), "Headline figures").splitlines()
        if line.startswith("| [")
    ]
    assert rows
    for row in rows:
        link = re.search(r"\]\(([^)#\s]+)(?:#[^)\s]*)?\)", row).group(1)
        page = _markdown(ROOT / link)
        shown = re.sub(
            r"<!--.*?-->", "", re.sub(r"\]\([^)]*\)", "]", row)
        )  # figures' markers: scripts/figures.py
        figures = re.findall(r"\d[\d,]*(?:\.\d+)?", shown)
        missing = [figure for figure in figures if figure not in page]
        assert not missing, f"README.md's headline row {row[:60]}...: {missing} not on {link}"

"""Every tutorial page runs: its ```python blocks, in order, in one fresh namespace per page.

The pages (docs/tutorial/*.md) are Markdown notebooks (jupytext's "md" format): prose and fenced
```python cells. Each page runs with CI-sized settings in a temporary working directory with
matplotlib's Agg backend, so a page whose code no longer runs against agentax's API fails here.
"""

from __future__ import annotations

import os
import re
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TUTORIAL = ROOT / "docs" / "tutorial"
PAGES = sorted(TUTORIAL.glob("*.md"))
SLOW_PAGES = {"07-deep-q-learning.md", "08-training-architecture-and-atari.md"}
PAGE_TIMEOUT = 240  # seconds per page; the pages themselves take 2-15 s of CPU
# Modules a page needs beyond agentax's core install (the page is skipped without them).
REQUIRES = {"08-training-architecture-and-atari.md": ("ale_py", "cv2")}

# A fenced block opens with ```python (jupytext's md cells) and closes with a bare ```.
BLOCK = re.compile(r"^```python[^\n]*\n(.*?)^```[ \t]*$", re.MULTILINE | re.DOTALL)


def python_blocks(page: Path) -> list[str]:
    """The source of each ```python block of ``page``, in order."""
    return BLOCK.findall(page.read_text())


def run_page(page: Path) -> dict:
    """Run ``page``'s blocks in order in one namespace; return the namespace."""
    namespace: dict = {"__name__": "__tutorial__"}
    for index, source in enumerate(python_blocks(page)):
        code = compile(source, f"{page.name}[block {index + 1}]", "exec")
        exec(code, namespace)
    return namespace


def test_pages_exist():
    names = [page.name for page in PAGES]
    for number in range(1, 9):
        assert any(name.startswith(f"{number:02d}-") for name in names), f"no tutorial page {number:02d}-*.md"
    for page in PAGES:
        assert python_blocks(page), f"{page.name} has no ```python block"


def _params():
    for page in PAGES:
        marks = [pytest.mark.timeout(PAGE_TIMEOUT)]
        if page.name in SLOW_PAGES:
            marks.append(pytest.mark.slow)
        yield pytest.param(page, id=page.stem, marks=marks)


@pytest.mark.parametrize("page", list(_params()))
def test_page_runs(page: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    for module in REQUIRES.get(page.name, ()):
        pytest.importorskip(module)
    import matplotlib

    matplotlib.use("Agg")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    start = time.perf_counter()
    try:
        run_page(page)
    finally:
        import matplotlib.pyplot as plt

        plt.close("all")
    print(f"{page.name}: {time.perf_counter() - start:.1f} s")


def test_figures_the_pages_link_exist():
    """Every image a page shows (![...](file)) is in the docs."""
    for page in PAGES:
        for target in re.findall(r"!\[[^\]]*\]\(([^)\s]+)\)", page.read_text()):
            if "://" not in target:
                assert (page.parent / target).is_file(), f"{page.name} shows {target}, which is missing"


# After a ```python block, an optional ```text block holds what the block printed (written by --write).
CELL = re.compile(
    r"(^```python[^\n]*\n.*?^```[ \t]*\n)(\n?```text\n.*?^```[ \t]*\n)?", re.MULTILINE | re.DOTALL
)


def write_outputs(page: Path) -> None:
    """Run ``page`` in a temporary folder; put each block's output after it and its PNGs beside it."""
    import contextlib
    import io
    import shutil
    import tempfile

    namespace: dict = {"__name__": "__tutorial__"}
    counter = iter(range(1000))
    here = Path.cwd()

    def run_cell(match: re.Match) -> str:
        cell = match.group(1)
        source = BLOCK.match(cell).group(1)
        output = io.StringIO()
        with contextlib.redirect_stdout(output):
            exec(compile(source, f"{page.name}[block {next(counter) + 1}]", "exec"), namespace)
        text = output.getvalue().rstrip()
        return cell + (f"\n```text\n{text}\n```\n" if text else "")

    with tempfile.TemporaryDirectory() as folder:
        os.chdir(folder)
        try:
            new = CELL.sub(run_cell, page.read_text())
        finally:
            os.chdir(here)
        for png in Path(folder).glob("*.png"):
            shutil.copy(png, page.parent / png.name)
    page.write_text(new)


if __name__ == "__main__":
    # python tests/test_tutorial.py [--write] [PAGE...]: run pages and time them; --write refreshes the
    # pages' output blocks and figures (docs/tutorial/*.png).
    import sys

    import matplotlib

    matplotlib.use("Agg")
    args = sys.argv[1:]
    write = "--write" in args
    names = [a for a in args if a != "--write"] or [p.name for p in PAGES]
    for name in names:
        page = Path(name) if Path(name).is_file() else TUTORIAL / name
        start = time.perf_counter()
        write_outputs(page) if write else run_page(page)
        print(f"== {page.name}: {time.perf_counter() - start:.1f} s", flush=True)

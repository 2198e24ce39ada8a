"""scripts/figures.py: every figure on the README and the docs pages is its source's value, printed
exactly; a figure one off in its last digit fails the check; the bench records the CPU.

The README's headline figures are bound (each marked, each also on the page its row links to), and
every trained score on it has its evidence folder. Nothing counts figures: the README may hold few,
and each one that is there is checked."""

from __future__ import annotations

import importlib.util
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.timeout(120)

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "figures.py"


def _load_figures():
    spec = importlib.util.spec_from_file_location("agentax_figures", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the class is made
    spec.loader.exec_module(module)
    return module


figures = _load_figures()


def _off_by_one(printed: str) -> str:
    """``printed`` with its last digit one higher (9 -> 8): 2.96 -> 2.97, 51.2M -> 51.3M, −1.4 -> −1.5."""
    position = max(i for i, char in enumerate(printed) if char.isdigit())
    digit = int(printed[position])
    return printed[:position] + str(digit + 1 if digit < 9 else digit - 1) + printed[position + 1 :]


def _marked(text: str) -> list[re.Match]:
    return list(figures.MARKER.finditer(text))


def test_every_figure_on_the_pages_is_its_sources_value():
    """Each marked figure of every page equals what scripts/figures.py computes from its source, each
    name is a figure, and each figure is on some page."""
    assert figures.check() == []
    assert _marked((ROOT / "README.md").read_text()), "the README shows no marked figure"


@pytest.mark.slow
def test_each_figure_one_off_in_its_last_digit_fails_the_check():
    """Every marked figure of the README and the docs pages, one at a time, changed by one in its last
    digit: the check names that figure, on that page and line."""
    shown = figures.values(ROOT)
    mutated = set()
    for page in figures.pages(ROOT):
        text = page.read_text()
        for match in _marked(text):
            name, printed = match.groups()
            if not any(char.isdigit() for char in printed):  # a CPU's name
                continue
            wrong = text[: match.start(2)] + _off_by_one(printed) + text[match.end(2) :]
            found = figures.problems(wrong, shown, page.name)
            line = text.count("\n", 0, match.start()) + 1
            assert found == [
                f"{page.name}:{line}: fig:{name} shows {_off_by_one(printed)!r}, its source gives {printed!r}"
            ]
            mutated.add(name)
    numeric = {name for name, value in shown.items() if any(char.isdigit() for char in value)}
    assert mutated == numeric, f"figures never mutated: {sorted(numeric - mutated)}"


def _copy_of_the_repository(tmp_path: Path) -> Path:
    """The pages and the sources the figures are read from, under ``tmp_path``."""
    for part in ("README.md", "docs", "benchmarks/results", "evidence", "benchmarks/run.py"):
        source, target = ROOT / part, tmp_path / part
        target.parent.mkdir(parents=True, exist_ok=True)
        (shutil.copytree if source.is_dir() else shutil.copy)(source, target)
    return tmp_path


def test_the_script_fails_on_a_mutated_copy_and_write_repairs_it(tmp_path: Path):
    """``--check`` on a copy whose benchmarks page says 2.97 where dqn.json gives 2.96 exits 1 naming it;
    ``--write`` prints the source's value back; a JSON changed under a page fails the check too."""
    root = _copy_of_the_repository(tmp_path)
    page = root / "docs" / "benchmarks.md"
    text = page.read_text()
    marker = "<!-- fig:dqn.warm.seconds -->2.96<!-- /fig -->"
    assert marker in text
    page.write_text(text.replace(marker, marker.replace("2.96", "2.97"), 1))
    command = [sys.executable, str(SCRIPT), "--root", str(root)]
    result = subprocess.run([*command, "--check"], capture_output=True, text=True, timeout=60)
    assert result.returncode == 1
    assert "fig:dqn.warm.seconds shows '2.97', its source gives '2.96'" in result.stdout

    result = subprocess.run([*command, "--write"], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stdout + result.stderr
    assert page.read_text() == text

    source = root / "benchmarks" / "results" / "dqn.json"
    result_file = json.loads(source.read_text())
    for row in result_file["rows"]:
        if row[0] == "`agentax train dqn` process, warm compile cache":
            row[5] = 2.95
    source.write_text(json.dumps(result_file))
    found = figures.check(root)
    assert any("fig:dqn.warm.seconds shows '2.96', its source gives '2.95'" in line for line in found), found


def test_unknown_names_open_markers_and_unused_figures_are_problems():
    shown = {"dqn.warm.seconds": "2.96"}
    assert figures.problems("<!-- fig:dqn.warm.seconds -->2.96<!-- /fig -->", shown) == []
    assert figures.problems("<!-- fig:nope -->1<!-- /fig -->", shown) == [
        ":1: fig:nope is not a figure of scripts/figures.py"
    ]
    assert figures.problems("<!-- fig:dqn.warm.seconds -->2.96\n<!-- /fig -->", shown)  # split over lines
    extra = {
        **figures.FIGURES,
        "spare": figures.bench("dqn", "SB3 DQN, RL-Zoo settings, whole process", col="seeds"),
    }
    assert "fig:spare is on no page (drop it from FIGURES)" in figures.check(ROOT, extra)


def _headline_rows() -> list[str]:
    text = (ROOT / "README.md").read_text()
    section = re.search(r"^## Headline figures\n(.*?)(?=^## )", text, re.MULTILINE | re.DOTALL).group(1)
    return [line for line in section.splitlines() if line.startswith("| [")]


def test_the_readme_headline_figures_are_bound_and_on_their_pages():
    """Every number of a headline row's results (its agentax, peer and CPU cells) is a marked figure,
    but for the few that are no measurement (targets, the 8 seeds of a row's name); each marked
    figure is also marked on the page the row links to, under the same name."""
    not_measured = {"1.6", "200", "0"}  # the parallel runner's target, SAC's bar of -200, taskset -c 0
    rows = _headline_rows()
    assert rows
    for row in rows:
        cells = row.split(" | ")
        link = re.search(r"\]\(([^)#\s]+)", cells[0]).group(1)
        results = " | ".join(cells[1:])
        names = [match.group(1) for match in _marked(results)]
        assert names, f"README headline row {cells[0][:50]} has no marked figure"
        loose = re.findall(r"(?<![\w.])\d[\d,.]*", figures.MARKER.sub("", results))
        assert set(loose) <= not_measured, f"{cells[0][:50]}: {loose} unmarked"
        page = (ROOT / link).read_text()
        assert all(f"<!-- fig:{name} -->" in page for name in names), f"{link} lacks one of {names}"
        assert re.search(r"<!-- fig:[\w.\-]+\.cpu -->", cells[-1]), f"{cells[0][:50]}: no CPU named"


def test_every_trained_score_on_the_readme_has_its_evidence_folder():
    """A score row of the headline figures reads from ``evidence/NAME/``, which holds the run's config,
    metrics, evaluation and run record (command, wall-clock, CPU with its flags)."""
    scores = [row for row in _headline_rows() if "trained score" in row]
    assert scores
    for row in scores:
        sources = {figures.FIGURES[match.group(1)].source for match in _marked(row)}
        folders = {Path(source).parent for source in sources}
        assert len(folders) == 1 and next(iter(folders)).parent == Path("evidence"), sources
        folder = ROOT / next(iter(folders))
        for file in ("config.json", "metrics.csv", "eval.json", "run.json"):
            assert (folder / file).is_file(), f"{folder} lacks {file}"
        run = json.loads((folder / "run.json").read_text())
        assert run["command"].startswith("agentax train") and run["wall_seconds"] > 0
        assert run["cpu"]["model_name"] and run["cpu"]["flags"]


def test_the_bench_records_the_cpu_and_names_it():
    harness = figures.HARNESS
    info = harness.cpu_info()
    assert info["model_name"] and "fpu" in info["flags"] or not Path("/proc/cpuinfo").exists()
    amd = {"cpu": {"model_name": "AMD EPYC", "flags": ["fpu", "avx512f"]}}
    xeon_flags = ["avx512f", "amx_tile", "amx_bf16"]
    xeon = {"cpu": {"model_name": "Intel(R) Xeon(R) Platinum 8481C CPU", "flags": xeon_flags}}
    zen3 = {"cpu": {"model_name": "AMD EPYC", "flags": ["fpu", "avx2", "fma"]}}
    assert harness.cpu_label(amd) == "AMD EPYC, no AMX"
    assert harness.cpu_label(zen3) == "AMD EPYC, no AVX-512"
    assert harness.cpu_label(xeon) == "Intel Xeon Platinum 8481C CPU, AMX"
    slugs = [harness.cpu_slug(m) for m in (amd, zen3, xeon)]
    assert slugs == ["amd-epyc", "amd-epyc-no-avx512", "intel-xeon"]
    assert harness.cpu_label({"processor": "Intel(R) Xeon(R) Processor"}) == "Intel Xeon"
    assert harness.cpu_label({}) == "CPU not recorded"


def test_an_evidence_folder_from_a_run_folder(tmp_path: Path):
    run = tmp_path / "run"
    run.mkdir()
    for file, content in (
        ("config.json", "{}"),
        ("metrics.csv", "env_steps\n1\n"),
        ("eval.json", '{"mean_return": 1}'),
    ):
        (run / file).write_text(content)
    log = tmp_path / "time.log"
    clock = "\tElapsed (wall clock) time (h:mm:ss or m:ss): 1:02:03.5\n"
    share = "\tPercent of CPU this job got: 183%\n"
    log.write_text('\tCommand being timed: ".venv/bin/agentax train ppo --env X"\n' + share + clock)
    timed = figures.time_log(log)
    assert timed == {"command": "agentax train ppo --env X", "wall_seconds": 3723.5, "cpu_percent": 183}
    folder = figures.make_evidence(run, "x", root=tmp_path, **timed)
    assert sorted(p.name for p in folder.iterdir()) == ["config.json", "eval.json", "metrics.csv", "run.json"]
    record = json.loads((folder / "run.json").read_text())
    assert (record["wall_seconds"], record["cpu_percent"]) == (3723.5, 183)
    with pytest.raises(FileNotFoundError, match="lacks eval.json"):
        (run / "eval.json").unlink()
        figures.make_evidence(run, "y", "c", 1.0, root=tmp_path)


def test_a_score_passed_is_read_from_the_evidence_metrics(tmp_path: Path):
    """The first row where the mean of the last 3 scores reaches 7, and 4, worked by hand: scores
    1, none (no game finished in that row), 5, 7, 9, 11: 1-5-7 (mean 4.3) at 400, 5-7-9 (7) at 500."""
    folder = tmp_path / "evidence" / "x"
    folder.mkdir(parents=True)
    rows = [(100, 1.0, 10), (200, "", 20), (300, 5.0, 30), (400, 7.0, 40), (500, 9.0, 50), (600, 11.0, 60)]
    text = "env_steps,mean_return,wall_seconds\n" + "".join(f"{a},{b},{c}\n" for a, b, c in rows)
    (folder / "metrics.csv").write_text(text)
    assert figures.passed("x", 7.0, "env_steps", rows=3).show(tmp_path) == "500.0"
    assert figures.passed("x", 7.0, "wall_seconds", rows=3).show(tmp_path) == "50.0"
    assert figures.passed("x", 4.0, "env_steps", rows=3).show(tmp_path) == "400.0"
    with pytest.raises(LookupError, match="never reaches a mean of 100"):
        figures.passed("x", 100.0, "env_steps", rows=3).show(tmp_path)

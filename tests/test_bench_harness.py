"""benchmarks/run.py: discovery, the result contract, JSON results, the generated README, exit codes."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

pytestmark = pytest.mark.timeout(60)

GOOD = """
def run():
    return {"name": "good", "title": "Good section", "headers": ["envs", "steps/s"],
            "rows": [[8192, 21800000.0], [1, 130000.0]], "notes": "Measured *here*."}
"""
BROKEN = "def run():\n    raise RuntimeError('no reference env')\n"
WRONG_NAME = GOOD.replace('"name": "good"', '"name": "other"')


@pytest.fixture
def harness(tmp_path, monkeypatch):
    """benchmarks/run.py, pointed at a scratch benchmarks folder."""
    spec = importlib.util.spec_from_file_location(
        "bench_run", Path(__file__).parents[1] / "benchmarks" / "run.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    monkeypatch.setattr(module, "BENCH_DIR", tmp_path)
    monkeypatch.setattr(module, "RESULTS_DIR", tmp_path / "results")
    monkeypatch.setattr(module, "README", tmp_path / "README.md")
    return module


def test_runs_sections_stores_results_and_writes_the_readme(harness, tmp_path, capsys):
    (tmp_path / "bench_good.py").write_text(GOOD)
    (tmp_path / "bench_broken.py").write_text(BROKEN)
    assert list(harness.discover()) == ["broken", "good"]

    assert harness.main([]) == 1  # the broken section fails, the good one still runs
    out = capsys.readouterr()
    assert "no reference env" in out.err and "== broken FAILED" in out.out
    assert "| 8,192 | 21.8M |" in out.out  # the table, numbers formatted

    stored = json.loads((tmp_path / "results" / "good.json").read_text())
    assert stored["rows"] == [[8192, 21800000.0], [1, 130000.0]]
    assert {"cpu_count", "jax", "date"} <= set(stored["machine"]) and stored["wall_seconds"] >= 0
    assert not (tmp_path / "results" / "broken.json").exists()
    readme = (tmp_path / "README.md").read_text()
    assert "## Good section" in readme and "| envs | steps/s |" in readme and "Measured *here*." in readme

    assert harness.main(["good"]) == 0
    assert harness.main(["nope"]) == 2
    assert "unknown benchmark nope; choose from broken, good" in capsys.readouterr().err


def test_a_result_of_another_cpu_stays_and_this_cpus_goes_beside_it(harness, tmp_path, monkeypatch):
    """A stored result of another CPU is never replaced: this machine's goes to NAME@CPU.json, and a
    rerun on this CPU replaces only its own."""
    (tmp_path / "bench_good.py").write_text(GOOD)
    results = tmp_path / "results"
    results.mkdir()
    xeon = {"name": "good", "title": "Good", "headers": ["envs"], "rows": [], "notes": "", "machine": {}}
    xeon["machine"]["cpu"] = {"model_name": "Intel(R) Xeon(R) Platinum 8481C CPU"}
    (results / "good.json").write_text(json.dumps(xeon))
    amd = {"model_name": "AMD EPYC 9B14", "flags": ["fpu", "avx512f", "avx512_bf16"]}
    monkeypatch.setattr(harness, "cpu_info", lambda: amd)
    assert harness.main(["good"]) == 0 and harness.main(["good"]) == 0
    assert json.loads((results / "good.json").read_text()) == xeon
    assert sorted(p.name for p in results.glob("*.json")) == ["good.json", "good@amd-epyc.json"]
    assert json.loads((results / "good@amd-epyc.json").read_text())["machine"]["cpu"] == amd
    (results / "good.json").unlink()  # no other CPU's result: NAME.json
    assert harness.main(["good"]) == 0 and (results / "good.json").is_file()


def test_a_result_that_breaks_the_contract_fails_its_section(harness, tmp_path):
    (tmp_path / "bench_good.py").write_text(WRONG_NAME)
    assert harness.main(["good"]) == 1
    with pytest.raises(ValueError, match="lacks notes"):
        harness.check_result("x", {"name": "x", "title": "", "headers": [], "rows": []})
    with pytest.raises(ValueError, match="has 1 cells, headers have 2"):
        harness.check_result(
            "x", {"name": "x", "title": "", "headers": ["a", "b"], "rows": [[1]], "notes": ""}
        )


@pytest.mark.parametrize(
    ("value", "text"),
    [
        (21_800_000.0, "21.8M"),
        (130_000.0, "130k"),
        (6884.2, "6,884"),
        (1.3456, "1.35"),
        (1024, "1,024"),
        (None, ""),
    ],
)
def test_cells_read_at_a_glance(harness, value, text):
    assert harness.format_cell(value) == text


BENCH_DIR = Path(__file__).parents[1] / "benchmarks"


def _agentax_imports(path: Path) -> list[tuple[str, str]]:
    """``(module, name)`` of every ``from agentax... import name`` in a bench file (inside functions too)."""
    import ast

    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "agentax":
            found += [(node.module, alias.name) for alias in node.names]
    return found


@pytest.mark.parametrize(
    "path", [*sorted(BENCH_DIR.glob("bench_*.py")), BENCH_DIR / "_pin.py"], ids=lambda path: path.stem
)
def test_every_bench_imports_names_agentax_has(path):
    """The sections import agentax inside run(); a renamed or removed API fails here, not in make bench."""
    import importlib

    missing = []
    for module_name, name in _agentax_imports(path):
        module = importlib.import_module(module_name)
        if not hasattr(module, name):
            try:
                importlib.import_module(f"{module_name}.{name}")
            except ImportError:
                missing.append(f"{module_name}.{name}")
    assert not missing, f"{path.name} imports {', '.join(missing)}, which agentax no longer has"

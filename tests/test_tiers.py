"""The test tiers: ``conftest.LONG_CASES`` names tests that exist, and only those become ``long``."""

import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import COLLECTED, LONG_CASES, is_long_case

TESTS = Path(__file__).parent


def unmatched(cases: dict[str, tuple[str, ...]], nodeids: list[str]) -> list[str]:
    """The entries of ``cases`` that name no test of ``nodeids``."""
    return [
        f"{file}::{case}"
        for file, names in cases.items()
        for case in names
        if not any(
            n.startswith(f"tests/{file}::")
            and (
                n.partition("::")[2] == case
                or (case.endswith(("[", "-")) and n.partition("::")[2].startswith(case))
            )
            for n in nodeids
        )
    ]


@pytest.mark.timeout(120)
def test_every_long_case_names_a_collected_test():
    """A renamed test or case would fall back into make test unseen: every entry must match. The ids
    are this session's where it collected every file LONG_CASES names (make test), else collected now."""
    files = [f"tests/{file}" for file in LONG_CASES]
    if {nodeid.partition("::")[0] for nodeid in COLLECTED} >= set(files):
        check_cases(COLLECTED)
        return
    listed = subprocess.run(
        [sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:xdist", "-p", "no:cacheprovider"]
        + files,
        cwd=TESTS.parent,
        capture_output=True,
        text=True,
        timeout=110,
    )
    check_cases([line for line in listed.stdout.splitlines() if "::" in line], listed.stdout + listed.stderr)


def check_cases(nodeids: list[str], output: str = "") -> None:
    """Every LONG_CASES entry names a test of ``nodeids``, and each names at least one."""
    assert nodeids, output[-4000:]
    assert unmatched(LONG_CASES, nodeids) == []
    long = [n for n in nodeids if is_long_case(n)]
    assert len(long) >= sum(map(len, LONG_CASES.values()))


def test_the_check_catches_a_case_that_names_no_test():
    nodeids = ["tests/test_a.py::test_b[x-1]", "tests/test_a.py::test_c"]
    cases = {"test_a.py": ("test_b[x-", "test_c", "test_d", "test_b[y-"), "test_e.py": ("test_c",)}
    assert unmatched(cases, nodeids) == ["test_a.py::test_d", "test_a.py::test_b[y-", "test_e.py::test_c"]


def test_an_entry_is_a_whole_id_or_a_prefix_ending_a_case():
    assert is_long_case("tests/test_golden.py::test_metrics_rows_match_the_golden_file[td3_host]")
    assert is_long_case("tests/test_tutorial.py::test_page_runs_and_prints_what_it_shows[07-deep-q-learning]")
    assert not is_long_case("tests/test_golden.py::test_metrics_rows_match_the_golden_file[ppo_compiled]")
    assert not is_long_case(
        "tests/test_tutorial.py::test_page_runs_and_prints_what_it_shows[01-environments]"
    )
    assert not is_long_case("tests/test_golden.py::test_metrics_rows_match_the_golden_file")
    assert not is_long_case("tests/test_other.py::test_metrics_rows_match_the_golden_file[td3_host]")


GROUPED = """
import os, pytest

@pytest.mark.xdist_group("g")
@pytest.mark.parametrize("case", range(4))
def test_grouped(case):
    with open(os.path.join(os.environ["RAN"], f"ran-{case}"), "w") as file:
        file.write(os.environ["PYTEST_XDIST_WORKER"])

@pytest.mark.parametrize("case", range(4))
def test_free(case):
    pass
"""


@pytest.mark.timeout(120)
def test_make_tests_loadgroup_sends_a_group_to_one_worker(tmp_path):
    """``--dist loadgroup`` (make test's) keeps an ``xdist_group`` on one worker (a module's shared
    runs trained once, Ray's clusters one at a time) by appending ``@group`` to the test's id. pytest
    9.2 with pytest-xdist 3.8 stopped doing so without a word: every group was spread over both workers."""
    (tmp_path / "test_grouped.py").write_text(GROUPED)
    command = [sys.executable, "-m", "pytest", "-q", "-n", "2", "--dist", "loadgroup", "-p"]
    command += ["no:cacheprovider", "test_grouped.py"]
    env = {**os.environ, "RAN": str(tmp_path)}
    done = subprocess.run(command, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=110)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    workers = {(tmp_path / f"ran-{case}").read_text() for case in range(4)}
    assert len(workers) == 1, workers

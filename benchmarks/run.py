"""Run agentax's benchmarks: ``python benchmarks/run.py [NAME ...]`` (``make bench`` runs them all).

Each ``benchmarks/bench_<NAME>.py`` is one section. It exposes ``run() -> dict`` returning::

    {
        "name": "envs",                     # == <NAME> of the file; names results/<NAME>.json
        "title": "CartPole env steps/s",    # the section heading in benchmarks/README.md
        "headers": ["envs", "steps/s"],     # column names of the table
        "rows": [[1, 1.2e6], ...],          # one list per row, JSON-serialisable values, len == len(headers)
        "notes": "markdown paragraph",      # what was measured, how, against which reference
    }

``run()`` takes no arguments, measures everything it reports in the same process (ratios against
a reference run side by side, never against stored numbers) and should finish within ~2-3 minutes.
The harness adds machine info (the CPU as ``lscpu`` names it: model, vendor, family, model number
and flags; cpu count, platform, python, jax version and backend, date) and the section's wall time,
prints the table, writes ``benchmarks/results/<NAME>.json`` and then rebuilds ``benchmarks/README.md``
from every stored result, so sections run on different days coexist. A result never replaces another
CPU's: where ``<NAME>.json`` was measured on another CPU, this one's goes to ``<NAME>@<cpu>.json``
beside it (``amd-epyc``, ``intel-xeon``), so where the CPU changes a figure both machines' stand.

``python benchmarks/run.py`` runs every section; ``python benchmarks/run.py envs dqn`` runs the named
ones; ``--list`` prints the names. A section that raises prints its traceback and the others still
run; the exit code is 1 if any failed, 2 for an unknown name. ``AGENTAX_BENCH_QUICK=1`` asks the
sections that offer it (``parallel``) for smaller runs, which their notes then say.
"""

from __future__ import annotations

import argparse
import datetime
import importlib.util
import json
import os
import platform
import subprocess
import sys
import time
import traceback
from pathlib import Path

BENCH_DIR = Path(__file__).resolve().parent
RESULTS_DIR = BENCH_DIR / "results"
README = BENCH_DIR / "README.md"
REQUIRED_KEYS = ("name", "title", "headers", "rows", "notes")


def discover() -> dict[str, Path]:
    """Section name -> file, for every ``bench_<name>.py`` beside this script, sorted by name."""
    return {path.stem.removeprefix("bench_"): path for path in sorted(BENCH_DIR.glob("bench_*.py"))}


def machine_info() -> dict:
    """Where and when the figures were measured."""
    import jax

    return {
        "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "cpu_count": os.cpu_count(),
        "cpus_usable": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
        "processor": _processor_name(),
        "cpu": cpu_info(),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "jax": jax.__version__,
        "jax_backend": jax.default_backend(),
        "jax_devices": [str(device) for device in jax.devices()],
    }


def _processor_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


LSCPU_FIELDS = {
    "Model name:": "model_name",
    "Vendor ID:": "vendor",
    "CPU family:": "family",
    "Model:": "model",
}


def cpu_info() -> dict:
    """The CPU as ``lscpu`` names it: ``{"model_name", "vendor", "family", "model", "flags": [...]}``
    (``/proc/cpuinfo``'s fields where ``lscpu`` is missing). The flags say what a figure may depend
    on (``amx_tile``: oneDNN's bf16 on AMX; ``avx512f``); ``{}`` where neither can be read."""
    try:
        entries = json.loads(
            subprocess.run(["lscpu", "--json"], capture_output=True, text=True, timeout=10).stdout
        )
    except (OSError, ValueError, subprocess.SubprocessError):
        return _cpuinfo_fields()
    info = {}
    for entry in _flatten(entries.get("lscpu", [])):
        if entry.get("field") in LSCPU_FIELDS:
            info.setdefault(LSCPU_FIELDS[entry["field"]], entry.get("data"))
        elif entry.get("field") == "Flags:":
            info["flags"] = (entry.get("data") or "").split()
    return info or _cpuinfo_fields()


def _flatten(entries: list[dict]):
    for entry in entries:
        yield entry
        yield from _flatten(entry.get("children", []))


def _cpuinfo_fields() -> dict:
    names = {"model name": "model_name", "vendor_id": "vendor", "cpu family": "family", "model": "model"}
    info = {}
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        return info
    for line in lines:
        key, _, value = (part.strip() for part in line.partition(":"))
        if key in names:
            info.setdefault(names[key], value)
        elif key == "flags":
            info.setdefault("flags", value.split())
    return info


def cpu_label(machine: dict) -> str:
    """A short name for the CPU a result was measured on: ``AMD EPYC, no AMX``, ``Intel Xeon, AMX``
    (AVX-512 CPUs), ``AMD EPYC, no AVX-512`` (an AMD EPYC Zen 3's: the model name alone does not tell
    it from a Zen 4); without recorded flags (results older than the ``cpu`` field) the model name alone."""
    name = machine.get("cpu", {}).get("model_name") or machine.get("processor") or "CPU not recorded"
    name = " ".join(
        word for word in name.replace("(R)", "").replace("(TM)", "").split() if word != "Processor"
    )
    flags = machine.get("cpu", {}).get("flags")
    if not flags:
        return name
    if "avx512f" not in flags:
        return f"{name}, no AVX-512"
    return f"{name}, {'AMX' if 'amx_tile' in flags else 'no AMX'}"


def cpu_slug(machine: dict) -> str:
    """The CPU in a file name: ``amd-epyc``, ``intel-xeon`` (the first two words of its label), with
    ``-no-avx512`` for a CPU without AVX-512, so a Zen 3's results never replace a Zen 4's."""
    label = cpu_label(machine)
    slug = "-".join(label.replace(",", " ").lower().split()[:2])
    return f"{slug}-no-avx512" if label.endswith("no AVX-512") else slug


def result_path(name: str, machine: dict) -> Path:
    """Where this machine's result of section ``name`` goes: ``results/NAME.json``, unless that file
    holds another CPU's figures, which stay beside it: then ``results/NAME@CPU.json`` (``cpu_slug``)."""
    path = RESULTS_DIR / f"{name}.json"
    if path.is_file() and cpu_slug(json.loads(path.read_text()).get("machine", {})) != cpu_slug(machine):
        return RESULTS_DIR / f"{name}@{cpu_slug(machine)}.json"
    return path


def load_section(name: str, path: Path):
    """Import ``path`` as a module (the benchmarks folder is importable, for shared helpers)."""
    if str(BENCH_DIR) not in sys.path:
        sys.path.insert(0, str(BENCH_DIR))
    spec = importlib.util.spec_from_file_location(f"agentax_bench_{name}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def check_result(name: str, result: dict) -> None:
    """Raise ``ValueError`` if ``result`` breaks the contract of the module docstring."""
    if not isinstance(result, dict):
        raise ValueError(f"bench_{name}.run() returned {type(result).__name__}, expected a dict")
    missing = [key for key in REQUIRED_KEYS if key not in result]
    if missing:
        needs = ", ".join(REQUIRED_KEYS)
        raise ValueError(f"bench_{name}.run() result lacks {', '.join(missing)}; it needs {needs}")
    if result["name"] != name:
        raise ValueError(f"bench_{name}.run() returned name {result['name']!r}, expected {name!r}")
    width = len(result["headers"])
    for row in result["rows"]:
        if len(row) != width:
            raise ValueError(f"bench_{name}: row {row!r} has {len(row)} cells, headers have {width}")


def format_cell(value) -> str:
    """Numbers readable at a glance: 21,800,000 -> 21.8M; ratios and seconds with 3 significant digits."""
    if isinstance(value, bool) or value is None:
        return "" if value is None else str(value)
    if isinstance(value, int):
        return f"{value:,}"
    if isinstance(value, float):
        if value != value:  # NaN
            return "—"
        magnitude = abs(value)
        if magnitude >= 1e9:
            return f"{value / 1e9:.3g}G"
        if magnitude >= 1e6:
            return f"{value / 1e6:.3g}M"
        if magnitude >= 1e4:
            return f"{value / 1e3:.3g}k"
        if magnitude >= 100:
            return f"{value:,.0f}"
        return f"{value:.3g}"
    return str(value)


def markdown_table(headers: list, rows: list) -> str:
    lines = ["| " + " | ".join(str(h) for h in headers) + " |", "|" + " --- |" * len(headers)]
    lines += ["| " + " | ".join(format_cell(cell) for cell in row) + " |" for row in rows]
    return "\n".join(lines)


def render_readme(results: list[dict]) -> str:
    """``benchmarks/README.md``: one section per stored result."""
    parts = [
        "# agentax benchmarks",
        "",
        "Generated by `python benchmarks/run.py` (`make bench`) from `benchmarks/results/*.json`;",
        "do not edit by hand. Run `python benchmarks/run.py NAME` to refresh one section. Every ratio",
        "compares two measurements taken in the same process, one after the other; absolute figures",
        "depend on the machine and its load. A section is a `benchmarks/bench_NAME.py` whose `run()`",
        "returns the dict described in `benchmarks/run.py`'s docstring.",
    ]
    for result in results:
        machine = result.get("machine", {})
        parts += [
            "",
            f"## {result['title']}",
            "",
            markdown_table(result["headers"], result["rows"]),
            "",
            result["notes"].strip(),
            "",
            f"*Measured {machine.get('date', '?')} on {cpu_label(machine)}"
            f"{'' if machine.get('cpu', {}).get('flags') else ', CPU flags not recorded'} "
            f"({machine.get('cpus_usable', '?')} of {machine.get('cpu_count', '?')} CPUs usable), "
            f"jax {machine.get('jax', '?')} ({machine.get('jax_backend', '?')}), "
            f"Python {machine.get('python', '?')}; "
            f"section took {result.get('wall_seconds', float('nan')):.0f} s.*",
        ]
    return "\n".join(parts) + "\n"


def stored_results() -> list[dict]:
    """Every stored section result (a JSON file of results/ holding :data:`REQUIRED_KEYS`; other
    evidence kept there, such as flat_env_cost.json, is no section of the README)."""
    results = [json.loads(path.read_text()) for path in sorted(RESULTS_DIR.glob("*.json"))]
    return [r for r in results if isinstance(r, dict) and all(key in r for key in REQUIRED_KEYS)]


def run_section(name: str, path: Path) -> dict:
    start = time.perf_counter()
    result = load_section(name, path).run()
    check_result(name, result)
    result = dict(result, machine=machine_info(), wall_seconds=round(time.perf_counter() - start, 1))
    RESULTS_DIR.mkdir(exist_ok=True)
    path = result_path(name, result["machine"])
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(result, indent=1) + "\n")
    tmp.replace(path)
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="benchmarks/run.py", description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", help="sections to run (default: all)")
    parser.add_argument("--list", action="store_true", help="print the section names and exit")
    args = parser.parse_args(argv)
    sections = discover()
    if args.list:
        print("\n".join(sections))
        return 0
    unknown = [name for name in args.names if name not in sections]
    if unknown:
        print(f"unknown benchmark {', '.join(unknown)}; choose from {', '.join(sections)}", file=sys.stderr)
        return 2
    failed = []
    for name in args.names or list(sections):
        print(f"== {name} ({sections[name].name})", flush=True)
        try:
            result = run_section(name, sections[name])
        except Exception:
            traceback.print_exc()
            print(f"== {name} FAILED", flush=True)
            failed.append(name)
            continue
        print(f"## {result['title']}  ({result['wall_seconds']:.0f} s)")
        print(markdown_table(result["headers"], result["rows"]))
        print(flush=True)
    README.write_text(render_readme(stored_results()))
    print(f"wrote {README}" + (f"; failed: {', '.join(failed)}" if failed else ""))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())

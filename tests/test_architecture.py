"""The layers' import direction (STYLE anti-pattern 6) and the one algorithm registry (pattern 14).

Imports are read with ``ast`` from every module under ``src/agentax``, those inside functions
included, so a lazy import that reaches up is caught as well as a top-level one. The algorithm
rules cover every module of :data:`agentax.agents.ALGORITHMS`, and each rule has a test feeding the
checker a module that breaks it.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import jax
import pytest

import agentax
from agentax.agents import (
    ALGORITHMS,
    algorithm,
    algorithm_config,
    config_from_dict,
    config_to_dict,
    presets_of,
)
from agentax.agents.presets import DEFAULT_PRESETS, PRESETS
from agentax.agents.protocol import ACTING_UNUSED, Agent, EnvSpec, acting_view
from agentax.cli import main
from agentax.runners import RUNNERS

PACKAGE_ROOT = Path(agentax.__file__).resolve().parent
RANKS: dict[str, int] = {
    "agentax.cli": 9,
    "agentax": 8,  # the package's __init__: the public names, from api
    "agentax.api": 8,
    "agentax.sweeps": 8,
    "agentax.runners": 7,
    "agentax.agents": 6,  # the registry, presets and the algorithms
    "agentax.search": 6,
    "agentax.tabular": 6,
    "agentax.agents.protocol": 5,
    "agentax.replay": 5,
    "agentax.runs": 5,
    "agentax.formats": 4,
    "agentax.curves": 5,
    "agentax.evaluate": 5,
    "agentax.render": 5,
    "agentax.report": 5,
    "agentax.nets": 4,
    "agentax.returns": 4,
    "agentax.normalize": 4,
    "agentax.policies": 4,
    "agentax.envs": 3,
    "agentax.kernels": 3,
    "agentax.kernel_choice": 3,
    "agentax.errors": 2,
    "agentax._xla": 2,
}
"""Every module's layer, top to bottom: a module imports only from its own layer or below (its own
layer only where the graph stays acyclic, checked apart). A module takes the rank of the longest
prefix naming it (``agentax.agents.ppo`` is ``agentax.agents``'s 6)."""
ALGORITHM_MODULES = tuple(entry.module for entry in ALGORITHMS.values())
"""Every registered algorithm's module: runners never import one, and no algorithm imports another
(shared pieces live in the blocks: nets, returns, policies, ``agents.off_policy``)."""
MAY_IMPORT_XLA = (
    "agentax",
    "agentax.api",
    "agentax.sweeps",
    "agentax.runners",
    "agentax.cli",
    "agentax.kernels",
    "agentax.kernel_choice",
)
"""The platform's workarounds (the CPU hang's cure, the compilation cache, the written-out loop for
XLA's convolutions) stay in the entry points, the runners and the kernels: no algorithm, env or
store shapes itself around a backend."""


def rank(module: str) -> int:
    """The layer of ``module`` (a ``KeyError`` for a module missing from :data:`RANKS`)."""
    parts = module.split(".")
    for end in range(len(parts), 0, -1):
        if ".".join(parts[:end]) in RANKS:
            return RANKS[".".join(parts[:end])]
    raise KeyError(f"{module} has no rank in RANKS; give it its layer")


def within(name: str, package: str) -> bool:
    """Whether module ``name`` is ``package`` or lies inside it."""
    return name == package or name.startswith(package + ".")


def module_name(path: Path, root: Path = PACKAGE_ROOT) -> str:
    """``.../agentax/agents/ppo.py`` → ``agentax.agents.ppo``; a package's ``__init__`` is the package."""
    parts = ["agentax", *path.relative_to(root).with_suffix("").parts]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def is_module(name: str) -> bool:
    """Whether ``name`` is a module or package of agentax (rather than a name defined in one)."""
    if not within(name, "agentax"):
        return False
    path = PACKAGE_ROOT.joinpath(*name.split(".")[1:])
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def imports_of(source: str, module: str, is_package: bool = False) -> list[tuple[int, str]]:
    """``(line, module)`` of every import in ``source``, at any depth. ``from P import x`` yields
    ``P.x`` where ``x`` is a submodule (``from agentax import train``), else ``P``; relative imports
    are resolved against ``module``."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                package = module.split(".") if is_package else module.split(".")[:-1]
                anchor = package[: len(package) - (node.level - 1)]
                base = ".".join([*anchor, base] if base else anchor)
            names = [f"{base}.{alias.name}" for alias in node.names]
            submodules = [name for name in names if is_module(name)]
            found += [(node.lineno, name) for name in submodules]
            if len(submodules) < len(names):
                found.append((node.lineno, base))
    return found


def algorithm_of(module: str) -> str | None:
    """The registered algorithm module ``module`` is or lies in (None for any other)."""
    return next((m for m in ALGORITHM_MODULES if within(module, m)), None)


def rule_broken(module: str, imported: str) -> str | None:
    """Why ``module`` may not import ``imported`` (None if it may)."""
    if algorithm_of(module) and within(imported, "tyro"):
        return "an algorithm imports tyro (its CLI flags live in the CLI)"
    if not within(imported, "agentax"):
        return None
    if rank(imported) > rank(module):
        return f"layer {rank(module)} imports layer {rank(imported)}"
    if within(module, "agentax.runners") and algorithm_of(imported):
        return "a runner imports an algorithm module (runners see agents through the protocol)"
    if algorithm_of(module) and algorithm_of(imported) not in (None, algorithm_of(module)):
        return "an algorithm imports another algorithm (move the shared piece into a block)"
    if algorithm_of(module) and within(imported, "agentax.agents.presets"):
        return "an algorithm imports the presets (which import the algorithms' configs: a cycle)"
    if (
        within(imported, "agentax._xla")
        and not any(module == m or within(module, m) for m in MAY_IMPORT_XLA if m != "agentax")
        and module != "agentax"
    ):
        return "a platform workaround (_xla) outside the entry points and runners"
    return None


def import_graph(sources: dict[str, tuple[str, bool]]) -> dict[str, set[str]]:
    """``module -> modules it imports`` among ``sources`` (``module -> (source, is_package)``)."""
    return {
        module: {imported for _, imported in imports_of(source, module, is_package) if imported in sources}
        - {module}
        for module, (source, is_package) in sources.items()
    }


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of ``graph`` with more than one module (Tarjan), sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for successor in sorted(graph[node]):
            if successor not in index:
                visit(successor)
                low[node] = min(low[node], low[successor])
            elif successor in on_stack:
                low[node] = min(low[node], index[successor])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return sorted(found)


def package_sources() -> dict[str, tuple[str, bool]]:
    paths = sorted(PACKAGE_ROOT.rglob("*.py"))
    assert len(paths) > 30, paths  # the whole package was found, not an empty folder
    return {module_name(path): (path.read_text(), path.name == "__init__.py") for path in paths}


def violations(source: str, module: str, filename: str, is_package: bool = False) -> list[str]:
    return [
        f"{filename}:{line}: {module} imports {imported} ({why})"
        for line, imported in imports_of(source, module, is_package)
        if (why := rule_broken(module, imported))
    ]


def test_every_module_has_a_rank_and_imports_only_downwards():
    found = []
    for module, (source, is_package) in package_sources().items():
        found += violations(source, module, module, is_package)
    assert not found, "layers reaching up:\n" + "\n".join(found)


def test_no_import_cycle():
    """No cycle among agentax's modules, function-local imports included: a lazy import that closes a
    loop hides it from Python's import order, not from the graph (STYLE anti-pattern 7)."""
    assert cycles(import_graph(package_sources())) == []


def test_the_checker_catches_violations():
    """The rules above fire on synthetic sources (so the tests above can fail)."""
    agent_source = "import jax\n\ndef f():\n    from agentax.runners import host\n    return host\n"
    assert violations(agent_source, "agentax.agents.ppo", "ppo.py") == [
        "ppo.py:4: agentax.agents.ppo imports agentax.runners.host (layer 6 imports layer 7)"
    ]
    assert violations("from agentax import runners\n", "agentax.runs", "runs.py")  # the store reaching up
    assert violations("import agentax.evaluate\n", "agentax.envs.cartpole", "c.py")
    assert violations("from agentax.policies import Policy\n", "agentax.envs.vacuum", "v.py")
    assert violations("from ..agents import ppo\n", "agentax.envs.gym", "g.py")  # relative, resolved
    assert violations("from agentax.agents import ppo\n", "agentax.replay.uniform", "u.py")
    assert violations("from agentax.api import train\n", "agentax.runners", "r.py", is_package=True)
    assert violations("import agentax.cli.train\n", "agentax.runners.host", "h.py")
    assert violations("from agentax.agents.dqn import DQNConfig\n", "agentax.runners.host", "h.py") == [
        "h.py:1: agentax.runners.host imports agentax.agents.dqn "
        "(a runner imports an algorithm module (runners see agents through the protocol))"
    ]
    assert violations("from agentax import _xla\n", "agentax.agents.ppo", "ppo.py")
    assert violations("from agentax import _xla\n", "agentax.runs", "runs.py")
    assert violations("import tyro\n", "agentax.agents.sac", "sac.py") == [
        "sac.py:1: agentax.agents.sac imports tyro "
        "(an algorithm imports tyro (its CLI flags live in the CLI))"
    ]
    assert violations("from agentax.agents.presets import PRESETS\n", "agentax.agents.ppo", "ppo.py")
    with pytest.raises(KeyError, match="no rank"):
        rank("elsewhere.module")
    # what is allowed stays allowed
    assert violations("from agentax.agents.protocol import Agent\n", "agentax.replay.core", "r.py") == []
    assert violations("from agentax import agents\n", "agentax.agents.ppo", "ppo.py") == []
    assert violations("from agentax.runners import host\n", "agentax.cli.train", "t.py") == []
    assert violations("from agentax.envs.core import Box\n", "agentax.nets", "n.py") == []
    assert violations("from agentax import _xla\n", "agentax.runners.host", "h.py") == []
    assert violations("from agentax.api import train\n", "agentax", "__init__.py", is_package=True) == []
    assert violations("from agentax.agents.off_policy import warm_up\n", "agentax.agents.td3", "t.py") == []
    assert violations("from agentax.agents import presets\n", "agentax.cli.train", "t.py") == []


@pytest.mark.parametrize("name", list(ALGORITHMS))
def test_the_checker_catches_an_algorithm_importing_another(name):
    """For every registered algorithm: importing any other registered algorithm (top level or inside
    a function, by either import form) is reported; importing itself and the blocks is not."""
    module = ALGORITHMS[name].module
    assert module in package_sources(), f"{module} (registered as {name}) is not a module of agentax"
    for other in (entry.module for other_name, entry in ALGORITHMS.items() if other_name != name):
        package, leaf = other.rsplit(".", 1)
        for source in (f"from {other} import make_agent\n", f"def f():\n    from {package} import {leaf}\n"):
            assert [v.split(" (", 1)[1] for v in violations(source, module, "m.py")] == [
                "an algorithm imports another algorithm (move the shared piece into a block))"
            ], (name, source)
    allowed = f"from {module} import make_agent\nfrom agentax.returns import bootstrap_discount\n"
    assert violations(allowed, module, "m.py") == []


COMPARISONS = (ast.Eq, ast.NotEq, ast.In, ast.NotIn)


def _strings(node: ast.AST) -> list[str]:
    """The string literals ``node`` is, or holds as a tuple, list or set display."""
    items = node.elts if isinstance(node, ast.Tuple | ast.List | ast.Set) else [node]
    return [item.value for item in items if isinstance(item, ast.Constant) and isinstance(item.value, str)]


def runner_name_branches(source: str, filename: str) -> list[str]:
    """``file:line`` of every ``==``, ``!=``, ``in`` or ``not in`` with a runner kind's name
    (a key of :data:`agentax.runners.RUNNERS`) as a literal on either side."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.Compare):
            continue
        operands = [node.left, *node.comparators]
        for op, left, right in zip(node.ops, operands[:-1], operands[1:], strict=True):
            names = [n for n in _strings(left) + _strings(right) if n in RUNNERS]
            if isinstance(op, COMPARISONS) and names:
                found.append(f"{filename}:{node.lineno}: compares with {', '.join(map(repr, names))}")
    return found


def test_only_the_runners_table_branches_on_a_runner_name():
    """Adding a runner is a row of :data:`agentax.runners.RUNNERS` (and its launcher): no other module
    picks behaviour by comparing a kind's name. The run-folder migrations (``formats.py``) may: they
    describe folders as older versions wrote them, whatever the table holds today."""
    exempt = {PACKAGE_ROOT / "runners" / "__init__.py", PACKAGE_ROOT / "formats.py"}
    found = []
    for path in sorted(PACKAGE_ROOT.rglob("*.py")):
        if path not in exempt:
            found += runner_name_branches(path.read_text(), str(path.relative_to(PACKAGE_ROOT.parent)))
    assert not found, "branches on a runner's name outside the table:\n" + "\n".join(found)


def test_the_runner_name_checker_catches_branches():
    source = (
        'if kind == "compiled":\n    pass\n'
        'ok = kind in ("parallel", "ray")\n'
        'x = "compiled-atari" != kind\n'
        'y = kind not in ["host"]\n'
        'z = a < b == "ray"\n'
    )
    assert runner_name_branches(source, "m.py") == [
        "m.py:1: compares with 'compiled'",
        "m.py:3: compares with 'parallel', 'ray'",
        "m.py:4: compares with 'compiled-atari'",
        "m.py:5: compares with 'host'",
        "m.py:6: compares with 'ray'",
    ]
    # names used as data, and other strings compared, pass
    allowed = (
        'run_config("ppo", env, "p", "compiled", r, c)\nif choice == "auto":\n    pass\nd = {"host": 1}\n'
    )
    assert runner_name_branches(allowed, "m.py") == []


def test_the_cycle_check_finds_cycles_closed_by_a_lazy_import():
    sources = {
        "agentax.runs": ("def load():\n    from agentax.runners import host\n", False),
        "agentax.runners.host": ("from agentax.runs import Run\n", False),
        "agentax.replay.frames": ("from agentax.replay.host import Dataset\n", False),
        "agentax.replay.host": ("def save():\n    from agentax.replay import frames\n", False),
        "agentax.replay": ("", True),
        "agentax.envs.core": ("", False),
        "agentax.policies": ("from agentax.envs.core import Box\n", False),
    }
    assert cycles(import_graph(sources)) == [
        ["agentax.replay.frames", "agentax.replay.host"],
        ["agentax.runners.host", "agentax.runs"],
    ]
    del sources["agentax.runs"]
    assert cycles(import_graph(sources)) == [["agentax.replay.frames", "agentax.replay.host"]]


def test_module_names_and_relative_imports_resolve():
    root = Path("/x/agentax")
    assert module_name(root / "agents" / "ppo.py", root) == "agentax.agents.ppo"
    assert module_name(root / "replay" / "__init__.py", root) == "agentax.replay"
    assert imports_of("from .core import Box\n", "agentax.envs.gym") == [(1, "agentax.envs.core")]
    assert imports_of("from . import nstep\n", "agentax.replay", is_package=True) == [
        (1, "agentax.replay.nstep")
    ]
    assert imports_of("from agentax.agents import ALGORITHMS, ppo\n", "agentax.cli.train") == [
        (1, "agentax.agents.ppo"),
        (1, "agentax.agents"),
    ]


@pytest.mark.slow
@pytest.mark.parametrize("name", list(ALGORITHMS))
def test_every_registered_algorithm_follows_the_protocol(name):
    module = algorithm(name)
    presets = presets_of(name)
    assert "default" in presets, f"{name} has no default preset"
    for preset_name, preset in presets.items():
        cfg = preset.config
        assert type(cfg) is algorithm_config(name), (name, preset_name)
        assert config_from_dict(algorithm_config(name), config_to_dict(cfg)) == cfg, (name, preset_name)
        assert cfg.total_steps > 0
    for default_preset in DEFAULT_PRESETS.get(name, {}).values():
        assert default_preset in presets
    from agentax.envs import make_host_env

    continuous_only = name in ("sac", "td3")  # the others take CartPole's discrete actions
    env = make_host_env("Pendulum-v1" if continuous_only else "CartPole-v1", 1)
    spec = EnvSpec.of(env)
    agent = module.make_agent(spec, presets["default"].config)
    env.close()
    assert isinstance(agent, Agent) and agent.name == name
    # act reads only what acting_view keeps (the ray runner sends actors that and nothing more)
    state = agent.init(jax.random.key(0))
    view = acting_view(state)
    dropped = [n for n in ACTING_UNUSED if hasattr(state, n)]
    assert dropped and all(getattr(view, n) is None for n in dropped), dropped
    obs = jax.random.uniform(jax.random.key(1), (3, *spec.obs_shape))
    for progress in (0, 10_000):
        full = agent.act(state, obs, jax.random.key(2), progress)
        assert jax.tree.all(
            jax.tree.map(
                lambda a, b: bool((a == b).all()), full, agent.act(view, obs, jax.random.key(2), progress)
            )
        )


def test_presets_cover_the_registry_and_no_algorithm_imports_them_or_tyro():
    """The tuned configs live in agents/presets.py, which imports the algorithms' configs (an
    algorithm module importing it back would close a cycle); CLI flags and aliases live in the CLI."""
    assert list(PRESETS) == list(ALGORITHMS) and set(DEFAULT_PRESETS) <= set(ALGORITHMS)
    assert PRESETS["reinforce"]["lecture"] is PRESETS["reinforce"]["default"]  # one config, two names
    # the import rules (rule_broken, checked for every module above) cover every registered algorithm
    assert set(ALGORITHM_MODULES) == {entry.module for entry in ALGORITHMS.values()} <= set(package_sources())


def test_train_help_lists_exactly_the_registered_algorithms(capsys):
    assert main(["train", "--help"]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("algorithms:")]
    assert len(lines) == 1, lines
    listed = lines[0].removeprefix("algorithms:").split("(")[0]
    assert [n.strip() for n in listed.split(",")] == list(ALGORITHMS)


def markdown_blocks(text: str) -> list[tuple[int, str]]:
    """``(first line, text)`` of each paragraph, list item, table row or heading of ``text``
    (a wrapped paragraph or item joined into one)."""
    blocks: list[tuple[int, str]] = []
    starts = re.compile(r"\s*(?:[-*|#]|\d+\.)\s")
    for number, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        if blocks and blocks[-1][0] + blocks[-1][1].count("\n") == number - 1 and not starts.match(line):
            blocks[-1] = (blocks[-1][0], blocks[-1][1] + "\n" + line)
        else:
            blocks.append((number, line))
    return blocks


def partial_algorithm_lists(text: str, filename: str) -> list[str]:
    """``file:line: ...`` of every paragraph, item or row that lists registered algorithms, three or
    more of their names in code font (`ppo`), without naming all of them."""
    found = []
    for number, block in markdown_blocks(text):
        named = [name for name in ALGORITHMS if f"`{name}`" in block]
        if 3 <= len(named) < len(ALGORITHMS):
            missing = [name for name in ALGORITHMS if name not in named]
            found.append(f"{filename}:{number}: lists {', '.join(named)} without {', '.join(missing)}")
    return found


def test_the_docs_list_every_registered_algorithm():
    """A list of the algorithms in the README or docs names every one of the registry's."""
    root = PACKAGE_ROOT.parents[1]
    pages = [root / "README.md", *sorted((root / "docs").rglob("*.md"))]
    assert len(pages) > 5, pages
    found = []
    for page in pages:
        found += partial_algorithm_lists(page.read_text(), str(page.relative_to(root)))
    assert not found, "algorithm lists missing registered algorithms:\n" + "\n".join(found)


def test_the_docs_list_check_catches_a_stale_list():
    names = [f"`{name}`" for name in ALGORITHMS]
    stale = (
        f"Every algorithm ({', '.join(names[:3])}) offers\n\n"
        f"- all: {' '.join(names[:3])}\n  and {' '.join(names[3:])}, wrapped\n"
        f"- only {' or '.join(names[:2])}\n| row | {', '.join(names[1:])} |\n"
    )
    assert partial_algorithm_lists(stale, "d.md") == [
        f"d.md:1: lists {', '.join(list(ALGORITHMS)[:3])} without {', '.join(list(ALGORITHMS)[3:])}",
        f"d.md:6: lists {', '.join(list(ALGORITHMS)[1:])} without {list(ALGORITHMS)[0]}",
    ]


# ---------------------------------------------------------------- the runner module contract

RUNNER_CONTRACT: dict[str, tuple[str, ...]] = {
    "configure": ("run_args", "agent", "preset"),
    "train": ("agent", "env_id", "runner", "run"),
    "restore": ("run_dir", "config", "agent"),
}
"""The functions every runner module (a row of :data:`agentax.runners.RUNNERS`) exports, by their
positional parameters (:mod:`agentax.runners.launch` calls them so); ``train`` also takes the
keywords ``resume`` and ``progress``, and any further parameter of it is keyword-only."""


def runner_contract_violations(module) -> list[str]:
    """What ``module`` lacks of the runner contract: a ``Config`` dataclass and the functions of
    :data:`RUNNER_CONTRACT` with their parameters."""
    import dataclasses
    import inspect

    name = module.__name__
    found = []
    config = getattr(module, "Config", None)
    if not (isinstance(config, type) and dataclasses.is_dataclass(config)):
        found.append(f"{name}: no Config dataclass")
    for function, wanted in RUNNER_CONTRACT.items():
        fn = getattr(module, function, None)
        if not callable(fn):
            found.append(f"{name}: no {function}()")
            continue
        parameters = inspect.signature(fn).parameters.values()
        positional = [p.name for p in parameters if p.kind is inspect.Parameter.POSITIONAL_OR_KEYWORD]
        if positional != list(wanted):
            found.append(f"{name}.{function} takes ({', '.join(positional)}), not ({', '.join(wanted)})")
        if function == "train":
            keywords = {p.name: p for p in parameters if p.kind is inspect.Parameter.KEYWORD_ONLY}
            for flag in ("resume", "progress"):
                if keywords.get(flag) is None or keywords[flag].default is not False:
                    found.append(f"{name}.train has no keyword {flag}=False")
            if positional[-1:] == ["run"] and fn.__defaults__ != (None,):
                found.append(f"{name}.train's run is not optional (None)")
    return found


@pytest.mark.parametrize("kind", list(RUNNERS))
def test_every_runner_row_names_a_module_that_keeps_the_contract(kind):
    module = RUNNERS[kind].load()
    assert runner_contract_violations(module) == []
    assert RUNNERS[kind].chosen_as in ("compiled", "host", "parallel", "ray")


@pytest.mark.parametrize("kind", ["compiled", "compiled-atari"])
def test_a_compiled_runners_config_is_no_other_runners(kind):
    """The compiled runners' settings are their own classes, not a host runner's config extended."""
    others = {RUNNERS[k].load().Config for k in RUNNERS if RUNNERS[k].module != RUNNERS[kind].module}
    assert not others & set(RUNNERS[kind].load().Config.__mro__[1:])


def test_the_runner_contract_check_catches_a_module_that_breaks_it():
    import dataclasses
    import types

    fake = types.ModuleType("fake_runner")
    fake.Config = type("Config", (), {})  # not a dataclass
    fake.configure = lambda run_args, agent: None  # no preset
    fake.train = lambda agent, env_id, runner, run=None, resume=False, progress=False: (
        None
    )  # flags positional
    assert runner_contract_violations(fake) == [
        "fake_runner: no Config dataclass",
        "fake_runner.configure takes (run_args, agent), not (run_args, agent, preset)",
        "fake_runner.train takes (agent, env_id, runner, run, resume, progress), "
        "not (agent, env_id, runner, run)",
        "fake_runner.train has no keyword resume=False",
        "fake_runner.train has no keyword progress=False",
        "fake_runner: no restore()",
    ]
    fake.Config = dataclasses.make_dataclass("Config", [("seed", int, 0)])
    fake.configure = lambda run_args, agent, preset: None
    fake.restore = lambda run_dir, config, agent: None

    def train(agent, env_id, runner, run=None, *, resume=False, progress=False):
        return None

    fake.train = train
    assert runner_contract_violations(fake) == []

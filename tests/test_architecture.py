"""The layers' import direction (STYLE anti-pattern 6) and the one algorithm registry (pattern 14).

Imports are read with ``ast`` from every module under ``src/agentax``, those inside functions
included, so a lazy import that reaches up is caught as well as a top-level one.
"""

from __future__ import annotations

import ast
from pathlib import Path

import jax
import pytest

import agentax
from agentax.agents import ALGORITHMS, algorithm
from agentax.agents.protocol import ACTING_UNUSED, Agent, EnvSpec, acting_view
from agentax.cli import main

PACKAGE_ROOT = Path(agentax.__file__).resolve().parent
LEAVES = (
    "agentax.nets",
    "agentax.returns",
    "agentax.policies",
    "agentax.errors",
    "agentax.replay",
    "agentax.agents.protocol",
)
LEAF_MAY_NOT_IMPORT = ("agentax.agents", "agentax.train", "agentax.runs", "agentax.evaluate", "agentax.cli")


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


def rule_broken(module: str, imported: str) -> str | None:
    """Why ``module`` may not import ``imported`` (None if it may)."""
    if not within(imported, "agentax"):
        return None
    if within(module, "agentax.agents") and any(
        within(imported, p) for p in ("agentax.train", "agentax.cli", "agentax.runs")
    ):
        return "an agent imports a runner, the CLI or the run folder"
    if within(module, "agentax.envs") and any(
        within(imported, p)
        for p in (
            "agentax.evaluate",
            "agentax.runs",
            "agentax.agents",
            "agentax.train",
            "agentax.search",
            "agentax.cli",
        )
    ):
        return "an env imports evaluation, agents, runners, search, runs or the CLI"
    if any(within(module, leaf) for leaf in LEAVES):
        if not within(imported, "agentax.agents.protocol") and any(
            within(imported, p) for p in LEAF_MAY_NOT_IMPORT
        ):
            return "a leaf module imports agents, runners, runs, evaluation or the CLI"
    if within(imported, "agentax.cli") and not within(module, "agentax.cli"):
        return "a module outside agentax.cli imports the CLI"
    return None


def violations(source: str, module: str, filename: str, is_package: bool = False) -> list[str]:
    return [
        f"{filename}:{line}: {module} imports {imported} ({why})"
        for line, imported in imports_of(source, module, is_package)
        if (why := rule_broken(module, imported))
    ]


def test_every_module_imports_only_downwards():
    paths = sorted(PACKAGE_ROOT.rglob("*.py"))
    assert len(paths) > 30, paths  # the whole package was found, not an empty folder
    found = []
    for path in paths:
        module = module_name(path)
        found += violations(path.read_text(), module, str(path), is_package=path.name == "__init__.py")
    assert not found, "layers reaching up:\n" + "\n".join(found)


def test_the_checker_catches_violations():
    """The rules above fire on synthetic sources (so the test above can fail)."""
    agent_source = "import jax\n\ndef f():\n    from agentax.train import host\n    return host\n"
    assert violations(agent_source, "agentax.agents.ppo", "ppo.py") == [
        "ppo.py:4: agentax.agents.ppo imports agentax.train.host "
        "(an agent imports a runner, the CLI or the run folder)"
    ]
    assert violations("from agentax import runs\n", "agentax.agents.dqn", "dqn.py")
    assert violations("import agentax.evaluate\n", "agentax.envs.cartpole", "c.py")
    assert violations("from agentax import agents\n", "agentax.envs.gym", "g.py")
    assert violations("from ..agents import ppo\n", "agentax.envs.gym", "g.py")  # relative, resolved
    assert violations("from agentax.agents import ppo\n", "agentax.replay.uniform", "u.py")
    assert violations("from agentax.train.host import Actor\n", "agentax.agents.protocol", "p.py")
    assert violations("from . import train\n", "agentax", "__init__.py", is_package=True) == []
    assert violations("import agentax.cli.train\n", "agentax.train.host", "h.py")
    # what is allowed stays allowed
    assert violations("from agentax.agents.protocol import Agent\n", "agentax.replay.core", "r.py") == []
    assert violations("from agentax.agents import protocol\n", "agentax.replay.core", "r.py") == []
    assert violations("from agentax import agents\n", "agentax.agents.ppo", "ppo.py") == []
    assert violations("from agentax.train import host\n", "agentax.cli.train", "t.py") == []
    assert violations("from agentax.envs.core import Box\n", "agentax.nets", "n.py") == []


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


@pytest.mark.parametrize("name", list(ALGORITHMS))
def test_every_registered_algorithm_follows_the_protocol(name):
    module = algorithm(name)
    assert "default" in module.PRESETS, f"{name} has no default preset"
    for preset_name, preset in module.PRESETS.items():
        cfg = preset.config
        assert module.config_from_dict(module.config_to_dict(cfg)) == cfg, (name, preset_name)
        assert cfg.total_steps > 0
    for default_preset in getattr(module, "DEFAULT_PRESETS", {}).values():
        assert default_preset in module.PRESETS
    assert callable(module.make_train)
    from agentax.train.host import make_host_env

    env = make_host_env("CartPole-v1", 1)
    agent = module.make_agent(EnvSpec.of(env), module.PRESETS["default"].config)
    env.close()
    assert isinstance(agent, Agent) and agent.name == name
    # act reads only what acting_view keeps (the ray runner sends actors that and nothing more)
    state = agent.init(jax.random.key(0))
    view = acting_view(state)
    dropped = [n for n in ACTING_UNUSED if hasattr(state, n)]
    assert dropped and all(getattr(view, n) is None for n in dropped), dropped
    obs = jax.random.uniform(jax.random.key(1), (3, 4))
    for progress in (0, 10_000):
        full = agent.act(state, obs, jax.random.key(2), progress)
        assert jax.tree.all(
            jax.tree.map(
                lambda a, b: bool((a == b).all()), full, agent.act(view, obs, jax.random.key(2), progress)
            )
        )


def test_train_help_lists_exactly_the_registered_algorithms(capsys):
    assert main(["train", "--help"]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("algorithms:")]
    assert len(lines) == 1, lines
    listed = lines[0].removeprefix("algorithms:").split("(")[0]
    assert [n.strip() for n in listed.split(",")] == list(ALGORITHMS)

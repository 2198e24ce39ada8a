"""A trained policy outside agentax: one pure function of the env's observations, written as an ONNX
file (jax2onnx, run by onnxruntime) or a serialized StableHLO module (``jax.export``), with a model
card beside it (``FILE.json``).

The exported function takes a batch of observations exactly as agentax's env gives them to the agent
and returns what the env takes:

- greedy (the default): ``action = f(obs)``, ``obs [N, *obs_shape]`` in the env's observation dtype
  (float32 for CartPole and Pendulum, uint8 ``[N, 4, 84, 84]`` stacked frames for Atari) →
  ``action [N]`` int32 (discrete) or ``[N, action_dim]`` float32 (continuous, already clipped or
  rescaled to the action space's bounds, as the agent's evaluation sends it);
- ``stochastic`` (StableHLO only): ``action = f(obs, key)`` with ``key uint32[2]``, the data of a
  threefry key (``jax.random.key_data(jax.random.key(seed))``), split into one key per row: the
  agent's collect policy (``act``, at the end of its exploration schedule) then ``env_action``.

Where the env's observations are composite (a Dict or Tuple, an action mask, Discrete states, an
image ``[H, W, C]``), agentax packs them into one flat vector (:mod:`agentax.envs.spaces`) and the
file takes that packed vector, mask included, so it acts only among the legal actions it is given.
The model card's ``layout`` (and the ONNX file's metadata entry ``agentax_layout``, the same JSON)
says where each leaf lies in it: :attr:`Exported.layout` packs a batch of observations as the env
gives them (``exported.run(exported.layout.pack(obs))``), and docs/howto/spaces.md shows how to pack
by hand without agentax.

What lies between the env's observation and the network (casts, the Nature CNN's division by 255,
normalization statistics an agent keeps in its state) is inside the file, because the function is
the agent's own ``greedy_policy(state)`` (or ``act``) closed over the trained state: nothing here
knows an algorithm, so every agent of the protocol exports (PPO's categorical and Gaussian heads,
DQN's and PQN's greedy Q, REINFORCE, and later ones). What the env itself does before it hands
out an observation (Atari's frame skip, grey scale, resize and frame stack) stays the env's.

How: the one-observation policy is traced to a jaxpr of ``lax`` primitives first, then vmapped over
the batch. (jax2onnx swaps flax's linen layers for primitives of its own while it traces, and those
have no batching rule; traced beforehand, it never sees a flax layer.) The policy must be built on
XLA's convolutions and products (the backend ``xla``, which the exporting entry point hands to the
agent): oneDNN's FFI calls exist in neither format.
ONNX gets no stochastic head: its random operators take their seed as a fixed attribute of the
graph, not as an input, so a key could not drive them.

A recurrent policy (``--core``: PPO, PQN, REINFORCE) exports as ``(action, next_state) = f(obs, state)``:
``state [N, S]`` float32 is its core's carry, flat (LSTM: ``c`` then ``h``, ``S = 2 * core_size``;
GRU: ``h``, ``S = core_size``), zeros at an episode's start, and ``next_state`` is what the caller
feeds back as the next step's ``state`` (zeros again where the next observation starts an episode,
as the agent's own evaluation resets its carry). One flat tensor rather than one input per part:
a caller carries one array per env whatever the core, and the card's ``state`` names the parts.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import logging
from collections.abc import Callable
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from agentax.agents.protocol import Agent, AgentState
from agentax.envs import Box, Discrete, make
from agentax.envs.core import RecurrentPolicy
from agentax.envs.spaces import Layout, Leaf, MultiBinary, MultiDiscrete
from agentax.errors import UsageError
from agentax.policies import Policy
from agentax.runs import read_json, write_atomic, write_json

FORMATS: dict[str, str] = {"onnx": ".onnx", "stablehlo": ".stablehlo"}
"""Each format and the suffix of its files."""
OBS, KEY, ACTION = "obs", "key", "action"
"""The names of the exported function's inputs and output."""
STATE, NEXT_STATE = "state", "next_state"
"""The names of a recurrent policy's state input and output (its core's carry, flat)."""
BATCH = "N"
"""The name of the batch dimension (any size at run time)."""
EXTRA = "pip install 'agentax[export]' && pip install --no-deps jax2onnx==0.17.1"
"""What installs the ONNX exporter (jax2onnx without its declared orbax and hub dependencies, as
``make`` does: its orbax pin is older than flax's and its conversion imports neither)."""
STABLEHLO_PLATFORMS = ("cpu", "cuda")
"""Where the StableHLO module runs (one lowering per platform, chosen when it is called)."""


# The policy as one batched function.


def check_format(format: str, stochastic: bool = False) -> str:
    """``format`` if it is one of :data:`FORMATS` and can hold the asked head, else a ``UsageError``;
    for ONNX, also a ``UsageError`` naming the extra where jax2onnx or onnxruntime is missing."""
    if format not in FORMATS:
        raise UsageError(f"unknown export format {format!r}; choose from {', '.join(FORMATS)}")
    if format == "onnx" and stochastic:
        raise UsageError(
            "--stochastic needs a key input, which ONNX's random operators cannot take (their seed is "
            "fixed in the graph): export it with --format stablehlo, or the greedy policy to ONNX"
        )
    if format == "onnx":
        for module in ("jax2onnx", "onnxruntime"):
            try:
                importlib.import_module(module)
            except ImportError as error:
                raise UsageError(f"ONNX export needs {module} ({error}); install it: {EXTRA}") from None
    return format


def sampling_policy(agent: Agent) -> Callable[[AgentState], Policy]:
    """``state -> policy(obs, key)``: ``agent.act`` on one observation at the end of the agent's
    exploration schedule (DQN's final ε), then ``agent.env_action`` (PPO's clip to the bounds)."""
    progress = jnp.int32(agent.total_steps)

    def policy_of(state: AgentState) -> Policy:
        def policy(obs: jax.Array, key: jax.Array) -> jax.Array:
            action, _ = agent.act(state, obs[None], key, progress)
            return agent.env_action(action[0])

        return policy

    return policy_of


@dataclasses.dataclass(frozen=True)
class SamplingAlgorithm:
    """An algorithm module whose agents answer ``greedy_policy`` with their sampling head, so that
    a run folder restores its stochastic policy through the same path as its greedy one."""

    module: Any

    def make_agent(self, spec: Any, cfg: Any, **options: Any) -> Agent:
        agent = self.module.make_agent(spec, cfg, **options)
        return dataclasses.replace(agent, greedy_policy=sampling_policy(agent))


def batched(
    policy: Policy, obs: jax.ShapeDtypeStruct, stochastic: bool = False
) -> tuple[Callable[..., jax.Array], jax.ShapeDtypeStruct]:
    """``(f, action)``: ``f(obs [N, *obs_shape])`` (``f(obs, key uint32[2])`` when ``stochastic``)
    → ``[N, *action_shape]``, and one action's shape and dtype.

    ``policy(obs, key)`` acts on one observation; it is traced once at ``obs`` to ``lax`` primitives
    (see the module docstring). The greedy function passes a constant key (greedy policies ignore
    theirs); the stochastic one splits ``key`` into ``N``, one per row.
    """
    key_data = jax.ShapeDtypeStruct((2,), jnp.uint32)
    closed, action = jax.make_jaxpr(lambda o, k: policy(o, jax.random.wrap_key_data(k)), return_shape=True)(
        obs, key_data
    )

    def one(obs: jax.Array, key_data: jax.Array) -> jax.Array:
        return jax.core.eval_jaxpr(closed.jaxpr, closed.consts, obs, key_data)[0]

    if stochastic:

        def f(obs: jax.Array, key: jax.Array) -> jax.Array:
            keys = jax.random.split(jax.random.wrap_key_data(key), obs.shape[0])
            return jax.vmap(one)(obs, jax.random.key_data(keys))

    else:

        def f(obs: jax.Array) -> jax.Array:
            return jax.vmap(one, in_axes=(0, None))(obs, jnp.zeros(2, jnp.uint32))

    return f, action


def batched_recurrent(
    policy: RecurrentPolicy, obs: jax.ShapeDtypeStruct
) -> tuple[Callable[..., tuple[jax.Array, jax.Array]], jax.ShapeDtypeStruct, jax.ShapeDtypeStruct]:
    """``(f, action, state)``: ``f(obs [N, *obs_shape], state [N, S]) -> (action [N, ...], next_state
    [N, S])``, one action's and one state's shape and dtype.

    The policy's memory (a pytree, zeros at an episode's start) travels flat, its leaves raveled in
    order (LSTM ``(c, h)``: ``[c, h]``); ``policy.step`` is traced once to ``lax`` primitives, as in
    :func:`batched`, then vmapped over obs and state together, with a constant key.
    """
    initial, unravel = ravel_pytree(policy.initial())
    state = jax.ShapeDtypeStruct(initial.shape, initial.dtype)
    key_data = jax.ShapeDtypeStruct((2,), jnp.uint32)

    def flat_step(obs: jax.Array, state: jax.Array, key_data: jax.Array) -> tuple[jax.Array, jax.Array]:
        memory, action = policy.step(unravel(state), obs, jax.random.wrap_key_data(key_data))
        return action, ravel_pytree(memory)[0]

    closed, (action, _) = jax.make_jaxpr(flat_step, return_shape=True)(obs, state, key_data)

    def one(obs: jax.Array, state: jax.Array, key_data: jax.Array) -> tuple[jax.Array, jax.Array]:
        action, next_state = jax.core.eval_jaxpr(closed.jaxpr, closed.consts, obs, state, key_data)
        return action, next_state

    def f(obs: jax.Array, state: jax.Array) -> tuple[jax.Array, jax.Array]:
        return jax.vmap(one, in_axes=(0, 0, None))(obs, state, jnp.zeros(2, jnp.uint32))

    return f, action, state


def to_onnx(
    f: Callable,
    obs: jax.ShapeDtypeStruct,
    name: str = "agentax_policy",
    metadata: dict[str, str] | None = None,
    state: jax.ShapeDtypeStruct | None = None,
) -> bytes:
    """The ONNX model (opset jax2onnx's default) of the greedy ``f``, input ``obs`` ``[N, ...]`` (and
    ``state`` ``[N, S]`` with output ``next_state`` for a recurrent ``f``, given ``state``'s one-row
    spec); ``metadata``: entries of the model's ``metadata_props`` (what onnxruntime's
    ``custom_metadata_map`` reads back)."""
    from jax2onnx import to_onnx as convert

    specs = [jax.ShapeDtypeStruct((BATCH, *s.shape), s.dtype) for s in (obs, state) if s is not None]
    inputs, outputs = ([OBS, STATE], [ACTION, NEXT_STATE]) if state is not None else ([OBS], [ACTION])
    serde = logging.getLogger("onnx_ir.serde")  # warns of shape constants it leaves untyped: harmless
    level = serde.level
    serde.setLevel(logging.ERROR)
    try:
        model = convert(f, specs, model_name=name, input_names=inputs, output_names=outputs)
    finally:
        serde.setLevel(level)
    for key, value in (metadata or {}).items():
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    return model.SerializeToString()


def to_stablehlo(
    f: Callable,
    obs: jax.ShapeDtypeStruct,
    stochastic: bool = False,
    state: jax.ShapeDtypeStruct | None = None,
) -> bytes:
    """``jax.export``'s serialized module of ``f`` for :data:`STABLEHLO_PLATFORMS`, batch symbolic
    (a recurrent ``f``'s second argument ``state [N, S]``, given its one-row spec)."""
    (n,) = jax.export.symbolic_shape(BATCH)
    args = [jax.ShapeDtypeStruct((n, *s.shape), s.dtype) for s in (obs, state) if s is not None]
    if stochastic:
        args.append(jax.ShapeDtypeStruct((2,), jnp.uint32))
    exported = jax.export.export(jax.jit(f), platforms=STABLEHLO_PLATFORMS)(*args)
    return bytes(exported.serialize())


# The model card.


def space_card(space: Any) -> dict[str, Any]:
    """A space as JSON: ``{"type": "Discrete", "n"}``, ``{"type": "MultiDiscrete", "nvec"}``,
    ``{"type": "MultiBinary", "n"}`` or ``{"type": "Box", "shape", "dtype", "low", "high"}`` (a
    bound equal everywhere as one number)."""
    if isinstance(space, MultiDiscrete | MultiBinary):
        size = {"nvec": list(space.nvec)} if isinstance(space, MultiDiscrete) else {"n": int(space.n)}
        kind = type(space).__name__
        return {"type": kind, **size, "shape": list(space.shape), "dtype": _dtype(space.dtype)}
    if isinstance(space, Discrete):
        return {
            "type": "Discrete",
            "n": int(space.n),
            "shape": list(space.shape),
            "dtype": _dtype(space.dtype),
        }

    def finite(x: Any) -> Any:  # infinities as "inf" / "-inf": JSON has no number for them
        return [finite(y) for y in x] if isinstance(x, list) else x if np.isfinite(x) else str(x)

    def bound(value: Any) -> Any:
        value = np.asarray(value, np.float64)
        return finite(
            float(value.flat[0]) if value.size and np.all(value == value.flat[0]) else value.tolist()
        )

    return {
        "type": "Box",
        "shape": list(space.shape),
        "dtype": _dtype(space.dtype),
        "low": bound(space.low),
        "high": bound(space.high),
    }


LAYOUT_METADATA = "agentax_layout"
"""The ONNX metadata entry that holds the packed observation's layout (JSON, as the card's)."""


def layout_card(layout: Layout | None) -> dict[str, Any] | None:
    """A layout as JSON: the packed vector's ``size``, ``dtype`` and ``structure`` (single, dict or
    tuple), and each leaf's key, kind, shape and ``[start, start + size)`` (with a Discrete or
    MultiDiscrete leaf's ``categories``, an image's ``channels_first`` and ``scale``, an ``encoder``
    the run chose); None without one."""
    if layout is None:
        return None
    return {
        "size": layout.size,
        "dtype": layout.dtype,
        "structure": layout.structure,
        "leaves": [
            {
                "key": leaf.key,
                "kind": leaf.kind,
                "shape": list(leaf.shape),
                "start": leaf.start,
                "size": leaf.size,
                **({"categories": list(leaf.categories)} if leaf.categories else {}),
                **({"channels_first": True} if leaf.channels_first else {}),
                **({"scale": leaf.scale} if leaf.scale != 1.0 else {}),
                **({"encoder": leaf.encoder} if leaf.encoder != "auto" else {}),
            }
            for leaf in layout.leaves
        ],
    }


def layout_from_card(card: dict[str, Any] | None) -> Layout | None:
    """The :class:`~agentax.envs.spaces.Layout` of a card's ``layout`` (:func:`layout_card`'s inverse)."""
    if card is None:
        return None
    leaves = tuple(
        Leaf(
            leaf["key"],
            leaf["kind"],
            tuple(leaf["shape"]),
            leaf["start"],
            leaf["size"],
            tuple(leaf.get("categories", ())),
            leaf.get("channels_first", False),
            leaf.get("scale", 1.0),
            leaf.get("encoder", "auto"),
        )
        for leaf in card["leaves"]
    )
    return Layout(leaves, card["dtype"], card["structure"])


def _dtype(dtype: Any) -> str:
    return np.dtype(dtype).name


def _tensor(name: str, shape: tuple[int, ...], dtype: Any, batch: bool = True) -> dict[str, Any]:
    return {"name": name, "shape": [BATCH, *shape] if batch else list(shape), "dtype": _dtype(dtype)}


def model_card(
    format: str,
    file: Path,
    env_id: str,
    spaces: tuple[Discrete | Box, Any],
    obs: jax.ShapeDtypeStruct,
    action: jax.ShapeDtypeStruct,
    stochastic: bool,
    run: dict[str, Any],
    layout: Layout | None = None,
    state: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """What ``FILE.json`` holds: the format, env and spaces, the inputs and output, the layout of a
    packed observation (null where the env's observations are plain), a recurrent policy's ``state``
    (:func:`state_card`; no such entry for a feed-forward one), the run it came from (``run``: its
    algo, folder, final evaluation and evaluation settings) and the versions."""
    inputs = [_tensor(OBS, obs.shape, obs.dtype)]
    outputs = [_tensor(ACTION, action.shape, action.dtype)]
    if stochastic:
        inputs.append(_tensor(KEY, (2,), jnp.uint32, batch=False))
    if state is not None:
        inputs.append({"name": STATE, "shape": state["shape"], "dtype": state["dtype"]})
        outputs.append({"name": NEXT_STATE, "shape": state["shape"], "dtype": state["dtype"]})
    versions = {"agentax": _version("agentax"), "jax": jax.__version__}
    if format == "onnx":
        versions.update(jax2onnx=_version("jax2onnx"), onnx=_version("onnx"))
    return {
        "format": format,
        "file": file.name,
        "policy": "stochastic" if stochastic else "greedy",
        "env": env_id,
        "observation_space": space_card(spaces[0]),
        "action_space": space_card(spaces[1]),
        "layout": layout_card(layout),
        "inputs": inputs,
        "outputs": outputs,
        **({"state": state} if state is not None else {}),
        **({"platforms": list(STABLEHLO_PLATFORMS)} if format == "stablehlo" else {}),
        **run,
        "versions": versions,
    }


def state_card(state: jax.ShapeDtypeStruct, config: dict[str, Any]) -> dict[str, Any]:
    """A recurrent policy's state as JSON: its ``shape`` ``[N, S]`` and dtype, its ``initial`` value
    (``"zeros"``), the ``core`` (the run's ``--core``) and the ``parts`` of the flat carry (LSTM: ``c``
    then ``h``, GRU: ``h``, each ``start`` and ``size``), and how it is carried (``feed_back``)."""
    core = config.get("config", {}).get("core", "none")
    names = ["c", "h"] if core == "lstm" else ["h"]
    size = state.shape[0] // len(names)
    if size * len(names) != state.shape[0]:  # a carry of another shape: one part, as it is
        names, size = ["memory"], state.shape[0]
    return {
        **_tensor(STATE, state.shape, state.dtype),
        "initial": "zeros",
        "core": core,
        "parts": [{"name": name, "start": i * size, "size": size} for i, name in enumerate(names)],
        "feed_back": (
            f"feed each step's {NEXT_STATE} back as the next step's {STATE}, row by row; zeros at "
            "the first observation of each episode"
        ),
    }


def _version(distribution: str) -> str:
    try:
        return version(distribution)
    except PackageNotFoundError:
        return "unknown"


def run_summary(run_dir: Path, config: dict[str, Any]) -> dict[str, Any]:
    """The card's lines on the run: algo, folder, its final evaluation (eval.json's pooled statistics,
    or None before it has one) and the env settings a score depends on (Atari's backend and sticky
    actions, which ``agentax evaluate --policy FILE`` reuses)."""
    evaluation = None
    if (run_dir / "eval.json").is_file():
        pooled = read_json(run_dir / "eval.json")
        names = ("mean_return", "std_return", "min_return", "max_return", "episodes", "mean_length")
        evaluation = {name: pooled[name] for name in names if name in pooled}
    runner = config.get("runner") or {}
    settings = {k: runner[k] for k in ("env_backend", "sticky_actions") if k in runner}
    return {
        "algo": config["algo"],
        "run": run_dir.resolve().name,
        "final_evaluation": evaluation,
        "env_settings": settings,
    }


def card_path(path: str | Path) -> Path:
    """The model card beside an exported file: ``FILE.json``."""
    return Path(f"{path}.json")


def env_spaces(env_id: str) -> tuple[Discrete | Box, Any, Layout | None]:
    """``(observation_space, action_space, layout)`` of one ``env_id`` env, as agentax makes it (the
    observation space that of its packed vectors where it has a layout)."""
    env = make(env_id, 1)
    try:
        return env.observation_space(), env.action_space(), getattr(env, "layout", None)
    finally:
        if hasattr(env, "close"):
            env.close()


def export_run(
    run_dir: str | Path,
    config: dict[str, Any],
    restore: Callable[[], Policy],
    format: str = "onnx",
    out: str | Path | None = None,
    stochastic: bool = False,
) -> Path:
    """Write the policy ``restore()`` gives (called once the format is checked) for the run in
    ``run_dir`` (its ``config.json`` as ``config``) to ``out`` (default ``RUN_DIR/policy.onnx`` or
    ``.stablehlo``, ``policy-stochastic...`` for the sampling head), its model card beside it; the path.
    """
    check_format(format, stochastic)
    run_dir = Path(run_dir)
    name = "policy-stochastic" if stochastic else "policy"
    path = Path(out) if out is not None else run_dir / f"{name}{FORMATS[format]}"
    if path.is_dir() or not path.parent.is_dir():
        raise UsageError(f"--out {path}: give a file in an existing folder")
    *spaces, layout = env_spaces(config["env"])
    if layout is not None:  # the card says how the network encodes each leaf, as the run chose
        layout = layout.with_encoders(config.get("encoders", {}))
    obs = jax.ShapeDtypeStruct(tuple(spaces[0].shape), jnp.dtype(spaces[0].dtype))
    if stochastic and config.get("config", {}).get("core", "none") != "none":
        raise UsageError(
            f"--stochastic: {run_dir}'s policy has a recurrent core (--core), whose sampling head "
            "export does not write; export its greedy policy (without --stochastic)"
        )
    data, action, state = convert(restore(), obs, format, stochastic, layout)
    write_atomic(path, data)
    card = model_card(
        format,
        path,
        config["env"],
        tuple(spaces),
        obs,
        action,
        stochastic,
        run_summary(run_dir, config),
        layout,
        None if state is None else state_card(state, config),
    )
    write_json(card_path(path), card)
    return path


def convert(
    policy: Policy | RecurrentPolicy,
    obs: jax.ShapeDtypeStruct,
    format: str,
    stochastic: bool = False,
    layout: Layout | None = None,
) -> tuple[bytes, jax.ShapeDtypeStruct, jax.ShapeDtypeStruct | None]:
    """``(data, action, state)``: the file's bytes in ``format``, one action's spec and one row of a
    recurrent policy's state (None for a policy without memory)."""
    state = None
    if isinstance(policy, RecurrentPolicy):
        f, action, state = batched_recurrent(policy, obs)
    else:
        f, action = batched(policy, obs, stochastic)
    if format == "onnx":
        metadata = {} if layout is None else {LAYOUT_METADATA: json.dumps(layout_card(layout))}
        return to_onnx(f, obs, metadata=metadata, state=state), action, state
    return to_stablehlo(f, obs, stochastic, state), action, state


# Running an exported file.


@dataclasses.dataclass(frozen=True)
class Exported:
    """An exported file loaded back: its model card and ``run(obs [N, ...], key?) -> action [N, ...]``
    (a recurrent policy's: ``run(obs, state [N, S]) -> (action, next_state)``), NumPy in and out,
    through onnxruntime (ONNX) or ``jax.export.deserialize`` (StableHLO)."""

    card: dict[str, Any]
    run: Callable[..., np.ndarray]

    @property
    def stochastic(self) -> bool:
        return self.card["policy"] == "stochastic"

    @property
    def obs(self) -> jax.ShapeDtypeStruct:
        spec = self.card["inputs"][0]
        return jax.ShapeDtypeStruct(tuple(spec["shape"][1:]), np.dtype(spec["dtype"]))

    @property
    def state(self) -> jax.ShapeDtypeStruct | None:
        """One row of a recurrent policy's state (zeros at an episode's start); None without memory."""
        spec = self.card.get("state")
        return (
            None if spec is None else jax.ShapeDtypeStruct(tuple(spec["shape"][1:]), np.dtype(spec["dtype"]))
        )

    def initial_state(self, n: int) -> np.ndarray:
        """The state ``[n, S]`` that ``n`` episodes start from: zeros."""
        return np.zeros((n, *self.state.shape), self.state.dtype)

    @property
    def layout(self) -> Layout | None:
        """How the env's observations are packed into the file's input (None: they go in as they are)."""
        return layout_from_card(self.card.get("layout"))

    @property
    def action(self) -> jax.ShapeDtypeStruct:
        spec = self.card["outputs"][0]
        return jax.ShapeDtypeStruct(tuple(spec["shape"][1:]), np.dtype(spec["dtype"]))


def is_exported(path: str | Path) -> bool:
    """Whether ``path`` names an exported file (an export format's suffix, not a folder)."""
    return Path(path).suffix in FORMATS.values() and not Path(path).is_dir()


def load(path: str | Path) -> Exported:
    """The exported file at ``path`` with its model card (``FILE.json``, which must be beside it)."""
    path = Path(path)
    if not path.is_file():
        raise UsageError(f"no exported policy at {path}; write one with agentax export RUN_DIR")
    if not card_path(path).is_file():
        raise UsageError(f"{path} has no model card beside it ({card_path(path).name}); export it again")
    card = read_json(card_path(path))
    if check_format(card.get("format", "")) == "stablehlo":
        call = jax.jit(jax.export.deserialize(bytearray(path.read_bytes())).call)
        return Exported(card, lambda *args: jax.tree.map(np.asarray, call(*args)))
    import onnxruntime

    session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    if "state" in card:
        return Exported(
            card,
            lambda obs, state: tuple(
                session.run([ACTION, NEXT_STATE], {OBS: np.asarray(obs), STATE: np.asarray(state)})
            ),
        )
    return Exported(card, lambda obs: session.run([ACTION], {OBS: np.asarray(obs)})[0])


def as_policy(exported: Exported) -> Policy:
    """The exported function as an agentax policy ``(obs, key) -> action`` on one observation, for
    :func:`agentax.evaluate.evaluate` (inside ``jit``, vmapped over episodes); a recurrent file's is a
    :class:`~agentax.envs.core.RecurrentPolicy` (:func:`as_recurrent_policy`).

    The file runs as its own program, called back from the host (``jax.pure_callback``), as a user
    would run it: a StableHLO module compiled into the evaluation's loop instead acted differently
    on near-ties (compiled together with the loop, ~30 of 100 CartPole episodes of a PPO
    policy ended at other lengths). Under ``vmap`` the batch goes to the file in one call; a stochastic
    file, whose keys are batched too, gets one call per key.
    """
    if exported.state is not None:
        return as_recurrent_policy(exported)
    obs_spec, action = exported.obs, exported.action

    @jax.custom_batching.custom_vmap
    def batch(obs: jax.Array, *key: jax.Array) -> jax.Array:  # obs [N, *obs_shape]
        out = jax.ShapeDtypeStruct((obs.shape[0], *action.shape), action.dtype)
        return jax.pure_callback(lambda *a: np.asarray(exported.run(*a), action.dtype), out, obs, *key)

    @batch.def_vmap
    def batch_rule(axis_size: int, in_batched: list[bool], obs: jax.Array, *key: jax.Array):
        if not in_batched[0]:
            obs = jnp.broadcast_to(obs, (axis_size, *obs.shape))
        if any(in_batched[1:]):
            key = tuple(
                k if b else jnp.broadcast_to(k, (axis_size, *k.shape))
                for k, b in zip(key, in_batched[1:], strict=True)
            )
            return jax.lax.map(lambda args: batch(*args), (obs, *key)), True
        flat = batch(obs.reshape(-1, *obs.shape[2:]), *key)
        return flat.reshape(axis_size, -1, *flat.shape[1:]), True

    def policy(obs: jax.Array, key: jax.Array) -> jax.Array:
        if tuple(obs.shape) != obs_spec.shape:
            raise ValueError(
                f"the exported policy reads observations of shape {obs_spec.shape}, not {obs.shape}"
            )
        keys = (jax.random.key_data(key),) if exported.stochastic else ()
        return batch(obs.astype(obs_spec.dtype)[None], *keys)[0]

    return policy


def as_recurrent_policy(exported: Exported) -> RecurrentPolicy:
    """A recurrent file as an agentax :class:`~agentax.envs.core.RecurrentPolicy`: its memory the flat
    state ``[S]``, zeros at an episode's start, each step one host call (``jax.pure_callback``, every
    vmapped env in that one call) of ``run(obs, state) -> (action, next_state)``."""
    obs_spec, action, state = exported.obs, exported.action, exported.state

    def call(obs: np.ndarray, memory: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # [*B, ...], [*B, S]
        batch = memory.shape[: memory.ndim - len(state.shape)]
        actions, next_state = exported.run(
            np.asarray(obs, obs_spec.dtype).reshape(-1, *obs_spec.shape),
            np.asarray(memory, state.dtype).reshape(-1, *state.shape),
        )
        return (
            np.asarray(actions, action.dtype).reshape(*batch, *action.shape),
            np.asarray(next_state, state.dtype).reshape(*batch, *state.shape),
        )

    def step(memory: jax.Array, obs: jax.Array, key: jax.Array) -> tuple[jax.Array, jax.Array]:
        if tuple(obs.shape) != obs_spec.shape:
            raise ValueError(
                f"the exported policy reads observations of shape {obs_spec.shape}, not {obs.shape}"
            )
        out = (action, state)
        actions, next_state = jax.pure_callback(
            call, out, obs.astype(obs_spec.dtype), memory, vmap_method="broadcast_all"
        )
        return next_state, actions

    return RecurrentPolicy(lambda: jnp.zeros(state.shape, state.dtype), step)

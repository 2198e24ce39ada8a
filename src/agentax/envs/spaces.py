"""Composite spaces, and observations packed into one flat vector by a :class:`Layout`.

A practitioner's env rarely gives one flat vector: a robot gives its joints and a camera image, a
board game the board and the legal moves, a grid world the cell it is in (``Discrete``). agentax
takes them all the same way (the lecture's preprocessing layers and combiner, TF-Agents' nested
specs): the env's observation, however nested, is *packed* leaf by leaf into one flat vector, and the
:class:`Layout` beside it says where each leaf lies and what it is. Runners, rollouts, every replay
buffer, checkpoints, evaluation and export carry the packed vector as they carry CartPole's four
numbers (one array per step, no new code paths, flat envs unchanged); the agent's network unpacks it
with an encoder per leaf (:class:`agentax.nets.Encoder`): Box vectors as they are, images through a
CNN sized to them, ``Discrete`` leaves one-hot, ``MultiDiscrete`` one one-hot per entry,
``MultiBinary`` as 0/1; a leaf named ``action_mask`` is not seen by the network but masks its
actions (:meth:`Layout.legal`).

A packed vector is uint8 where every leaf fits a byte and one is an image (a 48×48×3 picture stays
6,912 bytes in replay), else float32.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from agentax.envs.core import Box, Environment, EnvParams, TimeStep
from agentax.errors import UsageError

MASK_KEY = "action_mask"
"""The key of a Dict observation that holds the legal actions (PettingZoo's and Jumanji's convention;
Gymnasium's toy-text envs give the same array as ``info["action_mask"]``)."""
SMALLEST_IMAGE = 8
"""The least height and width of an observation taken as an image (a smaller 2-D or 3-D Box is a vector)."""
NATURE_PIXELS = 36
"""The least height and width the Nature CNN's convolutions take (its 8×8/4, 4×4/2, 3×3/1 stack)."""
ENCODERS: dict[str, tuple[str, ...]] = {
    "image": ("auto", "nature", "small", "flat"),
    "discrete": ("auto", "one_hot", "scalar"),
    "multi_discrete": ("auto", "one_hot", "scalar"),
    "vector": ("auto", "flat"),
    "binary": ("auto", "flat"),
}
"""The encoders a leaf of each kind may choose (:meth:`Layout.with_encoders`; the modules are
:class:`agentax.nets.Encoder`'s): "auto" is an image's Nature CNN from :data:`NATURE_PIXELS`, else its
two small convolutions; a Discrete entry's one-hot; a vector's numbers as they are. "flat" takes an
image's pixels as a scaled vector, "scalar" a Discrete entry's integer as one float."""
SUPPORTED = (
    "Box, Discrete, MultiDiscrete, MultiBinary, and a Dict or Tuple of them (one level), with an "
    f"optional {MASK_KEY!r} entry"
)


@dataclass(frozen=True)
class MultiDiscrete:
    """A vector of choices, entry ``i`` in ``0 .. nvec[i]-1``."""

    nvec: tuple[int, ...]
    dtype: Any = jnp.int32

    @property
    def shape(self) -> tuple[int, ...]:
        return (len(self.nvec),)

    def sample(self, key: jax.Array) -> jax.Array:
        return jax.random.randint(key, self.shape, 0, jnp.asarray(self.nvec), dtype=self.dtype)

    def __str__(self) -> str:
        return f"MultiDiscrete({list(self.nvec)})"


@dataclass(frozen=True)
class MultiBinary:
    """``n`` independent on/off switches, each 0 or 1."""

    n: int
    dtype: Any = jnp.int32

    @property
    def shape(self) -> tuple[int, ...]:
        return (self.n,)

    @property
    def nvec(self) -> tuple[int, ...]:
        return (2,) * self.n

    def sample(self, key: jax.Array) -> jax.Array:
        return jax.random.bernoulli(key, 0.5, self.shape).astype(self.dtype)

    def __str__(self) -> str:
        return f"MultiBinary({self.n})"


@dataclass(frozen=True)
class Dict:
    """Named sub-spaces, in order: ``Dict((("board", Box(...)), ("action_mask", MultiBinary(7))))``."""

    spaces: tuple[tuple[str, Any], ...]

    def __str__(self) -> str:
        return "Dict(" + ", ".join(f"{k}: {v}" for k, v in self.spaces) + ")"


@dataclass(frozen=True)
class Tuple:
    """Sub-spaces by position."""

    spaces: tuple[Any, ...]

    def __str__(self) -> str:
        return "Tuple(" + ", ".join(str(s) for s in self.spaces) + ")"


@dataclass(frozen=True)
class Leaf:
    """One leaf of a packed observation: entries ``[start, start + size)`` of the vector."""

    key: str | int | None
    """its key in the Dict (name) or Tuple (position); None for an observation that is one leaf"""
    kind: str
    """vector, image, discrete, multi_discrete, binary or mask"""
    shape: tuple[int, ...]
    """the leaf's own shape as the env gives it (``()`` for Discrete)"""
    start: int
    size: int
    categories: tuple[int, ...] = ()
    """a Discrete leaf's ``(n,)``, a MultiDiscrete leaf's ``nvec``"""
    channels_first: bool = False
    """an image laid out ``[C, H, W]`` (else ``[H, W, C]``, or ``[H, W]`` for one channel)"""
    scale: float = 1.0
    """what an image's values are multiplied by (1/255 for bytes)"""
    encoder: str = "auto"
    """how the network encodes the leaf, one of :data:`ENCODERS` of its kind (packing ignores it)"""

    @property
    def name(self) -> str:
        """The leaf's key as an encoder override names it: the Dict key, the Tuple position as a
        string, or "obs" for an observation that is one leaf."""
        return "obs" if self.key is None else str(self.key)

    @property
    def image_hwc(self) -> tuple[int, int, int]:
        """An image leaf's ``(H, W, C)``."""
        if len(self.shape) == 2:
            return (*self.shape, 1)
        return (*self.shape[1:], self.shape[0]) if self.channels_first else self.shape

    def __str__(self) -> str:
        where = "" if self.key is None else f"{self.key}: "
        extra = f" {list(self.categories)}" if self.categories else ""
        encoder = "" if self.encoder == "auto" else f" ({self.encoder})"
        return f"{where}{self.kind} {list(self.shape)}{extra}{encoder}"


@dataclass(frozen=True)
class Layout:
    """Where each leaf of an observation lies in its packed vector ``[size]`` of ``dtype``."""

    leaves: tuple[Leaf, ...]
    dtype: str
    structure: str = "single"
    """how the leaves nest: single (the observation is one leaf), dict or tuple"""

    @property
    def size(self) -> int:
        return sum(leaf.size for leaf in self.leaves)

    @property
    def mask(self) -> Leaf | None:
        return next((leaf for leaf in self.leaves if leaf.kind == "mask"), None)

    def pack(self, obs: Any, xp: Any = np) -> Any:
        """The packed vector ``[..., size]`` of an observation as the env gives it (its leaves with
        the same leading batch axes); ``xp``: ``numpy`` on the host, ``jax.numpy`` in a program."""
        parts = []
        for leaf in self.leaves:
            value = xp.asarray(obs if leaf.key is None else obs[leaf.key])
            batch = value.shape[: value.ndim - len(leaf.shape)]
            parts.append(value.reshape(*batch, leaf.size).astype(self.dtype))
        return parts[0] if len(parts) == 1 else xp.concatenate(parts, axis=-1)

    def unpack(self, packed: Any) -> Any:
        """The observation as the env gives it, from its packed vector ``[..., size]`` (NumPy or JAX)."""
        values = {}
        for leaf in self.leaves:
            value = packed[..., leaf.start : leaf.start + leaf.size]
            values[leaf.key] = value.reshape((*value.shape[:-1], *leaf.shape))  # a tuple: NumPy takes () too
        if self.structure == "single":
            return values[None]
        return values if self.structure == "dict" else tuple(values[i] for i in range(len(values)))

    def legal(self, packed: jax.Array) -> jax.Array | None:
        """The legal actions ``bool [..., n]`` of packed observations ``[..., size]`` (None: all are)."""
        leaf = self.mask
        if leaf is None:
            return None
        return packed[..., leaf.start : leaf.start + leaf.size] > 0

    def with_encoders(self, overrides: dict[str, str]) -> Layout:
        """This layout with the leaves ``overrides`` names (by :attr:`Leaf.name`) encoded by the
        choice given, the rest as they were; packing is unchanged. An unknown key, or a choice that
        does not fit the leaf's kind, is a one-line ``UsageError`` naming those that do."""
        leaves = {leaf.name: leaf for leaf in self.leaves if leaf.kind != "mask"}
        for name, choice in overrides.items():
            if name not in leaves:
                mask = f" ({MASK_KEY} masks the actions: it has no encoder)" if name == MASK_KEY else ""
                raise UsageError(
                    f"--encoder {name}: no such key{mask}; the observation's keys are {', '.join(leaves)}"
                )
            check_encoder(leaves[name], choice)
        return dataclasses.replace(
            self,
            leaves=tuple(
                dataclasses.replace(leaf, encoder=overrides[leaf.name]) if leaf.name in overrides else leaf
                for leaf in self.leaves
            ),
        )

    def __str__(self) -> str:
        return "; ".join(str(leaf) for leaf in self.leaves)


def check_encoder(leaf: Leaf, choice: str) -> None:
    """A one-line ``UsageError`` where ``choice`` cannot encode ``leaf``: not one of its kind's
    :data:`ENCODERS`, or the Nature CNN on an image under :data:`NATURE_PIXELS` pixels."""
    fits = ENCODERS[leaf.kind]
    if choice not in fits:
        raise UsageError(
            f"--encoder {leaf.name}={choice}: not an encoder of a {leaf.kind} leaf; "
            f"choose from {', '.join(fits)}"
        )
    height, width = leaf.image_hwc[:2] if leaf.kind == "image" else (NATURE_PIXELS, NATURE_PIXELS)
    if choice == "nature" and min(height, width) < NATURE_PIXELS:
        raise UsageError(
            f"--encoder {leaf.name}=nature: the Nature CNN takes images of at least {NATURE_PIXELS}×"
            f"{NATURE_PIXELS} pixels, this one is {height}×{width}; choose small or flat"
        )


def is_plain(space: Any) -> bool:
    """Whether agents take ``space``'s observations as they come: a flat Box vector ``[n]``, or
    stacked frames ``[C, H, W]`` of at least 36×36 (Atari's ``[4, 84, 84]``; the Nature CNN's path)."""
    if type(space).__name__ != "Box":
        return False
    shape = tuple(space.shape)
    return len(shape) == 1 or (len(shape) == 3 and shape[0] <= 4 and min(shape[1:]) >= 36)


def layout_of(space: Any, env_id: str | None = None, mask: int | None = None) -> Layout | None:
    """The layout that packs observations of ``space`` (None where the space is plain, see
    :func:`is_plain`, and no mask is added); ``mask``: the number of actions of a mask that comes
    beside the observation (``info["action_mask"]``), packed as a last leaf named ``action_mask``.
    A space no encoder takes is a one-line ``UsageError``."""
    if mask is None and is_plain(space):
        return None
    name = type(space).__name__
    if name == "Dict":
        items, structure = list(space.spaces), "dict"
    elif name == "Tuple":
        items, structure = list(enumerate(space.spaces)), "tuple"
    else:
        items, structure = [(None, space)], "single"
    if mask is not None:
        if structure == "tuple":
            raise UsageError(
                f"{env_id or 'the env'}: a Tuple observation beside an info action mask is not supported"
            )
        if structure == "single":
            items = [("obs", space)]
        items, structure = [*items, (MASK_KEY, MultiBinary(mask))], "dict"
    leaves, start = [], 0
    for key, sub in items:
        leaf = _leaf(key, sub, start, env_id)
        leaves.append(leaf)
        start += leaf.size
    fits_a_byte = all(
        leaf.kind in ("mask", "binary")
        or (leaf.kind in ("image", "vector") and leaf.scale != 1.0)
        or (leaf.kind in ("discrete", "multi_discrete") and max(leaf.categories) <= 256)
        for leaf in leaves
    )
    has_image = any(leaf.kind == "image" for leaf in leaves)
    layout = Layout(tuple(leaves), "uint8" if fits_a_byte and has_image else "float32", structure)
    if layout.size == 0:
        raise UsageError(f"{env_id or 'the env'} has empty observations {space}")
    if all(leaf.kind == "mask" for leaf in leaves):
        raise UsageError(f"{env_id or 'the env'} observes only its action mask; it needs something to act on")
    return layout


def _leaf(key: Any, space: Any, start: int, env_id: str | None) -> Leaf:
    """One leaf of a packed observation: its kind read from ``space``."""
    name = type(space).__name__
    shape = tuple(int(d) for d in getattr(space, "shape", ()) or ())
    if name in ("Dict", "Tuple"):
        raise UsageError(
            f"{env_id or 'the env'} nests {name} spaces two levels deep ({space}); agentax takes {SUPPORTED}"
        )
    if key == MASK_KEY and name in ("MultiBinary", "Box"):
        return Leaf(key, "mask", shape, start, math.prod(shape))
    if name == "Discrete":
        if int(getattr(space, "start", 0)) != 0:
            raise UsageError(
                f"{env_id or 'the env'}: Discrete observations must start at 0, not {space.start}"
            )
        return Leaf(key, "discrete", (), start, 1, (int(space.n),))
    if name == "MultiDiscrete":
        nvec = tuple(int(n) for n in np.asarray(space.nvec).reshape(-1))
        if int(np.min(getattr(space, "start", 0))) != 0:
            raise UsageError(f"{env_id or 'the env'}: MultiDiscrete observations must start at 0")
        return Leaf(key, "multi_discrete", shape, start, len(nvec), nvec)
    if name == "MultiBinary":
        return Leaf(key, "binary", shape, start, math.prod(shape))
    if name == "Box":
        size = math.prod(shape)
        high = np.asarray(space.high, np.float64)
        byte = np.dtype(space.dtype) == np.uint8 or (
            np.all(np.isfinite(high)) and float(np.max(high)) == 255.0
        )
        scale = 1.0 / 255.0 if byte else 1.0
        if len(shape) == 2 and min(shape) >= SMALLEST_IMAGE:
            return Leaf(key, "image", shape, start, size, scale=scale)
        if len(shape) == 3:
            channels_first = shape[0] < shape[-1]
            height, width = shape[1:] if channels_first else shape[:2]
            if min(height, width) >= SMALLEST_IMAGE:
                return Leaf(key, "image", shape, start, size, channels_first=channels_first, scale=scale)
        return Leaf(key, "vector", shape, start, size, scale=scale if byte else 1.0)
    raise UsageError(
        f"{env_id or 'the env'} has observations {space}, which agentax does not take; it takes {SUPPORTED}"
    )


def packed_space(layout: Layout) -> Box:
    """The Box of packed vectors ``[size]``."""
    if layout.dtype == "uint8":
        return Box(0, 255, (layout.size,), jnp.uint8)
    return Box(-jnp.inf, jnp.inf, (layout.size,), jnp.float32)


def check_mask(legal: Any, env_id: str | None = None) -> None:
    """A ``UsageError`` where a mask ``[..., n]`` leaves some observation without a legal action."""
    legal = np.asarray(legal)
    if legal.size and not np.all(legal.reshape(-1, legal.shape[-1]).any(axis=-1)):
        raise UsageError(
            f"{env_id or 'the env'} gave an action mask with no legal action; every step needs one"
        )


class Packed(Environment):
    """A JAX env whose observations are composite, seen through its :class:`Layout`: ``reset`` and
    ``step`` return packed vectors ``[layout.size]``, ``observation_space()`` their Box, and the
    env's own Dict or Tuple space stays known as :attr:`original_space` (what the Gymnasium adapter
    gives back)."""

    def __init__(self, env: Environment, layout: Layout | None = None):
        self.env, self.id = env, env.id
        self.original_space = env.observation_space()
        self.layout = layout or layout_of(self.original_space, env.id)

    def default_params(self) -> EnvParams:
        return self.env.default_params()

    def reset_env(self, key: jax.Array, params: EnvParams) -> tuple[jax.Array, Any]:
        obs, state = self.env.reset_env(key, params)
        return self.layout.pack(obs, jnp), state

    def step_env(
        self, key: jax.Array, state: Any, action: jax.Array, params: EnvParams
    ) -> tuple[TimeStep, Any]:
        ts, state = self.env.step_env(key, state, action, params)
        obs = self.layout.pack(ts.obs, jnp)
        return ts.replace(obs=obs, final_obs=obs), state

    def observation_space(self, params: EnvParams | None = None) -> Box:
        return packed_space(self.layout)

    def action_space(self, params: EnvParams | None = None) -> Any:
        return self.env.action_space(params)

    def render_frame(self, state: Any, params: EnvParams | None = None) -> np.ndarray:
        return self.env.render_frame(state, params)

    def __getattr__(self, name: str) -> Any:  # the wrapped env's other attributes (its constants)
        if name == "env":
            raise AttributeError(name)
        return getattr(self.env, name)


def packed(env: Environment) -> Environment:
    """``env`` itself where its observations are plain, else :class:`Packed` around it."""
    if isinstance(env, Packed) or layout_of(env.observation_space(), env.id) is None:
        return env
    return Packed(env)

"""Flax modules shared by every agent: MLP and convolutional torsos, the policy heads, Q-networks;
DQN's Rainbow pieces (noisy layers, distributional heads, random-shift augmentation).

Parameters are plain pytrees (``module.init`` / ``module.apply``), so they scan, vmap over seeds
and checkpoint cleanly. A policy over discrete actions returns action *logits* ``[..., num_actions]``
(the lecture's one-sigmoid-output network for two actions is the categorical with logits ``[z, 0]``,
since ``softmax([z, 0])[0] == sigmoid(z)``); one over continuous actions returns a diagonal
Gaussian's ``(mean, log_std)``, each ``[..., action_dim]``, from :func:`gaussian_head` (a
state-independent ``log_std`` for PPO and REINFORCE, a state-dependent bounded one for SAC, whose
:class:`SquashedGaussianActor` samples through a tanh with :func:`sample_squashed`).
"""

from __future__ import annotations

import functools
import itertools
from collections.abc import Sequence
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp

from agentax import kernels
from agentax.envs.spaces import NATURE_PIXELS

ACTIVATIONS = {"elu": nn.elu, "relu": nn.relu, "tanh": nn.tanh, "gelu": nn.gelu, "swish": nn.swish}


def dense_layer(features: int, precision: str = "f32", **kwargs: Any) -> nn.Dense:
    """``nn.Dense(features, **kwargs)`` whose product is in ``precision``: flax's own for ``f32``
    (parameters and numbers as always), bfloat16 operands with float32 sums for ``bf16``
    (:func:`agentax.kernels.dot_general_for`); parameters and outputs float32 either way."""
    return nn.Dense(features, dot_general=kernels.dot_general_for(precision), **kwargs)


class MLP(nn.Module):
    """Dense layers with one activation: ``[..., in] -> [..., hidden[-1]]`` (or ``out`` if given)."""

    hidden: Sequence[int]
    activation: str = "elu"
    out: int | None = None
    layer_norm: bool = False
    """LayerNorm between each dense layer and its activation (PQN's regularizer: it keeps TD learning
    stable without a target network)"""
    precision: str = "f32"
    """the products' precision (:data:`agentax.kernels.PRECISIONS`), chosen by the entry point"""

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        act = ACTIVATIONS[self.activation]
        for width in self.hidden:
            x = dense_layer(width, self.precision)(x)
            x = act(nn.LayerNorm()(x) if self.layer_norm else x)
        if self.out is not None:
            x = dense_layer(self.out, self.precision)(x)
        return x


class NatureCNN(nn.Module):
    """The DQN Nature paper's torso (Mnih et al., 2015): ``[..., 4, 84, 84]`` frames → ``[..., 512]``.

    Conv 32 8×8 stride 4, conv 64 4×4 stride 2, conv 64 3×3 stride 1, dense 512, ReLU after each.
    Observations stay uint8 (channel-first stacks, as EnvPool and the frame replay give them) until
    here: the network divides by 255.
    """

    layer_norm: bool = False
    """LayerNorm before each ReLU (PQN's network, as purejaxql's ``pqn_atari``)"""
    conv: str = "xla"
    """the convolution backend (:data:`agentax.kernels.BACKENDS`), chosen by the entry point"""
    precision: str = "f32"
    """the dense layer's precision where the backend is XLA's (oneDNN's keeps its own); the
    convolutions stay the backend's"""

    @nn.compact
    def __call__(self, frames: jax.Array) -> jax.Array:
        x = nature_convolutions(frames, self.layer_norm, self.conv)
        init = nn.initializers.orthogonal(jnp.sqrt(2.0))
        if self.conv == "xla" and self.precision != "f32":
            x = dense_layer(512, self.precision, kernel_init=init)(x)
        else:
            x = nn.Dense(512, kernel_init=init, dot_general=kernels.dot_general_with(self.conv))(x)
        return nn.relu(nn.LayerNorm()(x) if self.layer_norm else x)


def nature_convolutions(frames: jax.Array, layer_norm: bool = False, conv: str = "xla") -> jax.Array:
    """The Nature CNN's three convolutions, inside the calling module: uint8 ``[..., 4, 84, 84]``
    → ``[..., 3136]`` features (the frames divided by 255 first; ``layer_norm``: LayerNorm over
    each position's channels before each ReLU). The convolutions are :mod:`agentax.kernels`' on
    backend ``conv`` (oneDNN's FFI calls on the CPU, or XLA's), with flax's parameters unchanged."""
    batch_shape = frames.shape[:-3]
    x = frames.reshape(-1, *frames.shape[-3:]).astype(jnp.float32) / 255.0
    x = jnp.transpose(x, (0, 2, 3, 1))  # [N, C, H, W] -> [N, H, W, C]
    init = nn.initializers.orthogonal(jnp.sqrt(2.0))
    for features, size, stride in ((32, 8, 4), (64, 4, 2), (64, 3, 1)):
        x = nn.Conv(
            features,
            (size, size),
            (stride, stride),
            padding="VALID",
            kernel_init=init,
            conv_general_dilated=kernels.conv_general_dilated_with(conv),
        )(x)
        x = nn.relu(nn.LayerNorm()(x) if layer_norm else x)
    return x.reshape(*batch_shape, -1)


def is_image(obs_shape: Sequence[int]) -> bool:
    """Whether observations of this shape are stacked frames ``[C, H, W]`` (the Nature CNN's input)."""
    return len(obs_shape) == 3


class Encoder(nn.Module):
    """Packed observations ``[..., layout.size]`` (:mod:`agentax.envs.spaces`) → features ``[..., F]``:
    one encoder per leaf, concatenated (the lecture's preprocessing layers and combiner).

    Each leaf's :attr:`~agentax.envs.spaces.Leaf.encoder` picks its row of :data:`LEAF_ENCODERS`;
    "auto" is: Box vectors as they are (bytes scaled to [0, 1]); images through :class:`ImageEncoder`;
    ``Discrete`` leaves one-hot, ``MultiDiscrete`` one one-hot per entry; ``MultiBinary`` as 0/1.
    The ``action_mask`` leaf is not seen: it masks the actions (:func:`masked`).
    """

    layout: Any
    """an :class:`agentax.envs.spaces.Layout`"""
    precision: str = "f32"
    """the products' precision (:data:`agentax.kernels.PRECISIONS`), chosen by the entry point"""

    @nn.compact
    def __call__(self, packed: jax.Array) -> jax.Array:
        parts = []
        for leaf in self.layout.leaves:
            if leaf.kind != "mask":
                x = packed[..., leaf.start : leaf.start + leaf.size]
                parts.append(LEAF_ENCODERS[resolved_encoder(leaf)](leaf, x, self.precision))
        return jnp.concatenate(parts, axis=-1)


def resolved_encoder(leaf: Any) -> str:
    """The encoder a leaf's choice names: "auto" resolved by its kind (an image's by its size)."""
    if leaf.encoder != "auto":
        return leaf.encoder
    if leaf.kind == "image":
        return "nature" if min(leaf.image_hwc[:2]) >= NATURE_PIXELS else "small"
    return "one_hot" if leaf.kind in ("discrete", "multi_discrete") else "flat"


def one_hot_entries(leaf: Any, x: jax.Array, precision: str = "f32") -> jax.Array:
    """A Discrete or MultiDiscrete leaf ``[..., k]`` → one one-hot per entry ``[..., Σ categories]``."""
    ints = x.astype(jnp.int32)
    return jnp.concatenate([jax.nn.one_hot(ints[..., i], n) for i, n in enumerate(leaf.categories)], -1)


def flat_numbers(leaf: Any, x: jax.Array, precision: str = "f32") -> jax.Array:
    """A leaf's entries ``[..., size]`` as floats, scaled (an image's pixels, a vector, an integer)."""
    return x.astype(jnp.float32) * leaf.scale


def image_encoder(torso: str) -> Any:
    """``encode(leaf, x)``: an image leaf through an :class:`ImageEncoder` with ``torso`` (created
    in the calling module, so its parameters keep their names: ``ImageEncoder_<i>``)."""

    def encode(leaf: Any, x: jax.Array, precision: str = "f32") -> jax.Array:
        return ImageEncoder(leaf.image_hwc, leaf.channels_first, leaf.scale, torso, precision)(x)

    return encode


LEAF_ENCODERS: dict[str, Any] = {
    "nature": image_encoder("nature"),
    "small": image_encoder("small"),
    "one_hot": one_hot_entries,
    "scalar": flat_numbers,
    "flat": flat_numbers,
}
"""Each encoder choice (:data:`agentax.envs.spaces.ENCODERS`) → ``encode(leaf, x [..., size], precision) →
features [..., F]``: nature 512, small 256, one_hot Σ categories, scalar one per entry, flat size."""


class ImageEncoder(nn.Module):
    """One image leaf ``[..., H·W·C]`` → ``[..., 512]`` (``torso`` "nature": the Nature CNN's
    convolutions, from 36 px) or ``[..., 256]`` ("small": two 3×3 convolutions, 16 and 32 channels);
    "auto": nature from 36 px, small below. ReLU after each layer."""

    hwc: tuple[int, int, int]
    channels_first: bool = False
    scale: float = 1.0
    torso: str = "auto"
    precision: str = "f32"
    """the dense layer's and the small convolutions' precision (the Nature CNN's stay float32)"""

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        batch_shape = x.shape[:-1]
        height, width, channels = self.hwc
        x = x.astype(jnp.float32).reshape(
            -1, *((channels, height, width) if self.channels_first else self.hwc)
        )
        if self.channels_first:
            x = jnp.transpose(x, (0, 2, 3, 1))
        x = x * self.scale
        init = nn.initializers.orthogonal(jnp.sqrt(2.0))
        large = self.torso == "nature" or (self.torso == "auto" and min(height, width) >= NATURE_PIXELS)
        if large:
            for features, size, stride in ((32, 8, 4), (64, 4, 2), (64, 3, 1)):
                x = nn.relu(nn.Conv(features, (size, size), (stride, stride), "VALID", kernel_init=init)(x))
        else:  # as matrix products over patches: nn.Conv ran ~5x slower in the runner's programs
            x = nn.relu(MatmulConv(16, 3, init, self.precision)(x))
            x = nn.relu(MatmulConv(32, 3, init, self.precision)(x))
        features = 512 if large else 256
        x = nn.relu(dense_layer(features, self.precision, kernel_init=init)(x.reshape(x.shape[0], -1)))
        return x.reshape(*batch_shape, -1)


class MatmulConv(nn.Module):
    """A stride-1 VALID convolution ``[N, H, W, C] → [N, H−size+1, W−size+1, features]``, computed by
    :func:`valid_conv_as_matmul`."""

    features: int
    size: int
    kernel_init: Any = nn.initializers.lecun_normal()
    precision: str = "f32"
    """the products' precision (:data:`agentax.kernels.PRECISIONS`), chosen by the entry point"""

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        return valid_conv_as_matmul(self, x, self.features, self.size, self.kernel_init, self.precision)


class Encoded(nn.Module):
    """``net`` on the :class:`Encoder`'s features of packed observations: ``(obs, *args) →
    net(Encoder(layout)(obs), *args)`` (the network of an env whose observations are packed)."""

    layout: Any
    net: nn.Module
    precision: str = "f32"
    """the encoder's precision (the net has its own)"""

    @nn.compact
    def __call__(self, obs: jax.Array, *args, **kwargs):
        return self.net(Encoder(self.layout, self.precision)(obs), *args, **kwargs)


def with_encoder(net: nn.Module, layout: Any, precision: str = "f32") -> nn.Module:
    """``net`` itself for plain observations (``layout`` None: parameters as they always were), else
    :class:`Encoded` (its encoder's products in ``precision``)."""
    return net if layout is None else Encoded(layout, net, precision)


def unwrapped(net: nn.Module) -> nn.Module:
    """The network an :class:`Encoded` wraps (its settings: actions, atoms, noise); else ``net``."""
    return net.net if isinstance(net, Encoded) else net


def legal_actions(net: nn.Module, obs: jax.Array) -> jax.Array | None:
    """The legal actions ``bool [..., n]`` of observations ``[..., *obs_shape]`` that ``net`` takes,
    from its encoder's layout (None: no mask, every action legal)."""
    return net.layout.legal(obs) if isinstance(net, Encoded) else None


class PolicyNet(nn.Module):
    """Action logits ``[..., num_actions]`` from observations ``[..., obs_dim]``.

    ``sigmoid_head=True`` (two actions only) is the lecture's network: one output ``z`` with
    ``P(action 0) = sigmoid(z)``, returned as logits ``[z, 0]``.
    """

    num_actions: int
    hidden: Sequence[int] = (5,)
    activation: str = "elu"
    sigmoid_head: bool = False
    precision: str = "f32"
    """the products' precision (:data:`agentax.kernels.PRECISIONS`), chosen by the entry point"""

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        x = MLP(self.hidden, self.activation, precision=self.precision)(obs)
        if self.sigmoid_head:
            z = dense_layer(1, self.precision)(x)
            return jnp.concatenate([z, jnp.zeros_like(z)], axis=-1)
        return dense_layer(self.num_actions, self.precision)(x)


class GaussianPolicyNet(nn.Module):
    """A diagonal Gaussian over actions ``[..., action_dim]``: ``obs -> (mean, log_std)``, the mean an
    MLP's output and ``log_std`` a learned parameter independent of the state (:func:`gaussian_head`;
    REINFORCE's policy)."""

    action_dim: int
    hidden: Sequence[int] = (64, 64)
    activation: str = "tanh"
    precision: str = "f32"
    """the products' precision (:data:`agentax.kernels.PRECISIONS`), chosen by the entry point"""

    @nn.compact
    def __call__(self, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        mlp = MLP(self.hidden, self.activation, out=self.action_dim, precision=self.precision)
        return gaussian_head(self, mlp(obs))


def gaussian_head(
    module: nn.Module, out: jax.Array, log_std_range: tuple[float, float] | None = None
) -> tuple[jax.Array, jax.Array]:
    """A diagonal Gaussian's ``(mean, log_std)`` ``[..., d]`` from a policy's last layer ``out``,
    inside ``module`` (its parameters are the module's own, so the tree keeps its names).

    ``log_std_range`` None: ``out`` ``[..., d]`` is the mean and ``log_std`` a learned parameter
    ``"log_std"`` ``[d]`` (zeros at first) independent of the state (PPO's and REINFORCE's head).
    ``(low, high)``: ``out`` ``[..., 2d]`` holds the mean and a raw ``ρ`` squashed smoothly into the
    range, ``log_std = low + (high − low)(tanh(ρ) + 1) / 2`` (SAC's head, as SB3's and CleanRL's)."""
    if log_std_range is None:
        log_std = module.param("log_std", nn.initializers.zeros, (out.shape[-1],))
        return out, jnp.broadcast_to(log_std, out.shape)
    low, high = log_std_range
    mean, raw = jnp.split(out, 2, axis=-1)
    return mean, low + 0.5 * (high - low) * (jnp.tanh(raw) + 1.0)


class SquashedGaussianActor(nn.Module):
    """SAC's actor: ``obs [..., obs_dim] -> (mean [..., d], log_std [..., d])`` of the Gaussian before
    the tanh (:func:`sample_squashed`), ``log_std`` in ``[log_std_min, log_std_max]``."""

    action_dim: int
    hidden: tuple[int, ...]
    activation: str
    log_std_min: float
    log_std_max: float
    precision: str = "f32"
    """the products' precision (:data:`agentax.kernels.PRECISIONS`), chosen by the entry point"""

    @nn.compact
    def __call__(self, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        x = MLP(self.hidden, self.activation, precision=self.precision)(obs.astype(jnp.float32))
        out = dense_layer(2 * self.action_dim, self.precision)(x)
        return gaussian_head(self, out, (self.log_std_min, self.log_std_max))


def sample_squashed(mean: jax.Array, log_std: jax.Array, key: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``(a, log π(a))`` for ``a = tanh(u)``, ``u ~ N(mean, exp(log_std)²)``: ``[..., d]`` →
    ``([..., d], [...])``. The density includes the tanh's change of variables,
    ``log(1 − tanh(u)²) = 2(log 2 − u − softplus(−2u))`` (stable where ``tanh(u)`` rounds to ±1).
    """
    noise = jax.random.normal(key, mean.shape)
    u = mean + jnp.exp(log_std) * noise
    gaussian = (-0.5 * noise**2 - log_std - 0.5 * jnp.log(2 * jnp.pi)).sum(axis=-1)
    jacobian = (2.0 * (jnp.log(2.0) - u - jax.nn.softplus(-2.0 * u))).sum(axis=-1)
    return jnp.tanh(u), gaussian - jacobian


class NatureConvTorso(nn.Module):
    """The Nature CNN's three convolutions without its dense layer: ``[..., 4, 84, 84]`` → ``[..., 3136]``
    (for a noisy 512 layer on top; :class:`NatureCNN` is the same convolutions with a plain one)."""

    conv: str = "xla"
    """the convolution backend, as :class:`NatureCNN`'s"""

    @nn.compact
    def __call__(self, frames: jax.Array) -> jax.Array:
        return nature_convolutions(frames, conv=self.conv)


def scaled_noise(x: jax.Array) -> jax.Array:
    """``f(x) = sgn(x) · √|x|``, the map factorised noisy layers apply to their Gaussian draws."""
    return jnp.sign(x) * jnp.sqrt(jnp.abs(x))


def factorised_noise(key: jax.Array, in_features: int, out_features: int) -> tuple[jax.Array, jax.Array]:
    """Factorised Gaussian noise (Fortunato et al., 2018): ``(ε_kernel [in, out], ε_bias [out])``.

    ``in + out`` standard normal draws instead of ``in · out``: ``ε_kernel = f(ε_in) ⊗ f(ε_out)``,
    ``ε_bias = f(ε_out)`` with ``f`` = :func:`scaled_noise`.
    """
    in_key, out_key = jax.random.split(key)
    eps_in = scaled_noise(jax.random.normal(in_key, (in_features,)))
    eps_out = scaled_noise(jax.random.normal(out_key, (out_features,)))
    return jnp.outer(eps_in, eps_out), eps_out


class NoisyDense(nn.Module):
    """A dense layer with factorised Gaussian weight noise (NoisyNet, Fortunato et al., 2018).

    ``y = x (μ_W + σ_W ⊙ ε_W) + μ_b + σ_b ⊙ ε_b`` with the noise of :func:`factorised_noise`, drawn
    per call from the ``"noise"`` rng (``apply(..., rngs={"noise": key})``); one draw serves the
    whole batch. ``deterministic=True`` uses the mean weights (evaluation). The means are named
    ``kernel`` and ``bias`` as in ``nn.Dense``; initialisation as in the paper: ``μ ~ U[−1/√p, 1/√p]``,
    ``σ = σ0/√p`` for ``p`` inputs.
    """

    features: int
    sigma0: float = 0.5
    precision: str = "f32"
    """the products' precision (:data:`agentax.kernels.PRECISIONS`), chosen by the entry point"""

    @nn.compact
    def __call__(self, x: jax.Array, deterministic: bool = True) -> jax.Array:
        in_features = x.shape[-1]
        bound = 1.0 / jnp.sqrt(in_features)

        def uniform(key, shape, dtype=jnp.float32):
            return jax.random.uniform(key, shape, dtype, -bound, bound)

        sigma = nn.initializers.constant(self.sigma0 * bound)
        kernel = self.param("kernel", uniform, (in_features, self.features))
        bias = self.param("bias", uniform, (self.features,))
        sigma_kernel = self.param("sigma_kernel", sigma, (in_features, self.features))
        sigma_bias = self.param("sigma_bias", sigma, (self.features,))
        if deterministic:
            return kernels.matmul(x, kernel, self.precision) + bias
        eps_kernel, eps_bias = factorised_noise(self.make_rng("noise"), in_features, self.features)
        noisy_kernel = kernel + sigma_kernel * eps_kernel
        return kernels.matmul(x, noisy_kernel, self.precision) + bias + sigma_bias * eps_bias


class QNetwork(nn.Module):
    """Q-values ``[..., num_actions]``, or with ``num_atoms`` the logits ``[..., num_actions, num_atoms]``
    of a return distribution on ``support(v_min, v_max, num_atoms)`` (C51).

    ``dueling`` = "max" (the lecture) or "mean" splits V and A: ``Q = V + (A - max A)`` or
    ``Q = V + (A - mean A)``; with atoms, per atom, before the softmax over atoms (Rainbow).
    ``noisy``: the last hidden layer (the Nature CNN's 512 dense, or the MLP's last) and the heads are
    :class:`NoisyDense`; call with ``deterministic=False`` and ``rngs={"noise": key}`` to draw noise.
    """

    num_actions: int
    hidden: Sequence[int] = (32, 32)
    activation: str = "elu"
    dueling: str | None = None
    cnn: bool = False
    """the Nature CNN torso (image observations) instead of the MLP"""
    num_atoms: int | None = None
    """distributional (C51): logits over this many atoms per action (None: Q-values)"""
    v_min: float = -10.0
    v_max: float = 10.0
    noisy: bool = False
    """factorised noisy layers (NoisyNet) after the torso"""
    noisy_sigma0: float = 0.5
    conv: str = "xla"
    """the Nature CNN's convolution backend (with ``cnn``)"""
    precision: str = "f32"
    """the products' precision (:data:`agentax.kernels.PRECISIONS`), chosen by the entry point"""

    @nn.compact
    def __call__(self, obs: jax.Array, deterministic: bool = True) -> jax.Array:
        precision = self.precision

        def dense(features: int):
            if self.noisy:
                return lambda x: NoisyDense(features, self.noisy_sigma0, precision)(x, deterministic)
            return dense_layer(features, precision)

        if not self.noisy:
            x = (
                NatureCNN(conv=self.conv, precision=precision)(obs)
                if self.cnn
                else MLP(self.hidden, self.activation, precision=precision)(obs.astype(jnp.float32))
            )
        elif self.cnn:
            x = nn.relu(dense(512)(NatureConvTorso(self.conv)(obs)))
        else:
            x = MLP(self.hidden[:-1], self.activation, precision=precision)(obs.astype(jnp.float32))
            if self.hidden:
                x = ACTIVATIONS[self.activation](dense(self.hidden[-1])(x))
        atoms = self.num_atoms or 1
        batch_shape = x.shape[:-1]
        if self.dueling is None:
            out = dense(self.num_actions * atoms)(x).reshape(*batch_shape, self.num_actions, atoms)
        else:
            value = dense(atoms)(x).reshape(*batch_shape, 1, atoms)
            advantage = dense(self.num_actions * atoms)(x).reshape(*batch_shape, self.num_actions, atoms)
            out = dueling_aggregate(value, advantage, self.dueling, axis=-2)
        return out[..., 0] if self.num_atoms is None else out  # (..., num_actions[, num_atoms])


def support(v_min: float, v_max: float, num_atoms: int) -> jax.Array:
    """The C51 support ``[num_atoms]``: returns evenly spaced from ``v_min`` to ``v_max``."""
    return jnp.linspace(v_min, v_max, num_atoms)


def dueling_aggregate(value: jax.Array, advantage: jax.Array, mode: str, axis: int = -1) -> jax.Array:
    """``V + (A - max A)`` (mode "max") or ``V + (A - mean A)`` (mode "mean"), over the actions ``axis``."""
    if mode == "max":
        baseline = advantage.max(axis=axis, keepdims=True)
    elif mode == "mean":
        baseline = advantage.mean(axis=axis, keepdims=True)
    else:
        raise ValueError(f"unknown dueling mode {mode!r}; choose from max, mean")
    return value + advantage - baseline


def shift(frames: jax.Array, dx: jax.Array, dy: jax.Array, pad: int = 4) -> jax.Array:
    """Frames ``[C, H, W]`` moved right by ``dx`` and down by ``dy`` pixels (each in ``[−pad, pad]``),
    the edges replicated: ``out[:, y, x] = frames[:, clip(y − dy), clip(x − dx)]``."""
    padded = jnp.pad(frames, ((0, 0), (pad, pad), (pad, pad)), mode="edge")
    return jax.lax.dynamic_slice(padded, (0, pad - dy, pad - dx), frames.shape)


def random_shift(key: jax.Array, frames: jax.Array, pad: int = 4) -> jax.Array:
    """DrQ's augmentation (Kostrikov et al., 2020) on a batch ``[B, C, H, W]``: pad each sample by
    ``pad`` replicated pixels and crop back to ``H × W`` at a uniformly random offset, per sample."""
    offsets = jax.random.randint(key, (frames.shape[0], 2), -pad, pad + 1)
    return jax.vmap(lambda f, o: shift(f, o[0], o[1], pad))(frames, offsets)


def masked(logits: jax.Array, legal: jax.Array | None) -> jax.Array:
    """Logits (or Q-values) ``[..., n]`` with the illegal actions' entries at -1e9, so that they are
    never sampled, chosen or maximised over and take no probability (``legal`` None: all legal)."""
    return logits if legal is None else jnp.where(legal, logits, -1e9)


def legal_max(q: jax.Array, legal: jax.Array | None) -> jax.Array:
    """``max_a Q[..., a]`` ``[...]`` over the legal actions (``legal`` None: all), read at the masked
    argmax: an observation without a legal action (a final one) gives a finite value, not -1e9."""
    if legal is None:
        return q.max(axis=-1)
    return jnp.take_along_axis(q, jnp.argmax(masked(q, legal), axis=-1)[..., None], axis=-1)[..., 0]


def split_logits(logits: jax.Array, nvec: tuple[int, ...]) -> list[jax.Array]:
    """The logits ``[..., Σ nvec]`` of independent categoricals, one ``[..., nvec[i]]`` per entry."""
    return jnp.split(logits, list(itertools.accumulate(nvec))[:-1], axis=-1)


def sample_action(key: jax.Array, logits: jax.Array, nvec: tuple[int, ...] | None = None) -> jax.Array:
    """Sample actions ``[...]`` from logits ``[..., num_actions]`` (explore); with ``nvec`` (a
    MultiDiscrete or MultiBinary action), one per entry, ``[..., len(nvec)]``."""
    if nvec is None:
        return jax.random.categorical(key, logits, axis=-1)
    keys = jax.random.split(key, len(nvec))
    parts = split_logits(logits, nvec)
    return jnp.stack([jax.random.categorical(k, x) for k, x in zip(keys, parts, strict=True)], -1)


def greedy_action(logits: jax.Array, nvec: tuple[int, ...] | None = None) -> jax.Array:
    """The most probable action ``[...]`` (exploit); with ``nvec``, per entry ``[..., len(nvec)]``."""
    if nvec is None:
        return jnp.argmax(logits, axis=-1)
    return jnp.stack([jnp.argmax(x, axis=-1) for x in split_logits(logits, nvec)], -1)


def log_prob(logits: jax.Array, action: jax.Array, nvec: tuple[int, ...] | None = None) -> jax.Array:
    """``log pi(action | s)`` ``[...]`` from logits ``[..., num_actions]`` and integer actions ``[...]``;
    with ``nvec``, actions ``[..., len(nvec)]`` and the entries' log-probabilities summed."""
    if nvec is not None:
        parts = split_logits(logits, nvec)
        return sum(log_prob(x, action[..., i]) for i, x in enumerate(parts))
    log_probs = jax.nn.log_softmax(logits, axis=-1)
    return jnp.take_along_axis(log_probs, action[..., None].astype(jnp.int32), axis=-1)[..., 0]


def entropy(logits: jax.Array, nvec: tuple[int, ...] | None = None) -> jax.Array:
    """Entropy ``[...]`` of the categorical given by logits ``[..., num_actions]``; with ``nvec`` the
    sum of the entries' entropies."""
    if nvec is not None:
        return sum(entropy(x) for x in split_logits(logits, nvec))
    log_probs = jax.nn.log_softmax(logits, axis=-1)
    return -(jnp.exp(log_probs) * log_probs).sum(axis=-1)


class ActorCritic(nn.Module):
    """Separate actor and critic MLPs (PPO): ``obs [..., obs_dim] -> (actor_out, value [...])``.

    Discrete actions: ``actor_out`` is the logits ``[..., action_dim]``. Continuous actions
    (``continuous=True``): ``actor_out`` is :func:`gaussian_head`'s ``(mean, log_std)``, each
    ``[..., action_dim]``, ``log_std`` a learned parameter independent of the state.
    Orthogonal initialisation (gain √2 hidden, 0.01 policy head, 1 value head) as in the PPO paper's code.
    With ``cnn`` both heads sit on one shared Nature CNN; with ``image_shape`` on one shared
    :class:`MinAtarCNN` (flat observations of that image).
    """

    action_dim: int
    continuous: bool = False
    hidden: Sequence[int] = (64, 64)
    activation: str = "tanh"
    cnn: bool = False
    """one Nature CNN torso shared by actor and critic (image observations), as CleanRL's Atari PPO"""
    image_shape: tuple[int, ...] | None = None
    """one MinAtar conv torso shared by actor and critic, on flat observations of this ``[H, W, C]``"""
    conv: str = "xla"
    """the Nature CNN's convolution backend (with ``cnn``)"""
    precision: str = "f32"
    """the products' precision (:data:`agentax.kernels.PRECISIONS`), chosen by the entry point"""

    @nn.compact
    def __call__(self, obs: jax.Array):
        act = ACTIVATIONS[self.activation]
        hidden_init = nn.initializers.orthogonal(jnp.sqrt(2.0))
        shared = self.cnn or self.image_shape is not None
        precision = self.precision
        if self.cnn:
            actor = critic = NatureCNN(conv=self.conv, precision=precision)(obs)
        elif self.image_shape is not None:
            actor = critic = MinAtarCNN(tuple(self.image_shape), precision=precision)(obs)
        else:
            actor = critic = obs.astype(jnp.float32)
        for width in () if shared else self.hidden:
            actor = act(dense_layer(width, precision, kernel_init=hidden_init)(actor))
            critic = act(dense_layer(width, precision, kernel_init=hidden_init)(critic))
        orthogonal = nn.initializers.orthogonal
        actor_out = dense_layer(self.action_dim, precision, kernel_init=orthogonal(0.01))(actor)
        value = dense_layer(1, precision, kernel_init=orthogonal(1.0))(critic)[..., 0]
        return (gaussian_head(self, actor_out) if self.continuous else actor_out), value


CORES = ("none", "lstm", "gru")
"""The recurrent cores an actor-critic may carry after its torso ("none": feed-forward)."""
Memory = Any
"""A recurrent core's carry: LSTM ``(c, h)``, GRU ``h``, each ``[..., core_size]``."""


def zero_memory(core: str, core_size: int, batch_shape: tuple[int, ...] = ()) -> Memory:
    """The carry of a core at an episode's start: zeros ``[*batch_shape, core_size]``."""
    zeros = jnp.zeros((*batch_shape, core_size), jnp.float32)
    return (zeros, zeros) if core == "lstm" else zeros


def reset_where(first: jax.Array, memory: Memory) -> Memory:
    """``memory`` with the carry of each env whose observation starts an episode (``first``, bool
    ``[...]``) set back to zeros; the others' as they are."""
    return jax.tree.map(lambda m: jnp.where(first[..., None], jnp.zeros_like(m), m), memory)


class GateWeights(nn.Module):
    """One gate's weights as flax's recurrent cells name them: ``kernel [in, features]`` (and ``bias
    [features]``), created, not applied."""

    features: int
    use_bias: bool
    kernel_init: Any

    @nn.compact
    def __call__(self, in_features: int) -> tuple[jax.Array, jax.Array | None]:
        kernel = self.param("kernel", self.kernel_init, (in_features, self.features), jnp.float32)
        bias = (
            self.param("bias", nn.initializers.zeros, (self.features,), jnp.float32)
            if self.use_bias
            else None
        )
        return kernel, bias


CORE_GATES = {"lstm": "ifgo", "gru": "rzn"}
"""Each core's gates, in the order of its fused products (flax's: LSTM i, f, g, o; GRU r, z, n)."""


class RecurrentCore(nn.Module):
    """An LSTM or GRU core, the same function and parameters as flax's ``OptimizedLSTMCell`` /
    ``GRUCell`` (its gates' weights under their names: ``ii``, ``hi``, ... / ``ir``, ``hr``, ...), so
    runs and checkpoints saved with the flax cells load as they were.

    ``(memory [B, ...], x [B, in], first [B])`` → ``(memory, out [B, features])``: one step, the memory
    reset to zeros first where ``first`` is set. With ``over_time`` the inputs run through a sequence,
    ``x [T, B, in]``, ``first [T, B]`` → ``(the memory after each step [T, B, ...], out [T, B, features])``.

    Why not the flax cell under ``lax.scan``: XLA's CPU backend runs a loop's body op by op, each
    op's few µs each step, and autodiff of the cell in a scan adds the largest ops of all to the
    gradient's loop: each step's weight gradient ``h_{t-1}ᵀ · dz_t`` as an outer product, summed
    into a ``[n, G·n]`` array, and the transposed weights' product. So over a sequence the input's
    product for every gate of every step is one matrix product before the loop, the loop keeps only
    ``h · W_h`` and the gates (:func:`lstm_sequence`, :func:`gru_sequence`), and their hand-written
    gradient's loop only ``dz_t · W_hᵀ``: the weight gradient is one product over all steps after it.
    """

    kind: str = "lstm"
    features: int = 128

    @nn.compact
    def __call__(self, memory: Memory, x: jax.Array, first: jax.Array, over_time: bool = False):
        orthogonal, lecun = nn.initializers.orthogonal(), nn.initializers.lecun_normal()
        inputs, hiddens = [], []
        for gate in CORE_GATES[self.kind]:  # flax's order of creation: the input's weights, then h's
            input_bias, hidden_bias = self.kind == "gru", self.kind == "lstm" or gate == "n"
            inputs.append(GateWeights(self.features, input_bias, lecun, name=f"i{gate}")(x.shape[-1]))
            hiddens.append(
                GateWeights(self.features, hidden_bias, orthogonal, name=f"h{gate}")(self.features)
            )
        w_x = jnp.concatenate([kernel for kernel, _ in inputs], axis=-1)  # (in, G·n)
        w_h = jnp.concatenate([kernel for kernel, _ in hiddens], axis=-1)  # (n, G·n)
        projected = x @ w_x  # (..., G·n): every step's at once
        if self.kind == "gru":
            projected = projected + jnp.concatenate([bias for _, bias in inputs])
            b_h = hiddens[2][1]  # (n,): h's only bias, inside the reset gate's product
        else:
            b_h = jnp.concatenate([bias for _, bias in hiddens])  # (4n,)
        if over_time:
            sequence = lstm_sequence if self.kind == "lstm" else gru_sequence
            memories = sequence(w_h, b_h, memory, projected, first)
            return memories, memories[1] if self.kind == "lstm" else memories
        step = lstm_step if self.kind == "lstm" else gru_step
        memory = step(w_h, b_h, reset_where(first, memory), projected)[0]
        return memory, memory[1] if self.kind == "lstm" else memory


def lstm_step(w_h: jax.Array, b_h: jax.Array, memory: Memory, projected: jax.Array):
    """One LSTM step from the input's product ``projected = x · W_x`` ``[..., 4n]``:
    ``i, f, g, o = σ, σ, tanh, σ(h · W_h + b_h + projected)``, ``c' = f c + i g``, ``h' = o tanh(c')``
    (flax's ``OptimizedLSTMCell``, its sums in its order). Returns ``((c', h'), gates [..., 4n])``,
    the gates ``i, f, g, o`` after their nonlinearities (what the gradient needs)."""
    c, h = memory
    i, f, g, o = jnp.split(h @ w_h + b_h + projected, 4, axis=-1)
    i, f, g, o = jax.nn.sigmoid(i), jax.nn.sigmoid(f), jnp.tanh(g), jax.nn.sigmoid(o)
    c = f * c + i * g
    return (c, o * jnp.tanh(c)), jnp.concatenate([i, f, g, o], axis=-1)


def gru_step(w_h: jax.Array, b_hn: jax.Array, h: jax.Array, projected: jax.Array):
    """One GRU step from the input's product with its biases ``projected = x · W_x + b_x`` ``[..., 3n]``:
    ``r, z = σ(x_r + h · W_hr), σ(x_z + h · W_hz)``, ``n = tanh(x_n + r (h · W_hn + b_hn))``,
    ``h' = (1 − z) n + z h`` (flax's ``GRUCell``). Returns ``(h', (r, z, n, h · W_hn + b_hn))``."""
    x_r, x_z, x_n = jnp.split(projected, 3, axis=-1)
    h_r, h_z, h_n = jnp.split(h @ w_h, 3, axis=-1)
    r, z = jax.nn.sigmoid(x_r + h_r), jax.nn.sigmoid(x_z + h_z)
    h_n = h_n + b_hn
    n = jnp.tanh(x_n + r * h_n)
    return (1.0 - z) * n + z * h, (r, z, n, h_n)


def _flat_product(a: jax.Array, b: jax.Array) -> jax.Array:
    """``Σ_{t, b} a[t, b]ᵀ b[t, b]``: ``[T, B..., m] × [T, B..., k] → [m, k]``, one matrix product."""
    return a.reshape(-1, a.shape[-1]).T @ b.reshape(-1, b.shape[-1])


def _run(step: Any, memory: Memory, projected: jax.Array, first: jax.Array) -> Memory:
    """``step(memory, projected_t) -> (memory, _)`` through ``projected`` ``[T, ...]``, resetting where
    ``first`` ``[T, B...]`` says: the memory after each step ``[T, B..., n]`` (all the loop keeps)."""

    def body(memory: Memory, inputs: tuple[jax.Array, jax.Array]) -> tuple[Memory, Memory]:
        memory = step(reset_where(inputs[1], memory), inputs[0])[0]
        return memory, memory

    return jax.lax.scan(body, memory, (projected, first))[1]


def _starts(memory: Memory, memories: Memory, first: jax.Array) -> Memory:
    """The memory each step of a sequence started from ``[T, B..., n]``: the one before it (``memory``
    for the first), reset where ``first``."""
    shifted = jax.tree.map(lambda m, ms: jnp.concatenate([m[None], ms[:-1]]), memory, memories)
    return reset_where(first, shifted)


@jax.custom_vjp
def lstm_sequence(w_h: jax.Array, b_h: jax.Array, memory: Memory, projected: jax.Array, first: jax.Array):
    """The LSTM run through a sequence from ``memory`` ``(c, h)`` ``[B..., n]``: ``projected``
    ``[T, B..., 4n]`` (each step's ``x · W_x``), ``first`` bool ``[T, B...]`` (reset before the step)
    → the memory after each step, ``(c, h)`` ``[T, B..., n]``. Its gradient is written out: the
    gates are recomputed for all steps at once, the loop back through time carries ``dc, dh``, and
    ``∂W_h = Σ_t h_{t-1}ᵀ dz_t`` is one product after it."""
    return _run(functools.partial(lstm_step, w_h, b_h), memory, projected, first)


def _lstm_sequence_fwd(w_h, b_h, memory, projected, first):
    memories = lstm_sequence(w_h, b_h, memory, projected, first)
    c_prevs, h_prevs = _starts(memory, memories, first)
    _, gates = lstm_step(w_h, b_h, (c_prevs, h_prevs), projected)  # (T, B..., 4n), every step at once
    return memories, (w_h, memories[0], (c_prevs, h_prevs, gates), first)


def _lstm_sequence_bwd(residuals, cotangents):
    w_h, cs, (c_prevs, h_prevs, gates), first = residuals
    w_t = w_h.T  # (4n, n), laid out once for the loop's product

    def body(carry, inputs):
        dc_next, dh_next = carry  # from step t + 1, through its c_prev and h_prev
        dc_out, dh_out, c, c_prev, gate, first_t = inputs
        i, f, g, o = jnp.split(gate, 4, axis=-1)
        dh = dh_out + dh_next
        tanh_c = jnp.tanh(c)
        dc = dc_out + dc_next + dh * o * (1.0 - tanh_c * tanh_c)
        dz = jnp.concatenate(
            [
                dc * g * i * (1.0 - i),
                dc * c_prev * f * (1.0 - f),
                dc * i * (1.0 - g * g),
                dh * tanh_c * o * (1.0 - o),
            ],
            axis=-1,
        )
        return reset_where(first_t, (dc * f, dz @ w_t)), dz

    zeros = jnp.zeros_like(cs[0])
    inputs = (*cotangents, cs, c_prevs, gates, first)
    (dc0, dh0), dz = jax.lax.scan(body, (zeros, zeros), inputs, reverse=True)  # dz: (T, B..., 4n)
    return _flat_product(h_prevs, dz), dz.reshape(-1, dz.shape[-1]).sum(0), (dc0, dh0), dz, None


lstm_sequence.defvjp(_lstm_sequence_fwd, _lstm_sequence_bwd)


@jax.custom_vjp
def gru_sequence(w_h: jax.Array, b_hn: jax.Array, h: jax.Array, projected: jax.Array, first: jax.Array):
    """The GRU run through a sequence from ``h`` ``[B..., n]``: ``projected`` ``[T, B..., 3n]`` (each
    step's ``x · W_x + b_x``), ``first`` bool ``[T, B...]`` → ``h`` after each step ``[T, B..., n]``,
    its gradient written out as :func:`lstm_sequence`'s."""
    return _run(functools.partial(gru_step, w_h, b_hn), h, projected, first)


def _gru_sequence_fwd(w_h, b_hn, h, projected, first):
    hs = gru_sequence(w_h, b_hn, h, projected, first)
    h_prevs = _starts(h, hs, first)
    _, saved = gru_step(w_h, b_hn, h_prevs, projected)  # every step at once
    return hs, (w_h, (h_prevs, *saved), first)


def _gru_sequence_bwd(residuals, dhs):
    w_h, (h_prevs, rs, zs, ns, h_ns), first = residuals
    w_t = w_h.T  # (3n, n)

    def body(dh_next, inputs):
        dh_out, h_prev, r, z, n, h_n, first_t = inputs
        dh = dh_out + dh_next
        dn = dh * (1.0 - z) * (1.0 - n * n)  # through n's tanh
        dr = dn * h_n * r * (1.0 - r)
        dz = dh * (h_prev - n) * z * (1.0 - z)
        dx = jnp.concatenate([dr, dz, dn], axis=-1)  # the input's product's gradient
        da = jnp.concatenate([dr, dz, dn * r], axis=-1)  # h · W_h's
        return reset_where(first_t, dh * z + da @ w_t), (dx, da)

    inputs = (dhs, h_prevs, rs, zs, ns, h_ns, first)
    dh0, (dx, da) = jax.lax.scan(body, jnp.zeros_like(h_prevs[0]), inputs, reverse=True)
    n = h_prevs.shape[-1]
    return _flat_product(h_prevs, da), da[..., 2 * n :].reshape(-1, n).sum(0), dh0, dx, None


gru_sequence.defvjp(_gru_sequence_fwd, _gru_sequence_bwd)


def core_step(
    core: str, core_size: int, memory: Memory, first: jax.Array, x: jax.Array, over_time: bool = False
) -> tuple[Memory, jax.Array]:
    """The recurrent core inside a compact module (its parameters the caller's, named as flax's
    ``OptimizedLSTMCell`` / ``GRUCell`` were: :class:`RecurrentCore`, ``core_size`` units): the
    features ``x [..., F]`` with ``memory`` reset to zeros first where ``first`` (bool ``[...]``)
    marks an episode's start; ``(memory, output [..., core_size])``, or over a sequence with
    ``over_time`` (``x [T, B, F]``, ``first [T, B]``)."""
    name = "OptimizedLSTMCell_0" if core == "lstm" else "GRUCell_0"  # the flax cells' names
    return RecurrentCore(core, core_size, name=name)(memory, x, first, over_time)


class RecurrentActorCritic(nn.Module):
    """PPO's actor-critic with memory, one step: ``(obs [..., *obs_shape], memory, first [...]) ->
    (memory, (actor_out, value [...]))``; with ``over_time=True`` a sequence, ``obs [T, B, ...]``,
    ``first [T, B]`` from ``memory [B, ...]`` → ``(the memory after each step [T, B, ...], (actor_out,
    value) [T, B, ...])``, the same numbers as the step run ``T`` times.

    The torso (the MLP of ``hidden``, or the Nature / MinAtar CNN) encodes the observation, the core
    (:class:`RecurrentCore`: ``"lstm"`` or ``"gru"``, ``core_size`` units) takes it with its carry,
    reset to zeros first where ``first`` marks an episode's start (PureJaxRL's ``ppo_rnn``, CleanRL's
    ``ppo_atari_lstm``), and an actor and a critic head of one hidden layer (``core_size`` units) each
    read the core's output. ``actor_out`` as :class:`ActorCritic`'s. Over a sequence only the core
    loops; the torso and the heads take all steps at once.
    """

    action_dim: int
    continuous: bool = False
    hidden: Sequence[int] = (64,)
    activation: str = "tanh"
    core: str = "lstm"
    core_size: int = 128
    cnn: bool = False
    image_shape: tuple[int, ...] | None = None
    conv: str = "xla"

    @nn.compact
    def __call__(self, obs: jax.Array, memory: Memory, first: jax.Array, over_time: bool = False):
        act = ACTIVATIONS[self.activation]
        hidden_init = nn.initializers.orthogonal(jnp.sqrt(2.0))
        if self.cnn:
            x = NatureCNN(conv=self.conv)(obs)
        elif self.image_shape is not None:
            x = MinAtarCNN(tuple(self.image_shape))(obs)
        else:
            x = obs.astype(jnp.float32)
            for width in self.hidden:
                x = act(nn.Dense(width, kernel_init=hidden_init)(x))
        memory, x = core_step(self.core, self.core_size, memory, first, x, over_time)
        actor = act(nn.Dense(self.core_size, kernel_init=hidden_init)(x))
        critic = act(nn.Dense(self.core_size, kernel_init=hidden_init)(x))
        actor_out = nn.Dense(self.action_dim, kernel_init=nn.initializers.orthogonal(0.01))(actor)
        value = nn.Dense(1, kernel_init=nn.initializers.orthogonal(1.0))(critic)[..., 0]
        return memory, ((gaussian_head(self, actor_out) if self.continuous else actor_out), value)


class RecurrentQNetwork(nn.Module):
    """PQN's Q-network with memory, one step: ``(obs [..., *obs_shape], memory, first [...]) ->
    (memory, Q [..., num_actions])``, or over a sequence with ``over_time`` as
    :class:`RecurrentActorCritic`: the torso with LayerNorm (the MLP of ``hidden``, or the Nature
    / MinAtar CNN), the core (:func:`core_step`, reset where ``first``), a hidden layer of
    ``core_size`` units with LayerNorm, and the Q head."""

    num_actions: int
    hidden: Sequence[int] = (128,)
    activation: str = "relu"
    core: str = "lstm"
    core_size: int = 128
    cnn: bool = False
    image_shape: tuple[int, ...] | None = None
    conv: str = "xla"

    @nn.compact
    def __call__(self, obs: jax.Array, memory: Memory, first: jax.Array, over_time: bool = False):
        if self.cnn:
            x = NatureCNN(layer_norm=True, conv=self.conv)(obs)
        elif self.image_shape is not None:
            x = MinAtarCNN(tuple(self.image_shape), layer_norm=True)(obs)
        else:
            x = MLP(self.hidden, self.activation, layer_norm=True)(obs.astype(jnp.float32))
        memory, x = core_step(self.core, self.core_size, memory, first, x, over_time)
        x = ACTIVATIONS[self.activation](nn.LayerNorm()(nn.Dense(self.core_size)(x)))
        return memory, nn.Dense(self.num_actions)(x)


def gaussian_log_prob(mean: jax.Array, log_std: jax.Array, action: jax.Array) -> jax.Array:
    """``log N(action; mean, exp(log_std)^2)`` summed over the action dimensions: ``[..., d] -> [...]``."""
    z = (action - mean) * jnp.exp(-log_std)
    return (-0.5 * z**2 - log_std - 0.5 * jnp.log(2 * jnp.pi)).sum(axis=-1)


def gaussian_entropy(log_std: jax.Array) -> jax.Array:
    """Entropy of a diagonal Gaussian, summed over the action dimensions: ``[..., d] -> [...]``."""
    return (log_std + 0.5 * jnp.log(2 * jnp.pi * jnp.e)).sum(axis=-1)


class MinAtarCNN(nn.Module):
    """MinAtar's network torso (Young & Tian, 2019, ``examples/dqn.py``; purejaxql's ``pqn_minatar``
    ``CNN`` is the same with LayerNorm): flat observations ``[..., H·W·C]`` → ``[..., features]``.

    The vector is reshaped back to the env's ``image_shape`` ``[H, W, C]`` (MinAtar: ``[10, 10, C]``
    channels of 0/1), then conv 16 3×3 stride 1 without padding (→ ``[8, 8, 16]``), ReLU, dense
    ``features``, ReLU; ``layer_norm`` puts LayerNorm before each ReLU (over each position's 16
    channels after the conv), as PQN does. Orthogonal initialisation with gain √2, as the Nature CNN.

    The convolution is computed as one matrix product over 3×3 patches
    (:func:`valid_conv_as_matmul`), the same function as ``nn.Conv``: XLA on CPU ran ``nn.Conv``
    under the runner's vmap over seeds several times slower (PPO on Breakout-MinAtar, one seed:
    ~670 agent steps/s with ``nn.Conv``, ~3,500 with the matrix product, measured on 2 shared cores).
    """

    image_shape: tuple[int, ...]
    features: int = 128
    layer_norm: bool = False
    precision: str = "f32"
    """the products' precision (:data:`agentax.kernels.PRECISIONS`), chosen by the entry point"""

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        batch_shape = obs.shape[:-1]
        x = obs.astype(jnp.float32).reshape(-1, *self.image_shape)  # (N, H, W, C)
        init = nn.initializers.orthogonal(jnp.sqrt(2.0))
        x = valid_conv_as_matmul(self, x, 16, 3, init, self.precision)  # (N, H-2, W-2, 16)
        x = nn.relu(nn.LayerNorm()(x) if self.layer_norm else x)
        x = dense_layer(self.features, self.precision, kernel_init=init)(x.reshape(x.shape[0], -1))
        x = nn.relu(nn.LayerNorm()(x) if self.layer_norm else x)
        return x.reshape(*batch_shape, self.features)


def valid_conv_as_matmul(
    module: nn.Module, x: jax.Array, features: int, size: int, init, precision: str = "f32"
) -> jax.Array:
    """A stride-1 VALID convolution ``[N, H, W, C] -> [N, H-size+1, W-size+1, features]`` inside
    ``module``, computed as one matrix product over the ``size × size`` patches (im2col), in
    ``precision``: ``out[n, y, x] = Σ_{i, j, c} x[n, y+i, x+j, c] · kernel[i, j, c] + bias``, as
    ``nn.Conv``."""
    n, h, w, c = x.shape
    kernel = module.param("conv_kernel", init, (size, size, c, features))
    bias = module.param("conv_bias", nn.initializers.zeros, (features,))
    oh, ow = h - size + 1, w - size + 1
    patches = jnp.concatenate(
        [x[:, i : i + oh, j : j + ow, :] for i in range(size) for j in range(size)], axis=-1
    )  # (N, oh, ow, size·size·C), ordered as the kernel's (kh, kw, C)
    return kernels.matmul(patches, kernel.reshape(size * size * c, features), precision) + bias


class TwinQ(nn.Module):
    """Two independent Q-networks on ``(obs, action)`` (SAC and TD3's clipped double Q):
    ``obs [..., obs_dim], action [..., action_dim] -> q [2, ...]``."""

    hidden: Sequence[int] = (256, 256)
    activation: str = "relu"
    precision: str = "f32"
    """the products' precision (:data:`agentax.kernels.PRECISIONS`), chosen by the entry point"""

    @nn.compact
    def __call__(self, obs: jax.Array, action: jax.Array) -> jax.Array:
        x = jnp.concatenate([obs.astype(jnp.float32), action], axis=-1)
        mlp = functools.partial(MLP, self.hidden, self.activation, out=1, precision=self.precision)
        return jnp.stack([mlp()(x)[..., 0] for _ in range(2)])


def polyak(target: Any, online: Any, tau: float | jax.Array) -> Any:
    """``θ⁻ ← τ θ + (1 − τ) θ⁻`` leaf by leaf (τ = 1 copies)."""
    return jax.tree.map(lambda t, p: tau * p + (1.0 - tau) * t, target, online)

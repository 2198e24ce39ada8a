"""Deep Q-learning (Mnih et al., 2015) and its variants, each a config flag that combines with the others.

A Q-network maps an observation to one value per action; the agent acts ε-greedily and learns
from replayed transitions by regressing ``Q(s, a)`` onto the TD target::

    y = r + γ^k · Q_target(s′, argmax_a Q_select(s′, a)) · (1 − terminated)

``k`` is 1, or the number of rewards summed by an n-step transition. Truncation by a time limit
still bootstraps (from the observation the step really reached); only termination stops it. Where
observations carry a legal-action mask (:meth:`~agentax.agents.protocol.EnvSpec.legal`), the argmax
runs over the legal actions of ``s′`` and ε-greedy acts among the legal actions of ``s``.

==================  =============================  ==========================================
variant             flag                           what changes
==================  =============================  ==========================================
fixed Q targets     ``target_update_period`` > 0   Q_target uses ``target_params``, synced every
                    (``target_update_tau`` < 1:    K learning steps (copy, or Polyak averaging
                    Polyak)                        ``θ⁻ ← τ θ + (1 − τ) θ⁻``)
Double DQN          ``double``                     Q_select is the online network, Q_target values
dueling             ``dueling``                    ``Q = V + (A − max A)`` (the lecture) or mean
prioritized replay  ``prioritized``                sample ∝ (|δ| + ε)^ζ, loss weighted by w
n-step returns      ``n_step`` > 1                 r is a discounted sum of n rewards, γ^n bootstrap
distributional      ``distributional``             C51: a categorical return distribution per
(C51)               (``num_atoms``, ``v_min``,     action, Q = Σ z p; the target distribution
                    ``v_max``)                     r + γ^k z (1 − terminated) is projected onto the
                                                   support; cross-entropy loss (also the priority)
noisy networks      ``noisy`` (``noisy_sigma0``)   factorised Gaussian weight noise after the torso
                                                   explores (ε can be 0); evaluation: mean weights
augmentation        ``augment="shift"``            DrQ's random shifts of replayed frames (±4 px)
==================  =============================  ==========================================

All of them together (Double, dueling, prioritized, n-step, distributional, noisy) are Rainbow
(Hessel et al., 2018); preset ``der`` (:mod:`agentax.agents.presets`) is its data-efficient version
for Atari 100k.

Without a target network (``target_update_period=0``, the lecture's plain DQN) both Q_select and
Q_target are the online network, and ``double`` changes nothing.

The algorithm is pure functions: ``init``, ``act`` and ``learn = make_learn(cfg)``, the last
picking the loss pieces once, outside ``jit``. Runners own the loop: ``make_agent(spec, cfg)`` hands
them these functions and the replay and schedule they learn with (``OffPolicy``); the compiled
runner builds its program from them (:mod:`agentax.runners.rollout`, where the per-seed early stop
``--freeze-at-return`` lives), the host runners drive them with a Driver.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax
from flax import struct

from agentax.agents.protocol import PRIORITY, Agent, EnvSpec, Loop, OffPolicy, check_fields, discrete_actions
from agentax.envs.spaces import Layout
from agentax.errors import UsageError
from agentax.nets import (
    QNetwork,
    is_image,
    legal_actions,
    masked,
    random_shift,
    support,
    unwrapped,
    with_encoder,
)
from agentax.policies import Policy, epsilon_greedy, linear_schedule
from agentax.replay import ReplaySample
from agentax.returns import bootstrap_discount


@dataclass(frozen=True)
class DQNConfig:
    """Hyperparameters of DQN and its variants (defaults: the tuned CartPole-v1 preset, "default")."""

    hidden: tuple[int, ...] = (64, 64)
    """Widths of the Q-network's hidden layers."""
    activation: str = "relu"
    """Activation of the hidden layers: elu, relu, tanh, gelu or swish."""
    dueling: bool = False
    """Dueling head: Q = V + A − baseline(A), the baseline chosen by dueling_baseline."""
    dueling_baseline: str = "max"
    """The dueling head's baseline: "max" (Q = V + A − max A, the lecture) or "mean" (A − mean A)."""
    double: bool = True
    """Double DQN: the online network picks the next action, the target network values it."""
    target_update_period: int = 256
    """Learning steps between target-network updates; 0: no target network (bootstrap from online)."""
    target_update_tau: float = 1.0
    """Share of the online weights mixed into the target at each update: 1 copies, 0.01 is Polyak."""
    discount_factor: float = 0.99
    """γ, the weight of the next state's value in the TD target."""
    learning_rate: float = 2.3e-3
    """The optimizer's step size."""
    optimizer: str = "adam"
    """"adam", or "rmsprop" (centered, decay 0.95, ε 1e-5: the TF-Agents and Nature DQN's optimizer)."""
    adam_eps: float = 1e-8
    """Adam's ε (1e-8 as Optax's; DQN on Atari often uses 1.5e-4 or 1e-2 / batch size)."""
    anneal_learning_rate: bool = False
    """Decay the step size linearly to 0 over the run's learning steps (settles a solved agent)."""
    max_grad_norm: float | None = 10.0
    """Clip the gradient to this global norm (None: no clipping)."""
    loss: str = "huber"
    """TD loss: "mse" (mean squared TD error, the lecture) or "huber" (quadratic within ±1, then linear)."""
    batch_size: int = 64
    """Transitions per learning step."""
    buffer_size: int = 50_000
    """Replay capacity: the most recent transitions kept."""
    n_step: int = 3
    """Rewards summed per transition before bootstrapping (1: one-step TD)."""
    prioritized: bool = False
    """Prioritized replay: sample ∝ (|δ| + ε)^ζ and weight the loss by importance weights."""
    priority_exponent: float = 0.6
    """ζ: how strongly sampling follows the priorities (0: uniform)."""
    importance_exponent_start: float = 0.4
    """β at the start of training, annealed linearly to 1 by the end."""
    num_envs: int = 4
    """Environments stepped side by side to collect transitions."""
    schedule_unit: str = "steps"
    """Unit of learning_starts, train_frequency and exploration_duration: "steps" (env steps summed over
    envs) or "episodes" (the lecture's loop: ε per episode, learning steps at episode ends; one env)."""
    learning_starts: int = 1_000
    """Collect this many steps (or episodes) before the first learning step."""
    train_frequency: int = 64
    """Steps per env (or episodes) collected between learning phases."""
    gradient_steps: int = 128
    """Learning steps per learning phase."""
    epsilon_start: float = 1.0
    """ε at the start: the probability of a random action."""
    epsilon_end: float = 0.04
    """ε after exploration_duration."""
    exploration_duration: int = 8_000
    """Steps (or episodes) over which ε moves linearly from epsilon_start to epsilon_end."""
    max_episodes: int = 0
    """Stop collecting and learning after this many episodes (0: no limit; the lecture's 600)."""
    total_steps: int = 60_000
    """Env steps of the whole run (summed over envs)."""
    distributional: bool = False
    """C51 (Bellemare et al., 2017): learn a categorical return distribution on ``num_atoms`` atoms from
    v_min to v_max (cross-entropy to the projected target; ``loss`` is then unused)."""
    num_atoms: int = 51
    """Atoms of the distributional support."""
    v_min: float = -10.0
    """The distributional support's lowest return."""
    v_max: float = 10.0
    """The distributional support's highest return."""
    noisy: bool = False
    """Noisy networks (Fortunato et al., 2018): factorised Gaussian noise in the last hidden layer and
    the heads, drawn anew at every action and learning step; exploration comes from the noise (ε can be
    0); evaluation uses the mean weights."""
    noisy_sigma0: float = 0.5
    """σ0 of the noisy layers: the noise scale starts at σ0/√(inputs)."""
    augment: str = "none"
    """Image augmentation of replayed observations: "none" or "shift" (DrQ: pad 4 pixels by replication,
    crop back at a random offset, per sample, for obs and next_obs)."""

    @property
    def steps_per_update(self) -> int:
        """Env steps (summed over envs) of one ``update`` of the compiled runner."""
        return self.num_envs * (1 if self.schedule_unit == "episodes" else self.train_frequency)

    @property
    def num_updates(self) -> int:
        return max(1, self.total_steps // self.steps_per_update)

    @property
    def num_learning_steps(self) -> int:
        """Learning steps of a whole run in the steps schedule (in the episode one: an upper bound)."""
        if self.schedule_unit == "episodes":
            return max(self.max_episodes or self.total_steps, 1) * self.gradient_steps // self.train_frequency
        learning_updates = self.num_updates - self.learning_starts // self.steps_per_update
        return max(learning_updates, 0) * self.gradient_steps

    def validate(self) -> DQNConfig:
        """Raise ``UsageError`` naming the first bad value; return ``self``."""
        check_fields(
            self,
            positive=("learning_rate", "target_update_tau"),
            unit_interval=("discount_factor", "target_update_tau"),
            non_negative=("noisy_sigma0",),
        )
        checks = [
            (self.loss in ("mse", "huber"), f"unknown loss {self.loss!r}; choose from mse, huber"),
            (
                self.optimizer in ("adam", "rmsprop"),
                f"unknown optimizer {self.optimizer!r}; choose from adam, rmsprop",
            ),
            (
                self.dueling_baseline in ("max", "mean"),
                f"unknown dueling_baseline {self.dueling_baseline!r}; choose from max, mean",
            ),
            (self.n_step >= 1, f"n_step must be at least 1, got {self.n_step}"),
            (
                self.target_update_period >= 0,
                f"target_update_period must be >= 0, got {self.target_update_period}",
            ),
            (self.batch_size >= 1 and self.buffer_size >= 1, "batch_size and buffer_size must be at least 1"),
            (self.num_envs >= 1, f"num_envs must be at least 1, got {self.num_envs}"),
            (self.train_frequency >= 1, f"train_frequency must be at least 1, got {self.train_frequency}"),
            (self.total_steps >= 1, f"total_steps must be at least 1, got {self.total_steps}"),
            (
                self.schedule_unit in ("steps", "episodes"),
                f"unknown schedule_unit {self.schedule_unit!r}; choose from steps, episodes",
            ),
            (
                self.schedule_unit == "steps" or self.num_envs == 1,
                "schedule_unit='episodes' (the lecture's loop) needs num_envs=1",
            ),
            (self.num_atoms >= 2, f"num_atoms must be at least 2, got {self.num_atoms}"),
            (self.v_min < self.v_max, f"v_min must be below v_max, got {self.v_min} and {self.v_max}"),
            (
                self.augment in AUGMENTATIONS,
                f"unknown augment {self.augment!r}; choose from {', '.join(AUGMENTATIONS)}",
            ),
        ]
        for ok, message in checks:
            if not ok:
                raise UsageError(message)
        return self


@struct.dataclass
class DQNState:
    """The learner: online and target parameters, optimizer state, learning steps taken."""

    params: Any
    target_params: Any
    opt_state: Any
    step: jax.Array  # int32 []: learning steps so far
    network: nn.Module = struct.field(pytree_node=False)
    """the :class:`QNetwork`, behind its encoder where observations are packed (:func:`with_encoder`)"""


def q_network(
    cfg: DQNConfig, num_actions: int, cnn: bool = False, conv: str = "xla", precision: str = "f32"
) -> QNetwork:
    """The Q-network of ``cfg``'s variant (``cnn``: on the Nature CNN, its convolutions on ``conv``),
    its products in ``precision``."""
    return QNetwork(
        num_actions=num_actions,
        hidden=tuple(cfg.hidden),
        activation=cfg.activation,
        dueling=cfg.dueling_baseline if cfg.dueling else None,
        cnn=cnn,
        num_atoms=cfg.num_atoms if cfg.distributional else None,
        v_min=cfg.v_min,
        v_max=cfg.v_max,
        noisy=cfg.noisy,
        noisy_sigma0=cfg.noisy_sigma0,
        conv=conv,
        precision=precision,
    )


def forward(network: nn.Module, params: Any, obs: jax.Array, noise_key: jax.Array | None = None) -> jax.Array:
    """The network's output (Q-values, or C51 logits ``[..., num_actions, num_atoms]``); a noisy network
    draws its noise from ``noise_key``, or uses its mean weights without one."""
    if unwrapped(network).noisy and noise_key is not None:
        return network.apply(params, obs, deterministic=False, rngs={"noise": noise_key})
    return network.apply(params, obs)


def q_values(network: nn.Module, output: jax.Array) -> jax.Array:
    """Q-values ``[..., num_actions]`` from the network's output: itself, or ``Σ_i z_i p_i`` (C51)."""
    network = unwrapped(network)
    if network.num_atoms is None:
        return output
    probs = jax.nn.softmax(output, axis=-1)  # (..., num_actions, num_atoms)
    return jnp.sum(probs * support(network.v_min, network.v_max, network.num_atoms), axis=-1)


def optimizer(cfg: DQNConfig) -> optax.GradientTransformation:
    learning_rate = cfg.learning_rate
    if cfg.anneal_learning_rate:
        learning_rate = optax.linear_schedule(cfg.learning_rate, 0.0, max(cfg.num_learning_steps, 1))
    if cfg.optimizer == "rmsprop":
        step = optax.rmsprop(learning_rate, decay=0.95, eps=1e-5, centered=True)
    else:
        step = optax.adam(learning_rate, eps=cfg.adam_eps)
    return (
        step if cfg.max_grad_norm is None else optax.chain(optax.clip_by_global_norm(cfg.max_grad_norm), step)
    )


def init(
    key: jax.Array,
    obs_example: jax.Array,
    num_actions: int,
    cfg: DQNConfig,
    conv: str = "xla",
    layout: Layout | None = None,
    precision: str = "f32",
) -> DQNState:
    """A fresh learner for observations shaped like ``obs_example`` (one observation; stacked
    frames ``[4, 84, 84]`` get the Nature CNN, its convolutions on backend ``conv``; packed ones
    ``[layout.size]`` an encoder per leaf, and their mask picks the legal actions)."""
    cnn = is_image(jnp.shape(obs_example))
    if cfg.augment != "none" and not cnn:
        raise UsageError(
            f"augment={cfg.augment!r} shifts image frames, not observations {jnp.shape(obs_example)}"
        )
    network = with_encoder(q_network(cfg, num_actions, cnn, conv, precision), layout, precision)
    params = network.init(key, jnp.asarray(obs_example)[None])
    return DQNState(
        params=params,
        target_params=params,
        opt_state=optimizer(cfg).init(params),
        step=jnp.int32(0),
        network=network,
    )


def act(state: DQNState, obs: jax.Array, key: jax.Array, epsilon: jax.Array) -> jax.Array:
    """ε-greedy actions ``[num_envs]`` for observations ``[num_envs, *obs_shape]``, greedy and random
    ones among the legal actions where observations carry a mask; a noisy network draws fresh noise
    (one draw for all envs) from ``key``. When every env explores, the network is not run (a
    ``lax.cond``; the same keys give the same actions, as SB3 skips it for a random one)."""
    legal = legal_actions(state.network, obs)  # (num_envs, num_actions) or None
    noise_key = None
    if unwrapped(state.network).noisy:
        key, noise_key = jax.random.split(key)
    keys = jax.random.split(key, obs.shape[0])

    def q_of(params):  # (num_envs, num_actions)
        return q_values(state.network, forward(state.network, params, obs, noise_key))

    def actions(q):
        return jax.vmap(epsilon_greedy, in_axes=(0, 0, None, 0))(keys, q, epsilon, legal)

    explores = jax.vmap(lambda k: jax.random.uniform(jax.random.split(k)[0]) < epsilon)(
        keys
    )  # epsilon_greedy's draw
    unused_q = jnp.zeros(jax.eval_shape(q_of, state.params).shape, jnp.float32)
    return jax.lax.cond(explores.all(), lambda: actions(unused_q), lambda: actions(q_of(state.params)))


def greedy_q(state: DQNState, obs: jax.Array) -> jax.Array:
    """Q-values ``[..., num_actions]`` of the online network, noisy layers at their mean weights."""
    return q_values(state.network, forward(state.network, state.params, obs))


def greedy_policy(state: DQNState) -> Policy:
    """The trained greedy policy ``(obs, key) -> action`` on one observation (for evaluation), the
    best legal action where the observation carries a mask."""

    def policy(obs: jax.Array, key: jax.Array) -> jax.Array:
        return jnp.argmax(masked(greedy_q(state, obs), legal_actions(state.network, obs))).astype(jnp.int32)

    return policy


def td_error(
    q_tm1: jax.Array,
    a_tm1: jax.Array,
    r_t: jax.Array,
    discount_t: jax.Array,
    q_t_value: jax.Array,
    q_t_selector: jax.Array,
) -> jax.Array:
    """``r_t + discount_t · q_t_value[argmax q_t_selector] − q_tm1[a_tm1]`` for ONE transition.

    q_tm1, q_t_value, q_t_selector: ``[num_actions]``; the rest scalars. ``discount_t`` already holds
    ``γ^k · (1 − terminated)``. Q-learning passes the target network's ``q_t`` as both value and
    selector (a max); Double DQN passes the online network's as the selector; a mask puts -1e9 on the
    selector's illegal actions (the value read stays finite without a legal one). The target is a constant.
    """
    target = r_t + discount_t * q_t_value[jnp.argmax(q_t_selector)]
    return jax.lax.stop_gradient(target) - q_tm1[a_tm1]


def categorical_projection(
    z_t: jax.Array, probs_t: jax.Array, r_t: jax.Array, discount_t: jax.Array, z_tm1: jax.Array
) -> jax.Array:
    """The distribution with atoms ``r_t + discount_t · z_t`` and probabilities ``probs_t`` projected
    onto the support ``z_tm1``, for ONE transition (C51's projection Φ).

    z_t, probs_t: ``[n]``; z_tm1: ``[m]``, evenly spaced; r_t, discount_t: scalars (``discount_t`` holds
    ``γ^k · (1 − terminated)``). Returns ``[m]`` probabilities. Each shifted atom is clipped to
    ``[z_tm1[0], z_tm1[-1]]`` and its mass split between the two nearest support atoms in proportion to
    closeness (all of it to one atom it lands on), so the total mass is kept.
    """
    delta = z_tm1[1] - z_tm1[0]
    target_z = jnp.clip(r_t + discount_t * z_t, z_tm1[0], z_tm1[-1])  # (n,)
    closeness = jnp.clip(1.0 - jnp.abs(target_z[None, :] - z_tm1[:, None]) / delta, 0.0, 1.0)  # (m, n)
    return closeness @ probs_t


def categorical_td_loss(
    logits_tm1: jax.Array,
    a_tm1: jax.Array,
    r_t: jax.Array,
    discount_t: jax.Array,
    logits_t_value: jax.Array,
    q_t_selector: jax.Array,
    z: jax.Array,
) -> jax.Array:
    """C51's cross-entropy ``−Σ_i Φ(r_t + discount_t z)_i · log p_i(s, a_tm1)`` for ONE transition.

    logits_tm1, logits_t_value: ``[num_actions, num_atoms]``; q_t_selector: ``[num_actions]`` (picks
    the next action: the target network's Q, or the online one's for Double DQN); z: the support
    ``[num_atoms]``. The projected target is a constant.
    """
    probs_t = jax.nn.softmax(logits_t_value[jnp.argmax(q_t_selector)])  # (num_atoms,)
    target = jax.lax.stop_gradient(categorical_projection(z, probs_t, r_t, discount_t, z))
    return -jnp.sum(target * jax.nn.log_softmax(logits_tm1[a_tm1]))


def squared_loss(td: jax.Array) -> jax.Array:
    return td**2


def huber_loss(td: jax.Array) -> jax.Array:
    return optax.huber_loss(td, delta=1.0)


LOSSES: dict[str, Callable[[jax.Array], jax.Array]] = {"mse": squared_loss, "huber": huber_loss}

AUGMENTATIONS: dict[str, Callable[[jax.Array, jax.Array], jax.Array]] = {
    "none": lambda key, obs: obs,
    "shift": random_shift,
}
"""``augment(key, obs [batch, *obs_shape]) -> obs`` applied to replayed observations"""


def per_sample_loss(cfg: DQNConfig) -> Callable:
    """``(out_tm1, a_tm1, r_t, discount_t, out_t_value, q_t_selector) -> (loss, priority)`` for ONE
    transition: the TD error under ``cfg.loss`` (priority: the TD error), or C51's cross-entropy
    (priority: itself)."""
    if cfg.distributional:
        z = support(cfg.v_min, cfg.v_max, cfg.num_atoms)

        def cross_entropy(*args):
            loss = categorical_td_loss(*args, z)
            return loss, loss

        return cross_entropy
    loss_fn = LOSSES[cfg.loss]

    def td_loss(*args):
        td = td_error(*args)
        return loss_fn(td), td

    return td_loss


def update_target(target_params: Any, params: Any, step: jax.Array, period: int, tau: float) -> Any:
    """Every ``period`` learning steps ``θ⁻ ← τ θ + (1 − τ) θ⁻`` (τ = 1: copy); otherwise ``θ⁻``."""
    due = step % period == 0
    return jax.tree.map(lambda t, p: jnp.where(due, tau * p + (1 - tau) * t, t), target_params, params)


def make_learn(cfg: DQNConfig) -> Callable[..., tuple[DQNState, dict]]:
    """``learn(state, sample, key=None) -> (state, metrics)``: one gradient step on a replayed batch.

    The variant's pieces (per-sample loss: TD or C51; target network or not; Double or max; the
    augmentation) are picked here, outside ``jit``. ``key`` draws the noise of noisy networks (one
    draw for the online network on obs and next_obs, another for the target network) and the
    augmentation's shifts; configs with neither need none. ``sample.weights`` scale each transition's
    loss (ones for uniform replay). ``metrics`` holds ``loss``, ``q_mean`` and ``PRIORITY``
    ``[batch]`` (the priority for prioritized replay: the TD error, or C51's cross-entropy).
    """
    use_target = cfg.target_update_period > 0
    needs_key = cfg.noisy or cfg.augment != "none"
    tx = optimizer(cfg)
    batched_loss = jax.vmap(per_sample_loss(cfg))
    augment = AUGMENTATIONS[cfg.augment]

    def loss_and_td(params, target_params, network, sample: ReplaySample, key: jax.Array):
        transition = sample.transition
        online_key, target_key, obs_key, next_obs_key = jax.random.split(key, 4)
        obs, next_obs = augment(obs_key, transition.obs), augment(next_obs_key, transition.next_obs)
        out_tm1 = forward(network, params, obs, online_key)  # (batch, num_actions[, num_atoms])
        out_t_online = forward(network, params, next_obs, online_key)
        out_t_value = forward(network, target_params, next_obs, target_key) if use_target else out_t_online
        q_t_selector = masked(  # (batch, num_actions): the next action is a legal one of next_obs
            q_values(network, out_t_online if cfg.double else out_t_value), legal_actions(network, next_obs)
        )
        discount_t = bootstrap_discount(transition.terminated, transition.num_steps, cfg.discount_factor)
        losses, td = batched_loss(
            out_tm1, transition.action, transition.reward, discount_t, out_t_value, q_t_selector
        )
        loss = jnp.mean(sample.weights * losses)
        return loss, (td, q_values(network, out_tm1))

    def learn(state: DQNState, sample: ReplaySample, key: jax.Array | None = None) -> tuple[DQNState, dict]:
        if key is None:
            if needs_key:
                raise UsageError("noisy networks and augmentation draw random numbers: pass learn a key")
            key = jax.random.key(0)  # unused
        (loss, (td, q_tm1)), grads = jax.value_and_grad(loss_and_td, has_aux=True)(
            state.params, state.target_params, state.network, sample, key
        )
        updates, opt_state = tx.update(grads, state.opt_state, state.params)
        params = optax.apply_updates(state.params, updates)
        step = state.step + 1
        target_params = state.target_params
        if use_target:
            target_params = update_target(
                target_params, params, step, cfg.target_update_period, cfg.target_update_tau
            )
        metrics = {"loss": loss, "q_mean": q_tm1.mean(), PRIORITY: td}
        return state.replace(
            params=params, target_params=target_params, opt_state=opt_state, step=step
        ), metrics

    return learn


@functools.cache
def _cached_learn(cfg: DQNConfig) -> Callable:
    return jax.jit(make_learn(cfg))


def learn(
    state: DQNState, sample: ReplaySample, cfg: DQNConfig, key: jax.Array | None = None
) -> tuple[DQNState, dict]:
    """One learning step (``make_learn(cfg)``, jitted and cached per config)."""
    return _cached_learn(cfg)(state, sample, key)


def epsilon_at(cfg: DQNConfig, progress: jax.Array) -> jax.Array:
    """ε after ``progress`` steps or episodes (``cfg.schedule_unit``): linear, then constant."""
    duration = max(cfg.exploration_duration, 1)
    return linear_schedule(cfg.epsilon_start, cfg.epsilon_end, duration)(progress)


def importance_exponent_at(cfg: DQNConfig, env_steps: jax.Array) -> jax.Array:
    """β, annealed linearly from ``importance_exponent_start`` to 1 over ``total_steps``."""
    return linear_schedule(cfg.importance_exponent_start, 1.0, cfg.total_steps)(env_steps)


def make_agent(
    spec: EnvSpec, cfg: DQNConfig, *, loop: Loop = jax.lax.scan, conv: str = "xla", precision: str = "f32"
) -> Agent:
    """DQN's pure functions for every runner (see ``agentax.agents.protocol``).

    ``act``'s ``progress`` is the env steps (episodes, in the episode schedule) that set ε. ``learn``
    is one learning step, so ``loop`` goes unused: the runner loops over a learning phase's steps.
    ``conv``: the Nature CNN's convolution backend, ``precision`` the network's products' (the entry
    point's choices).
    """
    cfg.validate()
    num_actions = discrete_actions(spec, "dqn")
    learn_step = make_learn(cfg)

    def act_epsilon_greedy(state: DQNState, obs: jax.Array, key: jax.Array, progress: jax.Array):
        epsilon = epsilon_at(cfg, progress)
        return act(state, obs, key, epsilon), {"epsilon": epsilon}

    experience = OffPolicy(
        num_envs=cfg.num_envs,
        capacity=cfg.buffer_size,
        batch_size=cfg.batch_size,
        learning_starts=cfg.learning_starts,
        train_frequency=cfg.train_frequency,
        gradient_steps=cfg.gradient_steps,
        n_step=cfg.n_step,
        discount_factor=cfg.discount_factor,
        prioritized=cfg.prioritized,
        priority_exponent=cfg.priority_exponent,
        importance_exponent=lambda env_steps: importance_exponent_at(cfg, env_steps),
        by_episode=cfg.schedule_unit == "episodes",
        max_episodes=cfg.max_episodes,
    )
    return Agent(
        name="dqn",
        init=lambda key: init(
            key, jnp.zeros(spec.obs_shape, spec.obs_dtype), num_actions, cfg, conv, spec.layout, precision
        ),
        act=act_epsilon_greedy,
        greedy_policy=greedy_policy,
        learn=learn_step,
        experience=experience,
        total_steps=cfg.total_steps,
        learning_steps=lambda state: state.step,
    )


__all__ = [
    "DQNConfig",
    "DQNState",
    "act",
    "greedy_policy",
    "init",
    "learn",
    "make_agent",
    "make_learn",
    "td_error",
]

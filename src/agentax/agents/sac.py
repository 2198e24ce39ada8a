"""Soft actor-critic (Haarnoja et al., 2018): maximum-entropy off-policy learning for continuous actions.

The actor is a tanh-squashed diagonal Gaussian ``a = tanh(μ(s) + σ(s)·ε)`` in ``[-1, 1]^d`` (the env
receives ``a`` rescaled to its bounds); two Q-networks learn from replayed transitions, each
regressing onto the soft TD target of the smaller of two Polyak-averaged target networks::

    y      = r + γ^k (1 − terminated) · (min_i Q⁻_i(s′, a′) − α log π(a′|s′)),   a′ ~ π(·|s′)
    L_Q    = ½ Σ_i mean(w · (Q_i(s, a) − y)²)
    L_π    = mean(α log π(ã|s) − min_i Q_i(s, ã)),                              ã ~ π(·|s)
    L_α    = −mean(log α · (log π(ã|s) + H̄))                                    (automatic temperature)

with the target entropy ``H̄ = −d`` (SB3 and CleanRL's choice) and ``θ⁻ ← τ θ + (1 − τ) θ⁻`` after
every learning step. One ``learn`` is one step of all three, in SB3's order: the critics, then the
actor against the new critics, then α. Before ``learning_starts`` the agent acts uniformly at random.

``utd`` (updates per env step) sets the learning steps per collection phase; prioritized replay
weights the critic loss by ``w`` and takes the mean |TD error| of the two critics as priority.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp

from agentax.agents.off_policy import (
    ActorCriticState,
    ReplayConfig,
    actor_critic_setup,
    adam_step,
    continuous_agent,
    twin_q_loss,
    warm_up,
)
from agentax.agents.protocol import (
    PRIORITY,
    Agent,
    EnvSpec,
    Loop,
    scale_action,
)
from agentax.errors import UsageError
from agentax.nets import SquashedGaussianActor, polyak, sample_squashed, with_encoder
from agentax.policies import Policy
from agentax.replay import ReplaySample


@dataclass(frozen=True)
class SACConfig(ReplayConfig):
    """Hyperparameters of SAC (defaults: SB3's, which the RL Zoo uses for Pendulum and MuJoCo)."""

    initial_alpha: float = 1.0
    """The entropy temperature α at the start."""
    autotune: bool = True
    """Learn α towards the target entropy ``−target_entropy_scale · action_dim`` (else α stays fixed)."""
    target_entropy_scale: float = 1.0
    """The target entropy per action dimension, negated (1: SB3's −d)."""
    log_std_min: float = -5.0
    """Lowest log σ of the actor's Gaussian (the network's output is squashed into [min, max])."""
    log_std_max: float = 2.0
    """Highest log σ of the actor's Gaussian."""

    def validate(self) -> SACConfig:
        """Raise ``UsageError`` naming the first bad value; return ``self``."""
        self.check_replay(positive=("initial_alpha",))
        if not self.log_std_min < self.log_std_max:
            raise UsageError("log_std_min must be below log_std_max")
        return self


SACState = ActorCriticState
"""The learner: ``params`` {"actor", "critic", "log_alpha"}, the target critics, the optimizers'
states, learning steps taken."""


def make_agent(
    spec: EnvSpec, cfg: SACConfig, *, loop: Loop = jax.lax.scan, conv: str = "xla", precision: str = "f32"
) -> Agent:
    """SAC's pure functions for every runner (see ``agentax.agents.protocol``).

    ``act``'s ``progress`` counts env steps (uniform actions before ``learning_starts``); ``learn`` is
    one learning step, so ``loop`` goes unused, and so does ``conv`` (an image leaf's encoder uses
    XLA's). Actions live in ``[-1, 1]^d``: the replay stores them so, ``env_action`` and the greedy
    policy rescale them to the env's bounds. Packed observations (:mod:`agentax.envs.spaces`) go
    through an encoder per leaf, the actor's and the critics' own; stacked frames are refused.
    ``precision``: the networks' products' (acting and learning alike; the parameters, Adam's
    moments, the targets, losses and replay stay float32).
    """
    action_dim, critic, tx = actor_critic_setup("sac", spec, cfg, precision)
    actor = with_encoder(
        SquashedGaussianActor(
            action_dim, tuple(cfg.hidden), cfg.activation, cfg.log_std_min, cfg.log_std_max, precision
        ),
        spec.layout,
        precision,
    )
    target_entropy = -cfg.target_entropy_scale * action_dim

    def init(key: jax.Array) -> SACState:
        actor_key, critic_key = jax.random.split(key)
        obs = jnp.zeros((1, *spec.obs_shape), spec.obs_dtype)
        critic_params = critic.init(critic_key, obs, jnp.zeros((1, action_dim)))
        params = {
            "actor": actor.init(actor_key, obs),
            "critic": critic_params,
            "log_alpha": jnp.log(jnp.float32(cfg.initial_alpha)),
        }
        opt_state = {name: tx.init(value) for name, value in params.items()}
        return SACState(params, critic_params, opt_state, jnp.int32(0))

    def act(state: SACState, obs: jax.Array, key: jax.Array, progress: jax.Array):
        """Actions ``[E, d]`` in ``[-1, 1]``: π's samples, or uniform ones before ``learning_starts``."""
        policy_key, uniform_key = jax.random.split(key)
        action, _ = sample_squashed(*actor.apply(state.params["actor"], obs), policy_key)
        return warm_up(action, uniform_key, progress, cfg.learning_starts), {}

    def greedy_policy(state: SACState) -> Policy:
        """The deterministic policy for evaluation: ``tanh(μ(s))`` rescaled to the env's bounds."""

        def policy(obs: jax.Array, key: jax.Array) -> jax.Array:
            mean, _ = actor.apply(state.params["actor"], obs)
            return scale_action(jnp.tanh(mean), spec.action_space)

        return policy

    def critic_loss(critic_params, state: SACState, sample: ReplaySample, key: jax.Array):
        next_obs = sample.transition.next_obs
        alpha = jnp.exp(state.params["log_alpha"])
        next_action, next_log_prob = sample_squashed(*actor.apply(state.params["actor"], next_obs), key)
        next_q = critic.apply(state.target_params, next_obs, next_action).min(axis=0)
        next_value = next_q - alpha * next_log_prob
        loss, aux = twin_q_loss(critic, critic_params, sample, next_value, cfg.discount_factor)
        return 0.5 * loss, aux

    def actor_loss(actor_params, critic_params, log_alpha, obs: jax.Array, key: jax.Array):
        action, log_prob = sample_squashed(*actor.apply(actor_params, obs), key)
        q = critic.apply(critic_params, obs, action).min(axis=0)
        return (jnp.exp(log_alpha) * log_prob - q).mean(), log_prob

    def alpha_loss(log_alpha, log_prob: jax.Array):
        return -(log_alpha * jax.lax.stop_gradient(log_prob + target_entropy)).mean()

    def learn(state: SACState, sample: ReplaySample, key: jax.Array) -> tuple[SACState, dict]:
        critic_key, actor_key = jax.random.split(key)
        params, opt_state = dict(state.params), dict(state.opt_state)
        (q_loss, (q_mean, priority)), grads = jax.value_and_grad(critic_loss, has_aux=True)(
            params["critic"], state, sample, critic_key
        )
        params["critic"], opt_state["critic"] = adam_step(tx, "critic", params, opt_state, grads)
        (pi_loss, log_prob), grads = jax.value_and_grad(actor_loss, has_aux=True)(
            params["actor"], params["critic"], params["log_alpha"], sample.transition.obs, actor_key
        )
        params["actor"], opt_state["actor"] = adam_step(tx, "actor", params, opt_state, grads)
        if cfg.autotune:
            a_loss, grads = jax.value_and_grad(alpha_loss)(params["log_alpha"], log_prob)
            params["log_alpha"], opt_state["log_alpha"] = adam_step(tx, "log_alpha", params, opt_state, grads)
        else:
            a_loss = jnp.float32(0.0)
        target_params = polyak(state.target_params, params["critic"], cfg.tau)
        state = SACState(params, target_params, opt_state, state.step + 1)
        metrics = {
            "critic_loss": q_loss,
            "actor_loss": pi_loss,
            "alpha_loss": a_loss,
            "alpha": jnp.exp(params["log_alpha"]),
            "entropy": -log_prob.mean(),
            "q_mean": q_mean,
            PRIORITY: priority,
        }
        return state, metrics

    return continuous_agent("sac", spec, cfg, init=init, act=act, greedy_policy=greedy_policy, learn=learn)


__all__ = ["SACConfig", "SACState", "make_agent"]

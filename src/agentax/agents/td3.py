"""TD3, twin delayed deep deterministic policy gradient (Fujimoto et al., 2018), for continuous actions.

A deterministic actor ``μ(s) = tanh(MLP(s))`` in ``[-1, 1]^d`` (the env receives it rescaled to its
bounds) and two Q-networks, learned from replayed transitions with DDPG's three fixes::

    ã  = clip(μ⁻(s′) + clip(ε, −c, c), −1, 1),   ε ~ N(0, σ̃²)     target policy smoothing
    y  = r + γ^k (1 − terminated) · min_i Q⁻_i(s′, ã)               clipped double Q
    L_Q = Σ_i mean(w · (Q_i(s, a) − y)²)
    L_μ = −mean(Q_1(s, μ(s)))                                        every ``policy_delay`` steps

The actor and both target networks (``θ⁻ ← τ θ + (1 − τ) θ⁻``) move only every ``policy_delay``
learning steps. The agent explores with Gaussian noise ``N(0, exploration_noise²)`` on ``μ(s)``, and
acts uniformly at random before ``learning_starts``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import optax

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
from agentax.nets import MLP, polyak, with_encoder
from agentax.policies import Policy
from agentax.replay import ReplaySample


@dataclass(frozen=True)
class TD3Config(ReplayConfig):
    """Hyperparameters of TD3 (defaults: SB3's, which the RL Zoo uses for MuJoCo)."""

    learning_rate: float = 1e-3
    """Adam's step size for the actor and the critics."""
    learning_starts: int = 10_000
    """Env steps of uniformly random actions before the first learning step."""
    policy_delay: int = 2
    """Learning steps per update of the actor and the target networks."""
    exploration_noise: float = 0.1
    """σ of the Gaussian noise on collected actions (in [-1, 1] units)."""
    target_policy_noise: float = 0.2
    """σ̃ of the target policy smoothing."""
    target_noise_clip: float = 0.5
    """c: the smoothing noise is clipped to [−c, c]."""

    def validate(self) -> TD3Config:
        """Raise ``UsageError`` naming the first bad value; return ``self``."""
        self.check_replay(
            positive=("policy_delay",),
            non_negative=("exploration_noise", "target_policy_noise", "target_noise_clip"),
        )
        return self


TD3State = ActorCriticState
"""The learner: ``params`` and ``target_params`` {"actor", "critic"}, the optimizers' states,
learning steps taken."""


def make_agent(
    spec: EnvSpec, cfg: TD3Config, *, loop: Loop = jax.lax.scan, conv: str = "xla", precision: str = "f32"
) -> Agent:
    """TD3's pure functions for every runner (see ``agentax.agents.protocol``).

    ``act``'s ``progress`` counts env steps (uniform actions before ``learning_starts``); ``learn`` is
    one learning step, so ``loop`` goes unused, and so does ``conv`` (an image leaf's encoder uses
    XLA's). Actions live in ``[-1, 1]^d``: the replay stores them so, ``env_action`` and the greedy
    policy rescale them to the env's bounds. Packed observations (:mod:`agentax.envs.spaces`) go
    through an encoder per leaf, the actor's and the critics' own; stacked frames are refused.
    ``precision``: the networks' products' (acting and learning alike).
    """
    action_dim, critic, tx = actor_critic_setup("td3", spec, cfg, precision)
    mlp = MLP(tuple(cfg.hidden), cfg.activation, out=action_dim, precision=precision)
    actor = with_encoder(mlp, spec.layout, precision)

    def mu(actor_params: Any, obs: jax.Array) -> jax.Array:
        return jnp.tanh(actor.apply(actor_params, obs.astype(jnp.float32)))

    def init(key: jax.Array) -> TD3State:
        actor_key, critic_key = jax.random.split(key)
        obs = jnp.zeros((1, *spec.obs_shape), jnp.float32)
        params = {
            "actor": actor.init(actor_key, obs),
            "critic": critic.init(critic_key, obs, jnp.zeros((1, action_dim))),
        }
        opt_state = {name: tx.init(value) for name, value in params.items()}
        return TD3State(params, params, opt_state, jnp.int32(0))

    def act(state: TD3State, obs: jax.Array, key: jax.Array, progress: jax.Array):
        """Actions ``[E, d]`` in ``[-1, 1]``: ``μ(s)`` plus Gaussian noise (uniform ones at first)."""
        noise_key, uniform_key = jax.random.split(key)
        greedy = mu(state.params["actor"], obs)
        noise = cfg.exploration_noise * jax.random.normal(noise_key, greedy.shape)
        noisy = jnp.clip(greedy + noise, -1.0, 1.0)
        return warm_up(noisy, uniform_key, progress, cfg.learning_starts), {}

    def greedy_policy(state: TD3State) -> Policy:
        """The deterministic policy for evaluation: ``μ(s)`` rescaled to the env's bounds."""
        return lambda obs, key: scale_action(mu(state.params["actor"], obs), spec.action_space)

    def critic_loss(critic_params, state: TD3State, sample: ReplaySample, key: jax.Array):
        t = sample.transition
        greedy_next = mu(state.target_params["actor"], t.next_obs)
        smoothing = jnp.clip(
            cfg.target_policy_noise * jax.random.normal(key, greedy_next.shape),
            -cfg.target_noise_clip,
            cfg.target_noise_clip,
        )
        next_action = jnp.clip(greedy_next + smoothing, -1.0, 1.0)
        next_q = critic.apply(state.target_params["critic"], t.next_obs, next_action).min(axis=0)
        return twin_q_loss(critic, critic_params, sample, next_q, cfg.discount_factor)

    def actor_loss(actor_params, critic_params, obs: jax.Array):
        return -critic.apply(critic_params, obs, mu(actor_params, obs))[0].mean()

    def learn(state: TD3State, sample: ReplaySample, key: jax.Array) -> tuple[TD3State, dict]:
        params, opt_state = dict(state.params), dict(state.opt_state)
        (q_loss, (q_mean, priority)), grads = jax.value_and_grad(critic_loss, has_aux=True)(
            params["critic"], state, sample, key
        )
        params["critic"], opt_state["critic"] = adam_step(tx, "critic", params, opt_state, grads)

        step = state.step + 1
        obs = sample.transition.obs
        pi_loss, grads = jax.value_and_grad(actor_loss)(params["actor"], params["critic"], obs)
        updates, actor_opt_state = tx.update(grads, opt_state["actor"], params["actor"])
        delayed = step % cfg.policy_delay == 0  # the actor and the targets move on these steps only
        params["actor"], opt_state["actor"] = jax.tree.map(
            lambda new, old: jnp.where(delayed, new, old),
            (optax.apply_updates(params["actor"], updates), actor_opt_state),
            (params["actor"], opt_state["actor"]),
        )
        target_params = polyak(state.target_params, params, jnp.where(delayed, cfg.tau, 0.0))
        metrics = {"critic_loss": q_loss, "actor_loss": pi_loss, "q_mean": q_mean, PRIORITY: priority}
        return TD3State(params, target_params, opt_state, step), metrics

    return continuous_agent("td3", spec, cfg, init=init, act=act, greedy_policy=greedy_policy, learn=learn)


__all__ = ["TD3Config", "TD3State", "make_agent"]

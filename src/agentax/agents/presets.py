"""Every tuned configuration, by algorithm and name: what ``agentax train ALGO --preset NAME`` starts from.

A :class:`Preset` is data: an algorithm's frozen config, one line about it, and the compiled runner's
schedule for it. :data:`PRESETS` maps each algorithm to its presets (each has ``"default"``),
:data:`DEFAULT_PRESETS` each algorithm to the preset ``--preset auto`` picks for an env, and
:func:`preset` is the one lookup, overrides applied and validated. The registry reaches them by
:func:`agentax.agents.presets_of`. This module imports the algorithms' configs; no algorithm imports it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from agentax.agents.dqn import DQNConfig
from agentax.agents.ppo import PPOConfig
from agentax.agents.pqn import PQNConfig
from agentax.agents.reinforce import ReinforceConfig
from agentax.agents.sac import SACConfig
from agentax.agents.td3 import TD3Config
from agentax.errors import UsageError


@dataclass(frozen=True)
class Preset:
    """A named, tuned configuration: an algorithm's config and the compiled runner's schedule."""

    config: Any
    """the algorithm's frozen config dataclass"""
    description: str
    """one line for ``agentax train ALGO --help`` and the README"""
    updates_per_chunk: int = 10
    """updates per compiled call (one log row, one checkpoint)"""
    eval_every_chunks: int = 0
    """evaluate the greedy policy every this many chunks (0: the compiled runner's choice: every chunk
    when the run stops once solved, else about ten times a run)"""
    eval_episodes: int = 20
    """evaluation episodes per seed"""
    stop_at_solved: bool = False
    """stop once the evaluation reaches the env's solved threshold (the ``--stop-at-return`` default)"""
    freeze_at_return: float | None = None
    """compiled runner: each seed stops learning once its greedy policy's side episodes all reach
    this (the ``--freeze-at-return`` default; the other runners do not apply it unless asked)"""


# ---------------------------------------------------------------- REINFORCE

REINFORCE_LECTURE = Preset(
    ReinforceConfig(), "the lecture's settings (150 iterations of 10 episodes, γ 0.95, Adam 0.01)"
)
"""The lecture's REINFORCE: ``ReinforceConfig``'s defaults."""

REINFORCE_PRESETS: dict[str, Preset] = {
    "default": REINFORCE_LECTURE,
    "lecture": REINFORCE_LECTURE,  # an alias: the defaults are the lecture's
    "baseline": Preset(
        ReinforceConfig(baseline=True), "the lecture's settings with a learned value baseline"
    ),
    "pendulum": Preset(
        ReinforceConfig(
            total_steps=4_000_000,
            episodes_per_update=32,
            max_steps=200,
            learning_rate=3e-3,
            hidden=(64, 64),
            activation="tanh",
            sigmoid_head=False,
            baseline=True,
            baseline_hidden=(64, 64),
        ),
        "continuous control (Pendulum-v1): Gaussian head, value baseline, 32 episodes an update, 4M steps "
        "(4 seeds vmapped: from about -1,200 to -182.3 here, per seed -136 to -249)",
    ),
}


# ---------------------------------------------------------------- PPO

CARTPOLE_FAST = PPOConfig(
    total_steps=51_200,
    num_envs=8,
    num_steps=32,
    learning_rate=3e-3,
    discount_factor=0.98,
    gae_lambda=0.8,
    num_minibatches=2,
    update_epochs=10,
    clip_eps=0.2,
    anneal_clip=True,
    ent_coef=0.0,
)
"""PPO's settings that solve CartPole-v1 fast (RL-Zoo's, lr 3e-3, 10 epochs × 2 minibatches)"""

LUNAR_PPO = dataclasses.replace(
    PPOConfig(),
    total_steps=1_000_000,
    num_envs=16,
    num_steps=1024,
    num_minibatches=256,
    update_epochs=4,
    gae_lambda=0.98,
    discount_factor=0.999,
    ent_coef=0.01,
    learning_rate=3e-4,
    anneal_lr=False,
)
"""RL-Baselines3-Zoo's LunarLander PPO (hyperparams/ppo.yml): 16 envs × 1024 steps, batch 64 (256
minibatches), 4 epochs, GAE 0.98, γ 0.999, entropy 0.01, lr 3e-4 constant, 1M steps."""

PPO_PRESETS: dict[str, Preset] = {
    "default": Preset(PPOConfig(), "CleanRL's classic-control settings, 500k steps"),
    "cartpole-fast": Preset(
        CARTPOLE_FAST,
        "solves CartPole-v1 in ~5-10k env steps (RL-Zoo's settings, lr 3e-3, 10 epochs × 2 minibatches); "
        "stops when solved",
        updates_per_chunk=10,
        stop_at_solved=True,
    ),
    "memory": Preset(
        dataclasses.replace(
            CARTPOLE_FAST, total_steps=204_800, learning_rate=2e-3, hidden=(64,), core="lstm", core_size=64
        ),
        "an LSTM core (64 units) for partially observed tasks, cartpole-fast's settings with lr 2e-3: on "
        "CartPoleNoVel-v1 8 of 8 seeds evaluate 475 or more after 204,800 steps (mean 500), a GRU of 64 "
        "too (mean 500), feed-forward PPO 44 (bench_memory)",
    ),
    "small-games": Preset(
        PPOConfig(
            total_steps=32_768,
            num_envs=16,
            num_steps=32,
            learning_rate=2.5e-3,
            update_epochs=4,
            num_minibatches=4,
        ),
        "GridWorld-v0 and TicTacToe-v0 (16 envs × 32 steps, lr 2.5e-3): the grid's shortest paths from "
        "every start, tic-tac-toe won in about 95 % of games against the random opponent",
    ),
    "pendulum": Preset(
        PPOConfig(
            total_steps=200_000,
            num_envs=4,
            num_steps=512,
            learning_rate=1e-3,
            discount_factor=0.9,
            gae_lambda=0.95,
            num_minibatches=8,
            update_epochs=10,
            ent_coef=0.0,
        ),
        "continuous control (Pendulum-v1): Gaussian policy, γ 0.9, 10 epochs",
    ),
    "atari": Preset(
        PPOConfig(
            total_steps=10_000_000,
            num_envs=8,
            num_steps=128,
            learning_rate=2.5e-4,
            discount_factor=0.99,
            gae_lambda=0.95,
            num_minibatches=4,
            update_epochs=4,
            clip_eps=0.1,
            ent_coef=0.01,
            vf_coef=0.5,
            max_grad_norm=0.5,
        ),
        "CleanRL's ppo_atari_envpool settings (8 envs × 128 steps, lr 2.5e-4 annealed, clip 0.1, "
        "4 epochs × 4 minibatches, GAE 0.95, entropy 0.01; no value clipping), 10M agent steps, Nature CNN",
        eval_episodes=10,
    ),
    "minatar": Preset(
        PPOConfig(
            total_steps=10_000_000,
            num_envs=64,
            num_steps=128,
            learning_rate=5e-3,
            discount_factor=0.99,
            gae_lambda=0.95,
            num_minibatches=8,
            update_epochs=4,
            clip_eps=0.2,
            ent_coef=1e-4,
            vf_coef=0.5,
            max_grad_norm=0.5,
            activation="relu",
            conv_torso=True,
        ),
        "MinAtar (gymnax/*-MinAtar): PureJaxRL's MinAtar PPO settings (64 envs × 128 steps, lr 5e-3 "
        "annealed, 4 epochs × 8 minibatches) with entropy 1e-4 (theirs 0.01), 10M steps, MinAtar's conv "
        "torso (Breakout, 1M steps: ~2x the return of the MLP per step, ~4x slower per step on CPU; "
        "--no-conv-torso for the MLP)",
        updates_per_chunk=10,
    ),
    "mujoco": Preset(
        PPOConfig(
            total_steps=1_000_000,
            num_envs=1,
            num_steps=2048,
            learning_rate=3e-4,
            anneal_lr=True,
            discount_factor=0.99,
            gae_lambda=0.95,
            num_minibatches=32,
            update_epochs=10,
            clip_eps=0.2,
            ent_coef=0.0,
            vf_coef=0.5,
            max_grad_norm=0.5,
            hidden=(64, 64),
            activation="tanh",
            normalize_observations=True,
            observation_clip=10.0,
            normalize_rewards=True,
            reward_clip=10.0,
        ),
        "MuJoCo (HalfCheetah-v5, Hopper-v5, ...): CleanRL's ppo_continuous_action settings (1 env × 2048 "
        "steps, lr 3e-4 annealed, 10 epochs × 32 minibatches, entropy 0, net 64-64 tanh, observations "
        "and rewards normalised and clipped at 10; no value clipping), 1M steps",
        eval_episodes=10,
    ),
    "lunar": Preset(
        LUNAR_PPO,
        "RL-Zoo's LunarLander settings (16 envs × 1024 steps, 4 epochs, γ 0.999), 1M steps "
        "(solves LunarLander-v3: benchmarks/bench_lunar.py)",
        eval_episodes=10,
    ),
}


# ---------------------------------------------------------------- DQN

LECTURE = DQNConfig(
    hidden=(32, 32),
    activation="elu",
    double=False,
    target_update_period=0,
    discount_factor=0.95,
    learning_rate=1e-3,
    max_grad_norm=None,
    loss="mse",
    batch_size=32,
    buffer_size=2_000,
    n_step=1,
    num_envs=1,
    schedule_unit="episodes",
    learning_starts=50,
    train_frequency=1,
    gradient_steps=1,
    epsilon_start=1.0,
    epsilon_end=0.01,
    exploration_duration=495,
    max_episodes=600,
    total_steps=120_000,
)
"""The lecture's DQN (LECTURE-FACTS.md), episode for episode, on CartPole-v0.

The lecture loops over 600 episodes of at most 200 steps; in each step ε = max(1 − episode/500,
0.01); after each episode, once 50 episodes are done, one training step on a batch of 32 from the
last 2,000 transitions. In agentax's units: ``schedule_unit="episodes"`` counts ``learning_starts``
(50), ``train_frequency`` (1: a learning step at the end of every episode) and
``exploration_duration`` (495: ε reaches 0.01 at episode 495, as max(1 − 495/500, 0.01) does) in
finished episodes; ``max_episodes=600`` ends collection and learning after the 600th episode, and
``total_steps=120,000`` (600 × 200, the most those episodes can take) bounds the run. One env, no
target network, MSE, Adam 1e-3 (the lecture notes 1e-2 works better), γ 0.95. One difference: the
lecture stores ``done`` and so also cuts bootstrapping at the 200-step time limit; agentax keeps
truncation apart and bootstraps through it.
"""

LECTURE_ATARI = DQNConfig(
    optimizer="rmsprop",
    learning_rate=2.5e-4,
    max_grad_norm=None,
    loss="huber",
    discount_factor=0.99,
    double=False,
    n_step=1,
    target_update_period=2_000,
    batch_size=64,
    buffer_size=100_000,
    num_envs=4,
    learning_starts=20_000,
    train_frequency=1,
    gradient_steps=1,
    epsilon_start=1.0,
    epsilon_end=0.01,
    exploration_duration=250_000,
    total_steps=2_500_000,
)
"""The lecture's TF-Agents DQN on Breakout (LECTURE-FACTS.md): RMSprop 2.5e-4 (ρ 0.95, ε 1e-5,
centered), Huber, γ 0.99, target update every 2,000 learning steps, ε 1 → 0.01 over 1M frames
(250k agent steps), a learning step (batch 64) every 4 agent steps (4 envs, one step each), 20k
random steps first, 100k transitions of replay; 10M frames."""

NATURE = dataclasses.replace(
    LECTURE_ATARI,
    optimizer="adam",
    learning_rate=1e-4,
    adam_eps=1e-8,
    target_update_period=1_000,
    batch_size=32,
    buffer_size=1_000_000,
    num_envs=1,
    learning_starts=80_000,
    train_frequency=4,
    exploration_duration=1_000_000,
    total_steps=10_000_000,
)
"""DQN as in Mnih et al. 2015 with CleanRL's ``dqn_atari`` settings: Adam 1e-4, Huber, γ 0.99, target
synced every 1,000 learning steps, a learning step of batch 32 every 4 agent steps, ε 1 → 0.01 over
1M agent steps, 80k random steps first, 1M transitions of replay, 10M agent steps."""

DER = DQNConfig(
    distributional=True,
    num_atoms=51,
    v_min=-10.0,
    v_max=10.0,
    noisy=True,
    noisy_sigma0=0.1,
    dueling=True,
    dueling_baseline="mean",
    double=True,
    prioritized=True,
    priority_exponent=0.5,
    importance_exponent_start=0.4,
    n_step=10,
    discount_factor=0.99,
    optimizer="adam",
    learning_rate=1e-4,
    adam_eps=1.5e-4,
    max_grad_norm=10.0,
    batch_size=32,
    buffer_size=100_000,
    target_update_period=2_000,
    num_envs=1,
    learning_starts=1_600,
    train_frequency=1,
    gradient_steps=1,
    epsilon_start=0.0,
    epsilon_end=0.0,
    exploration_duration=1,
    total_steps=100_000,
)
"""Data-efficient Rainbow (van Hasselt, Hessel & Aslanides, 2019) for Atari 100k: 100k agent steps
(400k frames), a learning step (batch 32) every agent step from step 1,600 on, target every 2,000
learning steps, Adam 1e-4 (ε 1.5e-4), 10-step returns (the paper: 20; 10 as SPR and Dopamine's
``DER.gin``), prioritized replay (ζ 0.5, β 0.4 → 1) of all 100k transitions, dueling (mean), Double,
C51 (51 atoms on ±10), noisy nets σ0 0.1 and no ε (Dopamine's DER.gin keeps ε 0.01 after 2,000 steps).
The paper's smaller torso (256 hidden units) is not reproduced: the Nature CNN's. ``--augment shift``
adds DrQ's random shifts."""

LUNAR_DQN = DQNConfig(
    total_steps=150_000,
    num_envs=1,
    hidden=(256, 256),
    double=True,
    n_step=3,
    learning_rate=6.3e-4,
    anneal_learning_rate=True,
    batch_size=128,
    buffer_size=50_000,
    learning_starts=128,
    target_update_period=250,
    train_frequency=4,
    gradient_steps=4,
    epsilon_start=1.0,
    epsilon_end=0.1,
    exploration_duration=12_000,
    discount_factor=0.99,
)
"""RL-Baselines3-Zoo's LunarLander DQN (hyperparams/dqn.yml: Adam 6.3e-4, batch 128, 50k replay,
target every 250 learning steps, 4 learning steps every 4 env steps, ε 1 → 0.1 over 12k steps,
[256, 256]) made Double with 3-step returns, the step size decayed linearly to 0, over 150k steps
(the Zoo's 100k, one-step and not double, does not solve it with seed 0: benchmarks/bench_lunar.py)."""

DQN_PRESETS: dict[str, Preset] = {
    "default": Preset(
        DQNConfig(),
        "tuned for CartPole-v1: Double DQN, 3-step returns, 128 learning steps per 256 env steps; "
        "each seed stops learning once 8 greedy episodes in a row reach 475; stops when solved",
        updates_per_chunk=4,
        eval_every_chunks=1,
        eval_episodes=20,
        stop_at_solved=True,
        freeze_at_return=475.0,
    ),
    "lecture-atari": Preset(
        LECTURE_ATARI,
        "the lecture's TF-Agents DQN on Breakout: RMSprop 2.5e-4, target every 2,000 steps, ε over 1M frames",
        eval_episodes=10,
    ),
    "nature": Preset(
        NATURE, "DQN as in the Nature paper / CleanRL's dqn_atari (Adam 1e-4, 1M replay)", eval_episodes=10
    ),
    "der": Preset(
        DER,
        "data-efficient Rainbow for Atari 100k (van Hasselt et al. 2019): C51, noisy nets, dueling, "
        "Double, PER, 10-step returns, a learning step per agent step; add --augment shift for DrQ's shifts",
        eval_episodes=10,
    ),
    "lecture": Preset(
        LECTURE,
        "the lecture's DQN: 600 episodes of CartPole-v0, a learning step per episode, no target network",
        updates_per_chunk=1_000,
        eval_every_chunks=1,
        eval_episodes=20,
    ),
    "lunar": Preset(
        LUNAR_DQN,
        "RL-Zoo's LunarLander settings made Double with 3-step returns and lr decayed to 0, 150k steps",
        eval_episodes=10,
    ),
}


# ---------------------------------------------------------------- PQN

PQN_ATARI = PQNConfig(  # purejaxql's pqn_atari; Q(λ 0.65), γ 0.99, ε from 1 over 10 %: PQNConfig's defaults
    total_steps=10_000_000,
    num_envs=128,
    num_steps=32,
    learning_rate=2.5e-4,
    anneal_lr=False,
    update_epochs=2,
    num_minibatches=32,
    epsilon_end=0.001,
)

BREAKOUT_HOUR = dataclasses.replace(
    PQN_ATARI,
    total_steps=1_600_000,
    num_envs=64,
    learning_rate=5e-4,
    anneal_lr=True,
    num_minibatches=16,
    epsilon_end=0.01,
)

BREAKOUT_15MIN = dataclasses.replace(
    BREAKOUT_HOUR, total_steps=1_250_000, update_epochs=1, num_minibatches=32
)
"""half breakout-hour's learning per rollout with as many gradient steps (1 epoch × 32 minibatches of 64)"""

PQN_PRESETS: dict[str, Preset] = {
    "default": Preset(
        PQNConfig(),
        "CartPole-v1: 16 envs × 32 steps, Q(λ 0.65), 4 epochs × 8 minibatches, LayerNorm MLP 128-128, "
        "ε 1 → 0.05 over the first 10 %; stops when solved",
        updates_per_chunk=20,
        eval_every_chunks=1,
        stop_at_solved=True,
    ),
    "atari": Preset(
        PQN_ATARI,
        "purejaxql's pqn_atari settings (128 envs × 32 steps, Q(λ 0.65), 2 epochs × 32 minibatches, "
        "RAdam 2.5e-4, ε 1 → 0.001 over the first 10 %), 10M agent steps, Nature CNN with LayerNorm",
        eval_episodes=10,
    ),
    "breakout-hour": Preset(
        BREAKOUT_HOUR,
        "Breakout in under an hour on a 2-core CPU with oneDNN bf16 (~1,040 agent steps/s, 26 min): "
        "1.6M agent steps, 64 envs × 32 steps, 2 epochs × 16 minibatches of 128, RAdam 5e-4 annealed, "
        "ε 1 → 0.01 over the first 10 %",
        eval_episodes=10,
    ),
    "breakout-15min": Preset(
        BREAKOUT_15MIN,
        "Breakout past 30 in 15 minutes on a 2-core CPU (36.4 in 14 min 45 s on an AMD EPYC): "
        "breakout-hour with 1 epoch × 32 minibatches of 64 (half the learning, as many gradient steps; "
        "~1,450 agent steps/s at policy lag 1 on the compiled runner), 1.25M agent steps",
        eval_episodes=10,
    ),
    "breakout-100": Preset(
        dataclasses.replace(BREAKOUT_15MIN, total_steps=4_800_000),
        "Breakout past 100 in an hour on a 2-core CPU (268.5 in 55 min 51 s on an AMD EPYC): "
        "breakout-15min for 4.8M agent steps",
        eval_episodes=10,
    ),
    "memory": Preset(
        PQNConfig(
            total_steps=200_000,
            num_envs=32,
            hidden=(64,),
            core="gru",
            core_size=64,
            bptt=8,
            q_lambda=0.95,
            num_minibatches=8,
        ),
        "a GRU core (64 units) for partially observed tasks: 32 envs × 32 steps learned as sequences "
        "of 8 (8 minibatches of 16), Q(λ 0.95), 200k steps: on CartPoleNoVel-v1 8 seeds evaluate 264 on "
        "average over 20 greedy episodes each (worst 168, best 457), feed-forward PQN 40",
    ),
    "minatar": Preset(
        dataclasses.replace(PQN_ATARI, learning_rate=5e-4, anneal_lr=True, epsilon_end=0.05),
        "MinAtar (gymnax/*-MinAtar): purejaxql's pqn_minatar settings (128 envs × 32 steps, Q(λ 0.65), "
        "2 epochs × 32 minibatches, RAdam 5e-4 annealed, ε 1 → 0.05 over 10 %), 10M steps, LayerNorm MLP "
        "(Breakout, 1M steps: as good per step as their conv torso, ~8x faster on CPU; --conv-torso for it)",
        updates_per_chunk=20,
    ),
}


# ---------------------------------------------------------------- the lookup

# ---------------------------------------------------------------- SAC and TD3 (continuous actions)

SAC_MUJOCO_PRESET = Preset(
    SACConfig(learning_starts=10_000, total_steps=1_000_000),
    "the RL Zoo's MuJoCo settings (SB3's defaults, 10k random steps), 1M steps",
)

SAC_PRESETS: dict[str, Preset] = {
    "default": SAC_MUJOCO_PRESET,
    "mujoco": SAC_MUJOCO_PRESET,
    "pendulum": Preset(
        SACConfig(learning_rate=1e-3, total_steps=20_000),
        "the RL Zoo's Pendulum-v1 settings (SB3's defaults, lr 1e-3), 20k steps",
        updates_per_chunk=1_000,
        eval_episodes=10,
    ),
}

TD3_MUJOCO_PRESET = Preset(TD3Config(), "the RL Zoo's MuJoCo settings (SB3's defaults, noise 0.1), 1M steps")

TD3_PRESETS: dict[str, Preset] = {
    "default": TD3_MUJOCO_PRESET,
    "mujoco": TD3_MUJOCO_PRESET,
    "pendulum": Preset(
        TD3Config(
            hidden=(400, 300),
            discount_factor=0.98,
            buffer_size=200_000,
            learning_starts=10_000,
            total_steps=20_000,
        ),
        "the RL Zoo's Pendulum-v1 settings (net 400-300, γ 0.98, 10k random steps), 20k steps",
        updates_per_chunk=1_000,
        eval_episodes=10,
    ),
}

PRESETS: dict[str, dict[str, Preset]] = {
    "reinforce": REINFORCE_PRESETS,
    "ppo": PPO_PRESETS,
    "dqn": DQN_PRESETS,
    "pqn": PQN_PRESETS,
    "sac": SAC_PRESETS,
    "td3": TD3_PRESETS,
}
"""algorithm → preset name → preset; every algorithm has a ``"default"``"""

MINATAR = {
    f"gymnax/{game}-MinAtar": "minatar"
    for game in ("Asterix", "Breakout", "Freeway", "Seaquest", "SpaceInvaders")
}

MUJOCO = {f"{task}-v5": "mujoco" for task in ("HalfCheetah", "Hopper", "Walker2d", "Ant", "Humanoid")}

DEFAULT_PRESETS: dict[str, dict[str, str]] = {
    "ppo": {
        "atari": "atari",
        "CartPole-v0": "cartpole-fast",
        "CartPole-v1": "cartpole-fast",
        "CartPoleNoVel-v1": "memory",
        "Pendulum-v1": "pendulum",
        "GridWorld-v0": "small-games",
        "TicTacToe-v0": "small-games",
        "LunarLander-v3": "lunar",
        **MINATAR,
        **MUJOCO,
    },
    "reinforce": {"Pendulum-v1": "pendulum", "gymnax/Pendulum-v1": "pendulum"},
    "dqn": {"atari": "lecture-atari", "LunarLander-v3": "lunar"},
    "pqn": {"atari": "atari", "CartPoleNoVel-v1": "memory", **MINATAR},
    "sac": {"Pendulum-v1": "pendulum", "gymnax/Pendulum-v1": "pendulum"},
    "td3": {"Pendulum-v1": "pendulum", "gymnax/Pendulum-v1": "pendulum"},
}
"""algorithm → env → the preset ``--preset auto`` picks for it ("atari": every Atari game; any other
env, or an algorithm missing here: "default")"""


def preset(algo: str, name: str, **overrides: Any) -> Preset:
    """Preset ``name`` of algorithm ``algo``, its config with ``overrides`` applied and validated.

    ``preset("dqn", "der", augment="shift").config`` is data-efficient Rainbow with DrQ's shifts; an
    unknown algorithm, preset or setting is a ``UsageError`` naming the choices."""
    if algo not in PRESETS:
        raise UsageError(f"unknown algorithm {algo!r}; choose from {', '.join(PRESETS)}")
    if name not in PRESETS[algo]:
        raise UsageError(f"unknown {algo} preset {name!r}; choose from {', '.join(PRESETS[algo])}")
    chosen = PRESETS[algo][name]
    names = {field.name for field in dataclasses.fields(chosen.config)}
    unknown = sorted(set(overrides) - names)
    if unknown:
        raise UsageError(f"unknown {type(chosen.config).__name__} settings {unknown}")
    return dataclasses.replace(chosen, config=dataclasses.replace(chosen.config, **overrides).validate())

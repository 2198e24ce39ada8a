"""A TF-Agents-style Driver for host environments, its observers, and DQN's host training loop.

The vocabulary is TF-Agents' (see the lecture's last part): a **Driver** steps an environment with
a **collect policy** and hands every transition to its **observers** — plain callables such as the
replay buffer's add and the metrics ``EnvironmentSteps``, ``NumberOfEpisodes``, ``AverageReturn``,
``AverageEpisodeLength``. The driver knows nothing of learning; collection state goes in and out::

    driver = Driver(env, policy, observers=[replay_observer, returns, steps], max_steps=4)
    time_step, policy_state = driver.run(time_step, policy_state)

``env`` is an ``agentax.envs.gym.GymnasiumEnv`` (any Gymnasium env or vector env; its ``step`` returns
agentax's ``TimeStep`` with NumPy arrays ``[num_envs, ...]``) or anything with the same ``reset`` /
``step``. ``policy(obs, policy_state) -> (action, policy_state)`` acts on the batch of observations.

``train_dqn_host`` is DQN's host runner: driver + host replay (``agentax.replay.host``) + the same
jitted ``dqn.make_learn`` the compiled runner uses, for any Gymnasium env with discrete actions.
"""

from __future__ import annotations

import collections
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from agentax.agents import dqn
from agentax.envs.core import TimeStep
from agentax.replay import Transition, example_transition, host, nstep

Observer = Callable[[Transition], None]
CollectPolicy = Callable[[np.ndarray, Any], tuple[np.ndarray, Any]]


def first_time_step(env: Any, seed: int | None = None) -> TimeStep:
    """The time step a driver starts from: the envs' first observations ``[num_envs, ...]``."""
    obs = np.asarray(env.reset(seed=seed))
    zeros = np.zeros(len(obs), bool)
    reward = np.zeros(len(obs), np.float32)
    return TimeStep(obs=obs, reward=reward, terminated=zeros, truncated=zeros, final_obs=obs)


@dataclass
class Driver:
    """Steps ``env`` with ``policy`` and calls each observer with every transition ``[num_envs]``.

    ``run`` stops after ``max_steps`` env steps (summed over envs) or ``max_episodes`` finished
    episodes, whichever comes first (at least one must be set), as TF-Agents' step and episode drivers.
    """

    env: Any
    policy: CollectPolicy
    observers: Sequence[Observer] = ()
    max_steps: int | None = None
    max_episodes: int | None = None

    def __post_init__(self):
        if self.max_steps is None and self.max_episodes is None:
            raise ValueError("a Driver needs max_steps or max_episodes")

    def run(self, time_step: TimeStep, policy_state: Any) -> tuple[TimeStep, Any]:
        """Collect until a limit is reached; returns the time step and policy state to continue from."""
        steps = episodes = 0
        max_steps = np.inf if self.max_steps is None else self.max_steps
        max_episodes = np.inf if self.max_episodes is None else self.max_episodes
        while steps < max_steps and episodes < max_episodes:
            action, policy_state = self.policy(time_step.obs, policy_state)
            action = np.asarray(action)
            next_time_step = self.env.step(action)
            transition = Transition(
                obs=time_step.obs,
                action=action,
                reward=np.asarray(next_time_step.reward, np.float32),
                next_obs=np.asarray(next_time_step.final_obs),
                terminated=np.asarray(next_time_step.terminated, bool),
                truncated=np.asarray(next_time_step.truncated, bool),
                num_steps=np.ones(len(action), np.int32),
            )
            for observer in self.observers:
                observer(transition)
            steps += len(action)
            episodes += int(np.sum(transition.terminated | transition.truncated))
            time_step = next_time_step
        return time_step, policy_state


# ---------------------------------------------------------------- metric observers


@dataclass
class EnvironmentSteps:
    """Env steps seen, summed over envs."""

    count: int = 0

    def __call__(self, transition: Transition) -> None:
        self.count += len(transition.reward)

    def result(self) -> int:
        return self.count


@dataclass
class NumberOfEpisodes:
    """Episodes finished (terminated or truncated)."""

    count: int = 0

    def __call__(self, transition: Transition) -> None:
        self.count += int(np.sum(transition.terminated | transition.truncated))

    def result(self) -> int:
        return self.count


@dataclass
class EpisodeAverage:
    """The mean of a per-episode sum of ``quantity(transition)`` over the last ``buffer_size``
    finished episodes (NaN before the first)."""

    quantity: Callable[[Transition], np.ndarray]
    buffer_size: int = 10
    running: np.ndarray | None = None
    finished: collections.deque = field(default_factory=collections.deque)

    def __call__(self, transition: Transition) -> None:
        if self.running is None:
            self.running = np.zeros(len(transition.reward))
            self.finished = collections.deque(maxlen=self.buffer_size)
        self.running += self.quantity(transition)
        done = transition.terminated | transition.truncated
        self.finished.extend(self.running[done].tolist())
        self.running[done] = 0.0

    def result(self) -> float:
        return float(np.mean(self.finished)) if self.finished else float("nan")


class AverageReturn(EpisodeAverage):
    """The mean return of the last ``buffer_size`` finished episodes."""

    def __init__(self, buffer_size: int = 10):
        super().__init__(quantity=lambda transition: transition.reward, buffer_size=buffer_size)


class AverageEpisodeLength(EpisodeAverage):
    """The mean length of the last ``buffer_size`` finished episodes."""

    def __init__(self, buffer_size: int = 10):
        super().__init__(quantity=lambda transition: np.ones(len(transition.reward)), buffer_size=buffer_size)


# ---------------------------------------------------------------- replay as an observer


class ReplayObserver:
    """Adds each transition ``[num_envs]`` to a host replay buffer, through the n-step accumulator
    when ``n_step > 1`` (the jitted ``agentax.replay.nstep.push``, so both runners build the same
    n-step transitions)."""

    def __init__(self, buffer: Any, n_step: int = 1, discount_factor: float = 0.99):
        self.buffer = buffer
        self.prioritized = isinstance(buffer, host.HostPrioritizedState)
        self.n_step = n_step
        self.discount_factor = discount_factor
        self.accumulator: nstep.NStepState | None = None

    def __call__(self, transition: Transition) -> None:
        if self.n_step > 1:
            if self.accumulator is None:
                self.accumulator = nstep.init(self.n_step, jax.tree.map(jnp.asarray, transition))
            self.accumulator, emitted, full = _push(self.accumulator, transition, self.discount_factor)
            if not bool(full):
                return
            transition = jax.device_get(emitted)
        if self.prioritized:
            host.add_prioritized(self.buffer, transition)
        else:
            host.add(self.buffer, transition)


_push = jax.jit(nstep.push)


# ---------------------------------------------------------------- DQN on a host env


@dataclass
class HostLog:
    """What ``train_dqn_host`` reports at each logging interval."""

    env_steps: int
    episodes: int
    mean_return: float  # over the last 10 finished training episodes
    mean_length: float
    loss: float
    epsilon: float
    learning_steps: int
    seconds: float


def train_dqn_host(
    env: Any,
    cfg: dqn.DQNConfig,
    seed: int = 0,
    log_every_steps: int = 2_000,
    on_log: Callable[[HostLog, Any], bool | None] | None = None,
    resume_from: tuple[dqn.DQNState, int, int] | None = None,
) -> tuple[dqn.DQNState, list[HostLog]]:
    """Train DQN on host env ``env`` (a ``GymnasiumEnv`` with ``cfg.num_envs`` envs) with the driver.

    Collects ``cfg.train_frequency`` steps per env (or episodes, with ``schedule_unit="episodes"``)
    per driver run, then runs ``cfg.gradient_steps`` jitted ``dqn`` learning steps on host-sampled
    batches (uniform replay: all of them in one compiled call, a ``lax.scan`` over the batches).
    Every ``log_every_steps`` env steps calls ``on_log(log, agent)``; a truthy answer stops
    training early. ``resume_from=(agent, env_steps, episodes)`` continues a checkpointed agent (its
    schedules where they were; the replay buffer, not checkpointed, refills). Returns the final
    ``DQNState`` and the logs.
    """
    cfg = cfg.validate()
    num_actions = dqn.num_actions_of(env.action_space())
    key = jax.random.key(seed)
    key, agent_key = jax.random.split(key)
    time_step = first_time_step(env, seed)
    agent = dqn.init(agent_key, time_step.obs[0], num_actions, cfg)
    done_steps, done_episodes = 0, 0
    if resume_from is not None:
        agent, done_steps, done_episodes = resume_from
    one = jax.device_get(example_transition(np.asarray(time_step.obs[0], np.float32), np.int32(0)))
    if cfg.prioritized:
        buffer = host.init_prioritized(cfg.buffer_size, one, cfg.priority_exponent)
    else:
        buffer = host.init(cfg.buffer_size, one)
    by_episode = cfg.schedule_unit == "episodes"
    steps, episodes = EnvironmentSteps(done_steps), NumberOfEpisodes(done_episodes)
    returns, lengths = AverageReturn(), AverageEpisodeLength()
    observers = [ReplayObserver(buffer, cfg.n_step, cfg.discount_factor), steps, episodes, returns, lengths]

    act = jax.jit(_act_and_split)
    learn_step = dqn.make_learn(cfg)
    learn = jax.jit(learn_step)
    learn_many = jax.jit(lambda agent, samples: jax.lax.scan(learn_step, agent, samples))
    holder = {"agent": agent}

    def collect_policy(obs: np.ndarray, policy_key: jax.Array) -> tuple[np.ndarray, jax.Array]:
        epsilon = dqn.epsilon_at(cfg, episodes.count if by_episode else steps.count)
        action, policy_key = act(holder["agent"], np.asarray(obs, np.float32), policy_key, epsilon)
        return np.asarray(action), policy_key

    if by_episode:
        driver = Driver(env, collect_policy, observers, max_episodes=cfg.train_frequency)
    else:
        driver = Driver(env, collect_policy, observers, max_steps=cfg.train_frequency * cfg.num_envs)
    rng = np.random.default_rng(seed)
    key, policy_key = jax.random.split(key)
    logs: list[HostLog] = []
    loss, next_log, start = float("nan"), done_steps + log_every_steps, time.perf_counter()
    while steps.count < cfg.total_steps and not (cfg.max_episodes and episodes.count >= cfg.max_episodes):
        time_step, policy_key = driver.run(time_step, policy_key)
        started = episodes.count > cfg.learning_starts if by_episode else steps.count >= cfg.learning_starts
        if started and buffer_size(buffer) > 0 and cfg.prioritized:
            beta = float(dqn.importance_exponent_at(cfg, steps.count))
            for _ in range(cfg.gradient_steps):  # each batch depends on the priorities the last one set
                sample = host.sample_prioritized(buffer, rng, cfg.batch_size, beta)
                holder["agent"], metrics = learn(holder["agent"], sample)
                host.update_priorities(buffer, sample.indices, np.asarray(metrics["td_error"]))
            loss = float(metrics["loss"])
        elif started and buffer_size(buffer) > 0:
            # Uniform batches do not depend on learning: draw all of them, then learn in one call.
            samples = host.sample(buffer, rng, cfg.batch_size * cfg.gradient_steps)
            samples = jax.tree.map(
                lambda x: x.reshape(cfg.gradient_steps, cfg.batch_size, *x.shape[1:]), samples
            )
            holder["agent"], metrics = learn_many(holder["agent"], samples)
            loss = float(metrics["loss"][-1])
        finished = steps.count >= cfg.total_steps or (cfg.max_episodes and episodes.count >= cfg.max_episodes)
        if steps.count >= next_log or finished:
            next_log += log_every_steps
            log = HostLog(
                env_steps=steps.count,
                episodes=episodes.count,
                mean_return=returns.result(),
                mean_length=lengths.result(),
                loss=loss,
                epsilon=float(dqn.epsilon_at(cfg, episodes.count if by_episode else steps.count)),
                learning_steps=int(holder["agent"].step),
                seconds=time.perf_counter() - start,
            )
            logs.append(log)
            if on_log is not None and on_log(log, holder["agent"]):
                break
    return holder["agent"], logs


def _act_and_split(agent: Any, obs: jax.Array, key: jax.Array, epsilon: jax.Array) -> tuple[jax.Array, ...]:
    key, act_key = jax.random.split(key)
    return dqn.act(agent, obs, act_key, epsilon), key


def buffer_size(buffer: Any) -> int:
    """Transitions held by a host buffer (uniform or prioritized)."""
    return buffer.buffer.size if isinstance(buffer, host.HostPrioritizedState) else buffer.size


def run_dqn_host(
    env_id: str,
    cfg: dqn.DQNConfig,
    run: Any = None,
    *,
    seed: int = 0,
    log_every_steps: int = 2_000,
    eval_episodes: int = 10,
    stop_at_return: float | None = None,
    resume: bool = False,
    progress: bool = False,
    on_row: Callable[[dict], None] | None = None,
) -> dict[str, Any]:
    """DQN on Gymnasium env ``env_id`` through the driver, writing ``run`` (an ``agentax.runs.Run``).

    At each logging interval: a metrics row (``env_steps``, ``mean_return`` of the last training
    episodes, ``eval_return`` of the greedy policy over ``eval_episodes`` episodes, loss, ε), a
    checkpoint of the learner, and an early stop once ``eval_return >= stop_at_return``. At the end
    eval.json (on fresh evaluation seeds) and curve.png; ``on_row`` also receives each row. Returns the
    final evaluation.
    """
    from agentax.envs.gym import GymnasiumEnv
    from agentax.evaluate import host_episode_returns
    from agentax.runs import latest_checkpoint, load_tree

    env = GymnasiumEnv(env_id, cfg.num_envs)
    eval_env = GymnasiumEnv(env_id, min(eval_episodes, 8))
    resume_from, evaluations, elapsed_before = None, 0, 0.0
    if resume:
        target = jax.eval_shape(
            lambda: dqn.init(jax.random.key(0), _obs_example(env), _num_actions(env), cfg)
        )
        agent, meta = load_tree(latest_checkpoint(run.path), target)
        resume_from, evaluations = (
            (agent, int(meta["env_steps"]), int(meta["episodes"])),
            int(meta["evaluations"]),
        )
        run.truncate_metrics(meta["env_steps"])
    start, last = (
        time.perf_counter(),
        {"steps": resume_from[1] if resume_from else 0, "time": time.perf_counter()},
    )
    bar = _progress_bar(progress, cfg.total_steps)

    def on_log(log: HostLog, agent: dqn.DQNState) -> bool:
        nonlocal evaluations
        returns, _ = host_episode_returns(
            eval_env, dqn.greedy_policy(agent), eval_episodes, seed=10_000 + evaluations
        )
        evaluations += 1
        now = time.perf_counter()
        row = {
            "env_steps": log.env_steps,
            "mean_return": log.mean_return,
            "return_seed0": log.mean_return,
            "eval_return": float(np.mean(returns)),
            "steps_per_second": (log.env_steps - last["steps"]) / max(now - last["time"], 1e-9),
            "wall_seconds": elapsed_before + now - start,
            "loss": log.loss,
            "epsilon": log.epsilon,
            "learning_steps": log.learning_steps,
            "episodes": log.episodes,
        }
        last.update(steps=log.env_steps, time=now)
        solved = stop_at_return is not None and row["eval_return"] >= stop_at_return
        if on_row is not None:
            on_row(row)
        if run is not None:
            run.log(row)
            meta = {
                "env_steps": log.env_steps,
                "episodes": log.episodes,
                "evaluations": evaluations,
                "updates": log.learning_steps,
                "elapsed": row["wall_seconds"],
            }
            run.save_checkpoint(log.env_steps, agent, meta)
        if bar is not None:
            bar.update(
                bar.task_ids[0],
                completed=log.env_steps,
                description=f"dqn {env_id} return {row['eval_return']:.1f}",
            )
        return solved

    try:
        agent, logs = train_dqn_host(env, cfg, seed, log_every_steps, on_log, resume_from)
    finally:
        if bar is not None:
            bar.stop()
    returns, lengths = host_episode_returns(
        eval_env, dqn.greedy_policy(agent), eval_episodes, seed=20_000 + seed
    )
    result = {"mean_return": float(np.mean(returns)), "env_steps": logs[-1].env_steps if logs else 0}
    if run is not None:
        result = run.write_eval(returns[None], lengths[None], env_steps=result["env_steps"])
        run.plot()
        run.close()
    env.close()
    eval_env.close()
    return result


def _obs_example(env: Any) -> jax.Array:
    space = env.observation_space()
    return jnp.zeros(space.shape, jnp.float32)


def _num_actions(env: Any) -> int:
    return dqn.num_actions_of(env.action_space())


def _progress_bar(enabled: bool, total_steps: int):
    if not enabled:
        return None
    import sys

    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    bar = Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.completed:,.0f} env steps"),
        TimeElapsedColumn(),
        console=Console(file=sys.stderr),
    )
    bar.add_task("dqn", total=total_steps)
    bar.start()
    return bar


def train_cli(algo: str, module: Any, run_args: Any, cfg: dqn.DQNConfig, preset: Any, out: Any) -> int:
    """``agentax train dqn --env <Gymnasium id>``: check the env, create the run folder, train on the host.

    Same arguments as ``agentax.train.host.train_cli``; ``agentax.cli.train`` sends DQN on a
    Gymnasium-only env here. A continuous action space is refused before anything is written.
    """
    import dataclasses
    import sys
    from pathlib import Path

    from agentax.cli.train import parse_stop
    from agentax.envs.gym import GymnasiumEnv
    from agentax.errors import UsageError
    from agentax.runs import Run, run_config

    if run_args.seeds != 1:
        raise UsageError(f"{run_args.env} steps on the host: train one seed per process (--seeds 1)")
    probe = GymnasiumEnv(run_args.env, 1)
    dqn.num_actions_of(probe.action_space())
    spec = probe.vector_env.spec
    probe.close()
    threshold = dataclasses.make_dataclass("Threshold", ["reward_threshold"])(
        getattr(spec, "reward_threshold", None)
    )
    runner = {"seed": run_args.seed, "eval_episodes": preset.eval_episodes, "log_every_steps": 2_048}
    runner["stop_at_return"] = parse_stop(run_args.stop_at_return, preset, threshold)
    config = run_config(algo, run_args.env, run_args.preset, "host", runner, module.config_to_dict(cfg))
    run = Run.create(Path(out), config)
    print(f"training {algo} on {run_args.env} (host driver) into {out}", file=sys.stderr)
    return _train_and_report(run, cfg, resume=False, progress=run_args.progress)


def resume_cli(module: Any, run: Any, cfg: dqn.DQNConfig, progress: bool) -> int:
    """``agentax train --resume DIR`` for a DQN run on the host driver."""
    return _train_and_report(run, cfg, resume=True, progress=progress)


def _train_and_report(run: Any, cfg: dqn.DQNConfig, *, resume: bool, progress: bool) -> int:
    from agentax.cli.train import report

    runner = run.config["runner"]
    start = time.perf_counter()
    evaluation = run_dqn_host(
        run.config["env"],
        cfg,
        run,
        seed=runner["seed"],
        log_every_steps=runner["log_every_steps"],
        eval_episodes=runner["eval_episodes"],
        stop_at_return=runner["stop_at_return"],
        resume=resume,
        progress=progress,
    )
    report(evaluation, run.path, time.perf_counter() - start)
    return 0

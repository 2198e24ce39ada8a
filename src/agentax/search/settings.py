"""What grid and random search over the vacuum robot's (p, r) share: the lecture's (p, r) policy,
evaluating thousands of settings in one vmapped, jitted call, picking the best, re-evaluating it on fresh
episodes with a confidence interval, and the heatmap.

The lecture's stochastic policy is :func:`vacuum_policy`: with probability p move forward, with
probability 1 − p rotate by a random angle in [−r, r] (it ignores the observation).
:func:`evaluate_settings` plays several episodes of each of thousands of (p, r) settings in one call.

The best setting is the one with the highest mean dust over the search episodes. That mean is biased
upwards (the best of thousands of noisy means is partly luck), so the reported figure and its 95 %
confidence interval come from ``final_episodes`` fresh episodes of that setting, never the search's.
"""

from __future__ import annotations

import json
import math
import pathlib
from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from agentax.envs.core import episode_returns, threefry2x32
from agentax.envs.vacuum import Vacuum, VacuumParams
from agentax.errors import UsageError
from agentax.policies import Policy
from agentax.search.population import mean_confidence_interval

SEARCH_STREAM, EVAL_STREAM = 0, 1  # jax.random.fold_in streams: search episodes, fresh evaluation episodes


def _uniform2(key: jax.Array) -> jax.Array:
    """Two float32 uniforms in [0, 1) ``[2]``: the two words of one Threefry-2x32 hash of ``key``.

    Half the hashes of ``jax.random.uniform(key, (2,))`` and unrolled, so XLA fuses it (faster on CPU).
    """
    if str(jax.random.key_impl(key)) != "threefry2x32":
        return jax.random.uniform(key, (2,), jnp.float32)
    data = jax.random.key_data(key)
    bits = jnp.stack(threefry2x32(data[0], data[1], jnp.uint32(0), jnp.uint32(1)))
    return jax.lax.bitcast_convert_type((bits >> 9) | jnp.uint32(0x3F800000), jnp.float32) - 1.0


def vacuum_policy(p: float | jax.Array, r: float | jax.Array) -> Policy:
    """The lecture's policy: with probability ``p`` move forward, else turn by a uniform angle in [−r, r]."""

    def policy(obs: jax.Array, key: jax.Array) -> jax.Array:
        u = _uniform2(key)
        forward = u[0] < p
        angle = (2.0 * u[1] - 1.0) * r
        return jnp.stack([forward.astype(jnp.float32), jnp.asarray(angle, jnp.float32)])

    return policy


@partial(jax.jit, static_argnums=(3,))
def _evaluate_settings(p: jax.Array, r: jax.Array, key: jax.Array, num_episodes: int, params: VacuumParams):
    env = Vacuum()

    def one_setting(p, r, key):
        returns, _ = episode_returns(env, vacuum_policy(p, r), key, num_episodes, params)
        return returns

    return jax.vmap(one_setting)(p, r, jax.random.split(key, p.shape[0]))


def evaluate_settings(
    p: jax.Array, r: jax.Array, key: jax.Array, num_episodes: int = 4, params: VacuumParams | None = None
) -> jax.Array:
    """Dust collected ``[N, num_episodes]`` by the (p, r) policies ``p: [N]``, ``r: [N]``, in one call.

    Setting ``i`` plays its episodes with ``jax.random.split(key, N)[i]``, so one setting evaluated
    alone with that key gives the same returns.
    """
    params = Vacuum().default_params() if params is None else params
    p, r = jnp.asarray(p, jnp.float32).reshape(-1), jnp.asarray(r, jnp.float32).reshape(-1)
    return _evaluate_settings(p, r, key, num_episodes, params)


@dataclass(frozen=True)
class SettingsResult:
    """The outcome of a (p, r) search."""

    p: np.ndarray  # [num_settings]
    r: np.ndarray  # [num_settings]
    returns: np.ndarray  # [num_settings, num_episodes]: dust collected in the search episodes
    best_index: int  # of the highest mean in the search episodes
    final_returns: np.ndarray  # [final_episodes]: the best setting on fresh episodes
    ci95: tuple[float, float]  # 95 % confidence interval of the best setting's mean dust (fresh episodes)
    grid_shape: tuple[int, int] | None  # (num_p, num_r) when the settings form a grid (p major)

    @property
    def mean_returns(self) -> np.ndarray:
        return self.returns.mean(axis=1)

    @property
    def best_p(self) -> float:
        return float(self.p[self.best_index])

    @property
    def best_r(self) -> float:
        return float(self.r[self.best_index])

    def summary(self) -> dict:
        """eval.json: the best setting on fresh episodes."""
        final = self.final_returns
        return {
            "p": self.best_p,
            "r": self.best_r,
            "mean_return": float(final.mean()),
            "std_return": float(final.std()),
            "min_return": float(final.min()),
            "max_return": float(final.max()),
            "episodes": int(final.size),
            "ci95_low": self.ci95[0],
            "ci95_high": self.ci95[1],
            "search_mean_return": float(self.mean_returns[self.best_index]),
            "settings_evaluated": int(self.p.size),
        }


def check_search_config(config, counts: tuple[str, ...]) -> None:
    """Clear errors for a (p, r) search config: ``counts`` ≥ 1, final episodes ≥ 2, r max in [0, π]."""
    for name in counts:
        if getattr(config, name) < 1:
            raise UsageError(f"{name.replace('_', ' ')} must be >= 1, got {getattr(config, name)}")
    if config.final_episodes < 2:
        got = config.final_episodes
        raise UsageError(f"final episodes must be >= 2 for a confidence interval, got {got}")
    if not 0 <= config.r_max <= math.pi:
        raise UsageError(f"r max must be in [0, pi], got {config.r_max}")


def search_settings(
    p: np.ndarray,
    r: np.ndarray,
    seed: int,
    num_episodes: int,
    final_episodes: int,
    grid_shape: tuple[int, int] | None = None,
    params: VacuumParams | None = None,
) -> SettingsResult:
    """Evaluate all (p, r) at once, pick the best mean, re-evaluate it on ``final_episodes`` new episodes."""
    key = jax.random.key(seed)
    returns = np.asarray(
        evaluate_settings(p, r, jax.random.fold_in(key, SEARCH_STREAM), num_episodes, params)
    )
    best = int(np.argmax(returns.mean(axis=1)))
    final = np.asarray(
        evaluate_settings(
            p[best : best + 1],
            r[best : best + 1],
            jax.random.fold_in(key, EVAL_STREAM),
            final_episodes,
            params,
        )
    )[0]
    return SettingsResult(
        p=np.asarray(p, np.float32),
        r=np.asarray(r, np.float32),
        returns=returns,
        best_index=best,
        final_returns=final,
        ci95=mean_confidence_interval(final),
        grid_shape=grid_shape,
    )


def plot_heatmap(result: SettingsResult, path: pathlib.Path) -> tuple[float, float]:
    """Mean dust over the (p, r) plane as a PNG (a grid as cells, random settings as dots), the best marked.

    Returns the (p, r) it marked.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(6.4, 5.2))
    means = result.mean_returns
    if result.grid_shape is not None:
        num_p, num_r = result.grid_shape
        p_values, r_values = result.p.reshape(num_p, num_r)[:, 0], result.r.reshape(num_p, num_r)[0]
        image = axes.pcolormesh(
            r_values, p_values, means.reshape(num_p, num_r), shading="nearest", cmap="viridis"
        )
    else:
        image = axes.scatter(result.r, result.p, c=means, s=12, cmap="viridis")
    marked = (result.best_p, result.best_r)
    axes.plot(
        marked[1], marked[0], marker="*", markersize=18, color="red", markeredgecolor="white", linestyle=""
    )
    lo, hi = result.ci95
    axes.set_title(
        f"best p = {marked[0]:.3f}, r = {marked[1]:.3f}: {result.final_returns.mean():.1f} dust "
        f"(95 % CI {lo:.1f}-{hi:.1f}, fresh episodes)",
        fontsize=9,
    )
    axes.set_xlabel("r: largest rotation angle (radians)")
    axes.set_ylabel("p: probability to move forward")
    figure.colorbar(
        image, ax=axes, label=f"mean dust collected in 30 min ({result.returns.shape[1]} episodes)"
    )
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return marked


def load_best_setting(run_dir: pathlib.Path) -> tuple[float, float]:
    """The best ``(p, r)`` a vacuum search saved in ``run_dir/eval.json``."""
    path = pathlib.Path(run_dir) / "eval.json"
    try:
        best = json.loads(path.read_text())
        return float(best["p"]), float(best["r"])
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise UsageError(f"cannot read the best (p, r) from {path}: {error}") from None

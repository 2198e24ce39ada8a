"""Atari: EnvPool and ale-py backends give the same observations; the learning and evaluation views.

The ale backend preprocesses ale-py's frames itself; it is checked frame by frame against
Gymnasium's ``AtariPreprocessing`` + ``FrameStackObservation``. The EnvPool adapter is checked
against a bare EnvPool pool stepped with the same actions (its next-step reset made visible).
"""

import math

import gymnasium
import numpy as np
import pytest

import agentax
from agentax.envs.atari import AtariEnv, is_atari_id, make_atari
from agentax.errors import UsageError

ale_py = pytest.importorskip("ale_py")
pytest.importorskip("cv2")
envpool = pytest.importorskip("envpool")

BREAKOUT = "ALE/Breakout-v5"
pytestmark = pytest.mark.timeout(120)


def _random_actions(seed: int, num_envs: int, n: int, num_actions: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(num_actions, size=(n, num_envs))


def test_ids_and_spaces():
    assert is_atari_id(BREAKOUT) and is_atari_id("Breakout-v5") and is_atari_id("ALE/Nope-v5")
    assert not is_atari_id("CartPole-v1") and not is_atari_id("Nope-v5")
    env = agentax.envs.make("Breakout-v5", 2, backend="ale")
    assert isinstance(env, AtariEnv) and env.id == BREAKOUT and env.num_envs == 2
    assert env.observation_space().shape == (4, 84, 84) and env.observation_space().dtype == np.uint8
    assert env.action_space().n == 4  # Breakout's minimal set: NOOP, FIRE, RIGHT, LEFT
    obs = env.reset(seed=0)
    assert obs.shape == (2, 4, 84, 84) and obs.dtype == np.uint8
    assert env.render_rgb().shape == (210, 160, 3)
    env.close()


@pytest.mark.parametrize(
    "bad, closest",
    [("ALE/Breakot-v5", "ALE/Breakout-v5"), ("ALE/SpaceInvader-v5", "ALE/SpaceInvaders-v5")],
)
def test_unknown_game_names_the_closest(bad, closest):
    with pytest.raises(UsageError, match=closest) as error:
        agentax.envs.make(bad)
    assert "\n" not in str(error.value)
    with pytest.raises(UsageError, match="ALE/Breakout-v5"):
        agentax.envs.make("Breakoutt-v5")  # EnvPool's form, misspelt: not Gymnasium's either


def test_bad_backend_and_missing_backend(monkeypatch):
    with pytest.raises(UsageError, match="envpool, ale"):
        make_atari(BREAKOUT, backend="gpu")
    monkeypatch.setitem(__import__("sys").modules, "envpool", None)  # as if not installed
    with pytest.raises(UsageError, match=r"pip install 'agentax\[atari\]'"):
        make_atari(BREAKOUT, backend="envpool")
    assert make_atari(BREAKOUT, backend="auto").backend_name == "ale"  # auto falls back


@pytest.mark.slow
def test_first_frame_same_in_both_backends():
    """No no-ops, no sticky actions: after reset (and its FIRE) both backends show the same frame."""
    for game in (BREAKOUT, "ALE/Pong-v5", "ALE/SpaceInvaders-v5"):
        first = []
        for backend in ("envpool", "ale"):
            env = make_atari(game, 2, backend=backend, sticky_actions=0.0, noop_max=0)
            first.append(env.reset(seed=5))
            env.close()
        np.testing.assert_array_equal(first[0], first[1], err_msg=game)
        assert first[0].std() > 0  # a real screen, not a blank buffer


@pytest.mark.slow
def test_deterministic_games_identical_in_both_backends():
    """Sticky actions and no-ops off, Breakout is a function of the actions: both backends play the
    same games (rewards, life-loss ends, scores); the frames differ at most at a game over, where
    EnvPool keeps a stale max-pool frame in ``final_obs`` and agentax shows the last screen."""
    runs = []
    actions = _random_actions(1, 2, 900, 4)
    for backend in ("envpool", "ale"):
        env = make_atari(BREAKOUT, 2, backend=backend, sticky_actions=0.0, noop_max=0)
        env.reset(seed=0)
        steps = [env.step(a) for a in actions]
        runs.append((steps, env.drain_scores()))
        env.close()
    (steps_a, scores_a), (steps_b, scores_b) = runs
    assert scores_a == scores_b and len(scores_a) >= 4
    for a, b in zip(steps_a, steps_b, strict=True):
        np.testing.assert_array_equal(a.obs, b.obs)
        np.testing.assert_array_equal(a.reward, b.reward)
        np.testing.assert_array_equal(a.terminated, b.terminated)
        live = ~(a.terminated & (a.obs == a.obs[:, :1]).all(axis=(1, 2, 3)))  # not a game over
        np.testing.assert_array_equal(a.final_obs[live], b.final_obs[live])


class _FireOnReset(gymnasium.Wrapper):
    """The reference's FIRE: one frame after the emulator's reset, as EnvPool does it."""

    def reset(self, **kwargs):
        self.env.reset(**kwargs)
        return self.env.step(1)[0], {}


@pytest.mark.slow
def test_preprocessing_equals_gymnasium_atari_preprocessing():
    """ale backend == Gymnasium's AtariPreprocessing + FrameStackObservation, frame by frame, with
    sticky actions on (the same seed seeds the same emulator), until the first lost life (after it
    agentax fires, which Gymnasium's wrappers do not)."""
    from gymnasium.wrappers import AtariPreprocessing, FrameStackObservation

    gymnasium.register_envs(ale_py)
    for seed in (0, 1):
        raw = gymnasium.make(BREAKOUT, frameskip=1, repeat_action_probability=0.25, full_action_space=False)
        reference = FrameStackObservation(
            AtariPreprocessing(_FireOnReset(raw), noop_max=0, frame_skip=4, screen_size=84), 4
        )
        env = make_atari(BREAKOUT, 1, backend="ale", sticky_actions=0.25, noop_max=0)
        want, _ = reference.reset(seed=seed)
        np.testing.assert_array_equal(env.reset(seed=seed)[0], want)
        lives, compared = raw.unwrapped.ale.lives(), 0
        for action in _random_actions(seed, 1, 400, 4):
            want, reward, *_ = reference.step(int(action[0]))
            ts = env.step(action)
            np.testing.assert_array_equal(ts.final_obs[0], want)
            assert ts.reward[0] == np.sign(reward)
            compared += 1
            if raw.unwrapped.ale.lives() < lives:
                assert ts.terminated[0]
                break
            np.testing.assert_array_equal(ts.obs[0], want)
        assert compared > 20
        env.close()
        reference.close()


@pytest.mark.slow
def test_envpool_adapter_hides_next_step_reset():
    """Against a bare pool on the same seed and actions: EnvPool returns the last frame on the
    ending step and the next start one step later (ignoring that step's action); the adapter returns
    both on the ending step, in ``final_obs`` and ``obs``, and the two stay in step afterwards."""
    env = make_atari(BREAKOUT, 1, backend="envpool", sticky_actions=0.25, noop_max=30, training=True)
    bare = env.backend._make(7)
    env.reset(seed=7)
    bare_obs, _ = bare.reset()
    ends = game_overs = 0
    for action in _random_actions(2, 1, 700, 4):
        ts = env.step(action)
        bare_obs, _, term, trunc, info = bare.step(action.astype(np.int32))
        np.testing.assert_array_equal(ts.final_obs, bare_obs)  # the frame the step really reached
        assert ts.terminated[0] == (term[0] or trunc[0]) and not ts.truncated[0]
        if ts.terminated[0]:
            ends += 1
            bare_obs, reward, *_ = bare.step(np.zeros(1, np.int32))  # EnvPool's reset step
            assert reward[0] == 0
            over = bool(info["terminated"][0])
            game_overs += over
            # a new game starts from one frame stacked 4 times; after a lost life the stack goes on
            assert (bare_obs[0] == bare_obs[0, :1]).all() == over
        else:
            np.testing.assert_array_equal(ts.final_obs, ts.obs)
        np.testing.assert_array_equal(ts.obs, bare_obs)
    assert ends >= 6 and game_overs >= 1
    bare.close()
    env.close()


@pytest.mark.slow
@pytest.mark.parametrize("backend", ["envpool", "ale"])
def test_learning_view_and_true_scores(backend):
    """The same seeds and actions in training and evaluation mode play the same games: training
    clips rewards and ends an episode at each lost life while the game goes on; both report the
    true score (unclipped, all lives) of every game, which is the sum of the evaluation rewards.
    Space Invaders pays 5-30 per alien; games are cut at 1,200 frames (300 agent steps)."""
    kwargs = dict(backend=backend, sticky_actions=0.25, noop_max=30, max_frames=1200)
    train = make_atari("ALE/SpaceInvaders-v5", 2, training=True, **kwargs)
    evaluate = make_atari("ALE/SpaceInvaders-v5", 2, training=False, **kwargs)
    np.testing.assert_array_equal(train.reset(seed=3), evaluate.reset(seed=3))
    raw_sum, raw_scores = np.zeros(2), []
    lives_lost = truncations = 0
    for action in _random_actions(3, 2, 700, train.action_space().n):
        t, e = train.step(action), evaluate.step(action)
        np.testing.assert_array_equal(t.obs, e.obs)
        assert set(np.unique(t.reward)) <= {-1.0, 0.0, 1.0}
        np.testing.assert_array_equal(t.reward, np.sign(e.reward))
        assert (t.truncated == e.truncated).all() and not (e.terminated & ~t.terminated).any()
        life = t.terminated & ~e.terminated & ~e.truncated  # a lost life, the game goes on
        lives_lost += life.sum()
        np.testing.assert_array_equal(e.final_obs[life], e.obs[life])
        assert not (t.final_obs[life] == t.obs[life]).all(axis=(1, 2, 3)).any()
        raw_sum += e.reward
        for i in np.flatnonzero(e.terminated | e.truncated):
            raw_scores.append(raw_sum[i])
            raw_sum[i] = 0
        truncations += e.truncated.sum()
    train_scores, eval_scores = train.drain_scores(), evaluate.drain_scores()
    assert train_scores == eval_scores and train.drain_scores() == []
    assert sorted(s for s, _ in eval_scores) == sorted(raw_scores)
    assert any(score > 1 for score, _ in eval_scores)  # clipping mattered
    assert all(length <= 300 for _, length in eval_scores)
    assert lives_lost >= 2 and truncations >= 1
    train.close()
    evaluate.close()


def _play(backend: str, games: int, seed: int) -> np.ndarray:
    env = make_atari(BREAKOUT, 8, backend=backend, training=False)  # sticky 0.25, up to 30 no-ops
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    finished: list[tuple[float, int]] = []
    while len(finished) < games:
        env.step(rng.integers(4, size=8))
        finished += env.drain_scores()
    env.close()
    return np.asarray(finished[:games], np.float64)


@pytest.mark.long
@pytest.mark.timeout(180)
def test_random_policy_scores_agree_between_backends():
    """100 random-policy Breakout games per backend (different seeds, sticky actions and no-ops on):
    mean score and mean length agree within 4 standard errors of their difference (Welch's z; a
    false alarm about once in 16,000 runs). A real mismatch shows: a lost FIRE after a life leaves
    a random game ~2x longer, a lost no-op count shifts lengths by many standard errors."""
    games = 100
    envpool_games, ale_games = _play("envpool", games, seed=10), _play("ale", games, seed=20_000)
    # the standard error bounds what the test can see: ~15 % of the mean score (~1.4 points, sd ~1.4),
    # ~4 % of the mean length (~180 steps): 4 se is a ~60 % / ~16 % difference
    for column, what, resolution in ((0, "score", 0.25), (1, "length", 0.06)):
        a, b = envpool_games[:, column], ale_games[:, column]
        se = math.sqrt(a.var(ddof=1) / games + b.var(ddof=1) / games)
        assert abs(a.mean() - b.mean()) < 4 * se, (what, a.mean(), b.mean(), se)
        assert se < resolution * max(a.mean(), b.mean()), (what, se)

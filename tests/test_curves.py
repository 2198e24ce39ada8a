"""curve.png: the greedy evaluation beside the training return, the solved threshold, bootstrap bands
that stay within the data; TensorBoard tags in groups."""

import numpy as np
import pytest

from agentax.curves import bootstrap_band, curve_figure, plot_curves, run_curves, solved_threshold
from agentax.runs import Run, read_metrics, tensorboard_tag

# Eight CartPole-v1 seeds late in training: six at the cap, two still learning.
CARTPOLE_SEEDS = np.array([500, 500, 500, 500, 500, 500, 320, 210], float)


def test_bootstrap_band_stays_below_the_cap_where_a_normal_interval_does_not():
    per_seed = np.stack([CARTPOLE_SEEDS, CARTPOLE_SEEDS - 100, np.full(8, 500.0)])  # (rows, seeds)
    half = 1.96 * per_seed.std(1, ddof=1) / np.sqrt(8)
    normal_high = per_seed.mean(1) + half
    assert normal_high[0] > 500  # 453.75 + 1.96 · 109.4 / √8 = 529.6: a return CartPole cannot give
    low, high = bootstrap_band(per_seed)
    assert (high <= per_seed.max(1)).all() and (low >= per_seed.min(1)).all()
    assert low[0] < per_seed[0].mean() < high[0] <= 500
    assert low[2] == high[2] == 500  # every seed at 500: no spread, no band
    again = bootstrap_band(per_seed)  # a fixed seed: the same band every time
    np.testing.assert_array_equal(high, again[1])


def test_bootstrap_band_skips_missing_seeds_and_single_seeds():
    per_seed = np.array([[np.nan, np.nan, np.nan], [10.0, np.nan, np.nan], [10.0, 20.0, np.nan]])
    low, high = bootstrap_band(per_seed)
    assert np.isnan(low[:2]).all() and np.isnan(high[:2]).all()
    assert 10.0 <= low[2] < high[2] <= 20.0
    low, high = bootstrap_band(np.ones((4, 1)))
    assert np.isnan(low).all() and np.isnan(high).all()


def fake_run(path, seeds=8, env="CartPole-v1", eval_every=3):
    run = Run.create(path, {"algo": "ppo", "env": env})
    rng = np.random.default_rng(0)
    for i in range(1, 10):
        train = np.minimum(500.0, 55.0 * i + rng.normal(0, 40, seeds))
        evaluated = i % eval_every == 0
        greedy = (
            np.minimum(500.0, 70.0 * i + rng.normal(0, 40, seeds)) if evaluated else np.full(seeds, np.nan)
        )
        run.log(
            {
                "env_steps": 1000 * i,
                "mean_return": float(train.mean()),
                **{f"return_seed{k}": float(v) for k, v in enumerate(train)},
                "eval_return": float(greedy.mean()),
                **{f"eval_seed{k}": float(v) for k, v in enumerate(greedy)},
                "steps_per_second": 5000.0,
                "loss": 1.0 / i,
                "entropy": 0.6,
            }
        )
    run.close()
    return run.path


def legend_texts(fig):
    return [t.get_text() for t in fig.axes[0].get_legend().get_texts()]


def test_curve_draws_evaluation_training_band_and_threshold(tmp_path):
    path = fake_run(tmp_path / "r")
    curves = run_curves(path)
    assert curves.solved == 475.0
    np.testing.assert_array_equal(curves.evaluation.steps, [3000, 6000, 9000])  # only the evaluated rows
    assert curves.training.steps.size == 9 and curves.training.num_seeds == 8
    rows = read_metrics(path)
    eval_means = [
        np.mean([r[f"eval_seed{k}"] for k in range(8)]) for r in rows if np.isfinite(r["eval_return"])
    ]
    np.testing.assert_allclose(curves.evaluation.mean, eval_means)
    assert (curves.evaluation.high <= 500).all() and (curves.training.high <= 500).all()

    fig = curve_figure([path])
    lines = {line.get_label(): line for line in fig.axes[0].get_lines()}
    np.testing.assert_array_equal(lines["greedy evaluation"].get_xdata(), [3000, 6000, 9000])
    np.testing.assert_allclose(lines["greedy evaluation"].get_ydata(), eval_means)
    assert lines["greedy evaluation"].get_marker() == "o"
    assert len(lines["training episodes"].get_xdata()) == 9
    assert set(lines["solved (475)"].get_ydata()) == {475.0} and lines["solved (475)"].get_linestyle() == "--"
    assert legend_texts(fig) == [
        "training episodes",
        "greedy evaluation",
        "solved (475)",
        "band: 95 % bootstrap CI over 8 seeds",
    ]
    out = plot_curves([path], tmp_path / "curve.png")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_one_seed_has_no_band_and_unknown_envs_no_threshold(tmp_path):
    path = fake_run(tmp_path / "r", seeds=1, env="NoSuchEnv-v0")
    fig = curve_figure([path])
    assert legend_texts(fig) == ["training episodes", "greedy evaluation"]
    assert not fig.axes[0].collections  # no fill_between
    assert solved_threshold("NoSuchEnv-v0") is None and solved_threshold("ALE/Pong-v5") is None
    assert solved_threshold("Acrobot-v1") == -100.0  # from Gymnasium's spec


def test_several_runs_overlay_with_their_labels(tmp_path):
    a, b = fake_run(tmp_path / "a"), fake_run(tmp_path / "b", seeds=4)
    texts = legend_texts(curve_figure([a, b], labels=["A", "B"]))
    assert texts[:4] == [
        "A: training episodes",
        "A: greedy evaluation",
        "B: training episodes",
        "B: greedy evaluation",
    ]
    assert texts[4:] == [
        "solved (475)",
        "band: 95 % bootstrap CI over 4 seeds",
        "band: 95 % bootstrap CI over 8 seeds",
    ]


@pytest.mark.parametrize(
    "name, tag",
    [
        ("mean_return", "train/mean_return"),
        ("return_seed3", "train/return_seed3"),
        ("epsilon", "train/epsilon"),
        ("eval_return", "eval/eval_return"),
        ("eval_seed0", "eval/eval_seed0"),
        ("loss", "loss/loss"),
        ("value_loss", "loss/value_loss"),
        ("approx_kl", "loss/approx_kl"),
        ("q_mean", "loss/q_mean"),
        ("steps_per_second", "perf/steps_per_second"),
        ("learner_wait_fraction", "perf/learner_wait_fraction"),
        ("replay_bytes", "perf/replay_bytes"),
        ("policy_lag", "perf/policy_lag"),
        ("wall_seconds", "perf/wall_seconds"),
        ("surprise", "other/surprise"),
    ],
)
def test_tensorboard_tag_groups(name, tag):
    assert tensorboard_tag(name) == tag


def read_scalars(folder):
    """``{tag: [(step, value), ...]}`` from tensorboardX event files (TFRecord: length, CRC, record, CRC)."""
    import struct

    from tensorboardX.proto.event_pb2 import Event

    scalars = {}
    for path in sorted(folder.glob("events.out.tfevents.*")):
        data, offset = path.read_bytes(), 0
        while offset < len(data):
            (length,) = struct.unpack("<Q", data[offset : offset + 8])
            event = Event.FromString(data[offset + 12 : offset + 12 + length])
            offset += 12 + length + 4
            for value in event.summary.value:
                scalars.setdefault(value.tag, []).append((event.step, value.simple_value))
    return scalars


def test_tensorboard_event_file_holds_grouped_tags_and_csv_plain_names(tmp_path):
    path = fake_run(tmp_path / "r", seeds=2)
    scalars = read_scalars(path / "tensorboard")
    assert set(scalars) == {
        "train/mean_return",
        "train/return_seed0",
        "train/return_seed1",
        "eval/eval_return",
        "eval/eval_seed0",
        "eval/eval_seed1",
        "perf/steps_per_second",
        "loss/loss",
        "loss/entropy",
    }
    assert [step for step, _ in scalars["eval/eval_return"]] == [3000, 6000, 9000]  # NaN rows skipped
    assert "mean_return" in read_metrics(path)[0] and "train/mean_return" not in read_metrics(path)[0]

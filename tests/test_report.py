"""agentax.report (IQM, stratified bootstrap, probability of improvement), ``agentax report``,
the aggregates in a multi-seed eval.json, and ``agentax --version``."""

import json
from importlib.metadata import version

import numpy as np
import pytest
import scipy.stats

from agentax import report
from agentax.cli import main
from agentax.runs import Run, run_config

# Final returns of 8 seeds; sorted: 10, 12, 35, 120, 200, 480, 495, 500.
EIGHT = np.array([10.0, 200, 35, 500, 480, 12, 495, 120])


def test_aggregates_by_hand():
    # IQM: floor(8 / 4) = 2 cut at each end -> (35 + 120 + 200 + 480) / 4 = 835 / 4
    assert report.iqm(EIGHT) == 208.75
    assert report.mean(EIGHT) == 1852 / 8  # 10 + 12 + 35 + 120 + 200 + 480 + 495 + 500 = 1852
    assert report.median(EIGHT) == (120 + 200) / 2
    # n = 5: floor(5 / 4) = 1 cut at each end -> (2 + 3 + 4) / 3; n < 4 cuts nothing
    assert report.iqm([5.0, 1, 3, 2, 4]) == 3.0
    assert report.iqm([1.0, 2, 9]) == 4.0


def test_iqm_matches_scipy_trim_mean_and_vectorises():
    """rliable's IQM is scipy.stats.trim_mean(x, 0.25); along an axis it equals row by row."""
    rng = np.random.default_rng(0)
    for n in (1, 2, 3, 4, 5, 7, 8, 13, 100):
        x = rng.normal(size=n) * 100
        assert report.iqm(x) == pytest.approx(scipy.stats.trim_mean(x, 0.25), rel=1e-12)
    rows = rng.normal(size=(6, 9))
    np.testing.assert_allclose(report.iqm(rows, axis=-1), [report.iqm(r) for r in rows])


def test_bootstrap_interval_by_hand():
    """[0, 0, 0, 1]: k ones among 4 draws is Binomial(4, 1/4): P(k) = .316, .422, .211, .047, .004,
    cumulative .316, .738, .949, .996, 1. The 2.5th percentile lies in k = 0, the 97.5th in k = 3:
    the mean's interval is [0, 3/4]; the median's (= the IQM's for n = 4: 0.5 at k = 2, 1 at k >= 3)
    is [0, 1]."""
    scores = [0.0, 0.0, 0.0, 1.0]
    assert report.bootstrap_ci(scores, report.mean) == (0.0, 0.75)
    assert report.bootstrap_ci(scores, report.median) == (0.0, 1.0)
    assert report.bootstrap_ci(scores, report.iqm) == (0.0, 1.0)
    assert report.aggregate(scores) == {
        "iqm": 0.0,
        "iqm_ci": [0.0, 1.0],
        "mean": 0.25,
        "mean_ci": [0.0, 0.75],
        "median": 0.0,
        "median_ci": [0.0, 1.0],
    }


def test_bootstrap_is_stratified():
    """Strata [0, 1] and [10]: the second is always drawn whole, so the pooled mean is (a + b + 10) / 3
    with a + b in {0, 1, 2} (1/4, 1/2, 1/4): the interval is [10/3, 4]. Pooling first would let a
    resample of all zeros (1/27 > 2.5 %) pull the lower end to 0."""
    low, high = report.bootstrap_ci([[0.0, 1.0], [10.0]], report.mean)
    assert (low, high) == (pytest.approx(10 / 3), pytest.approx(4.0))
    assert report.bootstrap_ci([0.0, 1.0, 10.0], report.mean)[0] == 0.0


def test_bootstrap_is_reproducible_and_holds_the_estimate():
    for name, statistic in report.AGGREGATES.items():
        first = report.bootstrap_ci(EIGHT, statistic, seed=1)
        assert report.bootstrap_ci(EIGHT, statistic, seed=1) == first, name
        few = [report.bootstrap_ci(EIGHT, statistic, reps=100, seed=seed) for seed in (1, 2)]
        assert few[0] != few[1], name  # the seed matters (seen with few resamples; 50,000 converge)
        assert first[0] <= statistic(EIGHT) <= first[1], name
        assert EIGHT.min() <= first[0] < first[1] <= EIGHT.max(), name
    assert report.bootstrap_ci([7.0], report.iqm) == (7.0, 7.0)  # one seed: nothing to resample


def test_probability_of_improvement_by_hand():
    # X = [1, 2, 3], Y = [2, 2]: S(1, 2) = 0 twice, S(2, 2) = 1/2 twice, S(3, 2) = 1 twice -> 3 / 6
    assert report.probability_of_improvement([1.0, 2, 3], [2.0, 2]) == 0.5
    # X = [3, 4], Y = [1, 3, 5]: 3 beats 1, ties 3, loses to 5; 4 beats 1 and 3 -> 3.5 / 6
    assert report.probability_of_improvement([3.0, 4], [1.0, 3, 5]) == pytest.approx(3.5 / 6)
    assert report.probability_of_improvement([1.0, 3, 5], [3.0, 4]) == pytest.approx(2.5 / 6)  # 1 - P(X > Y)
    # two strata, averaged: (3.5 / 6 + 1) / 2
    two = report.probability_of_improvement([[3.0, 4], [5.0]], [[1.0, 3, 5], [4.0]])
    assert two == pytest.approx((3.5 / 6 + 1) / 2)
    with pytest.raises(ValueError, match="strata"):
        report.probability_of_improvement([[1.0], [2.0]], [[1.0]])


def test_probability_of_improvement_interval():
    assert report.probability_of_improvement_ci([5.0, 6, 7], [1.0, 2]) == (1.0, 1.0)  # X always wins
    x, y = [3.0, 4, 6, 2], [1.0, 3, 5]
    low, high = report.probability_of_improvement_ci(x, y, seed=3)
    assert report.probability_of_improvement_ci(x, y, seed=3) == (low, high)
    assert 0.0 <= low <= report.probability_of_improvement(x, y) <= high <= 1.0


def fake_run(path, env_id, seed_returns):
    """A run folder with config.json and the eval.json of per-seed returns [seeds, episodes]."""
    config = run_config("ppo", env_id, "default", "compiled", {}, {})
    returns = np.asarray(seed_returns, np.float64)
    Run.create(path, config).write_eval(returns, np.ones_like(returns))
    return path


def test_eval_json_of_several_seeds_holds_the_aggregates(tmp_path):
    returns = np.stack([EIGHT, EIGHT + 2])  # 2 episodes of each of 8 seeds: means EIGHT + 1
    evaluation = fake_run(tmp_path / "run", "CartPole-v1", returns.T)
    written = json.loads((evaluation / "eval.json").read_text())
    assert written["iqm"] == 209.75 and written["median"] == 161.0
    assert written["iqm_ci"] == report.aggregate(EIGHT + 1)["iqm_ci"]
    assert written["mean_ci"][0] <= written["mean_return"] == 232.5 <= written["mean_ci"][1]
    assert "mean" not in written and len(written["per_seed"]) == 8  # mean_return is the mean
    one = json.loads((fake_run(tmp_path / "one", "CartPole-v1", [[1.0, 2]]) / "eval.json").read_text())
    assert "iqm" not in one and one["mean_return"] == 1.5  # one seed: as before


def test_report_json_groups_by_label(tmp_path, capsys):
    a1 = fake_run(tmp_path / "a1", "CartPole-v1", [[10.0], [200], [35], [500]])
    a2 = fake_run(tmp_path / "a2", "CartPole-v1", [[480.0], [12], [495], [120]])
    b = fake_run(tmp_path / "b", "CartPole-v1", [[100.0], [150], [90]])
    argv = ["report", str(a1), str(a2), str(b), "--labels", "A", "A", "B", "--json", "--reps", "2000"]
    plot = tmp_path / "intervals.png"
    assert main([*argv, "--plot", str(plot)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) == {"runs", "probability_of_improvement"}
    (group_a, group_b) = out["runs"]
    keys = {"label", "seeds", "iqm", "iqm_ci", "mean", "mean_ci", "median", "median_ci"}
    assert keys <= set(group_a) and group_a["label"] == "A" and group_b["label"] == "B"
    assert group_a["seeds"] == 8 and group_a["iqm"] == 208.75 and group_a["mean"] == 231.5
    assert group_b["seeds"] == 3 and group_b["median"] == 100.0
    assert group_a == {
        "label": "A",
        "seeds": 8,
        "envs": ["CartPole-v1"],
        **report.aggregate(EIGHT, reps=2000),
    }
    improvement = out["probability_of_improvement"]
    # A's seeds against B's (90, 100, 150): 10, 12, 35 lose all 3; 120 beats 2; 200-500 beat all 3
    assert improvement["x"] == "A" and improvement["y"] == "B"
    assert improvement["probability"] == pytest.approx((2 + 4 * 3) / 24)
    assert improvement["ci"][0] <= improvement["probability"] <= improvement["ci"][1]
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_report_table_and_bad_input(tmp_path, capsys):
    a = fake_run(tmp_path / "a", "CartPole-v1", [[1.0], [2], [3]])
    b = fake_run(tmp_path / "b", "Acrobot-v1", [[-100.0], [-90]])
    assert main(["report", str(a), str(b), "--reps", "500"]) == 0
    out = capsys.readouterr().out
    assert "IQM" in out and "2.0 [" in out and "share no env" in out
    assert main(["report", str(a), str(b), "--labels", "x"]) == 2
    assert "--labels needs one label per run (2), got 1" in capsys.readouterr().err
    assert main(["report", str(tmp_path / "missing")]) == 2
    assert "is not a folder" in capsys.readouterr().err
    (tmp_path / "a" / "eval.json").unlink()
    assert main(["report", str(a)]) == 2
    assert "has no eval.json" in capsys.readouterr().err


def test_version(capsys):
    assert main(["--version"]) == 0
    assert capsys.readouterr().out == f"agentax {version('agentax')}\n"

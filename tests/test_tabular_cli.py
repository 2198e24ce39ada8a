"""``agentax solve`` through the dispatcher: JSON output against the lecture, plots, and bad input."""

import json

import numpy as np
import pytest

from agentax.cli import main


def solve_json(capsys, *args):
    assert main(["solve", *args, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_solve_lecture_q_value_iteration_json(capsys):
    result = solve_json(capsys, "--mdp", "lecture", "--method", "q-value-iteration")
    assert result["policy"] == [0, 0, 1]
    np.testing.assert_allclose(result["Q"][0], [18.92, 17.03, 13.62], atol=0.005)
    assert result["Q"][1][1] is None and result["Q"][2][0] is None  # impossible actions: −inf → null
    assert result["iterations"] < 200


@pytest.mark.slow
def test_solve_value_iteration_and_td_print_v(capsys):
    result = solve_json(capsys, "--mdp", "chain", "--method", "value-iteration", "--discount-factor", "0.5")
    # 10-state chain, reward 1 on entering state 9: V*(s) = 0.5^(8 − s) for s < 9, V*(9) = 0.
    np.testing.assert_allclose(result["V"], [0.5 ** (8 - s) for s in range(9)] + [0.0], atol=1e-6)
    assert result["policy"][:9] == [1] * 9
    td = solve_json(capsys, "--mdp", "lecture", "--method", "td", "--steps", "2000")
    assert len(td["V"]) == 3 and td["steps"] == 2000 and "Q" not in td


@pytest.mark.slow
def test_solve_cliffwalking_walks_around_the_cliff(capsys):
    result = solve_json(capsys, "--mdp", "cliffwalking", "--method", "value-iteration")
    # The shortest safe path from the start (36): up, 11 × right, down = 13 steps of reward −1,
    # so V*(36) = −(1 − 0.9^13) / (1 − 0.9) = −7.4581; the goal (47) is terminal.
    assert result["V"][36] == pytest.approx(-(1 - 0.9**13) / (1 - 0.9), abs=1e-4)
    assert result["V"][47] == 0.0
    assert result["policy"][36] == 0  # up, away from the cliff
    assert len(result["V"]) == 48


@pytest.mark.slow
def test_solve_table_and_plot(capsys, tmp_path):
    plot = tmp_path / "compare.png"
    assert (
        main(["solve", "--mdp", "lecture", "--method", "q-learning", "--steps", "3000", "--plot", str(plot)])
        == 0
    )
    out = capsys.readouterr().out
    assert "Q(s, 2)" in out and "optimal actions: [0, 0, 1]" in out
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize(
    "args, message",
    [
        (["--mdp", "mars"], "unknown MDP 'mars'; choose from lecture, frozenlake4x4"),
        (["--method", "sarsa-lambda"], "unknown method 'sarsa-lambda'; choose from value-iteration"),
        (["--discount-factor", "1.5"], "discount factor 1.5 is outside [0, 1]"),
        (["--discount-factor", "1.0"], "discount factor 1 needs every policy to terminate"),
        (["--mdp", "frozenlake4x4", "--discount-factor", "1"], "a policy can run forever"),
        (["--method", "q-learning", "--steps", "0"], "--steps must be at least 1"),
    ],
)
def test_solve_bad_input_is_one_line_and_exit_code_2(capsys, args, message):
    assert main(["solve", *args]) == 2
    captured = capsys.readouterr()
    assert message in captured.err
    assert captured.err.count("\n") == 1 and "Traceback" not in captured.err

"""Shared test setup. Every test runs under pytest-timeout (pyproject.toml): an XLA hang fails fast."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("AGENTAX_KERNELS_MEASURE", "0")  # AGENTAX_CONV=auto times nothing in tests

REPO_ROOT = str(Path(__file__).resolve().parents[1])
# One compilation cache for the test run, its xdist workers and the processes they start, so a program
# that several tests compile (the same tiny PPO, the same CLI run) compiles once. It lives in the clone's
# ignored .jax_cache/, never in the user's: a fresh clone starts cold, a second run in it warm.
os.environ.setdefault("AGENTAX_JAX_CACHE", str(Path(REPO_ROOT) / ".jax_cache" / "tests"))
if REPO_ROOT not in sys.path:
    sys.path.append(REPO_ROOT)  # for benchmarks/_pin.py (``from benchmarks import _pin``)


LONG_CASES: dict[str, tuple[str, ...]] = {
    # the golden cases make test runs: ppo_compiled, dqn_host, ppo_parallel, pqn_host; SAC compiled:
    # test_actor_critic's learning
    "test_golden.py": tuple(
        f"test_metrics_rows_match_the_golden_file[{case}]"
        for case in ("dqn_compiled", "reinforce_compiled", "ppo_host", "pqn_compiled")
        + ("sac_compiled", "sac_host", "td3_compiled", "td3_host")
    ),
    "test_formats.py": (  # format 1's folders act, evaluate and resume (through every migration)
        "test_a_fixture_acts_and_evaluates_as_it_did_when_written[2-",
        "test_a_fixture_resumes_in_todays_format[2-",
        "test_a_fixture_resumes_in_todays_format[1-dqn-compiled]",  # [1-ppo-compiled-2seeds]
        "test_a_fixture_resumes_in_todays_format[1-pqn-compiled]",
        "test_a_fixture_resumes_in_todays_format[1-reinforce-compiled]",
    ),
    "test_export.py": (  # sac-pendulum's both formats (a Gaussian head), test_export_memory's
        "test_both_formats_act_as_the_agentax_policy[ppo-pendulum]",  # PPO; the CLI's export
        "test_both_formats_act_as_the_agentax_policy[ppo-cartpole]",
        "test_both_formats_act_as_the_agentax_policy[dqn-cartpole]",  # a Q-network: the stochastic PPO's
        "test_evaluate_policy_file_gives_the_runs_evaluation",
    ),
    "test_export_memory.py": (  # the LSTM's
        "test_the_exported_state_steps_as_the_agents_memory[gru]",
        "test_evaluate_a_recurrent_file_gives_the_runs_evaluation",
    ),
    "test_memory_core.py": (  # the GRU's gradient; REINFORCE's core on the host runner (test_memory_runners)
        "test_the_cores_written_out_gradient_is_autodiffs[lstm]",
        "test_reinforce_with_a_core_learns_through_whole_episodes_and_its_greedy_policy_carries_memory",
    ),
    "test_memory_runners.py": (  # CartPoleNoVel's resume; PQN's core: test_memory_core; the CLI: [reinforce]
        "test_ppo_with_a_core_trains_on_the_host_runner_from_the_command_line",
        "test_a_resumed_host_run_continues_its_episodes_with_their_memory[CartPole-v1-False]",
        "test_pqn_and_reinforce_with_a_core_train_on_the_host_runner[pqn]",
    ),
    "test_logger.py": (  # [ppo-host-...]; test_train_cli's SIGTERM and resume
        "test_ctrl_c_says_how_to_resume_and_resume_works",
        "test_a_diverging_run_stops_with_one_line_and_exit_code_3[ppo-compiled-",
        "test_a_diverging_run_stops_with_one_line_and_exit_code_3[dqn-parallel-",
    ),
    "test_dqn_cli.py": (  # [checkpoint_half_written]; a restart from the config: test_formats' deleted one
        # every flag: each variant's learning step in test_dqn and test_replay, a CLI run's folder test_cli's
        "test_train_dqn_with_every_flag_writes_a_run",
        "test_resume_of_a_run_killed_before_its_first_checkpoint_starts_it_from_its_config[",
        "test_a_kill_at_each_stage_of_a_checkpoint_resumes_with_the_replay_of_its_checkpoint[first_committed]",
        "test_a_kill_at_each_stage_of_a_checkpoint_resumes_with_the_replay_of_its_checkpoint[replay_written]",
    ),
    "test_mujoco.py": (  # the compiled SAC Hopper; the pool's reset steps and lag 1: test_atari_compiled's
        "test_host_ppo_on_half_cheetah_two_updates",
        "test_compiled_ppo_on_hopper_two_updates",
    ),
    "test_observation_spaces.py": (  # [FrozenLake-v1]
        "test_discrete_observations_train_ppo_from_the_command_line[CliffWalking-v1]",
    ),
    "test_search_cli.py": ("test_cartpole_cem_run_folder",),  # a search's folder: the vacuum grid's
    "test_search.py": (  # CEM: the sphere's; the vacuum's searches: test_search_cli's grid run
        "test_improves_cartpole_and_solves_v0[",
        "test_vacuum_random_search_is_reproducible",
        "test_finds_the_optimum_of_a_shifted_sphere[ga]",
        "test_vacuum_grid_search_heatmap_marks_the_best",
    ),
    "test_runfile.py": (  # run files and sweeps apart; a file's fields: run.toml's repeat, the overrides
        "test_a_sweeps_best_toml_trains_the_best_setting",
        "test_a_preset_file_trains_as_the_flags_do",
    ),
    "test_normalize.py": (  # the compiled runner's normalised PPO, restored from its checkpoint
        "test_host_checkpoint_saves_and_restores_the_stats",
        "test_compiled_mujoco_picks_the_preset_and_leaves_envpools_reset_steps_out_of_the_stats",
    ),
    "test_train_cli.py": (  # test_api and test_cli; test_actor_critic's host Pendulum
        "test_train_then_plot_then_restore_policy",
        "test_host_loop_trains_pendulum_and_loads",
    ),
    "test_pqn.py": ("test_the_same_pqn_agent_learns_on_the_host_runner",),  # the pqn_host golden case
    "test_parallel.py": (  # the ppo_parallel golden case (policy lag 1), the other parallel tests
        "test_parallel_ppo_with_policy_lag_1_solves_cartpole",
        "test_policy_lag_1_runs_are_reproducible",
        "test_a_slow_learner_shows_as_actors_waiting",
    ),
    "test_reinforce.py": (  # PPO's Gaussian head; learning: [lecture]; a baseline: test_masks_and_encoders'
        "test_reinforce_with_the_gaussian_head_learns_pendulum",
        "test_reinforce_learns_cartpole_v0[baseline]",
    ),
    "test_compiled.py": (  # its seed tests; the compiled resume: test_formats', a torn one: test_logger's
        "test_looking_ahead_a_chunk_changes_no_number",
        # a seed alone as inside a vmapped batch: test_sweep's setting alone; reruns: the golden rows
        "test_seed_alone_equals_seed_inside_a_vmapped_batch_and_reruns_are_identical",
        "test_seeds_run_in_groups_give_each_seed_the_numbers_of_one_vmapped_batch",  # (the rule: a unit test)
        "test_interrupted_run_resumes_to_the_same_end_and_a_torn_checkpoint_is_a_clear_error",
    ),
    "test_ray.py": (  # the CLI's own Ray (errors), PPO recurrent (as threads) and on tic-tac-toe
        "test_ctrl_c_ends_the_clis_own_ray_and_says_how_to_resume",  # test_train_cli's SIGTERM, the own Ray
        "test_a_learner_error_ends_the_run_and_its_actor_processes",  # test_parallel's, the CLI's Ray ended
        "test_a_recurrent_ppo_on_ray_actors_gives_the_thread_actors_numbers",  # test_memory_runners' threads
        "test_packed_masked_dict_observations_train_through_ray_actors",  # the parallel runner's, same actors
        "test_ppo_on_ray_actors_learns_and_gives_the_thread_actors_numbers",
        "test_beside_a_ray_start_cluster_a_run_has_its_own_ray_and_auto_joins_it",
        "test_dqn_on_ray_actors_learns_and_resumes_with_its_replay",
        "test_ray_address_host_port_joins_a_token_cluster_and_a_wrong_token_is_one_line",
        "test_a_lost_node_whose_cpus_the_run_needs_ends_it_with_the_resume_hint",
        "test_a_lost_local_ray_node_ends_the_cli_run_with_one_line_saying_what_to_do",
        "test_a_killed_actor_process_is_replaced_and_the_run_finishes",
        "test_more_actors_than_the_cluster_has_cpus_is_refused",  # the rule: its unit test beside it
    ),
    "test_spaces_learning.py": (  # PPO's; DQN's Taxi mask: test_masks_and_encoders, frames: test_cnn_agent
        "test_blackjack_ppo_plays_near_the_basic_strategy",  # Blackjack's tuple: test_host_spaces
        "test_ppo_learns_multi_entry_actions_to_the_optimum[Match-MultiBinary-v0]",  # test_host_spaces' run
        # masks learned: REINFORCE's and PQN's in test_masks_and_encoders, DQN's Taxi mask there too
        "test_taxi_with_its_mask_is_learned_and_no_illegal_action_is_taken[",
        "test_pictures_of_ones_own_size_train_on_the_host_runner[",  # CNNs learning: test_cnn_agent's
    ),
    "test_host_spaces.py": (  # Blackjack's Tuple: its layout test; MultiDiscrete's run: MultiBinary's (the
        # same multi-entry actions) and test_spaces_learning's MultiDiscrete learning; Taxi's: the packed
        # runs of the others, its mask test_masks_and_encoders' DQN on Taxi
        "test_ppo_trains_evaluates_and_plays_on_packed_host_observations[Taxi-v4-host]",
        "test_ppo_trains_evaluates_and_plays_on_packed_host_observations[Blackjack-v1-host]",
        "test_ppo_trains_evaluates_and_plays_on_packed_host_observations[scripts.own_envs:Match-MultiDiscrete-v0-host]",
    ),
    "test_masks_and_encoders.py": (  # one-hot observations learned: PPO's FrozenLake, DQN's Taxi
        "test_dqn_reaches_the_goal_of_frozen_lake",
    ),
    "test_gymnax.py": ("test_the_adapter_steps_as_gymnax_steps[Asterix-MinAtar]",),  # Breakout's, Catch's
    "test_workers.py": (  # packed masked dicts in the compiled runner's program (test_board_and_grid)
        "test_packed_masked_dict_observations_train_over_two_worker_processes",
    ),
    "test_board_and_grid.py": (  # sweeps in test_sweep, the masked board game's PPO in this file
        "test_a_sweep_on_the_masked_board_game_traces_its_settings_beside_the_seeds",
    ),
    "test_atari_compiled.py": (  # the pool's games: its rollouts; a pool run's folder: test_mujoco's
        "test_in_program_pool_plays_the_host_adapters_games",
        # policy lag 1: the ppo_parallel golden case, the parallel runner's own tests
        "test_policy_lag_1_on_a_real_pool_learns_the_first_update_as_lag_0_and_then_goes_its_way",
        "test_short_run_writes_the_run_folder_loads_and_resumes",
    ),
    "test_cli.py": ("test_a_trained_run_folder_is_a_policy",),  # test_api's train-then-load evaluates one
    "test_encoders_override.py": (  # encoders: test_masks_and_encoders; a folder's settings: test_formats
        "test_a_run_trained_with_overrides_evaluates_resumes_and_repeats_from_its_folder",
    ),
    "test_sweep.py": ("test_optuna_asks_batches_and_a_rerun_asks_the_same",),  # the grid's: the others
    "test_rainbow.py": ("test_rainbow_on_the_compiled_runner",),  # its parts' tests; test_dqn_cli's flags
    "test_dqn.py": (  # the same learning step on both runners: its next test; DQN's schedule: the golden rows
        "test_one_agent_keeps_the_same_schedule_on_the_compiled_and_the_host_runner[",
    ),
    "test_atari_cli.py": (  # play's video: test_cli's demo GIF, test_api's video
        "test_play_a_run_writes_an_mp4_of_one_frame_per_step_with_the_runs_env_settings",
        # evaluate's random games: play random's game evaluated again; true scores: test_atari's
        "test_evaluate_random_gives_the_random_baseline_in_whole_games",
    ),
    "test_tutorial.py": tuple(  # the pages that train for most of a minute; make test runs the others
        f"test_page_runs_and_prints_what_it_shows[{page}-" for page in ("02", "03", "07", "09", "10", "11")
    ),
}
"""Tests ``make test`` leaves to ``make test-long`` (beside those marked ``long`` where they stand),
by file and test id (an id ending in ``[`` or ``-`` names every case it begins): each a further case
of a path ``make test`` checks with another (the comment says which), to keep ``make test`` near its
budget of 10 minutes on a new 2-core machine."""


def pytest_configure(config):
    import jax

    from agentax import _xla

    _xla.enable_compilation_cache()
    # jax's CPU client now, on one CPU (agentax's cure for the XLA hang): whichever test a worker runs
    # first, a host runner's (which would make it for every CPU) or a compiled one's. A worker that
    # ran EnvPool's compiled Hopper first, its client for both CPUs, hung in the next compiled
    # runner's first call of its seeds' program.
    jax.devices("cpu")


def is_long_case(nodeid: str) -> bool:
    file, _, name = nodeid.removeprefix("tests/").partition("::")
    return any(
        name == case or (case.endswith(("[", "-")) and name.startswith(case))
        for case in LONG_CASES.get(file, ())
    )


COLLECTED: list[str] = []
"""Every test id this session collected (before ``-m`` deselects any), for tests/test_tiers.py."""


@pytest.hookimpl(tryfirst=True)  # before --dist loadgroup appends "@group" to the ids of grouped tests
def pytest_collection_modifyitems(items):
    COLLECTED[:] = [item.nodeid for item in items]
    for item in items:
        if is_long_case(item.nodeid):
            item.add_marker(pytest.mark.long)


class OnDemand(dict):
    """A dict whose value for a key is ``make(key)``, made the first time it is asked for: a module's
    shared training runs, of which a test run trains only those its selected tests use."""

    def __init__(self, make):
        super().__init__()
        self.make = make

    def __missing__(self, key):
        self[key] = value = self.make(key)
        return value


def kernel_not_built() -> str | None:
    """The summary line when the oneDNN kernel is not built (its tests skip), else None."""
    from agentax import kernels

    if kernels.available():
        return None
    return f"agentax: the oneDNN kernel is not built, its tests skipped: {kernels.unavailable_reason()}"


def pytest_terminal_summary(terminalreporter):
    """A run without the kernel says so at its end (make test, CI), not only in skip reasons."""
    line = kernel_not_built()
    if line:
        terminalreporter.write_line(line, yellow=True, bold=True)


def with_sigint_ignored(command: list[str]) -> list[str]:
    """``command`` started as a shell script starts ``cmd &`` (``nohup agentax train ... &``): with
    SIGINT ignored, which the program inherits (a shell's ``trap '' INT``, then ``exec``: the same pid)."""
    return ["sh", "-c", 'trap "" INT; exec "$@"', "sh", *command]


def resume_to_the_end(out, env: dict[str, str], timeout: float = 150) -> subprocess.CompletedProcess:
    """``agentax train --resume OUT`` in a fresh process, which must finish the run."""
    done = subprocess.run(
        [sys.executable, "-m", "agentax.cli", "train", "--resume", str(out), "--no-progress"],
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return done

"""benchmarks/efficiency.py: its FLOP counts agree with a hand count, its data have the task's
shapes, and one algorithm's row is complete and self-consistent."""
import json

import jax
import jax.numpy as jnp
import pytest
from conftest import load_script


@pytest.fixture(scope="module")
def eff():
    return load_script("benchmarks/efficiency.py", "efficiency")


def test_the_cost_analysis_matches_a_hand_count_of_a_relu_mlp(eff):
    assert eff.relu_mlp_hand_count(2, [3, 4, 1]) == 2 * 2 * (12 + 4) + 2 * 5 + 2 * 4
    row = eff.check_cost_analysis(batch=16, dims=(5, 32, 7))
    assert row["xla_flops"] == row["hand_flops"]


def test_a_loop_body_counts_once_so_steps_are_compiled_alone(eff):
    w = jnp.ones((8, 8))
    one = eff.flops_of(lambda x: x @ w, jnp.ones((4, 8)))
    ten = eff.flops_of(lambda x: jax.lax.fori_loop(0, 10, lambda _, y: y @ w, x), jnp.ones((4, 8)))
    assert one == 2 * 4 * 8 * 8 and ten < 2 * one  # why a block's figure is not divided


def test_random_data_have_the_tasks_shapes_and_safe_and_unsafe_episodes(eff):
    from r2pac_jax.tasks import get_task

    task = get_task("ReachAvoid")
    ds = eff.random_dataset(task, episodes=6)
    assert ds.observations.shape == (6 * task.episode_len, task.obs_dim)
    assert ds.actions.shape == (6 * task.episode_len, task.act_dim)
    assert ds.timeouts.sum() == 6


def test_one_row_per_phase_with_consistent_figures(eff, capsys, tmp_path):
    out = tmp_path / "eff.jsonl"
    eff.BLOCK_STEPS["quick"] = 4
    assert eff.main(["--algos", "bc-all-mlp", "--presets", "quick", "--task", "ReachAvoid",
                     "--blocks", "1", "--peak-size", "64", "--set", "batch_size=32",
                     "--set", "hidden_dims=16,16", "--out", str(out)]) == 0
    rows = [json.loads(x) for x in out.read_text().splitlines()]
    assert [r["kind"] for r in rows] == ["check", "peak", "step"]
    r = rows[-1]
    assert r["width"] == 16 and r["batch"] == 32 and r["gflop_step"] > 0
    assert r["achieved_gflops"] == pytest.approx(r["gflop_per_step"] * r["seed_steps_per_s"])
    assert r["frac_of_peak"] == pytest.approx(r["achieved_gflops"] / r["matmul_gflops_peak"])
    eff.main(["--table", str(out)])
    text = capsys.readouterr().out
    assert "| bc-all-mlp | quick | actor | 1 |" in text
    head, _, row = text.strip().splitlines()[-3:]
    assert head.count("|") == row.count("|")


def test_the_gpu_hour_estimate_adds_steps_over_rates_per_task_and_phase(tmp_path):
    # two rows of the paper's layout: CarRun (Bullet) and AntVel (AntVelocity, MuJoCo)
    head = "\tBC\t\tCDT\t\tCPQ\t\tCOptiDICE\t\tTREBI\t\tFISOR\t\tours\t"
    nums = "\t0.5" * 14
    PAPER = "\n".join(["Table 1: Normalized DSRL benchmark results.", head,
                       "CarRun" + nums, "AntVel" + nums])
    gh = load_script("benchmarks/gpu_hours.py", "gpu_hours")
    paper = tmp_path / "paper.txt"
    paper.write_text(PAPER)

    def row(algo, phase, lanes, rate, precision="default"):
        return dict(kind="step", algo=algo, preset="paper", phase=phase, lanes=lanes,
                    seed_steps_per_s=rate, matmul_precision=precision, device="gpu")

    rows = [row("r2pac", "critic", 1, 100.0), row("r2pac", "critic", 4, 400.0),
            row("r2pac", "actor", 4, 800.0), row("r2pac", "actor", 4, 1e9, "bf16"),
            row("trebi", "actor", 4, 50.0)]
    text, hours = gh.estimate(rows, seeds=3, paper=paper)
    # 2 tasks x 3 seeds x (600k / 400 + 600k / 800) s; the 1-lane and bf16 rows are not used
    assert hours["r2pac"] == pytest.approx(2 * 3 * (600_000 / 400 + 600_000 / 800) / 3600)
    # TREBI's paper steps: 100k on a Bullet task, 200k on a MuJoCo one
    assert hours["trebi"] == pytest.approx(3 * (100_000 + 200_000) / 50 / 3600)
    assert "| CPQ | cpq | | not measured | |" in text
    assert " *" not in text
    # a phase not measured is estimated at a measured phase's rate, and the text says so
    text, hours = gh.estimate([row("r2pac", "critic", 4, 400.0)], seeds=3, paper=paper)
    assert hours["r2pac"] == pytest.approx(2 * 3 * (600_000 / 400 + 600_000 / 400) / 3600)
    assert "r2pac: its actor phase was not measured; its critic phase's rate stands in." in text
    assert f"{hours['r2pac']:,.1f} * |" in text

"""The one planner (`planner.plan`) behind train, table and sweep: what it adds to make_config."""
import textwrap

import pytest

from r2pac_jax import sweep as sw
from r2pac_jax.config import ConfigError
from r2pac_jax.planner import plan


def test_requested_algorithm_refuses_what_a_baseline_drops_with_a_note():
    notes = []
    asked = dict(chunk_len=3, quantile_alpha=0.8, seeds=2, steps=None)
    cfg = plan("ReachAvoid", "bc-all-mlp", "quick", asked, baseline=True, log=notes.append)
    assert cfg.chunk_len == 1 and cfg.seeds == 2  # pinned h = 1, the shared key kept
    assert notes == [f"note: baseline bc-all-mlp does not use {kv}; ignored for it"
                     for kv in ("chunk_len=3", "quantile_alpha=0.8")]
    with pytest.raises(ConfigError, match="chunk_len is fixed at 1"):
        plan("ReachAvoid", "bc-all-mlp", "quick", asked)
    main = plan("ReachAvoid", "r2pac", "quick", asked, log=notes.append)
    assert (main.chunk_len, main.quantile_alpha) == (3, 0.8) and len(notes) == 2


def test_steps_the_block_does_not_divide_shrink_the_block_unless_set():
    cfg = plan("ReachAvoid", "r2pac", "quick", dict(steps=750))
    assert (cfg.block_steps, cfg.eval_every, cfg.checkpoint_every) == (250, 750, 750)
    with pytest.raises(ConfigError, match="multiple of block_steps"):
        plan("ReachAvoid", "r2pac", "quick", dict(steps=750, block_steps=500))


def test_a_task_without_an_environment_evaluates_nothing_unless_asked(monkeypatch):
    from r2pac_jax.tasks import get_task

    task = get_task("ReachAvoid")
    monkeypatch.setattr(type(task), "has_env", property(lambda self: False))
    assert plan(task, "r2pac", "quick", {}).eval_episodes == 0
    assert plan(task, "r2pac", "quick", dict(eval_episodes=3)).eval_episodes == 3


def test_a_table_cell_evaluates_once_at_the_end():
    cfg = plan("ReachAvoid", "r2pac", "quick", dict(steps=1000), final_eval_only=True)
    assert cfg.eval_every == cfg.steps == 1000


def test_a_sweep_plans_its_groups_as_train_plans_a_run(tmp_path):
    # steps = 750 in a sweep file fits the block as `--steps 750` does on the command line
    p = tmp_path / "s.toml"
    p.write_text(textwrap.dedent("""
        task = "ReachAvoid"
        seeds = 2
        [config]
        steps = 750
        [grid]
        quantile_alpha = [0.7, 0.9]
    """))
    s = sw.load_sweep(p)
    (cfg,) = s.configs.values()
    assert (cfg.steps, cfg.block_steps, cfg.seeds) == (750, 250, 2)

import json

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import tiny_config
from r2pac_jax.config import ConfigError, default_hparams
from r2pac_jax.tasks import get_task
from r2pac_jax.train import Lanes, Run, chunk_dataset, main, make_train

from r2pac_jax.agents import algo_module, algo_names

ALL_ALGOS = algo_names()
# the algorithms of the pre-protocol fixture train bitwise as they did (test_agent_fixture.py);
# this test covers the others except the OSRL ports, which test_baselines.py trains
NEW_ALGOS = [a for a in ALL_ALGOS if algo_module(a).Agent.__module__.rsplit(".", 1)[1]
             not in ("r2pac", "bc_flow", "cpq", "bcq_lag", "coptidice", "fisor")]


@pytest.fixture(scope="module")
def task():
    return get_task("ReachAvoid")


def _leaves_close(a, b, **kw):
    for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), **kw)


def test_vmap_over_seeds_equals_separate_runs(reach_avoid_data, task):
    cfg = tiny_config(schedule="joint")
    data = chunk_dataset(cfg, task, reach_avoid_data)
    train = make_train(cfg, data, task.obs_dim, task.act_dim)
    hp = default_hparams(cfg)
    keys = jnp.stack([jax.random.PRNGKey(0), jax.random.PRNGKey(1)])
    hps = jax.tree_util.tree_map(lambda x: jnp.stack([x, x]), hp)
    batched, mb = jax.jit(jax.vmap(train))(keys, hps)
    for i in range(2):
        single, ms = jax.jit(train)(keys[i], hp)
        _leaves_close(jax.tree_util.tree_map(lambda x: x[i], batched.params), single.params,
                      rtol=1e-4, atol=1e-5)
        chex.assert_trees_all_close(mb["joint"]["loss_qc"][i], ms["joint"]["loss_qc"],
                                    rtol=1e-4, atol=1e-5)


def test_hparam_lanes_differ_and_match_their_config(reach_avoid_data, task):
    cfg = tiny_config(schedule="joint")
    data = chunk_dataset(cfg, task, reach_avoid_data)
    train = make_train(cfg, data, task.obs_dim, task.act_dim)
    hp = dict(quantile_alpha=jnp.array([0.5, 0.9]), penalty_c=jnp.array([1.0, 1.0]),
              guidance_scale=jnp.array([2.0, 2.0]))
    keys = jnp.stack([jax.random.PRNGKey(0)] * 2)
    st, _ = jax.jit(jax.vmap(train))(keys, hp)
    assert float(st.threshold[0]) < float(st.threshold[1])  # alpha 0.5 vs 0.9 quantile


def test_same_seed_same_result(reach_avoid_data, task):
    cfg = tiny_config()
    data = chunk_dataset(cfg, task, reach_avoid_data)
    train = jax.jit(make_train(cfg, data, task.obs_dim, task.act_dim))
    a, _ = train(jax.random.PRNGKey(3))
    b, _ = train(jax.random.PRNGKey(3))
    chex.assert_trees_all_equal(a.params, b.params)
    c, _ = train(jax.random.PRNGKey(4))
    assert not np.array_equal(np.asarray(a.params["actor"]["params"]["MLP_0"]["Dense_0"]["kernel"]),
                              np.asarray(c.params["actor"]["params"]["MLP_0"]["Dense_0"]["kernel"]))


@pytest.mark.parametrize("algo", NEW_ALGOS)
def test_every_algo_trains_and_acts(reach_avoid_data, task, algo):
    cfg = tiny_config(algo)
    data = chunk_dataset(cfg, task, reach_avoid_data)
    train = make_train(cfg, data, task.obs_dim, task.act_dim)
    state, metrics = jax.jit(train)(jax.random.PRNGKey(0))
    for phase in cfg.phases:
        for k, v in metrics[phase].items():
            assert np.all(np.isfinite(np.asarray(v))), (algo, phase, k)
    agent = train.agent
    pp = agent.policy_params(state, default_hparams(cfg))
    obs = jnp.asarray(reach_avoid_data.observations[:5])
    a = jax.jit(agent.act)(pp, obs, jax.random.PRNGKey(1))
    chex.assert_shape(a, (5, task.act_dim))
    assert np.all(np.abs(np.asarray(a)) <= 1.0)


def test_resume_equals_uninterrupted_run_bitwise(reach_avoid_data, task, tmp_path):
    cfg = tiny_config(steps=40, eval_every=20, checkpoint_every=10)
    lanes = Lanes.build(cfg, [0, 1])
    full = Run(cfg, task, reach_avoid_data, tmp_path / "full", lanes, progress=False,
               log=lambda m: None)
    full.run()
    part = Run(cfg, task, reach_avoid_data, tmp_path / "part", lanes, progress=False,
               log=lambda m: None)
    assert part.run(stop_after=5) is None  # interrupted mid critic-phase... (8 blocks total)
    with pytest.raises(ConfigError, match="already holds a run"):
        part.run()
    res = part.run(resume=True)
    assert res is not None
    from r2pac_jax.checkpoint import Checkpointer

    like = full.init_state()
    a, _ = Checkpointer(tmp_path / "full" / "checkpoints").restore(80, like)
    b, _ = Checkpointer(tmp_path / "part" / "checkpoints").restore(80, like)
    chex.assert_trees_all_equal(a, b)

    def rows(d, name):
        return [{k: v for k, v in json.loads(ln).items() if k != "steps_per_s"}
                for ln in (tmp_path / d / f"{name}.jsonl").read_text().splitlines()]

    assert rows("full", "metrics") == rows("part", "metrics")
    assert rows("full", "eval") == rows("part", "eval")
    full_res = json.loads((tmp_path / "full" / "results.json").read_text())
    assert full_res["normalized_reward"] == res["normalized_reward"]
    # the resumed call's wall time covers its part only, and results.json says which part
    assert full_res["resumed_from_step"] == 0 and res["resumed_from_step"] == 50


def test_a_restart_before_the_first_checkpoint_starts_the_logs_afresh(reach_avoid_data, task,
                                                                     tmp_path):
    # blocks of 10 steps, a checkpoint only at the end: an attempt stopped after two blocks
    # leaves log rows but nothing to resume from; the restart must not log those steps twice
    cfg = tiny_config(steps=20, block_steps=10, eval_every=10, checkpoint_every=40)
    part = Run(cfg, task, reach_avoid_data, tmp_path, Lanes.build(cfg, [0]), progress=False,
               log=lambda m: None)
    assert part.run(stop_after=2) is None
    assert not list((tmp_path / "checkpoints").glob("*"))
    assert (tmp_path / "metrics.jsonl").read_text()
    assert part.run(resume=True)["resumed_from_step"] == 0

    def steps(name):
        lines = (tmp_path / f"{name}.jsonl").read_text().splitlines()
        return [json.loads(ln)["step"] for ln in lines]

    blocks = len(part.schedule)
    assert blocks > 2
    assert steps("metrics") == [10 * (i + 1) for i in range(blocks)]
    assert steps("eval") == sorted(set(steps("eval"))) and steps("eval")[-1] == 10 * blocks


def test_cli_end_to_end_and_load_policy(data_dir, tmp_path, capsys):
    out = tmp_path / "run"
    sets = ["steps=20", "batch_size=32", "hidden_dims=16,16", "actor_hidden_dims=16,16",
            "block_steps=10", "checkpoint_every=10", "flow_steps=4", "num_candidates=4",
            "threshold_subset=256"]
    argv = ["--task", "ReachAvoid", "--preset", "quick", "--seeds", "2", "--eval-episodes", "3",
            "--eval-every", "10", "--out", str(out), "--no-progress", "--baselines",
            "bc-safe-mlp"]
    for s in sets:
        argv += ["--set", s]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "generating" in printed and "| ReachAvoid |" in printed
    assert "bc-safe-mlp reward" in printed
    # under the table: the setting, which agents were safe, and the experiments' context
    assert "Setting: r2pac at the registry's defaults (chunk_len=5, quantile_alpha=0.9, " \
        "penalty_c=1), quick preset, 2 seeds, 3 evaluation episodes each." in printed
    assert ("Safe (normalised cost < 1): " in printed) != ("No agent was safe" in printed)
    assert "Context: the alpha x h grid on this data found h 7 / alpha 0.99" in printed
    assert "Setting: r2pac" in (out / "table.md").read_text()
    # the one-step cloner drops the chunked agents' keys with a note instead of failing
    assert "note: baseline bc-safe-mlp does not use flow_steps=4; ignored for it" in printed
    mlp = json.loads((out / "baselines" / "bc-safe-mlp" / "config.json").read_text())
    assert mlp["chunk_len"] == 1 and mlp["steps"] == 20 and mlp["agent"]["hidden_dims"] == [16, 16]
    res = json.loads((out / "results.json").read_text())
    for key in ("normalized_reward", "normalized_cost"):
        assert set(res[key]) >= {"mean", "std", "per_seed"} and len(res[key]["per_seed"]) == 2
        assert abs(res[key]["mean"] - np.mean(res[key]["per_seed"])) < 1e-9
    assert np.asarray(res["returns"]).shape == (2, 3) and np.asarray(res["costs"]).shape == (2, 3)
    assert res["eval_backend"] == "jax"  # the simulator that scored it
    assert json.loads((out / "config.json").read_text())["steps"] == 20
    assert (out / "baselines" / "bc-safe-mlp" / "results.json").exists()
    assert (out / "table.md").exists() and (out / "metrics.jsonl").exists()
    # a resumed finished run does not retrain and gives the same scores
    assert main(argv + ["--resume"]) == 0
    res2 = json.loads((out / "results.json").read_text())
    assert res2["normalized_reward"] == res["normalized_reward"]

    import r2pac_jax

    act = r2pac_jax.load_policy(out, lane=1)
    a = act(np.zeros(6, np.float32), jax.random.PRNGKey(0))
    assert a.shape == (2,) and np.all(np.abs(np.asarray(a)) <= 1)
    b = act(np.zeros((4, 6), np.float32), jax.random.PRNGKey(0))
    assert b.shape == (4, 2)
    with pytest.raises(IndexError, match="out of range"):
        r2pac_jax.load_policy(out, lane=2)
    # re-evaluation under another selection rule, without retraining
    from r2pac_jax.evaluate import evaluate_run

    ev = evaluate_run(out, episodes=2, selection="first", guidance_scale=1.0)
    assert ev["returns"].shape == (2, 2) and len(ev["normalized_reward"]) == 2


def test_cli_errors(data_dir, capsys, tmp_path, monkeypatch):
    assert main(["--task", "Nope"]) == 2
    assert "unknown task 'Nope'" in capsys.readouterr().err
    assert main(["--task", "ReachAvoid", "--set", "quantile_alpha=2", "--out",
                 str(tmp_path / "x"), "--baselines", "none"]) == 2
    assert "quantile_alpha must lie in (0, 1)" in capsys.readouterr().err
    assert main(["--task", "ReachAvoid", "--resume"]) == 2
    assert "--resume needs --out" in capsys.readouterr().err
    assert main(["--task", "ReachAvoid", "--chunk-len", "100", "--out", str(tmp_path / "y"),
                 "--baselines", "none"]) == 2
    assert "longer than an episode" in capsys.readouterr().err
    assert main(["--task", "ReachAvoid", "--dataset", str(tmp_path / "missing.hdf5")]) == 2
    assert "no such file" in capsys.readouterr().err
    assert main(["--task", "ReachAvoid", "--algo", "bc-all-mlp", "--chunk-len", "5"]) == 2
    assert "bc-all-mlp clones one action per step" in capsys.readouterr().err
    assert main(["--task", "ReachAvoid", "--algo", "bc-all-mlp", "--set",
                 "quantile_alpha=0.8"]) == 2
    assert "unknown config key 'quantile_alpha' for bc-all-mlp" in capsys.readouterr().err
    assert main(["--task", "ReachAvoid", "--algo", "bc-all-mlp", "--baselines", "r2pac", "--set",
                 "quantile_alpha=0.8"]) == 2  # a baseline's key is not the requested algo's
    assert "not a config key of bc-all-mlp" in capsys.readouterr().err
    assert main(["--task", "ReachAvoid", "--set", "task=CarGoal2"]) == 2
    assert "task is chosen with --task" in capsys.readouterr().err
    assert main(["--task", "ReachAvoid", "--algo", "cpq-x"]) == 2
    assert "unknown algo 'cpq-x'; choose one of r2pac" in capsys.readouterr().err
    assert main(["--task", "ReachAvoid", "--set", "steps=ten"]) == 2
    assert "expected an integer" in capsys.readouterr().err
    # no dataset anywhere and a cache directory that cannot be written: a clear error, before
    # any generation or training starts
    blocker = tmp_path / "not-a-dir"
    blocker.write_text("")
    monkeypatch.setenv("R2PAC_DATA_DIR", str(blocker / "cache"))
    monkeypatch.setenv("DSRL_DATASET_DIR", str(tmp_path / "empty"))
    assert main(["--task", "CarGoal2", "--baselines", "none", "--out", str(tmp_path / "z")]) == 2
    err = capsys.readouterr().err
    assert "is not writable" in err and "R2PAC_DATA_DIR" in err


def test_tensorboard_and_jsonl_logs(tmp_path):
    from r2pac_jax.metrics_log import MetricsLog

    log = MetricsLog(tmp_path, tensorboard=True)
    log.write("metrics", {"step": 10, "loss": 1.5, "phase": "critic"})
    log.write("metrics", {"step": 20, "loss": 1.0, "phase": "critic"})
    log.close()
    assert [r["loss"] for r in log.read("metrics")] == [1.5, 1.0]
    assert list((tmp_path / "tb").glob("events.out.tfevents.*"))
    # a resumed log drops rows written after the checkpoint it resumes from
    MetricsLog(tmp_path, resume_step=10, tensorboard=False).close()
    assert [r["step"] for r in MetricsLog(tmp_path, tensorboard=False).read("metrics")] == [10]

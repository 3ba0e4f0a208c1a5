"""The agent protocol: every algorithm behind it, the MLP cloners, and the loop's generic checks."""
import json
import re

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import tiny_config
from r2pac_jax.agents import algo_module, algo_names, make_agent
from r2pac_jax.config import Config, ConfigError, default_hparams, make_config
from r2pac_jax.lanes import Lanes
from r2pac_jax.loop import Run, TrainingDiverged, make_data, make_train
from r2pac_jax.tasks import get_task

MODULE_NAMES = ("CONFIG", "PRESETS", "VARIANTS", "FIXED", "FIXED_WHY", "HPARAMS", "task_values",
                "phases", "validate", "check_hparams", "Agent")
PROTOCOL = ("check_data", "make_data", "sample", "init", "begin_block", "update",
            "policy_params", "act", "summary")


@pytest.fixture(scope="module")
def task():
    return get_task("ReachAvoid")


def _quiet():
    return dict(progress=False, log=lambda m: None)


@pytest.mark.parametrize("algo", algo_names())
def test_every_module_declares_the_protocol_and_act_checks_shapes(algo, task, reach_avoid_data):
    mod = algo_module(algo)
    for name in MODULE_NAMES:
        assert hasattr(mod, name), (algo, name)
    cfg = tiny_config(algo)
    agent = make_agent(cfg, task.obs_dim, task.act_dim)
    for name in PROTOCOL:
        assert callable(getattr(agent, name)), (algo, name)
    hp = default_hparams(cfg)
    assert set(hp) == set(mod.HPARAMS)
    state = agent.init(jax.random.PRNGKey(0), hp)
    pp = agent.policy_params(state, hp)
    obs = jnp.asarray(reach_avoid_data.observations[:3])
    act = jax.jit(agent.act)  # chex's shape checks run while tracing
    chex.assert_shape(act(pp, obs, jax.random.PRNGKey(1)), (3, task.act_dim))
    # chex at the border: a wrong observation size or an unbatched observation is refused
    with pytest.raises(AssertionError):
        act(pp, jnp.zeros((3, task.obs_dim + 1)), jax.random.PRNGKey(1))
    with pytest.raises(AssertionError):
        act(pp, jnp.zeros((task.obs_dim,)), jax.random.PRNGKey(1))


def test_unknown_algo_names_the_known_ones():
    with pytest.raises(ConfigError) as e:
        make_config("ReachAvoid", "bc-mlp")
    for name in algo_names():
        assert name in str(e.value)


def test_one_step_cloner_refuses_a_chunk_length():
    cfg = make_config("ReachAvoid", "bc-all-mlp")
    assert cfg.chunk_len == 1 and (cfg.batch_size, cfg.lr, cfg.hidden_dims) == (512, 1e-3,
                                                                                (256, 256))
    assert make_config("ReachAvoid", "bc-all-mlp", "paper").steps == 100_000
    with pytest.raises(ConfigError, match="bc-all-mlp clones one action per step .*chunk_len=5 "
                                          "does not apply"):
        make_config("ReachAvoid", "bc-all-mlp", overrides={"chunk_len": 5})
    # a key of another algorithm is unknown to it
    with pytest.raises(ConfigError, match="unknown config key 'quantile_alpha' for bc-safe-mlp"):
        make_config("ReachAvoid", "bc-safe-mlp", overrides={"quantile_alpha": 0.5})
    with pytest.raises(ConfigError, match="lr must be > 0"):
        make_config("ReachAvoid", "bc-all-mlp", overrides={"lr": float("nan")})
    with pytest.raises(ConfigError, match="task cannot be overridden"):
        make_config("ReachAvoid", "r2pac", overrides={"task": "CarGoal2"})


def _linear_policy_dataset(n_episodes=20, length=50, obs_dim=6, act_dim=2, seed=0):
    """Episodes whose actions are a fixed smooth function of the observation."""
    from r2pac_jax.data.dsrl import validate

    rng = np.random.default_rng(seed)
    w = rng.normal(size=(obs_dim, act_dim)) * 0.6
    obs = rng.normal(size=(n_episodes, length + 1, obs_dim)).astype(np.float32)
    act = np.tanh(obs[:, :-1] @ w).astype(np.float32)
    term = np.zeros((n_episodes, length), bool)
    tout = np.zeros((n_episodes, length), bool)
    tout[:, -1] = True
    costs = np.zeros((n_episodes, length), np.float32)
    costs[n_episodes // 2:, :] = 1.0  # the second half of the episodes is unsafe
    arrays = dict(observations=obs[:, :-1].reshape(-1, obs_dim),
                  next_observations=obs[:, 1:].reshape(-1, obs_dim),
                  actions=act.reshape(-1, act_dim), rewards=rng.normal(size=n_episodes * length)
                  .astype(np.float32), costs=costs.reshape(-1), terminals=term.reshape(-1),
                  timeouts=tout.reshape(-1))
    return validate(arrays, "linear_policy"), w


def test_mlp_cloner_imitates_a_deterministic_policy(task):
    ds, w = _linear_policy_dataset()
    cfg = make_config(task, "bc-all-mlp", "quick", dict(steps=1500, block_steps=500,
                                                        eval_every=500, checkpoint_every=500))
    data = make_data(cfg, task, ds)
    train = jax.jit(make_train(cfg, data, task.obs_dim, task.act_dim))
    state, metrics = train(jax.random.PRNGKey(0))
    loss = np.asarray(metrics["actor"]["loss_actor"])
    agent = make_agent(cfg, task.obs_dim, task.act_dim)
    pp = agent.policy_params(state, {})
    test_obs = np.random.default_rng(9).normal(size=(256, task.obs_dim)).astype(np.float32)
    err = np.mean((np.asarray(agent.act(pp, jnp.asarray(test_obs), jax.random.PRNGKey(0)))
                   - np.tanh(test_obs @ w)) ** 2)
    assert loss[-1] < 0.1 * loss[0], loss
    assert err < 0.01, err  # on fresh observations: it learned the map, not the rows
    # deterministic actions: the key does not matter
    a1 = agent.act(pp, jnp.asarray(test_obs[:4]), jax.random.PRNGKey(1))
    a2 = agent.act(pp, jnp.asarray(test_obs[:4]), jax.random.PRNGKey(2))
    chex.assert_trees_all_equal(a1, a2)


def test_safe_cloner_trains_on_the_safe_episodes_only(task):
    ds, _ = _linear_policy_dataset()
    kappa = task.kappa
    _, costs = ds.episode_sums()
    assert (costs <= kappa).sum() == 10
    data_all = make_data(make_config(task, "bc-all-mlp"), task, ds)
    data_safe = make_data(make_config(task, "bc-safe-mlp"), task, ds)
    assert data_all.num_starts == ds.size  # every transition is a chunk of length 1
    assert data_safe.num_starts == ds.size // 2
    assert np.all(np.asarray(ds.costs)[np.asarray(data_safe.starts)] == 0.0)


def test_mlp_cloner_torch_style_init():
    from r2pac_jax.nets import DeterministicActor

    p = DeterministicActor((256, 256), 2).init(jax.random.PRNGKey(0), jnp.zeros((1, 40)))
    k0 = np.asarray(p["params"]["Dense_0"]["kernel"])
    b1 = np.asarray(p["params"]["Dense_1"]["bias"])
    assert np.abs(k0).max() <= 1 / np.sqrt(40) and np.abs(k0).max() > 0.9 / np.sqrt(40)
    assert np.abs(b1).max() <= 1 / 16 and np.abs(b1).max() > 0.9 / 16  # fan_in 256
    assert abs(float(k0.std()) - 1 / np.sqrt(3 * 40)) < 0.01  # U(-b, b) has std b / sqrt(3)


@pytest.mark.parametrize("algo", ["bc-all-mlp", "bc-safe-mlp"])
def test_mlp_cloner_vmapped_seeds_equal_single_runs(algo, task, reach_avoid_data):
    cfg = tiny_config(algo)
    data = make_data(cfg, task, reach_avoid_data)
    train = make_train(cfg, data, task.obs_dim, task.act_dim)
    keys = jnp.stack([jax.random.PRNGKey(0), jax.random.PRNGKey(1)])
    batched, mb = jax.jit(jax.vmap(train))(keys, {})
    for i in range(2):
        single, ms = jax.jit(train)(keys[i])
        chex.assert_trees_all_close(jax.tree_util.tree_map(lambda x: x[i], batched.params),
                                    single.params, rtol=1e-5, atol=1e-6)
        chex.assert_trees_all_close(mb["actor"]["loss_actor"][i], ms["actor"]["loss_actor"],
                                    rtol=1e-5, atol=1e-6)
    assert not np.allclose(np.asarray(batched.params["actor"]["params"]["Dense_0"]["kernel"][0]),
                           np.asarray(batched.params["actor"]["params"]["Dense_0"]["kernel"][1]))


def test_mlp_cloner_resumes_bitwise_and_loads_as_a_policy(task, reach_avoid_data, tmp_path):
    from r2pac_jax.checkpoint import Checkpointer

    cfg = tiny_config("bc-safe-mlp", steps=40, eval_every=20, checkpoint_every=10)
    lanes = Lanes.build(cfg, [0, 1])
    full = Run(cfg, task, reach_avoid_data, tmp_path / "full", lanes, **_quiet()).run()
    part = Run(cfg, task, reach_avoid_data, tmp_path / "part", lanes, **_quiet())
    assert part.run(stop_after=2) is None
    res = part.run(resume=True)
    like = part.init_state()
    a, _ = Checkpointer(tmp_path / "full" / "checkpoints").restore(40, like)
    b, _ = Checkpointer(tmp_path / "part" / "checkpoints").restore(40, like)
    chex.assert_trees_all_equal(a, b)
    assert res["normalized_reward"] == full["normalized_reward"]
    assert res["returns"] == full["returns"] and len(res["returns"]) == 2
    assert "threshold" not in res  # the cloner reports no R2PAC threshold
    saved = json.loads((tmp_path / "full" / "config.json").read_text())
    assert saved["algo"] == "bc-safe-mlp" and saved["agent"]["hidden_dims"] == [16, 16]
    import r2pac_jax
    from r2pac_jax.evaluate import evaluate_run

    act = r2pac_jax.load_policy(tmp_path / "full", lane=1)
    assert act(np.zeros(task.obs_dim, np.float32), jax.random.PRNGKey(0)).shape == (2,)
    ev = evaluate_run(tmp_path / "full", episodes=2)
    assert ev["returns"].shape == (2, 2)
    with pytest.raises(ConfigError, match="bc-safe-mlp's policy draws no candidates"):
        evaluate_run(tmp_path / "full", episodes=2, selection="first")
    with pytest.raises(ConfigError, match="no guidance scale"):
        evaluate_run(tmp_path / "full", episodes=2, guidance_scale=1.0)


def test_resume_with_other_settings_is_refused(task, reach_avoid_data, tmp_path):
    cfg = tiny_config("bc-all-mlp", steps=40, eval_episodes=0)
    Run(cfg, task, reach_avoid_data, tmp_path / "r", Lanes.build(cfg, [0]),
        **_quiet()).run(stop_after=1)
    before = (tmp_path / "r" / "config.json").read_text()
    other = tiny_config("bc-all-mlp", steps=20, eval_episodes=0)
    with pytest.raises(ConfigError, match=r"--resume: .*steps: 40 -> 20"):
        Run(other, task, reach_avoid_data, tmp_path / "r", Lanes.build(other, [0]),
            **_quiet()).run(resume=True)
    with pytest.raises(ConfigError, match=r"seeds: \[0\] -> \[0, 1\]"):
        Run(cfg, task, reach_avoid_data, tmp_path / "r", Lanes.build(cfg, [0, 1]),
            **_quiet()).run(resume=True)
    assert (tmp_path / "r" / "config.json").read_text() == before  # nothing overwritten


def test_non_finite_training_stops_with_the_last_checkpoint_kept(task, reach_avoid_data,
                                                                  tmp_path):
    from r2pac_jax.checkpoint import Checkpointer

    cfg = tiny_config("r2pac", steps=40, eval_episodes=0, checkpoint_every=10, lr=1e38,
                      schedule="joint")
    run = Run(cfg, task, reach_avoid_data, tmp_path / "nan", Lanes.build(cfg, [0, 1]), **_quiet())
    with pytest.raises(TrainingDiverged, match=r"non-finite .*first at step \d+ \(lanes \[0, 1\]"):
        run.run()
    assert not (tmp_path / "nan" / "results.json").exists()
    steps = Checkpointer(tmp_path / "nan" / "checkpoints").latest_step()
    if steps is not None:  # whatever was saved was finite
        state, _ = Checkpointer(tmp_path / "nan" / "checkpoints").restore(steps, run.init_state())
        assert all(np.all(np.isfinite(np.asarray(x))) for x in jax.tree_util.tree_leaves(
            state.params))


@pytest.mark.parametrize("algo", ["r2pac", "bc-safe", "r2pac-awr"])
def test_configs_of_runs_made_before_the_protocol_still_load(algo):
    from pathlib import Path

    old = json.loads((Path(__file__).parents[1] / "fixtures" / f"config_a022372_{algo}.json")
                     .read_text())
    cfg = Config.from_dict(old)
    over = dict(seeds=2) if algo == "bc-safe" else dict(seeds=2, quantile_alpha=0.8)
    assert cfg == make_config("CarGoal2", algo, "quick", over)
    assert Config.from_dict(json.loads(cfg.to_json())) == cfg  # and the new layout round-trips


def test_a_sweep_marks_a_diverged_lane_and_the_others_finish(task, reach_avoid_data, tmp_path):
    """In mark mode (sweeps) one cell's lanes diverge (penalty C huge -> inf targets) while the
    other cell's finish and are scored; the report names the diverged seeds."""
    cfg = tiny_config("r2pac", steps=20, eval_episodes=2, schedule="joint")
    lanes = Lanes.build(cfg, [0, 1], [dict(penalty_c=1.0), dict(penalty_c=3e38)])
    msgs = []
    run = Run(cfg, task, reach_avoid_data, tmp_path / "g", lanes, progress=False,
              log=msgs.append, nonfinite="mark")
    res = run.run()
    ok, bad = res["cells"]
    assert "diverged" not in ok or not ok["diverged"]
    assert all(x is not None for x in ok["normalized_reward"]["per_seed"])
    assert [d["seed"] for d in bad["diverged"]] == [0, 1]
    # the huge penalty overflows within the first block (block_steps steps)
    assert all(1 <= d["step"] <= cfg.block_steps for d in bad["diverged"])
    assert bad["normalized_reward"]["mean"] is None and bad["safe"] is False
    assert bad["normalized_cost"]["per_seed"] == [None, None]
    assert any(re.search(r"diverged at step \d+ \(non-finite", m) for m in msgs)


def test_a_block_names_the_first_non_finite_step():
    """make_block(first_bad=True) returns the 0-based index of the first step whose metrics are
    not finite (a toy agent whose loss turns NaN at its 5th step of 8), and -1 when all are."""
    import types

    import flax.struct
    import jax
    import jax.numpy as jnp

    from r2pac_jax.loop import make_block

    @flax.struct.dataclass
    class S:
        key: jax.Array
        n: jax.Array

    def update(s, batch, hp, phase):
        n = s.n + 1
        return s.replace(n=n), dict(loss=jnp.where(n >= hp["bad_from"], jnp.nan, 1.0),
                                    ok=jnp.ones(3))

    agent = types.SimpleNamespace(cfg=types.SimpleNamespace(block_steps=8),
                                  begin_block=lambda s, hp, d: s, sample=lambda d, k: None,
                                  update=update)
    block = jax.jit(make_block(agent, "joint", first_bad=True))
    s0 = S(key=jax.random.PRNGKey(0), n=jnp.int32(0))
    state, means, first = block(s0, dict(bad_from=5), None)
    assert int(first) == 4 and int(state.n) == 8 and np.isnan(means["loss"])
    _, means, first = block(s0, dict(bad_from=100), None)
    assert int(first) == -1 and means["loss"] == 1.0

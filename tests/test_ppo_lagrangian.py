"""The PPO-Lagrangian data source (DSRL's recipe): GAE, the multiplier, the annealed limit,
a tiny run on ReachAvoid (valid DSRL data, deterministic), and its errors."""
import types

import chex
import jax.numpy as jnp
import numpy as np
import pytest

from r2pac_jax.data import factory
from r2pac_jax.data.dsrl import validate
from r2pac_jax.data.factory import ppo_lagrangian as pl
from r2pac_jax.tasks import get_task

TINY = dict(num_envs=8, rollout_len=40, updates=6, epochs=2, minibatches=2, hidden=(16,),
            snapshots=3)


def _col(x):
    return jnp.asarray(x, jnp.float32)[:, None]  # [T] -> [T, N=1]


def test_gae_bootstraps_a_time_limit_but_not_a_terminal():
    r, v, nv = _col([1, 1, 1]), _col([0, 0, 0]), _col([5, 5, 5])
    # the episode is cut by the time limit after step 3: its next value still counts
    adv, tgt = pl.gae(r, v, nv, _col([0, 0, 0]), _col([0, 0, 1]), gamma=0.5, lam=1.0)
    chex.assert_trees_all_close(adv[:, 0], jnp.array([6.125, 5.25, 3.5]))
    chex.assert_trees_all_close(tgt, adv + v)
    # a true terminal at step 3: no bootstrap there
    adv, _ = pl.gae(r, v, nv, _col([0, 0, 1]), _col([0, 0, 1]), gamma=0.5, lam=1.0)
    chex.assert_trees_all_close(adv[:, 0], jnp.array([5.5, 4.0, 1.0]))
    # an episode boundary after step 1 stops the recursion there
    adv, _ = pl.gae(r, v, nv, _col([1, 0, 0]), _col([1, 0, 0]), gamma=0.5, lam=1.0)
    chex.assert_trees_all_close(adv[0, 0], jnp.array(1.0))


def test_multiplier_and_annealed_limit():
    chex.assert_trees_all_close(pl.lagrange_update(jnp.array(1.0), 5.0, 3.0, 0.1), jnp.array(1.2))
    chex.assert_trees_all_close(pl.lagrange_update(jnp.array(0.1), 0.0, 3.0, 0.1), jnp.array(0.0))
    cfg = pl.PPOLagConfig(updates=11, limit_start=20.0, limit_end=2.0)
    assert pl.cost_limit(0, cfg) == 20.0 and pl.cost_limit(10, cfg) == pytest.approx(2.0)
    assert pl.cost_limit(5, cfg) == pytest.approx(11.0)


def test_tiny_run_on_reach_avoid_is_valid_dsrl_and_deterministic():
    task = get_task("ReachAvoid")
    cfg = pl.PPOLagConfig(limit_start=8.0, limit_end=1.0, **TINY)
    a = pl.generate(task, 7, seed=3, cfg=cfg, log=lambda m: None)
    ds = validate(a, "ppo", task.obs_dim, task.act_dim, task.name)
    rets, costs = ds.episode_sums()
    assert len(rets) == 7
    assert np.all(np.abs(a["actions"]) <= 1.0)
    b = pl.generate(task, 7, seed=3, cfg=cfg, log=lambda m: None)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    c = pl.generate(task, 7, seed=4, cfg=cfg, log=lambda m: None)
    assert not np.array_equal(a["observations"], c["observations"])


def test_training_metrics_and_snapshots():
    task = get_task("ReachAvoid")
    cfg = pl.PPOLagConfig(limit_start=8.0, limit_end=1.0, **TINY)
    import jax

    train = pl.make_train(task.make_env(), cfg)
    snaps, m = jax.jit(train)(jax.random.PRNGKey(0))
    assert jax.tree_util.tree_leaves(snaps)[0].shape[0] == cfg.snapshots
    for k in ("episode_return", "episode_cost", "lagrange", "cost_limit", "policy_loss"):
        assert m[k].shape == (cfg.updates,) and np.all(np.isfinite(np.asarray(m[k])))
    assert np.all(np.asarray(m["lagrange"]) >= 0.0)
    np.testing.assert_allclose(np.asarray(m["cost_limit"])[[0, -1]], [8.0, 1.0], rtol=1e-6)


def test_refuses_non_jax_physics_with_the_fix():
    fake = types.SimpleNamespace(is_jax=False, name="CarGoal2")
    with pytest.raises(ValueError, match="physics='mjx'"):
        pl.make_train(fake, pl.PPOLagConfig())
    with pytest.raises(factory.FactoryError, match="--physics mjx"):
        factory.generate_dataset(get_task("CarGoal2"), 4, source="ppo-lagrangian",
                                 physics="mujoco")
    with pytest.raises(factory.FactoryError, match="unknown data source"):
        factory.generate_dataset(get_task("ReachAvoid"), 4, source="sac")


def test_factory_writes_a_separately_named_dataset(tmp_path, monkeypatch):
    monkeypatch.setenv("R2PAC_DATA_DIR", str(tmp_path))
    full = pl.PPOLagConfig
    small = lambda **kw: full(**{**TINY, **kw})  # noqa: E731
    monkeypatch.setattr(pl, "PPOLagConfig", small)
    task = get_task("ReachAvoid")
    path = factory.generate_dataset(task, 5, seed=1, plot=False, source="ppo-lagrangian")
    assert path.name == "ReachAvoid-generated-ppolag-s1-n5.hdf5"
    card = __import__("json").loads(factory.card_path(path).read_text())
    assert card["trajectories"] == 5 and "PPO-Lagrangian" in card["sources"][0]
    assert card["thinning"]["generated"] == 10
    # train's automatic lookup only takes the scripted source's files
    assert factory.find_cached(task) is None


@pytest.mark.slow
def test_runs_on_an_mjx_task():
    """The recipe's point on an accelerator: a MuJoCo task on MJX (minutes to compile on CPU)."""
    task = get_task("HalfCheetahVelocity")
    cfg = pl.PPOLagConfig(num_envs=4, rollout_len=10, updates=2, epochs=1, minibatches=1,
                          hidden=(16,), snapshots=2, limit_start=40.0, limit_end=5.0)
    a = pl.generate(task, 2, seed=0, physics="mjx", cfg=cfg, log=lambda m: None)
    ds = validate(a, "ppo-mjx", task.obs_dim, task.act_dim, task.name)
    assert len(ds.episode_sums()[0]) == 2 and ds.size == 2 * task.episode_len

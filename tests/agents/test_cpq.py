"""CPQ as OSRL implements it (agents/cpq.py): its formulas, its OOD-penalty gradient rule, its
config values and refusals, and that it trains through the generic loop."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import tiny_config
from r2pac_jax.agents import cpq, make_agent
from r2pac_jax.agents.constraints import q_threshold
from r2pac_jax.config import ConfigError, default_hparams, make_config
from r2pac_jax.data import transitions
from r2pac_jax.data.dsrl import validate
from r2pac_jax.tasks import get_task


def test_q_threshold_spreads_kappa_over_an_episode():
    # 2 (1 - 0.99^80) / (0.01 * 80), by hand: 1.38119...
    assert np.isclose(float(q_threshold(2.0, 0.99, 80)), 2 * (1 - 0.99**80) / 0.8)
    assert np.isclose(float(q_threshold(10.0, 0.99, 1)), 10.0)  # one step: kappa itself
    cfg = make_config("CarGoal2", "cpq", "paper")
    assert (cfg.cost_limit, cfg.episode_len) == (get_task("CarGoal2").kappa, 1000)
    assert (cfg.batch_size, cfg.reward_scale, cfg.actor_lr, cfg.critic_lr, cfg.num_q,
            cfg.qc_scalar, cfg.beta) == (512, 0.1, 1e-4, 1e-3, 2, 1.5, 0.5)
    assert make_config("CarGoal2", "cpq", "paper").steps == 100_000
    quick = make_config("CarGoal2", "cpq")  # the CPU preset: smaller networks, fewer steps
    assert (quick.steps, quick.batch_size, quick.a_hidden_dims, quick.vae_hidden) == \
        (10_000, 256, (128, 128), 128)


def test_reward_target_drops_the_bootstrap_where_the_cost_critic_says_unsafe():
    r = jnp.array([1.0, 1.0, 1.0, 1.0])
    done = jnp.array([0.0, 0.0, 1.0, 0.0])
    q = jnp.array([5.0, 5.0, 5.0, 5.0])
    qc = jnp.array([0.5, 2.0, 0.5, 1.0])
    out = cpq.reward_target(r, done, q, qc, 1.0, 0.9)
    np.testing.assert_allclose(out, [1 + 0.9 * 5, 1.0, 1.0, 1 + 0.9 * 5])  # qc == thres is safe
    np.testing.assert_allclose(cpq.cost_target(jnp.array([1.0]), jnp.array([3.0]), 0.5), [2.5])


def test_ood_flags_the_top_quarter_and_alpha_moves_toward_the_threshold():
    kl = jnp.arange(40.0).reshape(10, 4)
    flags = cpq.ood_flags(kl, 0.75)
    assert float(flags.sum()) == 10 and np.all(np.asarray(flags).ravel()[30:] == 1)
    up = cpq.alpha_step(jnp.float32(0.0), qc_ood=0.0, qc_thres=1.0, alpha_lr=0.1)
    down = cpq.alpha_step(jnp.float32(0.0), qc_ood=2.0, qc_thres=1.0, alpha_lr=0.1)
    assert np.isclose(float(up), 0.1) and np.isclose(float(down), -0.1)
    assert float(cpq.alpha_step(jnp.float32(4.99), 0.0, 1.0, 1.0)) == 5.0  # OSRL's clamp


@pytest.mark.parametrize("ood_gradient", [False, True])
def test_the_ood_penalty_reaches_the_gradient_only_when_asked(reach_avoid_data, ood_gradient):
    """OSRL computes qc_ood from the target critic under no_grad: alpha changes the reported
    loss but not the cost critic's step. With ood_gradient=True it changes the step."""
    task = get_task("ReachAvoid")
    cfg = tiny_config("cpq", ood_gradient=ood_gradient)
    agent = make_agent(cfg, task.obs_dim, task.act_dim)
    hp = default_hparams(cfg)
    data = agent.make_data(task, reach_avoid_data)
    batch = agent.sample(data, jax.random.PRNGKey(1))
    s0 = agent.init(jax.random.PRNGKey(0), hp)
    # move the targets off the online nets, so the OOD term sees other values than the MSE's
    s0 = s0.replace(target={**s0.target, "cost_critic": agent.init(jax.random.PRNGKey(5), hp)
                            .params["cost_critic"]})
    step = jax.jit(agent.update, static_argnums=3)
    a, ma = step(s0, batch, hp, "actor")
    b, mb = step(s0.replace(log_alpha=jnp.float32(3.0)), batch, hp, "actor")
    assert not np.isclose(float(ma["loss_cost_critic"]), float(mb["loss_cost_critic"]))
    same = jax.tree_util.tree_all(jax.tree_util.tree_map(
        lambda x, y: bool(np.array_equal(x, y)), a.params["cost_critic"], b.params["cost_critic"]))
    assert same is (not ood_gradient)


def test_bad_cpq_values_are_refused_with_the_key_named():
    for key, value, fragment in [("num_q", 0, "num_q must be >= 1"),
                                 ("ood_quantile", 1.5, "ood_quantile must lie in"),
                                 ("qc_scalar", 0.0, "qc_scalar must be > 0"),
                                 ("done_rule", "never", "done_rule must be one of"),
                                 ("tau", 2.0, "tau must lie in")]:
        with pytest.raises(ConfigError, match=fragment):
            make_config("ReachAvoid", "cpq", overrides={key: value})
    with pytest.raises(ConfigError, match="cpq learns one-step critics"):
        make_config("ReachAvoid", "cpq", overrides={"chunk_len": 3})


def test_transitions_follow_osrls_done_rule_and_filter_episodes():
    from conftest import toy_arrays

    ds = validate(toy_arrays(((4, "timeout"), (3, "terminal"), (2, "timeout"))), "toy")
    osrl = transitions.transition_arrays(ds, reward_scale=0.1)
    assert osrl["done"].tolist() == [0, 0, 0, 1, 0, 0, 1, 0, 1]
    assert transitions.transition_arrays(ds, done_rule="terminal")["done"].tolist() == \
        [0, 0, 0, 0, 0, 0, 1, 0, 0]
    assert osrl["is_init"].tolist() == [1, 0, 0, 0, 1, 0, 0, 1, 0]
    np.testing.assert_allclose(osrl["rewards"], ds.rewards * 0.1, rtol=1e-6)
    assert osrl["observations"] is ds.observations  # every row kept: the file's array, no copy
    every = transitions.transition_arrays(ds, reward_scale=0.1, keep_episodes=np.ones(3, bool))
    assert all(np.array_equal(every[k], osrl[k]) for k in osrl)
    kept = transitions.build_transitions(ds, keep_episodes=np.array([False, True, True]))
    assert kept.size == 5 and np.asarray(kept.init_index).tolist() == [0, 3]
    b = transitions.sample(kept, jax.random.PRNGKey(0), 64)
    firsts = {tuple(np.round(ds.observations[i], 5)) for i in (4, 7)}
    assert {tuple(np.round(o, 5)) for o in np.asarray(b.init_observations)} <= firsts

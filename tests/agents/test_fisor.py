"""FISOR as its JAX code does (agents/fisor.py, agents/diffusion.py): the stage cost, the HJ
target, the feasibility-guided weights, the VP schedule and sampler, the min-Q_h selection, the
data preparation, config values and refusals."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import tiny_config
from r2pac_jax.agents import diffusion, fisor, make_agent
from r2pac_jax.config import ConfigError, default_hparams, make_config
from r2pac_jax.tasks import get_task


def test_stage_cost_and_hj_target():
    np.testing.assert_allclose(fisor.stage_cost(jnp.array([0.0, 1.0, 0.3]), 25.0), [-1, 25, 25])
    h = jnp.array([-1.0, 25.0, -1.0, 25.0])
    mask = jnp.array([1.0, 1.0, 0.0, 0.0])
    vh = jnp.array([3.0, -2.0, 3.0, 3.0])
    # m = 1: 0.01 h + 0.99 max(h, V_h'); m = 0: h
    np.testing.assert_allclose(fisor.hj_target(h, mask, 0.99, vh),
                               [0.01 * -1 + 0.99 * 3, 0.01 * 25 + 0.99 * 25, -1.0, 25.0],
                               rtol=1e-6)


def test_feasibility_weights():
    q, v = jnp.array([1.0, 1.0, 1.0, 3.0]), jnp.array([0.5, 0.5, 0.5, 0.0])
    qh = jnp.array([-1.0, 2.0, 0.5, -3.0])
    vh = jnp.array([-0.5, 1.0, -0.2, -2.0])
    w = fisor.feasibility_weights(q, v, qh, vh, 3.0, 5.0, 100.0, 150.0)
    # feasible: exp(3 * 0.5); infeasible: exp(5 (1 - 2)); feasible state, Q_h > 0: 0;
    # feasible with a huge advantage: clipped at 100
    np.testing.assert_allclose(w, [np.exp(1.5), np.exp(-5.0), 0.0, 100.0], rtol=1e-5)
    big = fisor.feasibility_weights(q[:1], v[:1], jnp.array([-40.0]), jnp.array([1.0]), 3.0, 5.0,
                                    100.0, 150.0)
    assert float(big[0]) == 150.0  # infeasible weights clip at cost_ub


def test_vp_schedule_and_noising():
    T = 5
    betas, alphas, ahat = diffusion.schedule(T)
    t = np.arange(1, T + 1)
    want = 1 - np.exp(-0.1 / T - 0.5 * 9.9 * (2 * t - 1) / T**2)
    np.testing.assert_allclose(betas, want, rtol=1e-5)
    np.testing.assert_allclose(ahat, np.cumprod(1 - want), rtol=1e-5)
    a, e = jnp.ones((2, 3)), jnp.full((2, 3), 2.0)
    x = diffusion.noised(a, jnp.array([0, 4]), e, ahat)
    np.testing.assert_allclose(x[1], np.sqrt(ahat[4]) + np.sqrt(1 - ahat[4]) * 2, rtol=1e-5)
    out = diffusion.sample(lambda s, x, t: jnp.zeros_like(x), jnp.zeros((7, 2)), 3,
                           jax.random.PRNGKey(0), T)
    assert out.shape == (7, 3) and float(jnp.abs(out).max()) <= 1.0


def test_act_takes_the_candidate_with_the_least_qh(reach_avoid_data):
    task = get_task("ReachAvoid")
    cfg = tiny_config("fisor", num_candidates=6)
    agent = make_agent(cfg, task.obs_dim, task.act_dim)
    st = agent.init(jax.random.PRNGKey(0), default_hparams(cfg))
    pp = agent.policy_params(st, default_hparams(cfg))
    obs = jnp.asarray(reach_avoid_data.observations[:3])
    key = jax.random.PRNGKey(7)
    act = agent.act(pp, obs, key)
    rep = jnp.repeat(obs, 6, axis=0)
    cand = diffusion.sample(lambda s, x, t: agent.actor_net.apply(pp["actor"], s, x, t), rep,
                            task.act_dim, key, cfg.diffusion_steps)
    qh = np.asarray(agent.q_net.apply(pp["qh"], rep, cand).max(0)).reshape(3, 6)
    want = np.asarray(cand).reshape(3, 6, -1)[np.arange(3), qh.argmin(1)]
    np.testing.assert_allclose(act, want, rtol=1e-6)


def test_data_are_prepared_as_fisor_does(reach_avoid_data):
    task = get_task("ReachAvoid")
    cfg = tiny_config("fisor")
    assert (cfg.reward_scale, cfg.cost_scale) == (1.0, 1.0)
    data = make_agent(cfg, task.obs_dim, task.act_dim).make_data(task, reach_avoid_data)
    scale = task.episode_len / (task.r_max - task.r_min)
    np.testing.assert_allclose(data.rewards, reach_avoid_data.rewards * scale, rtol=1e-5)
    assert set(np.unique(np.asarray(data.costs))) <= {-1.0, 25.0}
    assert float(jnp.abs(data.actions).max()) <= 1 - 1e-5
    # timeouts end the backup (FISOR's rule)
    assert float(data.done.sum()) == len(reach_avoid_data.episode_bounds()[0])


def test_fisor_values_and_refusals():
    cfg = make_config("CarGoal2", "fisor", "paper")
    assert (cfg.steps, cfg.batch_size, cfg.critic_batch, cfg.num_candidates,
            cfg.diffusion_steps, cfg.reward_temperature, cfg.cost_temperature,
            cfg.reward_weight_clip, cfg.cost_weight_clip, cfg.expectile, cfg.cost_expectile,
            cfg.actor_tau, cfg.stage_cost) == (1_000_000, 2048, 256, 16, 5, 3.0, 5.0, 100.0,
                                               150.0, 0.9, 0.9, 0.001, 25.0)
    for key, value, fragment in [("num_candidates", 0, "num_candidates must be >= 1"),
                                 ("expectile", 1.0, "expectile must lie in"),
                                 ("reward_scale", 2.0, "fisor normalises rewards as FISOR"),
                                 ("actor_dropout", 1.0, "actor_dropout must lie in")]:
        with pytest.raises(ConfigError, match=fragment):
            make_config("ReachAvoid", "fisor", overrides={key: value})
    with pytest.raises(ConfigError, match="critic_batch 512 exceeds batch_size 64"):
        make_agent(make_config("ReachAvoid", "fisor", overrides=dict(batch_size=64,
                                                                     critic_batch=512)), 6, 2)

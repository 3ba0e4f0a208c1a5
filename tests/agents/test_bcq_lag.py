"""BCQ-Lagrangian as OSRL implements it (agents/bcq_lag.py): the soft-clipped double Q, OSRL's
PID controller, the perturbation's range, the sample layout of the target, config refusals."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import tiny_config
from r2pac_jax.agents import bcq_lag, make_agent
from r2pac_jax.agents.constraints import pid_multiplier
from r2pac_jax.config import ConfigError, default_hparams, make_config
from r2pac_jax.tasks import get_task


def test_osrl_values_and_task_values():
    cfg = make_config("HalfCheetahVelocity", "bcq-lag", "paper")
    assert (cfg.actor_lr, cfg.critic_lr, cfg.vae_lr, cfg.phi, cfg.lmbda, cfg.beta, cfg.pid,
            cfg.batch_size, cfg.reward_scale, cfg.num_q, cfg.num_qc, cfg.sample_action_num) == \
        (1e-3, 1e-3, 1e-3, 0.05, 0.75, 0.5, (0.1, 0.003, 0.001), 512, 0.1, 2, 2, 10)
    assert (cfg.cost_limit, cfg.episode_len) == (get_task("HalfCheetahVelocity").kappa, 1000)


def test_soft_clipped_double_q():
    q = bcq_lag.soft_clipped_double_q(jnp.array([1.0, 4.0]), jnp.array([3.0, 2.0]), 0.75)
    np.testing.assert_allclose(q, [0.75 * 1 + 0.25 * 3, 0.75 * 2 + 0.25 * 4])


def test_pid_multiplier_runs_osrls_controller():
    """The same sequence through a plain transcription of OSRL's LagrangianPIDController."""
    kp, ki, kd, thres = 0.1, 0.003, 0.001, 1.0
    relu = lambda x: max(x, 0.0)  # noqa: E731
    old, integral = 0.0, 0.0
    e_j, i_j = jnp.float32(0.0), jnp.float32(0.0)
    rng = np.random.default_rng(0)
    for mean in (3.0, 2.0, 0.5, -1.0, 4.0):
        qc = rng.normal(mean, 0.1, 16).astype(np.float32)
        e = float(np.mean(qc - thres))
        diff = relu(e - old)
        integral = relu(integral + e)
        old = e
        want = relu(kp * relu(e) + ki * integral + kd * diff)
        got, e_j, i_j = pid_multiplier(jnp.asarray(qc), thres, e_j, i_j, kp, ki, kd)
        assert np.isclose(float(got), want, rtol=1e-5, atol=1e-7)
        assert np.isclose(float(i_j), integral, rtol=1e-5, atol=1e-6)


def test_the_actor_perturbs_within_phi_and_the_target_maxes_per_state(reach_avoid_data):
    task = get_task("ReachAvoid")
    cfg = tiny_config("bcq-lag", phi=0.05)
    agent = make_agent(cfg, task.obs_dim, task.act_dim)
    st = agent.init(jax.random.PRNGKey(0), default_hparams(cfg))
    obs = jnp.asarray(reach_avoid_data.observations[:64])
    a = jnp.asarray(np.random.default_rng(0).uniform(-0.9, 0.9, (64, task.act_dim)), jnp.float32)
    out = agent._perturb(st.params["actor"], obs, a)
    assert float(jnp.abs(out - a).max()) <= 0.05 + 1e-6
    assert float(jnp.abs(agent._perturb(st.params["actor"], obs, jnp.ones_like(a))).max()) <= 1
    # the target: 3 samples per state, repeated row-major by state; max over each state's own
    obs_rep = jnp.repeat(obs[:4], 3, axis=0)
    acts = jnp.asarray(np.random.default_rng(1).uniform(-1, 1, (12, task.act_dim)), jnp.float32)
    got = agent._target(agent.critic_net, st.params["critic"], cfg.num_q, obs_rep, acts, 4)
    q = agent.critic_net.apply(st.params["critic"], obs_rep, acts)
    v = bcq_lag.soft_clipped_double_q(q[:2].min(0), q[2:].min(0), cfg.lmbda)
    np.testing.assert_allclose(got, np.asarray(v).reshape(4, 3).max(1), rtol=1e-6)


def test_bad_bcq_lag_values_are_refused():
    for key, value, fragment in [("pid", (0.1, 0.1), "pid must be three gains"),
                                 ("lmbda", 1.5, "lmbda must lie in"),
                                 ("pid", (0.1, -1.0, 0.0), "pid must be >= 0"),
                                 ("sample_action_num", 0, "sample_action_num must be >= 1")]:
        with pytest.raises(ConfigError, match=fragment):
            make_config("ReachAvoid", "bcq-lag", overrides={key: value})

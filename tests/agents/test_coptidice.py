"""COptiDICE as OSRL implements it (agents/coptidice.py): f-divergences, the cost upper bound's
weights, the direction of the lambda dual step, the data statistics, config refusals."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import tiny_config
from r2pac_jax.agents import coptidice, make_agent
from r2pac_jax.config import ConfigError, default_hparams, make_config
from r2pac_jax.tasks import get_task


@pytest.mark.parametrize("f_type", coptidice.F_TYPES)
def test_f_prime_inverse_inverts_the_derivative_of_f(f_type):
    f, inv = coptidice.f_divergence(f_type)
    xs = jnp.linspace(0.05, 3.0, 40)
    grads = jax.vmap(jax.grad(f))(xs)
    np.testing.assert_allclose(inv(grads), xs, rtol=2e-3, atol=2e-3)
    assert abs(float(f(jnp.float32(1.0)))) < 1e-6  # f(1) = 0: no divergence from the data


def test_cost_upper_bound_weights():
    w, d = coptidice.cost_upper_bound_weights(jnp.full((8,), 3.0), 1.0)
    np.testing.assert_allclose(w, 1.0, rtol=1e-6)
    assert abs(float(d)) < 1e-6
    w, d = coptidice.cost_upper_bound_weights(jnp.arange(8.0), 0.5)
    assert np.isclose(float(w.mean()), 1.0) and float(d) > 0 and float(w[-1]) > float(w[0])


@pytest.mark.parametrize("cost_limit,direction", [(0.0, 1), (1e4, -1)])
def test_lambda_rises_when_the_weighted_cost_exceeds_the_threshold(reach_avoid_data, cost_limit,
                                                                   direction):
    task = get_task("ReachAvoid")
    cfg = tiny_config("coptidice", cost_limit=cost_limit, scalar_lr=0.1)
    agent = make_agent(cfg, task.obs_dim, task.act_dim)
    hp = default_hparams(cfg)
    data = agent.make_data(task, reach_avoid_data)
    st = agent.init(jax.random.PRNGKey(0), hp)
    step = jax.jit(agent.update, static_argnums=3)
    for i in range(3):
        st, m = step(st, agent.sample(data, jax.random.PRNGKey(i)), hp, "actor")
    assert float(m["weighted_cost"]) > 0  # ReachAvoid's data have costs
    assert np.sign(float(st.params["lmbda"]) - 1.0) == direction


def test_data_stats_and_osrl_values(reach_avoid_data):
    task = get_task("ReachAvoid")
    cfg = tiny_config("coptidice")
    agent = make_agent(cfg, task.obs_dim, task.act_dim)
    _, stats = agent.make_data(task, reach_avoid_data)
    starts, _ = reach_avoid_data.episode_bounds()
    assert np.isclose(float(stats.init_proportion), len(starts) / reach_avoid_data.size)
    np.testing.assert_allclose(stats.obs_std, reach_avoid_data.observations.std(0), rtol=1e-4)
    full = make_config("CarGoal2", "coptidice", "paper")
    assert (full.actor_lr, full.critic_lr, full.scalar_lr, full.alpha, full.f_type,
            full.cost_ub_epsilon, full.num_nu, full.num_chi, full.batch_size,
            full.reward_scale) == (1e-4, 1e-4, 1e-4, 0.5, "softchi", 0.01, 2, 2, 512, 0.1)


def test_bad_coptidice_values_are_refused():
    for key, value, fragment in [("alpha", 0.0, "alpha must be > 0"),
                                 ("alpha", -1.0, "alpha must be > 0"),
                                 ("f_type", "tv", "f_type must be one of"),
                                 ("cost_ub_epsilon", -0.1, "cost_ub_epsilon must be >= 0")]:
        with pytest.raises(ConfigError, match=fragment):
            make_config("ReachAvoid", "coptidice", overrides={key: value})
    from r2pac_jax.config import check_hparams

    with pytest.raises(ConfigError, match="alpha must be > 0"):
        check_hparams("coptidice", {"alpha": np.array([0.5, 0.0])})

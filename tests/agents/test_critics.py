import chex
import jax.numpy as jnp
import numpy as np

from r2pac_jax.agents import critics


def test_expectile_weights_hand_example():
    u = jnp.array([-2.0, -0.5, 0.0, 1.0, 3.0])
    tau = 0.9
    # u < 0 -> (1 - tau) u^2 ; u >= 0 -> tau u^2
    expected = jnp.array([0.1 * 4, 0.1 * 0.25, 0.0, 0.9 * 1, 0.9 * 9])
    chex.assert_trees_all_close(critics.expectile_loss(u, tau), expected, rtol=1e-6)


def test_reversed_expectile_weights_hand_example():
    u = jnp.array([-2.0, -0.5, 0.0, 1.0, 3.0])
    tau = 0.9
    # reversed: u < 0 (Q below V) weighs tau, so V moves to Q's low end
    expected = jnp.array([0.9 * 4, 0.9 * 0.25, 0.0, 0.1 * 1, 0.1 * 9])
    chex.assert_trees_all_close(critics.reversed_expectile_loss(u, tau), expected, rtol=1e-6)


def _fit_scalar(loss_fn, samples, tau):
    # minimise mean loss(samples - v) over v by grid search
    grid = jnp.linspace(samples.min(), samples.max(), 20001)
    losses = jnp.stack([loss_fn(samples - v, tau).mean() for v in grid[::50]])
    return grid[::50][jnp.argmin(losses)]


def test_expectiles_bracket_the_mean():
    x = jnp.array([0.0, 1.0, 2.0, 3.0, 10.0])
    upper = _fit_scalar(critics.expectile_loss, x, 0.9)
    lower = _fit_scalar(critics.reversed_expectile_loss, x, 0.9)
    assert lower < x.mean() < upper
    # the 0.9 expectile of x solves 0.9 * sum(x - v)_+ = 0.1 * sum(v - x)_+
    v = float(upper)
    lhs = 0.9 * np.clip(np.asarray(x) - v, 0, None).sum()
    rhs = 0.1 * np.clip(v - np.asarray(x), 0, None).sum()
    assert abs(lhs - rhs) < 0.05


def test_safety_threshold_is_the_alpha_quantile():
    vc = jnp.arange(101.0)  # 0..100
    chex.assert_trees_all_close(critics.safety_threshold(vc, 0.9), 90.0)
    chex.assert_trees_all_close(critics.safety_threshold(vc, 0.5), 50.0)
    assert float(critics.safety_threshold(vc, 0.25)) == 25.0


def test_penalised_target_three_transitions():
    # 1: next state safe -> backup; 2: next state unsafe -> C-bar; 3: terminal -> R only
    R = jnp.array([1.0, 2.0, 3.0])
    m = jnp.array([1.0, 1.0, 0.0])
    gh = 0.99**5
    vr_next = jnp.array([10.0, 10.0, 10.0])
    vc_next = jnp.array([0.1, 0.9, 5.0])
    l = 0.5
    cbar = critics.penalty_value(1.0, 0.99, "absorbing")
    assert abs(cbar - (-100.0)) < 1e-9
    y = critics.penalised_reward_target(R, m, gh, vr_next, vc_next, l, cbar)
    chex.assert_trees_all_close(y, jnp.array([1.0 + gh * 10.0, -100.0, 3.0]), rtol=1e-6)
    # w/o Vbar_r: no penalty anywhere
    y0 = critics.penalised_reward_target(R, m, gh, vr_next, vc_next, l, cbar, use_penalty=False)
    chex.assert_trees_all_close(y0, jnp.array([1.0 + gh * 10.0, 2.0 + gh * 10.0, 3.0]), rtol=1e-6)
    # direct mode: the target is -C
    assert critics.penalty_value(5.0, 0.99, "direct") == -5.0


def test_cost_and_feasibility_targets():
    gh = 0.9
    chex.assert_trees_all_close(
        critics.cost_target(jnp.array([1.0, 2.0]), jnp.array([1.0, 0.0]), gh, jnp.array([3.0, 3.0])),
        jnp.array([1.0 + 0.9 * 3.0, 2.0]))
    z = jnp.array([-1.0, 1.0, -1.0])
    vz = jnp.array([0.5, -1.0, -2.0])
    m = jnp.array([1.0, 1.0, 0.0])
    y = critics.feasibility_target(z, m, gh, vz)
    expected = jnp.array([0.1 * -1 + 0.9 * 0.5, 0.1 * 1 + 0.9 * 1.0, -1.0])
    chex.assert_trees_all_close(y, expected, rtol=1e-6)


def test_q_regression_loss_averages_ensemble():
    q = jnp.array([[1.0, 2.0], [3.0, 4.0]])
    t = jnp.array([1.0, 1.0])
    assert float(critics.q_regression_loss(q, t)) == (0 + 1 + 4 + 9) / 4

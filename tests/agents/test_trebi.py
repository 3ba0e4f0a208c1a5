"""TREBI's pieces: the planner's inpainting, guidance and choice, the budget recurrence, its
value targets and its bad input."""
import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import tiny_config

from r2pac_jax.agents import make_agent
from r2pac_jax.agents.trebi import choose_plan, cosine_schedule, guided_plan
from r2pac_jax.config import ConfigError, default_hparams, make_config
from r2pac_jax.data.sequences import to_go

A, O, H, P = 2, 3, 4, 5


def _plan(value_c, budget, scale, key=0, t_stopgrad=0):
    state = jnp.array([[0.5, -1.0, 2.0], [1.0, 0.0, -0.5]])
    return guided_plan(lambda x, t: x, lambda x, t: jnp.zeros(x.shape[0]), value_c, state,
                       jnp.asarray(budget, jnp.float32), jax.random.PRNGKey(key),
                       cosine_schedule(5), A, H, P, 2, scale, t_stopgrad, 5.0), state


def _action_cost(x, t):  # a hand-made cost value: the squared size of the first action
    return (x[:, 0, :A] ** 2).sum(-1)


def test_plans_keep_the_current_state_and_have_their_shapes():
    (x, y_r, y_c, chosen), state = _plan(_action_cost, [1.0, 1.0], 0.1)
    chex.assert_shape(x, (2, P, H, A + O))
    chex.assert_shape((y_r, y_c), (2, P))
    chex.assert_shape(chosen, (2,))
    np.testing.assert_array_equal(np.asarray(x[:, :, 0, A:]),
                                  np.broadcast_to(np.asarray(state)[:, None], (2, P, O)))


def test_cost_guidance_lowers_the_chosen_plans_predicted_cost():
    # a budget every plan exceeds: the guide pushes each plan down the cost value's gradient
    free, _ = _plan(_action_cost, [0.05, 0.05], 0.0)
    guided, _ = _plan(_action_cost, [0.05, 0.05], 0.02)
    pick = lambda out: np.take_along_axis(np.asarray(out[2]), np.asarray(out[3])[:, None], 1)  # noqa: E731
    assert np.all(pick(guided) < pick(free))
    # and no guidance at all below t_stopgrad: with t_stopgrad past the last step, none happens
    off, _ = _plan(_action_cost, [0.05, 0.05], 0.02, t_stopgrad=99)
    np.testing.assert_allclose(np.asarray(off[0]), np.asarray(free[0]), rtol=0, atol=0)


def test_the_choice_within_budget_and_without():
    y_r = jnp.array([[3.0, 9.0, 5.0], [3.0, 9.0, 5.0]])
    y_c = jnp.array([[1.0, 4.0, 2.0], [7.0, 8.0, 6.0]])
    # episode 0: plans 0 and 2 within 2.5, the better reward wins (not plan 1's 9 at cost 4);
    # episode 1: none within, the lowest cost wins
    np.testing.assert_array_equal(np.asarray(choose_plan(y_r, y_c, jnp.array([2.5, 2.5]))),
                                  [2, 2])
    np.testing.assert_array_equal(np.asarray(choose_plan(y_r, y_c, jnp.array([4.0, 0.0]))),
                                  [1, 2])


def test_the_budget_falls_by_each_steps_cost(reach_avoid_data):
    cfg = tiny_config("trebi")
    agent = make_agent(cfg, 6, 2)
    hp = default_hparams(cfg)
    assert float(hp["budget"]) == 2.0  # ReachAvoid's kappa
    pp = agent.policy_params(jax.jit(agent.init)(jax.random.PRNGKey(0), hp), hp)
    obs = jnp.asarray(reach_avoid_data.observations[:3])
    mem = agent.memory_init(pp, obs)
    a, mem = jax.jit(agent.act_memory)(pp, obs, jax.random.PRNGKey(1), mem)
    chex.assert_shape(a, (3, 2))
    mem = agent.observe(pp, mem, jnp.ones(3), jnp.array([0.0, 1.5, 3.0]))
    mem = agent.observe(pp, mem, jnp.ones(3), jnp.array([1.0, 0.0, 0.0]))
    np.testing.assert_allclose(np.asarray(mem.budget), [1.0, 0.5, -1.0])


def test_value_targets_are_discounted_to_the_episode_end():
    v = np.array([1.0, 2.0, 3.0, 10.0, 20.0])
    out = to_go(v, np.array([0, 3]), np.array([3, 2]), 0.5)
    np.testing.assert_allclose(out, [1 + 0.5 * 2 + 0.25 * 3, 2 + 0.5 * 3, 3, 10 + 0.5 * 20, 20])
    # undiscounted (CDT's returns-to-go) through the same function
    np.testing.assert_allclose(to_go(v, np.array([0, 3]), np.array([3, 2])), [6, 5, 3, 30, 20])


def test_presets_and_bad_input():
    paper = make_config("BallRun", "trebi", "paper")
    assert (paper.steps, paper.horizon, paper.diffusion_steps, paper.plans, paper.guide_steps,
            paper.unet_mults) == (100_000, 32, 20, 64, 2, (1, 2, 4, 8))
    assert make_config("CarGoal2", "trebi", "paper").steps == 200_000
    quick = make_config("BallRun", "trebi", "quick")
    assert (quick.horizon, quick.diffusion_steps, quick.plans, quick.guide_steps) == (16, 5, 8, 1)
    with pytest.raises(ConfigError, match="horizon 128 is longer than an episode"):
        make_config("BallRun", "trebi", overrides={"horizon": 128})
    with pytest.raises(ConfigError, match="budget must be > 0"):
        make_config("BallRun", "trebi", overrides={"budget": 0.0})
    for k in ("guide_steps", "plans", "diffusion_steps"):
        with pytest.raises(ConfigError, match=f"{k} must be >= 1"):
            make_config("BallRun", "trebi", overrides={k: 0})
    with pytest.raises(ConfigError, match="horizon 10 must be a multiple of 4"):
        make_config("BallRun", "trebi", overrides={"horizon": 10})


@pytest.mark.parametrize("kernel,stride,padding", [(5, 1, 2), (1, 1, 0), (3, 2, 1)])
def test_the_unets_matmul_convolution_is_flaxs_convolution(kernel, stride, padding):
    """temporal_unet.Conv (one matmul of shifted windows, for the CPU's speed) has nn.Conv's
    parameters, initialisation and outputs."""
    import flax.linen as nn

    from r2pac_jax.agents.temporal_unet import Conv

    x = jax.random.normal(jax.random.PRNGKey(0), (3, 8, 6))
    ours = Conv(4, kernel, stride, padding)
    flax_conv = nn.Conv(4, (kernel,), strides=(stride,), padding=padding)
    p_ours, p_flax = ours.init(jax.random.PRNGKey(1), x), flax_conv.init(jax.random.PRNGKey(1), x)
    for a, b in zip(jax.tree_util.tree_leaves(p_ours), jax.tree_util.tree_leaves(p_flax)):
        np.testing.assert_array_equal(a, b)
    p = jax.tree_util.tree_map(lambda a: a + 0.1, p_flax)  # a non-zero bias too
    np.testing.assert_allclose(ours.apply(p, x), flax_conv.apply(p, x), rtol=1e-5, atol=1e-5)


def test_the_unets_blocks_are_named_in_the_order_they_are_applied():
    """Checkpoints and Diffuser-ported weights address blocks by name: ResidualBlock_0 is the
    first applied (it reads the window's channels), and each level's second block reads the
    first's features."""
    from r2pac_jax.agents.temporal_unet import TemporalUnet, ValueFunction

    x, t = jnp.zeros((2, 8, 5)), jnp.zeros((2,))
    for net in (TemporalUnet(transition_dim=5, dim=16, dim_mults=(1, 2)),
                ValueFunction(dim=16, dim_mults=(1, 2))):
        p = net.init(jax.random.PRNGKey(0), x, t)["params"]
        first = p["ResidualBlock_0"]["ConvBlock_0"]["Conv_0"]["kernel"].shape
        second = p["ResidualBlock_1"]["ConvBlock_0"]["Conv_0"]["kernel"].shape
        third = p["ResidualBlock_2"]["ConvBlock_0"]["Conv_0"]["kernel"].shape
        assert (first, second, third) == ((5, 5, 16), (5, 16, 16), (5, 16, 32)), type(net)

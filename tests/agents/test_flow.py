import chex
import jax
import jax.numpy as jnp

from r2pac_jax.agents import extraction, flow
from r2pac_jax.agents.selection import select_candidate
from r2pac_jax.nets import NULL_LABEL


def test_cfg_combination():
    vu = jnp.array([[1.0, -1.0]])
    vc = jnp.array([[3.0, 0.0]])
    chex.assert_trees_all_close(flow.cfg_combine(vu, vc, 2.0), jnp.array([[5.0, 1.0]]))
    chex.assert_trees_all_close(flow.cfg_combine(vu, vc, 0.0), vu)
    chex.assert_trees_all_close(flow.cfg_combine(vu, vc, 1.0), vc)


def test_euler_integrates_constant_field_exactly():
    a0 = jnp.array([[0.5, -2.0, 1.0]])
    c = jnp.array([[1.0, 3.0, -0.25]])
    out = flow.euler_sample(lambda a, i: jnp.broadcast_to(c, a.shape), a0, steps=32)
    chex.assert_trees_all_close(out, a0 + c, atol=1e-5)


def test_euler_time_grid_starts_at_zero():
    # v = i integrates to sum_n (n/N)/N = (N-1)/(2N) with the left-point Euler rule
    out = flow.euler_sample(lambda a, i: jnp.full_like(a, i), jnp.zeros((1, 1)), steps=4)
    chex.assert_trees_all_close(out, jnp.full((1, 1), (0 + 0.25 + 0.5 + 0.75) / 4))


def test_interpolate_endpoints():
    a0, a1 = jnp.zeros((2, 3)), jnp.ones((2, 3))
    chex.assert_trees_all_close(flow.interpolate(a0, a1, jnp.array([0.0, 1.0])),
                                jnp.array([[0.0] * 3, [1.0] * 3]))


def test_flow_loss_masks_padding():
    a0 = jnp.zeros((1, 3, 2))
    a1 = jnp.ones((1, 3, 2))
    v = jnp.ones((1, 3, 2)).at[0, 2].set(100.0)  # wrong only on the padded step
    mask = jnp.array([[1.0, 1.0, 0.0]])
    assert float(flow.flow_matching_loss(v, a0, a1, mask)) == 0.0
    assert float(flow.flow_matching_loss(v, a0, a1, jnp.ones((1, 3)))) > 0.0


def test_candidate_selection_min_qc_and_safe_then_reward():
    qc = jnp.array([[0.5, 0.1, 0.9], [2.0, 3.0, 1.5]])
    qr = jnp.array([[1.0, 0.0, 5.0], [9.0, 1.0, 0.0]])
    chex.assert_trees_all_equal(select_candidate(qc, qr, 0.6, "min_qc"), jnp.array([1, 2]))
    # row 0: candidates 0, 1 are under l=0.6, the better reward is 0; row 1: none -> min Q_c
    chex.assert_trees_all_equal(select_candidate(qc, qr, 0.6, "safe_then_reward"),
                                jnp.array([0, 2]))
    chex.assert_trees_all_equal(select_candidate(qc, qr, 0.6, "first"), jnp.array([0, 0]))


def test_optimality_labels_follow_region():
    safe = jnp.array([True, True, False, False])
    adv_r = jnp.array([1.0, -1.0, 1.0, -1.0])
    adv_c = jnp.array([1.0, -1.0, 1.0, -1.0])
    # safe: 1[adv_r >= 0]; unsafe: 1[adv_c <= 0]
    chex.assert_trees_all_equal(extraction.optimality_labels(safe, adv_r, adv_c),
                                jnp.array([1, 0, 0, 1]))
    # w/o V_c: the reward advantage everywhere
    chex.assert_trees_all_equal(extraction.optimality_labels(safe, adv_r, adv_c, False),
                                jnp.array([1, 0, 1, 0]))


def test_label_dropout_rate():
    labels = jnp.ones((20000,), jnp.int32)
    out = extraction.drop_labels(jax.random.PRNGKey(0), labels, 0.1)
    frac = float((out == NULL_LABEL).mean())
    assert 0.09 < frac < 0.11
    assert set(map(int, jnp.unique(out))) == {1, NULL_LABEL}


def test_awr_weights_clip_and_branch():
    safe = jnp.array([True, False])
    w = extraction.awr_weights(safe, jnp.array([10.0, 10.0]), jnp.array([-0.1, -0.1]), 6.0, 100.0)
    chex.assert_trees_all_close(w, jnp.array([100.0, jnp.exp(0.6)]), rtol=1e-5)

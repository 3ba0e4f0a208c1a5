"""CDT (OSRL's Constrained Decision Transformer): the sequence view, the Pareto augmentation,
the network's causality, the loss terms on hand-made cases, and the policy's memory."""
import warnings

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import tiny_config, toy_arrays
from r2pac_jax.agents import cdt, make_agent
from r2pac_jax.agents.decision_transformer import DecisionTransformer
from r2pac_jax.agents.gaussian import entropy as gaussian_entropy
from r2pac_jax.agents.gaussian import log_prob as gaussian_log_prob
from r2pac_jax.config import ConfigError, default_hparams, make_config
from r2pac_jax.data import sequences
from r2pac_jax.data.dsrl import validate
from r2pac_jax.tasks import get_task

def _toy(episodes=((4, "timeout"), (3, "terminal"), (5, "timeout"))):
    return validate(toy_arrays(episodes), "toy")


def test_to_go_sums_each_episode_to_its_end():
    ds = _toy()
    starts, lengths, ret, cost = sequences.episode_table(ds)
    rtg = sequences.to_go(ds.rewards, starts, lengths)
    np.testing.assert_allclose(rtg[starts], ret, rtol=1e-6)
    ends = starts + lengths - 1
    np.testing.assert_allclose(rtg[ends], ds.rewards[ends], rtol=1e-6)
    np.testing.assert_allclose(rtg[1], ds.rewards[1:4].sum(), rtol=1e-6)


def test_windows_pad_past_the_episode_end_and_carry_time_steps():
    ds = _toy()
    data = sequences.build_sequences(ds, cost_weight_base=None)
    b = sequences.sample(data, jax.random.PRNGKey(0), 256, 3, reward_scale=0.1, cost_scale=2.0)
    starts, lengths, _, _ = sequences.episode_table(ds)
    rtg = sequences.to_go(ds.rewards, starts, lengths)
    ctg = sequences.to_go(ds.costs, starts, lengths)
    obs = np.asarray(ds.observations)
    for i in range(256):
        t0 = int(b.time_steps[i, 0])
        # find the episode from the first state
        row = int(np.flatnonzero((obs == np.asarray(b.states[i, 0])).all(1))[0])
        ep = int(np.searchsorted(starts, row, side="right") - 1)
        assert row - starts[ep] == t0
        np.testing.assert_array_equal(np.asarray(b.time_steps[i]), t0 + np.arange(3))
        valid = t0 + np.arange(3) < lengths[ep]
        np.testing.assert_array_equal(np.asarray(b.mask[i]) > 0, valid)
        n = int(valid.sum())
        np.testing.assert_allclose(np.asarray(b.states[i, :n]), obs[row:row + n])
        assert not np.asarray(b.states[i, n:]).any() and not np.asarray(b.actions[i, n:]).any()
        np.testing.assert_allclose(np.asarray(b.returns_to_go[i, :n]), 0.1 * rtg[row:row + n],
                                   rtol=1e-5)
        np.testing.assert_allclose(np.asarray(b.costs_to_go[i, :n]), 2.0 * ctg[row:row + n],
                                   rtol=1e-5)
    # every start index of every episode is drawn
    assert set(np.asarray(b.time_steps[:, 0]).tolist()) == set(range(int(lengths.max())))


def test_cost_weighted_sampling_never_draws_an_episode_at_or_above_the_base():
    ds = _toy()
    _, _, _, cost = sequences.episode_table(ds)
    base = float(np.sort(cost)[1])  # the cheapest episode only stays below the base
    data = sequences.build_sequences(ds, cost_weight_base=base)
    probs = np.exp(np.asarray(data.ep_logits))
    np.testing.assert_allclose(probs[cost >= base], 0.0)
    assert probs.sum() == pytest.approx(1.0, rel=1e-5)
    with pytest.raises(ValueError, match="cost_sample=false"):
        sequences.build_sequences(ds, cost_weight_base=float(cost.min()))


def test_pareto_front_and_grid_filter_on_hand_made_points():
    c = np.array([0.0, 1.0, 1.0, 2.0, 3.0, 0.5])
    r = np.array([1.0, 3.0, 2.0, 3.0, 5.0, 0.5])
    # (1, 2) is dominated by (1, 3); (2, 3) by (1, 3); (0.5, 0.5) by (0, 1)
    assert sorted(sequences.pareto_front(c, r).tolist()) == [0, 1, 4]
    rng = np.random.default_rng(0)
    x = np.array([0.0] * 5 + [1.0] * 2 + [2.0] * 12)
    y = np.zeros(x.size)
    kept = sequences.grid_filter(x, y, 2, 1, max_per_bin=10, min_per_bin=2, rng=rng)
    # bins: x in [0, 1) holds 5 (kept), [1, 2) holds 2 (<= 2: dropped), the max (2.0) 12 (10 kept)
    assert sorted(kept.tolist())[:5] == [0, 1, 2, 3, 4]
    assert len(kept) == 15 and not {5, 6} & set(kept.tolist())


def test_augmented_episodes_relabel_a_cheaper_episode_toward_the_frontier():
    rng = np.random.default_rng(1)
    cost = rng.uniform(0, 60, 400)
    ret = 10 + cost + rng.normal(0, 3, 400)  # more cost buys more return
    src, tc, tr = sequences.augment(cost, ret, deg=1, max_rew_decrease=20.0, beta=1.0,
                                    augment_percent=0.2, max_reward=90.0, min_reward=1.0,
                                    rng=np.random.default_rng(0))
    assert src.size == tc.size == tr.size > 0
    assert tc.min() >= cost.min() - 1e-9 and tc.max() <= cost.max() + 1e-9
    assert np.all(tr <= 90.0 + 1e-9)
    # the first source of a target is the nearest episode of no greater cost (before regrouping)
    assert np.all(cost[src] <= tc.max() + 1e-9)


def test_augmentation_draws_between_a_frontier_above_max_reward_and_max_reward():
    """OSRL's legacy np.random.uniform takes low > high; ours must too (AntVelocity's data put
    the frontier plus min_reward above max_reward and Generator.uniform refused it)."""
    rng = np.random.default_rng(1)
    cost = rng.uniform(0, 60, 400)
    ret = 10 + cost + rng.normal(0, 3, 400)
    kw = dict(deg=1, max_rew_decrease=20.0, beta=1.0, augment_percent=0.2, min_reward=1.0)
    src, tc, tr = sequences.augment(cost, ret, max_reward=40.0, rng=np.random.default_rng(0), **kw)
    assert src.size == tc.size == tr.size > 0
    # the frontier is about 10 + c (+ noise), so low = frontier + 1 lies below 40 for costs
    # under 20 (draws in [low, 40]) and above it beyond 45 (draws in [40, low])
    assert (tc < 20).any() and np.all(tr[tc < 20] <= 40.0 + 1e-9)
    assert (tc > 45).any() and np.all(tr[tc > 45] >= 40.0 - 1e-9)
    # the same draws as before this fix wherever low <= high: Generator.uniform is low +
    # (high - low) u with u from rng.random, so one stream gives both
    low, u = np.linspace(0.0, 1.0, 7), np.random.default_rng(5)
    assert np.array_equal(np.random.default_rng(5).uniform(low, 2.0, 7),
                          low + (2.0 - low) * u.random(7))


def test_augmented_rows_are_their_sources_with_shifted_targets():
    ds = validate(toy_arrays(tuple((4 + i % 3, "timeout") for i in range(60))), "toy60")
    starts, lengths, ret, cost = sequences.episode_table(ds)
    aug = dict(deg=1, max_rew_decrease=5.0, beta=1.0, augment_percent=0.5,
               max_reward=float(ret.max()) + 2, min_reward=0.1)
    data = sequences.build_sequences(ds, augmentation=aug, cost_weight_base=None, seed=3)
    m = starts.size
    n_aug = int(data.ep_len.shape[0]) - m
    assert n_aug > 0
    shift_r = np.asarray(data.ep_return_shift)
    assert not shift_r[:m].any()
    for j in range(m, m + n_aug):
        st = int(data.ep_start[j])
        src = int(np.flatnonzero(starts == st)[0])
        assert int(data.ep_len[j]) == lengths[src]
        # the relabelled episode's return-to-go at its first step is the target
        r0 = float(data.returns_to_go[st]) + shift_r[j]
        assert r0 == pytest.approx(ret[src] + shift_r[j], rel=1e-5)


def test_network_is_causal():
    net = DecisionTransformer(3, 2, 4, 20, 16, 2, 2, 0.0, 0.0, 0.0)
    key = jax.random.PRNGKey(0)
    ks = jax.random.split(key, 5)
    s, a = jax.random.normal(ks[0], (2, 4, 3)), jax.random.normal(ks[1], (2, 4, 2))
    r, c = jax.random.normal(ks[2], (2, 4)), jax.random.normal(ks[3], (2, 4))
    t = jnp.tile(jnp.arange(4), (2, 1))
    p = net.init(ks[4], s, a, r, c, t)
    apply = jax.jit(net.apply)
    out = apply(p, s, a, r, c, t)
    # a changed action at step 2 changes no prediction made from step 2's state or before
    out2 = apply(p, s, a.at[:, 2].add(5.0), r, c, t)
    np.testing.assert_allclose(out2[0][:, :3], out[0][:, :3], atol=1e-6)
    assert not np.allclose(out2[0][:, 3], out[0][:, 3])
    # the action token of step 2 feeds the cost prediction of step 2
    assert not np.allclose(out2[2][:, 2], out[2][:, 2])


def test_gaussian_terms_match_closed_forms():
    x, mu, ls = jnp.array([0.3]), jnp.array([-0.2]), jnp.array([np.log(0.5)])
    want = -0.5 * (0.5 / 0.5) ** 2 - np.log(0.5) - 0.5 * np.log(2 * np.pi)
    assert float(gaussian_log_prob(x, mu, ls)[0]) == pytest.approx(want, rel=1e-6)
    assert float(gaussian_entropy(ls)[0]) == pytest.approx(
        0.5 * np.log(2 * np.pi * np.e * 0.25), rel=1e-6)


def _agent(reach_avoid_data, **kw):
    task = get_task("ReachAvoid")
    cfg = tiny_config("cdt", **kw)  # conftest.TINY holds CDT's tiny network
    agent = make_agent(cfg, task.obs_dim, task.act_dim)
    hp = default_hparams(cfg)
    state = agent.init(jax.random.PRNGKey(0), hp)
    data = agent.make_data(task, reach_avoid_data)
    return task, cfg, agent, hp, agent.begin_block(state, hp, data), data


def test_padding_changes_no_loss_term(reach_avoid_data):
    _, cfg, agent, hp, state, data = _agent(reach_avoid_data)
    b = agent.sample(data, jax.random.PRNGKey(1))
    pad = b.mask == 0
    assert pad.any()
    noisy = b._replace(states=jnp.where(pad[..., None], 7.0, b.states),
                       actions=jnp.where(pad[..., None], 0.9, b.actions),
                       returns_to_go=jnp.where(pad, 3.0, b.returns_to_go),
                       cost_labels=jnp.where(pad, 1, b.cost_labels))
    p = state.params
    key = jax.random.PRNGKey(2)
    losses = jax.jit(agent.losses)
    _, aux1 = losses(p["model"], p["log_temperature"], b, key)
    _, aux2 = losses(p["model"], p["log_temperature"], noisy, key)
    for k in ("nll", "entropy", "loss_cost", "cost_acc"):
        assert float(aux1[k]) == pytest.approx(float(aux2[k]), rel=1e-5, abs=1e-6), k


@pytest.mark.slow
def test_temperature_moves_toward_the_target_entropy(reach_avoid_data):
    _, cfg, agent, hp, state, data = _agent(reach_avoid_data)
    b = agent.sample(data, jax.random.PRNGKey(1))
    new, m = jax.jit(agent.update, static_argnums=3)(state, b, hp, "actor")
    # entropy (about 1.4 per dimension at init) exceeds the target -act_dim: temperature falls
    assert float(m["entropy"]) > agent.target_entropy
    assert float(new.params["log_temperature"]) < float(state.params["log_temperature"])
    off = tiny_config("cdt", entropy_reg=False)
    agent2 = make_agent(off, 6, 2)
    new2, _ = jax.jit(agent2.update, static_argnums=3)(state, b, hp, "actor")
    assert float(new2.params["log_temperature"]) == float(state.params["log_temperature"])


def test_memory_acts_as_the_truncated_window_does(reach_avoid_data):
    """OSRL feeds states[:t + 1][-K:] (a shorter window at first); our fixed window with the
    newest entry at min(t, K - 1) gives the same actions and lowers the targets as it does."""
    task, cfg, agent, hp, state, _ = _agent(reach_avoid_data, seq_len=3)
    pp = agent.policy_params(state, hp)
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(6, 2, task.obs_dim)).astype(np.float32)
    rew = rng.normal(size=(6, 2)).astype(np.float32)
    cost = (rng.uniform(size=(6, 2)) < 0.5).astype(np.float32)
    mem = agent.memory_init(pp, jnp.asarray(obs[0]))
    act_memory, observe, apply = (jax.jit(agent.act_memory), jax.jit(agent.observe),
                                  jax.jit(agent.net.apply))
    hist_s, hist_a, hist_r, hist_c = [], [], [], []
    r_next = np.full(2, float(pp["target_return"]) * cfg.reward_scale)
    c_next = np.full(2, float(pp["target_cost"]) * cfg.cost_scale)
    for t in range(6):
        a, mem = act_memory(pp, jnp.asarray(obs[t]), jax.random.PRNGKey(t), mem)
        hist_s.append(obs[t])
        hist_a.append(np.zeros((2, task.act_dim), np.float32))
        hist_r.append(r_next)
        hist_c.append(c_next)
        lo = max(0, t + 1 - 3)
        win = [np.stack(h[lo:], 1) for h in (hist_s, hist_a, hist_r, hist_c)]
        ts = np.tile(np.arange(lo, t + 1), (2, 1))
        mu = apply(pp["model"], *[jnp.asarray(w) for w in win], jnp.asarray(ts))[0]
        np.testing.assert_allclose(np.asarray(a), np.clip(np.asarray(mu[:, -1]), -1, 1),
                                   atol=1e-5)
        hist_a[-1] = np.asarray(a)
        mem = observe(pp, mem, jnp.asarray(rew[t]), jnp.asarray(cost[t]))
        r_next = r_next - rew[t] * cfg.reward_scale
        c_next = c_next - cost[t] * cfg.cost_scale
        np.testing.assert_allclose(np.asarray(mem.next_rtg), r_next, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(np.asarray(mem.next_ctg), c_next, rtol=1e-5, atol=1e-6)
    chex.assert_shape(mem.states, (2, 3, task.obs_dim))


def test_targets_come_from_the_data_and_the_task(reach_avoid_data):
    task, cfg, agent, hp, state, data = _agent(reach_avoid_data)
    ret, cost = reach_avoid_data.episode_sums()
    assert float(state.target_return) == pytest.approx(float(ret[cost <= task.kappa].max()))
    pp = agent.policy_params(state, hp)
    assert float(pp["target_cost"]) == task.kappa
    fixed = tiny_config("cdt", target_rule="value", target_return=12.5)
    a2 = make_agent(fixed, task.obs_dim, task.act_dim)
    assert float(a2.make_data(task, reach_avoid_data).target_return) == 12.5


def test_augmentation_constants_follow_the_task_and_the_data():
    spec = get_task("CarGoal1")
    v = cdt.task_values(spec)
    deg, max_r, dec, min_r = cdt.OSRL_AUGMENTATION[spec.dsrl_id]
    span = spec.r_max - spec.r_min
    assert v["aug_deg"] == deg and v["aug_max_reward"] == pytest.approx((max_r - spec.r_min) / span)
    cfg = make_config("CarGoal1", "cdt", "quick")
    vals = cdt.augmentation_values(cfg, np.array([2.0, 12.0]))
    assert vals["max_reward"] == pytest.approx(2.0 + 10.0 * cfg.aug_max_reward)
    assert vals["max_rew_decrease"] == pytest.approx(10.0 * dec / span)


def test_bad_input_is_named(reach_avoid_data):
    task = get_task("ReachAvoid")
    with pytest.raises(ConfigError, match="multiple of num_heads"):
        tiny_config("cdt", embedding_dim=10, num_heads=4)
    with pytest.raises(ConfigError, match="target_rule"):
        tiny_config("cdt", target_rule="best")
    with pytest.raises(ConfigError, match="seq_len"):
        tiny_config("cdt", seq_len=100)  # ReachAvoid's episodes are 80 steps
    # a file whose episode ends are not flagged: one 'episode' runs past the task's length
    arr = {k: np.asarray(v) for k, v in reach_avoid_data.as_dict().items()}
    n = 200
    arr = {k: v[:n].copy() for k, v in arr.items()}
    arr["timeouts"][:] = False
    arr["terminals"][:] = False
    arr["terminals"][-1] = True
    arr["next_observations"][:-1] = arr["observations"][1:]
    long = validate(arr, "unflagged")
    agent = make_agent(tiny_config("cdt"), task.obs_dim, task.act_dim)
    with pytest.raises(ConfigError, match="timeouts"):
        agent.check_data(task, long)
    odd = make_agent(tiny_config("cdt", target_rule="value", target_return=1e6),
                     task.obs_dim, task.act_dim)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        odd.check_data(task, reach_avoid_data)
    assert any("target_return" in str(x.message) for x in w)


@pytest.mark.slow  # a Run with evaluation (~1 min); the default suite trains cdt in test_train
def test_a_finished_cdt_run_loads_as_a_policy_with_memory(reach_avoid_data, tmp_path):
    import r2pac_jax
    from r2pac_jax.lanes import Lanes
    from r2pac_jax.loop import Run

    task = get_task("ReachAvoid")
    cfg = tiny_config("cdt", steps=10, eval_every=10, checkpoint_every=10, block_steps=10)
    res = Run(cfg, task, reach_avoid_data, tmp_path / "run", Lanes.build(cfg, [0]),
              progress=False, log=lambda m: None).run()
    assert np.isfinite(res["normalized_reward"]["mean"])
    act = r2pac_jax.load_policy(tmp_path / "run")
    obs = jnp.asarray(reach_avoid_data.observations[:4])
    mem = act.init(obs)
    a, mem = act(obs, jax.random.PRNGKey(0), mem)
    chex.assert_shape(a, (4, task.act_dim))
    mem = act.observe(mem, jnp.ones(4), jnp.zeros(4))
    assert int(mem.t[0]) == 1
    ret, cost = reach_avoid_data.episode_sums()
    best = float(ret[cost <= task.kappa].max())
    np.testing.assert_allclose(np.asarray(mem.next_rtg), (best - 1.0) * cfg.reward_scale,
                               rtol=1e-5)


def test_a_one_episode_frontier_fits_a_constant():
    """OSRL's polyfit fails when the grid-filtered Pareto frontier is one episode (CarGoal1 v2:
    a safe episode of return 37.9 dominates every kept one); ours fits the frontier's degree to
    its points (one point: a constant) and still draws targets above it."""
    cost = np.array([0.0] * 3 + [10.0] * 3 + [20.0] * 3)
    ret = np.array([30.0] * 3 + [10.0] * 3 + [20.0] * 3)
    src, tc, tr = sequences.augment(cost, ret, deg=1, max_rew_decrease=50.0, beta=1.0,
                                    augment_percent=1.0, max_reward=40.0, min_reward=1.0,
                                    rng=np.random.default_rng(0))
    assert src.size == 9 and np.all(np.isfinite(tr))
    assert np.all(tr >= 31.0 - 1e-9)  # above the constant frontier (30) + min_reward

"""R2PAC's diagnostics (where its reward goes): training metrics, evaluation statistics of its
candidate choice and of how episodes end, their place in a run's files, and the evaluate CLI's
side-by-side selection rules. None consumes a random key: scores are the same without them."""
import json

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import tiny_config

from r2pac_jax.agents import diagnostics as dg
from r2pac_jax.tasks import get_task

TASK = get_task("ReachAvoid")


def test_masked_statistics_by_hand():
    x = jnp.array([1.0, 2.0, 3.0, 10.0])
    m = jnp.array([True, True, True, False])
    assert float(dg.masked_mean(x, m)) == pytest.approx(2.0)
    assert float(dg.masked_mean(x, jnp.zeros(4, bool))) == 0.0  # empty: 0, not NaN
    y = jnp.array([2.0, 4.0, 6.0, -50.0])  # y = 2x on the mask, an outlier off it
    assert float(dg.masked_corr(x, y, m)) == pytest.approx(1.0, abs=1e-6)
    assert float(dg.masked_corr(x, -y, m)) == pytest.approx(-1.0, abs=1e-6)
    assert float(dg.masked_corr(x, jnp.ones(4), m)) == 0.0  # no spread: undefined -> 0
    assert float(dg.rmse(jnp.array([[1.0, 1.0], [3.0, 3.0]]), jnp.array([2.0, 2.0]))) == 1.0


def test_candidate_stats_by_hand():
    qc = jnp.array([[0.5, 0.1, 0.9], [0.2, 0.2, 0.2]])
    qr = jnp.array([[3.0, 1.0, 5.0], [2.0, 4.0, 1.0]])
    s = dg.candidate_stats(qc, qr, jnp.array([1, 0]))
    np.testing.assert_allclose(s["qc_spread"], [0.8, 0.0], atol=1e-6)
    np.testing.assert_allclose(s["qr_spread"], [4.0, 3.0])
    np.testing.assert_allclose(s["qr_given_up"], [4.0, 2.0])  # best 5 - chosen 1; 4 - 2
    np.testing.assert_allclose(s["not_first"], [1.0, 0.0])


def test_label_balance_splits_into_its_safe_and_unsafe_parts():
    """label_balance = safe share x balance in safe states + unsafe share x in unsafe ones."""
    o = jnp.array([1, 0, 1, 1, 0, 0, 1], jnp.float32)
    safe = jnp.array([True, True, False, True, False, False, True])
    share = float(safe.mean())
    whole = share * float(dg.masked_mean(o, safe)) + (1 - share) * float(
        dg.masked_mean(o, ~safe))
    assert whole == pytest.approx(float(o.mean()))


def test_training_logs_the_fit_the_labels_and_the_advantage_reward_correlation(tiny_run):
    """metrics.jsonl of the session's tiny r2pac run (block means of each step's values)."""
    rows = [json.loads(x) for x in (tiny_run["run"] / "metrics.jsonl").read_text().splitlines()]
    critic = [r for r in rows if r["phase"] == "critic"]
    actor = [r for r in rows if r["phase"] == "actor"]
    assert critic and actor
    for r in critic:
        for k in ("qr_rmse_penalised", "qr_rmse_unpenalised", "chunk_reward_std", "vc_min"):
            assert np.isfinite(r[k]), k
        assert r["qr_rmse_penalised"] > 0 and r["chunk_reward_std"] > 0
    for r in actor:
        for k in ("label_balance_safe", "label_balance_unsafe"):
            assert 0.0 <= r[k] <= 1.0
        assert -1.0 <= r["corr_adv_r_reward_safe"] <= 1.0
        assert "qr_rmse_penalised" not in r  # the critics are not trained in this phase


def test_without_the_penalty_both_fits_are_the_same_number(reach_avoid_data):
    """r2pac-no-penalty's Qbar_r targets are the plain ones: the two RMSEs must coincide."""
    from r2pac_jax.lanes import Lanes
    from r2pac_jax.loop import compiled, make_data

    cfg = tiny_config("r2pac-no-penalty")
    _, init, blocks, _ = compiled(cfg, TASK.obs_dim, TASK.act_dim)
    ln = Lanes.build(cfg, [0])
    _, m, _ = blocks["critic"](init(ln.init_keys(), ln.hp), ln.hp,
                               make_data(cfg, TASK, reach_avoid_data))
    assert float(m["qr_rmse_penalised"][0]) == pytest.approx(float(m["qr_rmse_unpenalised"][0]),
                                                             rel=1e-6)


def _policy_state(algo="r2pac", **kw):
    from r2pac_jax.lanes import Lanes
    from r2pac_jax.loop import compiled, diagnostic_params

    cfg = tiny_config(algo, **kw)
    agent, init, _, policy_params = compiled(cfg, TASK.obs_dim, TASK.act_dim)
    ln = Lanes.build(cfg, [0, 1])
    state = init(ln.init_keys(), ln.hp)
    return cfg, agent, policy_params(state, ln.hp), diagnostic_params(
        cfg, TASK.obs_dim, TASK.act_dim)(state, ln.hp)


def test_act_info_acts_bit_for_bit_as_act_under_every_rule(tiny_run):
    """Eagerly (no compile per rule): the same action, and the statistics each rule has."""
    from r2pac_jax.agents import make_agent

    cfg, _, _, dp = _policy_state()
    one = jax.tree_util.tree_map(lambda x: x[0], dp)
    obs = jax.random.normal(jax.random.PRNGKey(1), (16, TASK.obs_dim))
    key = jax.random.PRNGKey(2)
    for selection in ("min_qc", "safe_then_reward", "first"):
        agent = make_agent(cfg.replace(selection=selection), TASK.obs_dim, TASK.act_dim)
        a = agent.act(one, obs, key)
        b, info = agent.act_info(one, obs, key)
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
        assert all(v.shape == (16,) for v in info.values())
        if selection == "first":  # one candidate: nothing to choose among, nothing reported
            assert set(info) == {"unsafe_state"}
            assert agent.diagnostics_note() == ("candidate statistics skipped: selection=first "
                                                "draws one candidate")
        else:
            assert set(info) == {"unsafe_state", "qc_spread", "qr_spread", "qr_given_up",
                                 "not_first"}
            assert agent.diagnostics_note() is None


def test_diagnostics_change_no_score_and_python_stepping_reports_the_same(tiny_run):
    """Evaluation with diagnostics scores every episode as without them (bit for bit), and the
    C-MuJoCo path (a Python loop over steps) accumulates them as the JAX rollout does."""
    from test_evaluate import _ViaPython

    from r2pac_jax.envs import reach_avoid as ra
    from r2pac_jax.evaluate import LaneEvaluator, policy_of

    from r2pac_jax.loop import lane_evaluator

    cfg, agent, pp, dp = _policy_state()
    keys = jnp.stack([jax.random.PRNGKey(7), jax.random.PRNGKey(8)])
    env = ra.ReachAvoidEnv()
    # the run's own evaluators (compiled by the session's tiny run in this process)
    plain = lane_evaluator(cfg, TASK, 2, "auto", False)(pp, keys)
    diag = lane_evaluator(cfg, TASK, 2, "auto", True)(dp, keys)
    for k in ("returns", "costs", "lengths", "terminals"):
        np.testing.assert_array_equal(plain[k], diag[k])
    assert plain["diagnostics"] == {}
    d = diag["diagnostics"]
    assert set(d) == {"unsafe_state", "qc_spread", "qr_spread", "qr_given_up", "not_first"}
    assert ((0 <= d["unsafe_state"]) & (d["unsafe_state"] <= 1)).all()
    assert (d["qc_spread"] >= 0).all() and (d["qr_given_up"] >= 0).all()
    assert (d["qr_given_up"] <= d["qr_spread"] + 1e-6).all()
    assert ((0 <= d["not_first"]) & (d["not_first"] <= 1)).all()
    py = LaneEvaluator(policy_of(agent, True), TASK, 2, env=_ViaPython(env))(dp, keys)
    np.testing.assert_array_equal(diag["lengths"], py["lengths"])
    np.testing.assert_array_equal(diag["terminals"], py["terminals"])
    for k in d:
        np.testing.assert_allclose(d[k], py["diagnostics"][k], rtol=1e-4, atol=1e-4)


def test_terminals_are_told_from_the_time_limit():
    """Driving straight out of the arena ends every episode by a true terminal; standing still
    ends every one at the time limit."""
    from r2pac_jax.evaluate import LaneEvaluator

    out_east = LaneEvaluator(lambda p, obs, k: jnp.tile(jnp.array([1.0, 0.0]), (obs.shape[0], 1)),
                             TASK, 3)({"x": jnp.zeros(1)}, jnp.stack([jax.random.PRNGKey(0)]))
    assert out_east["terminals"].all() and (out_east["lengths"] < TASK.make_env().episode_len
                                            ).all()
    assert out_east["terminal_share"][0] == 1.0
    still = LaneEvaluator(lambda p, obs, k: jnp.zeros((obs.shape[0], 2)), TASK, 3)(
        {"x": jnp.zeros(1)}, jnp.stack([jax.random.PRNGKey(0)]))
    assert not still["terminals"].any() and still["terminal_share"][0] == 0.0
    chex.assert_trees_all_equal(still["mean_length"], np.array([80.0]))


def test_a_run_logs_them_in_its_files(tiny_run):
    """eval.jsonl, results.json and eval.png of the session's tiny r2pac run."""
    run = tiny_run["run"]
    rows = [json.loads(x) for x in (run / "eval.jsonl").read_text().splitlines()]
    for k in ("mean_length", "terminal_share", "unsafe_state", "not_first", "qr_given_up",
              "qc_spread", "qr_spread"):
        assert all(k in r and np.isfinite(r[k]) for r in rows), k
    metrics = [json.loads(x) for x in (run / "metrics.jsonl").read_text().splitlines()]
    assert all("qr_rmse_unpenalised" in r for r in metrics if r["phase"] == "critic")
    assert all("corr_adv_r_reward_safe" in r for r in metrics if r["phase"] == "actor")
    res = json.loads((run / "results.json").read_text())
    assert len(res["terminal_share"]["per_seed"]) == 2
    assert set(res["diagnostics"]) >= {"unsafe_state", "not_first", "qr_given_up"}
    assert len(res["diagnostics"]["not_first"]["per_seed"]) == 2


def test_evaluate_sets_the_three_selection_rules_side_by_side(tiny_run, capsys):
    from r2pac_jax.evaluate import main

    assert main([str(tiny_run["run"]), "--episodes", "2"]) == 0
    out = capsys.readouterr().out
    table = [ln for ln in out.splitlines() if ln.startswith("| ")]
    assert table[0].startswith("| selection | reward | cost | ended by a terminal")
    rules = [ln.split("|")[1].strip() for ln in table[1:]]
    assert rules == ["min_qc (trained)", "safe_then_reward", "first"]
    first = table[-1].split("|")
    assert first[-2].strip() == "-"  # one candidate: no spread to report


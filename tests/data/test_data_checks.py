"""The dataset checks (coverage, temptation, imitability) and the CLI around them."""
import json

import numpy as np
import pytest

from r2pac_jax import imitability as checks  # the full checks (cloners trained)
from r2pac_jax.data import checks as data_checks  # coverage, the file's record
from r2pac_jax.data.dsrl import validate, write_dsrl
from r2pac_jax.tasks import get_task


def _episodes(returns, costs, length=80, obs_dim=6, act_dim=2, seed=0):
    """ReachAvoid-shaped episodes with the given per-episode return and cost sums."""
    rng = np.random.default_rng(seed)
    parts = {k: [] for k in ("observations", "next_observations", "actions", "rewards", "costs",
                             "terminals", "timeouts")}
    for r, c in zip(returns, costs):
        obs = rng.normal(size=(length + 1, obs_dim)).astype(np.float32)
        parts["observations"].append(obs[:-1])
        parts["next_observations"].append(obs[1:])
        parts["actions"].append(rng.uniform(-1, 1, (length, act_dim)).astype(np.float32))
        parts["rewards"].append(np.full(length, r / length, np.float32))
        cost = np.zeros(length, np.float32)
        cost[:int(c)] = 1.0
        parts["costs"].append(cost)
        parts["terminals"].append(np.zeros(length, bool))
        t = np.zeros(length, bool)
        t[-1] = True
        parts["timeouts"].append(t)
    return validate({k: np.concatenate(v) for k, v in parts.items()}, "synthetic")


def test_coverage_values_and_verdicts():
    task = get_task("ReachAvoid")  # r in [0, 40], kappa 2
    ds = _episodes([0.0, 10.0, 20.0, 38.0, 39.0], [0, 1, 3, 6, 7])
    cov = data_checks.coverage(task, ds)
    assert cov["best_normalised_return"] == pytest.approx(39 / 40, rel=1e-5)
    assert cov["worst_normalised_return"] == pytest.approx(0.0, abs=1e-6)
    assert cov["max_episode_cost"] == 7.0 and cov["safe_share"] == pytest.approx(0.4)
    assert all(cov["pass"].values())
    # the best safe episode is 10 / 40; the best overall 39 / 40
    assert cov["temptation"] == pytest.approx(29 / 40, rel=1e-5)
    narrow = data_checks.coverage(task, _episodes([20.0, 21.0, 22.0], [0, 0, 5]))
    assert not narrow["pass"]["best_return"] and not narrow["pass"]["worst_return"]
    assert not narrow["pass"]["max_cost"]  # 5 < 3 kappa = 6
    assert narrow["pass"]["safe_share"] and narrow["pass"]["unsafe_share"]


def test_fast_check_writes_its_file_and_names_what_failed(tmp_path, capsys):
    from r2pac_jax.data.__main__ import main

    path = tmp_path / "d.hdf5"
    write_dsrl(path, _episodes([20.0, 21.0, 22.0], [0, 0, 5]), attrs={"task": "ReachAvoid"})
    assert main(["check", str(path), "--fast"]) == 0
    out = capsys.readouterr().out
    res = json.loads(data_checks.checks_path(path).read_text())
    assert res["task"] == "ReachAvoid" and res["fast"] and not res["passed"]
    assert res["failed"] == ["best_return", "max_cost", "worst_return"]
    assert "failed: best_return, max_cost, worst_return" in out
    (tmp_path / "x.hdf5").write_text("not hdf5")  # named as damaged, as `train` names it
    assert main(["check", str(tmp_path / "x.hdf5")]) == 2
    assert "x.hdf5: cannot be read as HDF5" in capsys.readouterr().err


@pytest.mark.slow
def test_imitability_trains_the_three_cloners(tmp_path, reach_avoid_data):
    path = tmp_path / "ra.hdf5"
    write_dsrl(path, reach_avoid_data, attrs={"task": "ReachAvoid"})
    tiny = dict(steps=20, batch_size=32, hidden_dims=(16, 16), block_steps=10,
                eval_every=10, checkpoint_every=10, flow_steps=4, eval_episodes=2)
    res = checks.check_file(path, seeds=(100, 101), overrides=tiny, log=lambda m: None)
    imi = res["imitability"]
    assert set(imi) >= set(checks.IMITATORS)
    for algo in checks.IMITATORS:
        assert len(imi[algo]["normalized_cost"]["per_seed"]) == 2
        assert imi[algo]["eval_backend"] == "jax"  # ReachAvoid: the pure-JAX env scored it
    assert imi["eval_backend"] == "jax"
    flags = imi["pass"]
    assert set(flags) == {"bc-safe_safe", "bc-safe_return", "bc-safe-mlp_safe",
                          "bc-safe-mlp_return", "bc-all-mlp_cost_matches_data"}
    c = imi["bc-all-mlp"]["normalized_cost"]["mean"]
    d = res["coverage"]["mean_normalised_cost"]
    assert flags["bc-all-mlp_cost_matches_data"] == (abs(c - d) <= 0.25 * d)
    assert res["passed"] == (not res["failed"])


def test_a_file_without_safe_episodes_fails_the_safe_cloners_by_name(tmp_path):
    """No episode within kappa (a learner that never met the limit): the checks file is still
    written, the safe cloners are not trained and their checks fail with the reason."""
    path = tmp_path / "unsafe.hdf5"
    write_dsrl(path, _episodes([10.0, 20.0, 30.0, 39.0], [3, 5, 6, 9]),
               attrs={"task": "ReachAvoid"})  # kappa 2: none safe
    tiny = dict(steps=10, batch_size=32, hidden_dims=(16,), block_steps=10, eval_every=10,
                checkpoint_every=10, eval_episodes=2)
    res = checks.check_file(path, seeds=(100,), overrides=tiny, log=lambda m: None)
    imi = res["imitability"]
    assert imi["bc-safe"] == imi["bc-safe-mlp"] == {"skipped": "no episode with cost <= kappa = 2"}
    assert {"safe_share", "bc-safe_safe", "bc-safe_return", "bc-safe-mlp_safe",
            "bc-safe-mlp_return"} <= set(res["failed"])
    assert "normalized_cost" in imi["bc-all-mlp"]  # the all-data cloner still trains
    assert json.loads(data_checks.checks_path(path).read_text())["failed"] == res["failed"]

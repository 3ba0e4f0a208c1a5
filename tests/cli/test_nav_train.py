"""Training and evaluation on a navigation task end to end (slow: about 2-4 min on 2 cores).

The dataset is made here from random-action episodes of our own CarGoal2 environment, written in
DSRL's format with the library's writer, so the test needs neither DSRL's files nor a network.
"""
import json

import jax
import numpy as np
import pytest


def random_episodes(name: str, episodes: int, seed: int = 0) -> dict:
    """DSRL-format arrays of `episodes` full episodes of uniform random actions (C MuJoCo)."""
    from r2pac_jax.envs.navigation import make_env

    env = make_env(name, physics="mujoco")
    rng = np.random.default_rng(seed)
    s = env.reset_batch(jax.random.split(jax.random.PRNGKey(seed), episodes))
    live = np.ones(episodes, bool)
    rows = {k: [] for k in ("observations", "next_observations", "actions", "rewards", "costs",
                            "terminals", "timeouts", "episode")}
    for _ in range(env.episode_len):
        a = rng.uniform(-1, 1, (episodes, env.act_dim)).astype(np.float32)
        nxt = env.step_batch(s, a)
        for i in np.flatnonzero(live):
            rows["observations"].append(s.obs[i])
            rows["next_observations"].append(nxt.obs[i])
            rows["actions"].append(a[i])
            rows["rewards"].append(nxt.reward[i])
            rows["costs"].append(nxt.cost[i])
            rows["terminals"].append(bool(nxt.terminated[i]))
            rows["timeouts"].append(bool(nxt.truncated[i]) and not nxt.terminated[i])
            rows["episode"].append(i)
        live &= ~np.asarray(nxt.terminated | nxt.truncated)
        s = nxt
        if not live.any():
            break
    order = np.argsort(np.array(rows.pop("episode")), kind="stable")  # episodes contiguous
    return {k: np.asarray(v)[order] for k, v in rows.items()}


@pytest.mark.slow
def test_train_cli_on_car_goal2(data_dir, tmp_path):
    from r2pac_jax.data.dsrl import load_dsrl, write_dsrl
    from r2pac_jax.train import main

    path = write_dsrl(tmp_path / "CarGoal2-random.hdf5", random_episodes("CarGoal2", 3))
    ds = load_dsrl(path, obs_dim=72, act_dim=2)
    assert ds.size == 3000 and ds.timeouts.sum() == 3 and ds.costs.max() <= 1
    out = tmp_path / "run"
    argv = ["--task", "CarGoal2", "--dataset", str(path), "--preset", "quick", "--steps", "200",
            "--seeds", "1", "--baselines", "none", "--eval-episodes", "2", "--out", str(out),
            "--no-progress",
            # the quick preset's compiled block is 500 steps; 200 steps need a smaller block
            "--set", "block_steps=100"]
    assert main(argv) == 0
    res = json.loads((out / "results.json").read_text())
    # evaluated on our CarGoal2 environment: two full episodes of 1000 steps
    assert np.asarray(res["returns"]).shape == (1, 2)
    assert np.isfinite(res["normalized_reward"]["mean"])
    assert np.all(np.asarray(res["costs"]) >= 0)

"""Runs INSIDE the reference virtualenv (Safety-Gymnasium 0.4.0, MuJoCo 2.3.3): rolls out seeded
uniform-random actions in the original environment and writes what it saw to an .npz file.

    REF_PY reference_rollout.py ENV_ID SEED STEPS OUT.npz

Arrays: qpos0, qvel0 (state after reset), actions [T, A], obs [T, obs], reward [T], cost [T],
terminated [T], truncated [T], qpos [T, nq], qvel [T, nv] (after each step). The rollout stops
at the first terminal (T may be < STEPS); the action sequence is drawn from numpy's
default_rng(SEED) so that both sides apply the same actions.
"""
import sys
import warnings

warnings.filterwarnings("ignore")

import gymnasium  # noqa: E402
import numpy as np  # noqa: E402
import safety_gymnasium  # noqa: E402,F401  (registers the Safety*Gymnasium ids)


def main():
    env_id, seed, steps, out = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
    # DSRL's ids (Safety...Gymnasium-vN) are the gymnasium-API versions: cost in info["cost"]
    env = gymnasium.make(env_id, max_episode_steps=max(steps, 1000))
    env.reset(seed=seed)
    data = env.unwrapped.data
    rng = np.random.default_rng(seed)
    rec = {k: [] for k in ("actions", "obs", "reward", "cost", "terminated", "truncated",
                           "qpos", "qvel")}
    qpos0, qvel0 = data.qpos.copy(), data.qvel.copy()
    for _ in range(steps):
        a = rng.uniform(-1, 1, env.action_space.shape)
        obs, r, term, trunc, info = env.step(a)
        c = info["cost"]
        for k, v in zip(rec, (a, obs, r, c, term, trunc, data.qpos.copy(), data.qvel.copy())):
            rec[k].append(v)
        if term:
            break
    np.savez(out, qpos0=qpos0, qvel0=qvel0, **{k: np.asarray(v) for k, v in rec.items()})


if __name__ == "__main__":
    main()

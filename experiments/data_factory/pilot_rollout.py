"""Roll out a generation pilot's last policy (its state.pkl) on C MuJoCo and say where its cost
falls: the mean action alone and with half and all of the policy's noise, the share of saturated
mean actions, and the cost by tenth of the episode (GENERATION.md, SwimmerVelocity's section).

  python experiments/data_factory/pilot_rollout.py runs/pilots/SwimmerVelocity-b3000000-s0-recipe \
      [--task SwimmerVelocity] [--ppo mean_squash=none] [--envs 20]
"""
from __future__ import annotations

import argparse
import json
import pickle
from pathlib import Path

import numpy as np


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("pilot_dir")
    ap.add_argument("--task", default="SwimmerVelocity")
    ap.add_argument("--ppo", nargs="*", default=[], help="the pilot's recipe values, KEY=VALUE")
    ap.add_argument("--envs", type=int, default=20)
    a = ap.parse_args(argv)
    import jax
    import jax.numpy as jnp

    from r2pac_jax.data.factory import parse_recipe_values
    from r2pac_jax.data.factory import ppo_lagrangian as pl
    from r2pac_jax.tasks import get_task

    ppo = parse_recipe_values(a.ppo)
    state = pickle.loads((Path(a.pilot_dir) / "state.pkl").read_bytes())
    t = get_task(a.task)
    actor, _, _ = pl.networks(t.obs_dim, t.act_dim, pl.PPOLagConfig(**ppo))
    params = jax.tree_util.tree_map(jnp.asarray, state["params"])
    policy = jax.jit(lambda o: actor.apply(params["actor"], o))
    env = t.make_env(physics="mujoco")
    rng = np.random.default_rng(1)
    n = a.envs
    for scale in (0.0, 0.5, 1.0):
        s = env.reset_batch(jax.random.split(jax.random.PRNGKey(3), n))
        cost, ret, means, step_cost = np.zeros(n), np.zeros(n), [], []
        for _ in range(t.episode_len):
            mean, log_std = (np.asarray(x) for x in policy(jnp.asarray(s.obs)))
            act = np.clip(mean + scale * np.exp(log_std) * rng.standard_normal(mean.shape), -1, 1)
            s = env.step_batch(s, act.astype(np.float32))
            cost += np.asarray(s.cost)
            ret += np.asarray(s.reward)
            means.append(mean)
            step_cost.append(np.asarray(s.cost))
        c = np.stack(step_cost)
        tenth = t.episode_len // 10
        print(json.dumps(dict(
            noise_scale=scale, noise_std=float(scale * np.exp(log_std).mean()),
            episode_cost=round(float(cost.mean()), 2), cost_min=float(cost.min()),
            cost_max=float(cost.max()), within_kappa=float((cost <= t.kappa).mean()),
            episode_return=round(float(ret.mean()), 2),
            saturated_share=round(float((np.abs(np.stack(means)) > 0.99).mean()), 3),
            cost_by_tenth=[round(float(c[i * tenth:(i + 1) * tenth].sum(0).mean()), 2)
                           for i in range(10)])))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

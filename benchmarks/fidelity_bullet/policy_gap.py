"""One trained policy scored on the original's engine and on the MuJoCo re-creation: the last
column of benchmarks/FIDELITY.md ("Bullet tasks in MuJoCo").

    python benchmarks/fidelity_bullet/policy_gap.py --task BallRun [--updates 60] [--episodes 20]

Trains the data factory's PPO (ppo_lagrangian.py: DSRL's networks, reward only, multiplier 0) on
the `bullet` backend (the original's engine) for `--updates` x 5,000 env steps, then runs its mean
action (deterministic) for DSRL's 20 evaluation episodes on `bullet`, `mujoco` and `mjx` from the
same reset keys, and prints the normalised return and cost (data/checks.normalised: DSRL's reward
normalisation, cost over the task's kappa) of each.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from r2pac_jax.data.checks import normalised  # noqa: E402
from r2pac_jax.data.factory import ppo_lagrangian as ppo  # noqa: E402
from r2pac_jax.envs.bullet import make_env  # noqa: E402
from r2pac_jax.tasks import get_task  # noqa: E402


def train(spec, updates: int, seed: int, num_envs: int = 50, T: int = 100):
    cfg = ppo.PPOLagConfig(num_envs=num_envs, rollout_len=T)
    env = make_env(spec, "bullet")
    actor, critics, opt = ppo.networks(spec.obs_dim, spec.act_dim, cfg)
    key = jax.random.PRNGKey(seed)
    key, k = jax.random.split(key)
    params = ppo.init_params(k, spec.obs_dim, actor, critics)
    opt_state = opt.init(params)
    policy, update = ppo.make_policy_step(actor, critics), ppo.make_update(actor, critics, opt, cfg)
    key, k = jax.random.split(key)
    state = env.reset_batch(jax.random.split(k, num_envs))
    for u in range(updates):
        key, k_roll, k_upd = jax.random.split(key, 3)
        state, traj = ppo.rollout_batch(env, policy, params, state, k_roll, T)
        params, opt_state, _ = update(params, opt_state, ppo.as_update_batch(traj),
                                      jnp.float32(0.0), k_upd)
        if u % 10 == 0 or u == updates - 1:
            print(f"update {u}: mean reward per step {traj['r'].mean():.3f}, cost per step "
                  f"{traj['c'].mean():.3f}", flush=True)
    env.release(state)
    return actor, params


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--task", default="BallRun")
    p.add_argument("--updates", type=int, default=60)
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", default=None)
    args = p.parse_args()
    spec = get_task(args.task)
    t0 = time.time()
    actor, params = train(spec, args.updates, args.seed)
    train_s = time.time() - t0

    class Mean:  # the deterministic policy, stepped in batch from Python
        act = jax.jit(lambda obs: jnp.clip(actor.apply(params["actor"], obs)[0], -1.0, 1.0))

    keys = jax.random.split(jax.random.PRNGKey(args.seed + 100), args.episodes)
    out = dict(task=args.task, updates=args.updates, env_steps=args.updates * 5000,
               train_s=train_s)
    for backend in ("bullet", "mujoco", "mjx"):
        env = make_env(spec, backend)  # mjx: a JaxEnv, batched by its own step_batch
        state = env.reset_batch(keys)
        ret, cost = np.zeros(args.episodes), np.zeros(args.episodes)
        done = np.zeros(args.episodes, bool)
        for _ in range(spec.episode_len):
            state = env.step_batch(state, np.asarray(Mean.act(jnp.asarray(state.obs))))
            ret += np.where(done, 0.0, np.asarray(state.reward))
            cost += np.where(done, 0.0, np.asarray(state.cost))
            done |= np.asarray(state.terminated) | np.asarray(state.truncated)
            if done.all():
                break
        if hasattr(env, "release"):
            env.release(state)
        r, c = normalised(spec, ret, cost)
        out[backend] = dict(reward=float(np.mean(r)), reward_std=float(np.std(r)),
                            cost=float(np.mean(c)), cost_std=float(np.std(c)))
        print(f"{args.task} {backend}: normalised return {np.mean(r):.3f} +- {np.std(r):.3f}, "
              f"normalised cost {np.mean(c):.2f} +- {np.std(c):.2f} ({args.episodes} episodes)",
              flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()

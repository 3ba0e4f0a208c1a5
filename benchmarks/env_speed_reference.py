"""Runs INSIDE a reference virtualenv (Safety-Gymnasium 0.4.0 on MuJoCo 2.3.3, or
Bullet-Safety-Gym 1.4.0 on pybullet 3.2.7 for the Safety{Ball,Car,Drone,Ant}{Run,Circle} ids):
times the original simulator's own loop with uniform-random actions, prints one JSON line.

    REF_PY env_speed_reference.py ENV_ID [--mode seq|async] [--episodes N] [--steps S]
                                         [--workers K] [--seed SEED]

seq   (DSRL's protocol): N episodes one after another, each until terminated or truncated
      (gymnasium.make's time limit, 1000 steps), resets included in the time.
async gymnasium's AsyncVectorEnv with K worker processes (the original's only way to use more
      than one core), S vector steps, autoreset inside the workers; env-steps = S x K.
Random actions are drawn before the timed loop (numpy, seeded), so the figure is the
simulator's alone ("policy excluded").
"""
import argparse
import json
import time
import warnings

warnings.filterwarnings("ignore")

import gymnasium  # noqa: E402
import numpy as np  # noqa: E402


def seq(env_id, episodes, seed):
    env = gymnasium.make(env_id)
    rng = np.random.default_rng(seed)
    shape = env.action_space.shape
    actions = rng.uniform(-1, 1, (1000 * episodes,) + shape)
    env.reset(seed=seed)  # warm-up (first compile of the world, imports)
    steps, resets_s = 0, 0.0
    lengths = []
    t0 = time.perf_counter()
    for ep in range(episodes):
        r0 = time.perf_counter()
        env.reset(seed=seed + ep)
        resets_s += time.perf_counter() - r0
        n = 0
        while True:
            _, _, term, trunc, info = env.step(actions[steps])
            steps += 1
            n += 1
            if term or trunc:
                break
        lengths.append(n)
    wall = time.perf_counter() - t0
    return dict(mode="seq", batch=1, episodes=episodes, env_steps=steps, wall_s=wall,
                steps_per_s=steps / wall, reset_s=resets_s, mean_length=float(np.mean(lengths)))


def vec(env_id, workers, steps, seed):
    envs = gymnasium.vector.AsyncVectorEnv([lambda: gymnasium.make(env_id)] * workers)
    envs.reset(seed=seed)
    rng = np.random.default_rng(seed)
    actions = rng.uniform(-1, 1, (steps,) + envs.action_space.shape)
    for a in actions[:5]:  # warm-up
        envs.step(a)
    t0 = time.perf_counter()
    for a in actions:
        envs.step(a)
    wall = time.perf_counter() - t0
    envs.close()
    return dict(mode="async", batch=workers, env_steps=steps * workers, wall_s=wall,
                steps_per_s=steps * workers / wall)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("env_id")
    ap.add_argument("--mode", choices=["seq", "async"], default="seq")
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    if "Gymnasium" in args.env_id:
        import mujoco
        import safety_gymnasium as sim  # registers the Safety*Gymnasium ids

        engine = dict(mujoco=mujoco.__version__)
    else:
        import bullet_safety_gym as sim  # registers the Bullet ids
        import pybullet

        engine = dict(pybullet=pybullet.getAPIVersion())
    out = (seq(args.env_id, args.episodes, args.seed) if args.mode == "seq" else
           vec(args.env_id, args.workers, args.steps, args.seed))
    out.update(env_id=args.env_id,
               simulator=f"{sim.__name__} {getattr(sim, '__version__', '')}".strip(), **engine)
    print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()

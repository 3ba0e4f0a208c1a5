"""Cost of one generation step per episode, per task: the scripted controller plus C MuJoCo.

    python experiments/data_factory/step_cost.py CarGoal2 PointGoal1 ... [--n 200 --steps 50]

Times `steps` control steps of a batch of `n` episodes (after a warm-up step that compiles),
the loop the data factory runs, and prints seconds per episode-step, the implied seconds per
1000-step episode and the implied generation time of the task's default size (OVERSAMPLE x
default episodes), with the load average during the measurement.
"""
from __future__ import annotations

import argparse
import os
import time

import jax.numpy as jnp
import numpy as np


def nav_cost(name, n, steps):
    from r2pac_jax.data.factory import navigation as nav
    from r2pac_jax.data.factory.batch import episode_keys
    from r2pac_jax.tasks import get_task

    env = get_task(name).make_env(physics="mujoco")
    scene = nav.NavScene(env)
    control = nav.make_controller(scene)
    keys = episode_keys(0, 0, n)
    k_reset, k_knobs, k_steps = nav._split_keys(keys)
    knobs = nav._sample_knobs_batch(k_knobs)
    state = env.reset_batch(k_reset)
    wx, wf = jnp.zeros((n, 2)), jnp.zeros((n,), bool)

    def step(state, wx, wf, t):
        a, wx, wf = control(scene.read(state), knobs, wx, wf, k_steps, jnp.int32(t))
        return env.step_batch(state, np.asarray(a)), wx, wf

    state, wx, wf = step(state, wx, wf, 0)
    t0 = time.perf_counter()
    for t in range(1, steps + 1):
        state, wx, wf = step(state, wx, wf, t)
    return (time.perf_counter() - t0) / (steps * n), nav.DEFAULT_TRAJECTORIES[name], nav.OVERSAMPLE


def vel_cost(name, n, steps):
    from r2pac_jax.data.factory import velocity as vel
    from r2pac_jax.tasks import get_task

    env = get_task(name).make_env(physics="mujoco")
    vel.rollout(env, name, 0, 0, n, steps=1)  # compile
    t0 = time.perf_counter()
    vel.rollout(env, name, 0, 0, n, steps=steps)
    return (time.perf_counter() - t0) / (steps * n), vel.DEFAULT_TRAJECTORIES[name], vel.OVERSAMPLE


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("tasks", nargs="+")
    ap.add_argument("--n", type=int, default=200)
    ap.add_argument("--steps", type=int, default=50)
    args = ap.parse_args()
    from r2pac_jax.data.factory.velocity import VELOCITY_TASKS

    for name in args.tasks:
        load0 = os.getloadavg()[0]
        fn = vel_cost if name in VELOCITY_TASKS else nav_cost
        per, default, over = fn(name, args.n, args.steps)
        load1 = os.getloadavg()[0]
        print(f"{name}: {per * 1e3:.2f} ms per episode-step, {per * 1000:.2f} s per episode, "
              f"default {default} x {over} -> ~{per * 1000 * default * over / 60:.1f} min "
              f"(+ compile), load {load0:.1f}->{load1:.1f}", flush=True)


if __name__ == "__main__":
    main()

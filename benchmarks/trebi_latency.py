"""TREBI's time per action: one planning call (plans x denoising steps x guide gradients) for a
batch of episodes, at each preset, on whatever JAX runs on.

    python benchmarks/trebi_latency.py [--task BallRun] [--presets quick,paper] [--episodes 1,20]
                                       [--calls 5]

Freshly initialised networks (the time does not depend on training); the compile is timed
apart; each figure is the median over `--calls` calls after it, divided by nothing: a call
plans one action for every episode of the batch at once. Prints one JSON line per measurement.
"""
from __future__ import annotations

import argparse
import json
import statistics
import time

import jax

from r2pac_jax.agents import make_agent
from r2pac_jax.config import default_hparams, make_config
from r2pac_jax.machine import record
from r2pac_jax.tasks import get_task


def measure(task_name: str, preset: str, episodes: int, calls: int) -> dict:
    task = get_task(task_name)
    cfg = make_config(task, "trebi", preset)
    agent = make_agent(cfg, task.obs_dim, task.act_dim)
    hp = default_hparams(cfg)
    pp = agent.policy_params(jax.jit(agent.init)(jax.random.PRNGKey(0), hp), hp)
    obs = jax.random.normal(jax.random.PRNGKey(1), (episodes, task.obs_dim))
    mem = agent.memory_init(pp, obs)
    act = jax.jit(agent.act_memory)
    t0 = time.perf_counter()
    jax.block_until_ready(act(pp, obs, jax.random.PRNGKey(2), mem))
    compile_s = time.perf_counter() - t0
    times = []
    for i in range(calls):
        t0 = time.perf_counter()
        jax.block_until_ready(act(pp, obs, jax.random.PRNGKey(3 + i), mem))
        times.append(time.perf_counter() - t0)
    per_call = statistics.median(times)
    return dict(task=task_name, preset=preset, episodes=episodes, plans=cfg.plans,
                diffusion_steps=cfg.diffusion_steps, guide_steps=cfg.guide_steps,
                horizon=cfg.horizon, unet=[cfg.unet_dim, list(cfg.unet_mults)],
                s_per_call=per_call, s_per_1000_steps_of_one_batch=1000 * per_call,
                compile_s=compile_s, **record())


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--task", default="BallRun")
    ap.add_argument("--presets", default="quick,paper")
    ap.add_argument("--episodes", default="1,20")
    ap.add_argument("--calls", type=int, default=5)
    args = ap.parse_args()
    for preset in args.presets.split(","):
        for n in (int(x) for x in args.episodes.split(",")):
            print(json.dumps(measure(args.task, preset, n, args.calls)), flush=True)


if __name__ == "__main__":
    main()

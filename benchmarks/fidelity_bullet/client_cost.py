"""What one episode costs the bullet backend, per robot: resident memory of one pybullet client
with its world, and the time of a reset (the world rebuilt, the robot placed, the settling
step).

    python benchmarks/fidelity_bullet/client_cost.py [--tasks BallRun,CarRun,DroneRun,AntRun]

Memory: RSS growth over 50 new clients, divided by 50. Reset: mean over 50 resets of clients
that ran an episode before (so each rebuilds its world), after 2 warm-up resets.
"""
import argparse
import os
import time

import jax
import numpy as np

from r2pac_jax.envs.bullet import make_env
from r2pac_jax.tasks import get_task


def rss_mib() -> float:
    return int(open("/proc/self/statm").read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--tasks", default="BallRun,CarRun,DroneRun,AntRun")
    args = ap.parse_args()
    print("| task | MiB per client | ms per reset (world rebuilt) |")
    print("|---|---|---|")
    keep = []  # every env stays alive: freed clients' memory would be reused by the next task's
    for name in args.tasks.split(","):
        env = make_env(get_task(name))
        st = env.reset_batch(jax.random.split(jax.random.PRNGKey(0), 2))
        r0 = rss_mib()
        st = env.reset_batch(jax.random.split(jax.random.PRNGKey(1), 50))
        mib = (rss_mib() - r0) / 50
        st = env.step_batch(st, np.zeros((50, env.act_dim), np.float32))  # stepped: rebuilds
        env.release(st)
        t0 = time.perf_counter()
        st = env.reset_batch(jax.random.split(jax.random.PRNGKey(2), 50))
        ms = (time.perf_counter() - t0) / 50 * 1e3
        print(f"| {name} | {mib:.1f} | {ms:.1f} |")
        keep.append(env)


if __name__ == "__main__":
    main()

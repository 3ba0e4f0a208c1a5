"""Env steps/s of the learned-behaviour generation (rollout + update, checkpoints included) for a
few updates of a task, per (num_envs, rollout_len); the first update (compilation) is left out.

    python experiments/data_factory/time_learned.py --task CarGoal2 [--envs 10,20,40] [--updates 4]

Prints one JSON line per setting; the per-task estimates in GENERATION.md come from these.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from pathlib import Path

from r2pac_jax.data.dsrl import DatasetError
from r2pac_jax.data.factory import collect
from r2pac_jax.tasks import get_task


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--task", default="CarGoal2")
    ap.add_argument("--envs", default="10,20,40")
    ap.add_argument("--steps-per-update", type=int, default=10_000)
    ap.add_argument("--updates", type=int, default=4)
    ap.add_argument("--physics", default="auto")
    ap.add_argument("--rollout-len", type=int, default=None,
                    help="steps per env per update (default steps-per-update / envs; the "
                         "bullet backend needs a multiple of the episode length)")
    args = ap.parse_args()
    task = get_task(args.task)
    for n in (int(x) for x in args.envs.split(",")):
        t_len = args.rollout_len or args.steps_per_update // n
        d = Path(tempfile.mkdtemp())
        t0 = time.time()
        try:
            collect.generate_learned(task, d / "t.hdf5", trajectories=10_000,
                                     env_steps=n * t_len * args.updates, physics=args.physics,
                                     ppo=dict(num_envs=n, rollout_len=t_len), checkpoint_every=2,
                                     progress=False, log=lambda m: None)
        except DatasetError:  # no episode finished in so few steps: the log is still there
            pass
        wall = time.time() - t0
        log = d / "t.log.jsonl"  # the finished generation's log beside its file
        if not log.exists():
            log = d / "t.hdf5.partial" / "log.jsonl"
        rows = [json.loads(ln) for ln in log.read_text().splitlines()]
        rates = [r["steps_per_s"] for r in rows[1:]]
        print(json.dumps(dict(task=task.name, num_envs=n, rollout_len=t_len,
                              updates=len(rows), env_steps_per_s=sum(rates) / len(rates),
                              first_update_s=n * t_len / rows[0]["steps_per_s"], wall_s=wall,
                              cpus=os.cpu_count(), machine=platform.machine(),
                              date=time.strftime("%Y-%m-%d %H:%M"))), flush=True)


if __name__ == "__main__":
    main()

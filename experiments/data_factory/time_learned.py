"""Env steps/s of the learned-behaviour generation (rollout + update, checkpoints included) for a
few updates of a task, per (num_envs, rollout_len); the first update (compilation) is left out.

    python experiments/data_factory/time_learned.py --task CarGoal2 [--envs 10,20,40] [--updates 4]

Prints one JSON line per setting; the per-task estimates in GENERATION.md come from these. Each
line also says where an update's time goes (`parts`: seconds per update and share of the
rollout, of the simulator inside it where Python steps it, of the episode pool and its files,
of PPO's GAE and update, and of the checkpoints, from the generation's own log) and the
process's peak resident memory.
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


PARTS = ("t_rollout", "t_physics", "t_pool", "t_update", "t_checkpoint_before")


def breakdown(rows: list[dict]) -> dict:
    """Mean seconds per update of each part, and its share of an update's wall (the update's
    own time plus its share of the checkpoints, which the log's rate leaves out)."""
    if not rows:
        return {}
    spu = rows[0]["env_steps"] / rows[0]["update"]  # env steps per update
    mean = lambda k: sum(r.get(k, 0.0) for r in rows) / len(rows)  # noqa: E731
    total = sum(spu / r["steps_per_s"] for r in rows) / len(rows) + mean("t_checkpoint_before")
    out = {"update_s": round(total, 4)}
    for k in PARTS:
        if any(k in r for r in rows):  # t_physics: Python-stepped simulators only
            out[k] = dict(s=round(mean(k), 4), share=round(mean(k) / total, 3))
    return out


def peak_rss_gib() -> float:
    import resource

    return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20, 2)  # KiB on Linux


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
    ap.add_argument("--recipe", action="store_true",
                    help="the task's own num_envs and rollout_len (the files' recipe), not --envs")
    args = ap.parse_args()
    task = get_task(args.task)
    if args.recipe:
        ppo = collect.make_spec(task).ppo
        args.envs, args.rollout_len = str(ppo.num_envs), ppo.rollout_len
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
                              parts=breakdown(rows[1:]), peak_rss_gib=peak_rss_gib(),
                              first_update_s=n * t_len / rows[0]["steps_per_s"], wall_s=wall,
                              cpus=os.cpu_count(), machine=platform.machine(),
                              date=time.strftime("%Y-%m-%d %H:%M"))), flush=True)


if __name__ == "__main__":
    main()

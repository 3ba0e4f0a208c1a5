"""Peak memory (RSS) of `python -m r2pac_jax.train` on a file of a task's full DSRL size.

    python benchmarks/train_memory.py [--task CarPush2] [--algos r2pac,bc-all-mlp,cdt]
                                      [--trajectories N] [--steps 200] [--out runs/train_memory]

The largest file any MuJoCo recipe makes is CarPush2's at DSRL's count (4,407 episodes x 1,000
steps, observations of 88): this writes a DSRL-format file of exactly that shape (random
observations and actions, episode ends marked as timeouts, so every view of the data is built as
for a real file; the values do not change the memory), then runs `train` on it once per algorithm
in a child process and reads the child's peak RSS from `os.wait4`. Training is cut to `--steps`
gradient steps and one evaluation episode: the memory that grows with the file (the arrays, the
per-algorithm views built from them) is all allocated before the first step. Prints and writes
one JSON object (`{out}/train_memory.json`); the file is deleted afterwards unless --keep.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def write_file(path: Path, n_episodes: int, episode_len: int, obs_dim: int, act_dim: int,
               seed: int = 0, block: int = 100) -> int:
    """A DSRL-format HDF5 file of n_episodes x episode_len transitions, written block by block
    (uncompressed: random floats do not compress, and the loader reads either). Returns bytes.

    Not `dsrl.write_dsrl`, which needs the whole dataset in memory: this process must stay small,
    since on Linux a child's peak RSS counts its parent's RSS at the fork."""
    import h5py

    rng = np.random.default_rng(seed)
    n = n_episodes * episode_len
    tmp = path.with_suffix(".tmp")
    with h5py.File(tmp, "w") as f:
        d = {k: f.create_dataset(k, (n, obs_dim), "f4") for k in
             ("observations", "next_observations")}
        d["actions"] = f.create_dataset("actions", (n, act_dim), "f4")
        for k in ("rewards", "costs"):
            d[k] = f.create_dataset(k, (n,), "f4")
        for k in ("terminals", "timeouts"):
            d[k] = f.create_dataset(k, (n,), "bool")
        for e0 in range(0, n_episodes, block):
            e1 = min(e0 + block, n_episodes)
            a, b = e0 * episode_len, e1 * episode_len
            obs = rng.standard_normal((b - a + 1, obs_dim), dtype=np.float32)
            d["observations"][a:b] = obs[:-1]
            d["next_observations"][a:b] = obs[1:]
            d["actions"][a:b] = rng.uniform(-1, 1, (b - a, act_dim)).astype(np.float32)
            d["rewards"][a:b] = rng.standard_normal(b - a, dtype=np.float32)
            # per-episode cost rates 0-5%: episode costs 0-50 around kappa, so every algorithm
            # finds the safe and unsafe episodes its data view needs (CDT's return target)
            rate = np.repeat(rng.uniform(0, 0.05, e1 - e0), episode_len)
            d["costs"][a:b] = (rng.random(b - a) < rate).astype(np.float32)
            d["terminals"][a:b] = False
            ends = np.zeros(b - a, bool)
            ends[episode_len - 1::episode_len] = True
            d["timeouts"][a:b] = ends
    os.replace(tmp, path)
    return path.stat().st_size


def peak_rss_of(cmd: list[str], log: Path) -> tuple[int, float, float]:
    """(exit status, peak RSS in MiB, wall s) of one child process."""
    t0 = time.time()
    with open(log, "w") as out:
        p = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT)
        _, status, usage = os.wait4(p.pid, 0)
    p.returncode = os.waitstatus_to_exitcode(status)
    return p.returncode, usage.ru_maxrss / 1024, time.time() - t0  # Linux: ru_maxrss in KiB


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--task", default="CarPush2")
    ap.add_argument("--algos", default="r2pac,bc-all-mlp,cdt")
    ap.add_argument("--trajectories", type=int, default=None,
                    help="episodes in the file (default: the task's DSRL count)")
    ap.add_argument("--steps", type=int, default=200, help="gradient steps per phase")
    ap.add_argument("--out", default="runs/train_memory")
    ap.add_argument("--keep", action="store_true", help="keep the synthetic file")
    args = ap.parse_args()

    from r2pac_jax.machine import record
    from r2pac_jax.tasks import get_task

    task = get_task(args.task)
    n = args.trajectories if args.trajectories is not None else (
        task.collection.trajectories if task.collection else None)
    if n is None:
        ap.error(f"--trajectories: {args.task} has no DSRL count; pass a positive number")
    if n < 1:
        ap.error(f"--trajectories must be a positive number of episodes, got {n}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{task.name}-synthetic-n{n}.hdf5"
    t0 = time.time()
    size = write_file(path, n, task.episode_len, task.obs_dim, task.act_dim)
    write_s = time.time() - t0
    rows = []
    try:
        for algo in args.algos.split(","):
            run = out / algo
            cmd = [sys.executable, "-m", "r2pac_jax.train", "--task", task.name, "--algo", algo,
                   "--dataset", str(path), "--steps", str(args.steps), "--seeds", "1",
                   "--eval-episodes", "1", "--eval-every", str(args.steps), "--baselines",
                   "none", "--preset", "quick", "--out", str(run), "--no-progress"]
            rc, mib, wall = peak_rss_of(cmd, out / f"{algo}.log")
            rows.append(dict(algo=algo, exit=rc, peak_rss_mib=round(mib), wall_s=round(wall, 1)))
            print(json.dumps(rows[-1]), flush=True)
            if rc != 0:
                print(f"{algo}: train exited {rc}; see {out / (algo + '.log')}", file=sys.stderr)
    finally:
        if not args.keep:
            path.unlink(missing_ok=True)
    result = dict(task=task.name, trajectories=n, episode_len=task.episode_len,
                  transitions=n * task.episode_len, obs_dim=task.obs_dim, act_dim=task.act_dim,
                  file_mib=round(size / 2**20), write_s=round(write_s, 1),
                  steps=args.steps, runs=rows, **record())
    from r2pac_jax.io import atomic_write_json

    atomic_write_json(out / "train_memory.json", result)
    print(json.dumps(result))
    if any(r["exit"] != 0 for r in rows):
        sys.exit(1)


if __name__ == "__main__":
    main()

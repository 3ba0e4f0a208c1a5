"""`python -m r2pac_jax.data make --task TASK [--trajectories N] [--seed S]
[--source scripted|ppo-lagrangian] [--physics auto|mjx]`."""
from __future__ import annotations

import argparse
import sys
import time

from r2pac_jax.data.factory import SOURCE_KINDS


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m r2pac_jax.data")
    sub = ap.add_subparsers(dest="cmd", required=True)
    mk = sub.add_parser("make", help="generate a DSRL-format dataset for a task")
    mk.add_argument("--task", required=True)
    mk.add_argument("--trajectories", type=int, default=None)
    mk.add_argument("--seed", type=int, default=0)
    mk.add_argument("--source", default="scripted", choices=SOURCE_KINDS,
                    help="scripted (default: each task's controllers) | ppo-lagrangian (DSRL's "
                         "recipe in JAX; ReachAvoid, or MuJoCo tasks with --physics mjx)")
    mk.add_argument("--physics", default="auto", help="ppo-lagrangian only: auto | mjx")
    args = ap.parse_args(argv)

    from tqdm import tqdm

    from r2pac_jax.data import factory
    from r2pac_jax.tasks import UnknownTaskError, get_task

    try:
        task = get_task(args.task)
        n = args.trajectories or factory.default_trajectories(task)
        path = factory.dataset_path(task, args.seed, n, args.source)
        if path.exists() and factory.card_path(path).exists():
            print(f"{path} exists (card {factory.card_path(path)})")
            return 0
        t0 = time.time()
        with tqdm(total=n, unit="traj", desc=f"{task.name} data") as bar:
            path = factory.generate_dataset(task, n, args.seed, progress=bar.update,
                                            source=args.source, physics=args.physics)
    except (UnknownTaskError, factory.FactoryError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"wrote {path} in {time.time() - t0:.1f} s; card {factory.card_path(path)}; "
          f"plot {path.with_suffix('.png')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""`python -m r2pac_jax.data make --task TASK [--source scripted|ppo-lagrangian]
[--trajectories N] [--seed S] [--budget ENV_STEPS] [--ppo KEY=VALUE ...] [--physics auto|mujoco|mjx]
[--expect-log LOG] [--stop-after UPDATES] [--force]`;
`python -m r2pac_jax.data check FILE [--task T] [--fast] [--seeds 100,101,102]`."""
from __future__ import annotations

import argparse
import sys
import time

from r2pac_jax.data.factory import SOURCE_KINDS
from r2pac_jax.errors import R2pacError


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m r2pac_jax.data")
    sub = ap.add_subparsers(dest="cmd", required=True)
    mk = sub.add_parser("make", help="generate a DSRL-format dataset for a task")
    mk.add_argument("--task", required=True)
    mk.add_argument("--trajectories", type=int, default=None,
                    help="trajectories in the file (default: the source's; DSRL's size for "
                         "ppo-lagrangian)")
    mk.add_argument("--seed", type=int, default=0)
    mk.add_argument("--source", default=None, choices=SOURCE_KINDS,
                    help="ppo-lagrangian (DSRL's recipe: an observation-based Lagrangian agent "
                         "under DSRL's cost schedule, data v2; resumable; the default of every "
                         "task but ReachAvoid) | scripted (the controllers on simulator state, "
                         "data v1, minutes; only when named: their safe trajectories cannot be "
                         "imitated from observations, and the card lists the checks they fail)")
    mk.add_argument("--budget", type=int, default=None,
                    help="ppo-lagrangian: RL budget in env steps (default DSRL's, e.g. 22M for "
                         "CarGoal2); the schedule scales with it")
    mk.add_argument("--num-envs", type=int, default=None,
                    help="ppo-lagrangian: parallel environments (default the task's recipe)")
    mk.add_argument("--ppo", nargs="+", default=[], metavar="KEY=VALUE",
                    help="ppo-lagrangian: generator recipe values to try (PPOLagConfig's, JSON "
                         "values, e.g. stagger_starts=true); the file's name gets -ppo-KEY_VALUE "
                         "so that it never stands in for the task's recipe file")
    mk.add_argument("--checkpoint-every", type=int, default=10,
                    help="ppo-lagrangian: updates between checkpoints")
    mk.add_argument("--physics", default="auto",
                    help="ppo-lagrangian: auto (C MuJoCo on a CPU, MJX on an accelerator; "
                         "pybullet for the Bullet tasks) | mujoco | mjx | bullet")
    mk.add_argument("--expect-log", default=None, metavar="LOG",
                    help="ppo-lagrangian: the log of the file to make again (its .log.jsonl, or "
                         "the .log.jsonl.gz archived in results_v2/TASK); the generation stops "
                         "at the first update whose row differs (exit 3), an update in instead "
                         "of hours, its partial state kept")
    mk.add_argument("--stop-after", type=int, default=None, metavar="UPDATES",
                    help="ppo-lagrangian: stop after that many updates of this call, resumable "
                         "(with --expect-log: a probe of whether this machine makes the file)")
    mk.add_argument("--force", action="store_true",
                    help="discard an existing file (and a generation's partial state) first")
    ck = sub.add_parser("check", help="coverage, temptation and imitability of a dataset file "
                                      "(writes FILE.checks.json)")
    ck.add_argument("file")
    ck.add_argument("--task", default=None, help="the file's task (default: read from the file)")
    ck.add_argument("--fast", action="store_true", help="coverage only (no cloner training)")
    ck.add_argument("--seeds", default="100,101,102")
    args = ap.parse_args(argv)
    if args.cmd == "check":
        return _check(args)

    from tqdm import tqdm

    from r2pac_jax.data import factory
    from r2pac_jax.tasks import get_task

    try:
        task = get_task(args.task)
        task.check_physics(args.physics)
        # refused before any file or lock is made (0 trajectories would read as the default)
        factory.check_at_least_one(trajectories=args.trajectories, budget=args.budget,
                                   num_envs=args.num_envs,
                                   checkpoint_every=args.checkpoint_every,
                                   stop_after=args.stop_after)
        if args.source is None:
            args.source = factory.default_source(task)
        n = args.trajectories or (task.collection.trajectories
                                  if args.source == "ppo-lagrangian" and task.collection
                                  else factory.default_trajectories(task))
        for flag, value in (("--expect-log", args.expect_log), ("--stop-after", args.stop_after)):
            if value is not None and args.source != "ppo-lagrangian":
                raise R2pacError(f"{flag} applies to a ppo-lagrangian generation; the "
                                 f"{args.source} source has no updates: leave it out")
        t0 = time.time()
        if args.source == "ppo-lagrangian":
            trial = factory.parse_recipe_values(args.ppo)
            if trial and task.collection:  # unknown keys and bad values refused before any lock
                from r2pac_jax.data.factory.collect import make_spec

                make_spec(task, env_steps=args.budget, ppo=trial)
            path = factory.dataset_path(task, args.seed, n, args.source, args.budget,
                                        trial=trial) if task.collection else None
            if path is not None and not args.force and path.exists() and \
                    factory.card_path(path).exists():
                print(f"{path} exists (card {factory.card_path(path)}); --force makes it again")
                return 0
            ppo = {} if args.num_envs is None else {"num_envs": args.num_envs}
            extra = {}
            if args.expect_log is not None:
                from r2pac_jax.data.factory.collect import read_log

                read_log(args.expect_log)  # a missing or unreadable log: refused before any lock
                extra["expect_log"] = args.expect_log
            if args.stop_after is not None:
                extra["stop_after"] = args.stop_after
            path = factory.generate_dataset(task, n, args.seed, source=args.source,
                                            physics=args.physics, env_steps=args.budget,
                                            force=args.force, ppo=ppo, trial=trial,
                                            checkpoint_every=args.checkpoint_every,
                                            progress=True, **extra)
        else:
            limits = factory.scripted_limits(task)
            if limits is not None:
                print(f"warning: {limits}", file=sys.stderr)
            path = factory.dataset_path(task, args.seed, n, args.source)
            if not args.force and path.exists() and factory.card_path(path).exists():
                print(f"{path} exists (card {factory.card_path(path)}); --force makes it again")
                return 0
            with tqdm(total=n, unit="traj", desc=f"{task.name} data") as bar:
                path = factory.generate_dataset(task, n, args.seed, progress=bar.update,
                                                source=args.source, physics=args.physics,
                                                force=args.force)
    except R2pacError as e:
        print(f"error: {e}", file=sys.stderr)
        return 3 if isinstance(e, factory.LogMismatch) else 2
    if path is None:  # --stop-after
        print(f"stopped after {args.stop_after} updates ({time.time() - t0:.1f} s); the same "
              "command without --stop-after continues the generation")
        return 0
    print(f"wrote {path} in {time.time() - t0:.1f} s; card {factory.card_path(path)}; "
          f"plot {path.with_suffix('.png')}")
    return 0


def _check(args) -> int:
    import json

    from r2pac_jax.data.checks import checks_path
    from r2pac_jax.imitability import check_file

    try:
        seeds = [int(x) for x in args.seeds.split(",") if x]
        res = check_file(args.file, args.task, fast=args.fast, seeds=seeds)
    except (R2pacError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(json.dumps(res, indent=1))
    print(f"{'passed' if res['passed'] else 'failed: ' + ', '.join(res['failed'])}; "
          f"written to {checks_path(args.file)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

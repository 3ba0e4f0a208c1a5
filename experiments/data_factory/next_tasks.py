"""The tasks whose v2 chain is not finished yet, in make_learned.sh's order: a task is finished
when its quality-bar results are archived in results_v2/TASK (r2pac.json). Prints them
space-separated (the first N with --first N), for

    nice -n 5 bash experiments/data_factory/task_pipeline.sh $(python experiments/data_factory/next_tasks.py --first 1)

`--plan TASK [--hours H]` prints the RL budget and the file of one task's generation: DSRL's
budget, or with --hours the largest budget expected to finish in H hours on the 2-core CPU
(`collect.budget_for_hours`; the file's name and card record a budget below DSRL's). The
pipeline scripts read it (BUDGET_HOURS), so the budget is chosen by the clock before any score.
"""
from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def ordered_tasks() -> list[str]:
    """make_learned.sh's default task list, in its order (the one place the order is written)."""
    text = (HERE / "make_learned.sh").read_text()
    lists = [m.group(1).split() for m in re.finditer(r"TASKS=\(([^)]*)\)", text)]
    lists = [names for names in lists if names and not names[0].startswith('"')]
    if not lists:
        raise SystemExit("make_learned.sh: no default TASKS=(...) list found")
    return max(lists, key=len)


def unfinished(archive: Path = HERE / "results_v2") -> list[str]:
    return [t for t in ordered_tasks() if not (archive / t / "r2pac.json").exists()]


def plan(task: str, hours=None) -> tuple[int, Path]:
    """(RL budget in env steps, the file it makes) for one task's learned-behaviour data."""
    from r2pac_jax.data import factory
    from r2pac_jax.data.factory.collect import budget_for_hours
    from r2pac_jax.tasks import get_task

    t = get_task(task)
    if t.collection is None:
        raise SystemExit(f"{task} has no learned-behaviour recipe")
    budget = t.collection.env_steps
    if hours is not None:
        fit = budget_for_hours(t, hours)
        if fit is None:
            raise SystemExit(f"{task}: no measured generation rate to fit a budget to "
                             "(collect.CPU2_STEPS_PER_S); run without --hours")
        budget = fit
        need = t.collection.trajectories * t.episode_len
        if budget < need:  # fewer finished episodes than the file's target: the card will say so
            print(f"warning: {task}: {budget:,} steps in {hours:g} h hold at most "
                  f"{budget // t.episode_len:,} whole episodes, below the target "
                  f"{t.collection.trajectories:,} ({need:,} steps)", file=sys.stderr)
    return budget, factory.learned_path(t, env_steps=budget)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--first", type=int, default=None, help="only the first N")
    ap.add_argument("--plan", default=None, metavar="TASK",
                    help="print TASK's RL budget and file path instead")
    ap.add_argument("--hours", type=float, default=None,
                    help="with --plan: fit the budget to H hours on the 2-core CPU")
    args = ap.parse_args()
    if args.plan:
        from r2pac_jax.data import DatasetError

        try:
            budget, path = plan(args.plan, args.hours)
        except DatasetError as e:  # e.g. --hours 0
            ap.error(str(e))
        print(budget, path)
        return
    if args.hours is not None:
        ap.error("--hours goes with --plan TASK")
    todo = unfinished()
    print(" ".join(todo[:args.first] if args.first else todo))


if __name__ == "__main__":
    main()

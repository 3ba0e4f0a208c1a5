"""The tasks whose v2 chain is not finished yet, in make_learned.sh's order: a task is finished
when its quality-bar results are archived in results_v2/TASK (r2pac.json). Prints them
space-separated (the first N with --first N), for

    nice -n 5 bash experiments/data_factory/task_pipeline.sh $(python experiments/data_factory/next_tasks.py --first 1)
"""
from __future__ import annotations

import argparse
import re
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--first", type=int, default=None, help="only the first N")
    args = ap.parse_args()
    todo = unfinished()
    print(" ".join(todo[:args.first] if args.first else todo))


if __name__ == "__main__":
    main()

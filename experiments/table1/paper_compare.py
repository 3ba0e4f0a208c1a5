"""Our CPU table beside the paper's Table 1, cell by cell, for the columns both have.

    python experiments/table1/paper_compare.py [--table experiments/table1/cpu-quick/table.csv]
        [--paper ../shared/paper/r2pac-paper.txt] > experiments/table1/paper_compare.md

Not a reproduction check: the paper's numbers come from DSRL's datasets at each method's
published budget, ours from this project's learned-behaviour data (v2) at the CPU `quick`
preset. What the side-by-side shows is which qualitative patterns (who is safe, who clones the
data's cost, who stands still) recur on other data and budgets. The paper's table is parsed from
its text, not retyped.
"""
from __future__ import annotations

import argparse
import csv
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
# the paper's column -> our --algo name (BC is OSRL's MLP BC on all data: bc-all-mlp)
COLUMNS = {"BC": "bc-all-mlp", "CDT": "cdt", "CPQ": "cpq", "COptiDICE": "coptidice",
           "TREBI": "trebi", "FISOR": "fisor", "ours": "r2pac"}
PAPER_ORDER = ["BC", "CDT", "CPQ", "COptiDICE", "TREBI", "FISOR", "ours"]
# the paper's row names -> our task names
ROWS = {"AntVel": "AntVelocity", "HalfCheetah Vel": "HalfCheetahVelocity",
        "SwimmerVel": "SwimmerVelocity"}


def paper_table(path: Path) -> dict:
    """{task: {paper column: (reward, cost)}} from the paper's Table 1 (tab-separated rows)."""
    text = path.read_text()
    start = text.index("Table 1: Normalized DSRL")
    out = {}
    for line in text[start:].splitlines()[1:60]:
        cells = line.split("\t")
        if len(cells) != 1 + 2 * len(PAPER_ORDER) or "Average" in cells[0]:
            continue
        try:
            nums = [float(c) for c in cells[1:]]
        except ValueError:
            continue  # the header rows
        task = ROWS.get(cells[0].strip(), cells[0].strip())
        out[task] = {c: (nums[2 * i], nums[2 * i + 1]) for i, c in enumerate(PAPER_ORDER)}
    if not out:
        raise SystemExit(f"{path}: no Table-1 rows found")
    return out


def our_table(path: Path) -> dict:
    """{task: {algo: (reward, cost, safe)}} from table.csv."""
    out: dict = {}
    with open(path) as f:
        for r in csv.DictReader(f):
            if r["reward_mean"] in ("", "None"):
                continue
            out.setdefault(r["task"], {})[r["algo"]] = (
                float(r["reward_mean"]), float(r["cost_mean"]), r["safe"] == "True")
    return out


def fmt(reward: float, cost: float) -> str:
    s = f"{reward:.2f} / {cost:.2f}"
    return f"**{s}**" if cost < 1 else f"{s} †"


def compare(paper: dict, ours: dict) -> str:
    algos = [c for c in COLUMNS if any(COLUMNS[c] in ours.get(t, {}) for t in ours)]
    name = {"ours": "R2PAC"}
    head = "| Task | " + " | ".join(f"{name.get(c, c)}: paper | {name.get(c, c)}: here"
                                   for c in algos) + " |"
    lines = [head, "|---|" + "---|---|" * len(algos)]
    agree = total = 0
    for task in sorted(t for t in ours if t in paper):
        row = [task]
        for c in algos:
            p = paper[task][c]
            o = ours[task].get(COLUMNS[c])
            row += [fmt(*p), fmt(o[0], o[1]) if o else "–"]
            if o:
                total += 1
                agree += (p[1] < 1) == (o[1] < 1)
        lines.append("| " + " | ".join(row) + " |")
    lines.append("")
    lines.append(f"Normalised reward / cost; **bold** safe (cost < 1), † unsafe. Paper: DSRL's data, "
                 f"each method's published budget; here: this project's data v2, CPU quick preset. "
                 f"The safe/unsafe verdict is the same in {agree} of {total} cells; –: not run here "
                 "yet.")
    extra = sorted(t for t in ours if t not in paper)
    if extra:
        lines.append(f"Tasks of ours outside the paper's table: {', '.join(extra)}.")
    absent = sorted(t for t in paper if t not in ours)
    lines.append(f"Paper tasks without a row here: {', '.join(absent)}." if absent else
                 "Every task of the paper's table has a row here.")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--table", default=str(ROOT / "experiments/table1/cpu-quick/table.csv"))
    ap.add_argument("--paper", default=str(ROOT.parent / "shared/paper/r2pac-paper.txt"))
    args = ap.parse_args()
    print(compare(paper_table(Path(args.paper)), our_table(Path(args.table))))


if __name__ == "__main__":
    main()

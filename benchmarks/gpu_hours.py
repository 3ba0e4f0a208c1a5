"""What the paper-preset Table 1 costs in device-hours, from measured training rates.

    python benchmarks/gpu_hours.py benchmarks/results/efficiency_h100.jsonl [--precision default]
        [--seeds 3] [--out FILE.md]

Reads `benchmarks/efficiency.py`'s rows (preset `paper`), takes each algorithm's rate per phase
at the most lanes measured (seed-steps/s: seeds vmapped share the device), and adds up, for each
of the paper's Table-1 columns over its rows (the tasks of `../shared/paper`'s Table 1), the
training steps of `--seeds` seeds at the paper preset (per task: TREBI's steps depend on the
task's family) divided by that rate. Evaluation and data generation are excluded. The
arithmetic is printed beside every figure.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from r2pac_jax.config import make_config

ROOT = Path(__file__).resolve().parents[1]


PAPER = ROOT.parent / "shared" / "paper" / "r2pac-paper.txt"


def table1(paper: Path = PAPER):
    """(paper column -> algo, [task]) of the paper's Table 1."""
    sys.path.insert(0, str(ROOT / "experiments" / "table1"))
    import paper_compare

    return paper_compare.COLUMNS, list(paper_compare.paper_table(Path(paper)))


def rates(rows: list[dict], precision: str) -> dict:
    """{algo: {phase: (seed_steps_per_s, lanes, device)}} at the most lanes measured."""
    out: dict = {}
    for r in rows:
        if r.get("kind") != "step" or r["preset"] != "paper" or \
                r.get("matmul_precision", "default") != precision:
            continue
        have = out.setdefault(r["algo"], {}).get(r["phase"])
        if have is None or r["lanes"] > have[1]:
            out[r["algo"]][r["phase"]] = (r["seed_steps_per_s"], r["lanes"],
                                          r.get("device", r.get("cpu", "?")))
    return out


def estimate(rows: list[dict], precision: str = "default", seeds: int = 3,
             paper: Path = PAPER) -> tuple[str, dict]:
    """(the markdown, {algo: hours})."""
    columns, tasks = table1(paper)
    hours_of = {}
    got = rates(rows, precision)
    lines = [f"Paper preset, {len(tasks)} Table-1 tasks x {seeds} seeds, training only "
             f"(matmul_precision={precision}; rates at the most lanes measured):", "",
             "| column | algo | steps per seed (phases) | seed-steps/s (lanes) | hours |",
             "|---|---|---|---|---:|"]
    total, stand_ins = 0.0, []
    for col, algo in columns.items():
        if algo not in got:
            lines.append(f"| {col} | {algo} | | not measured | |")
            continue
        secs, steps_txt = 0.0, set()
        for task in tasks:
            cfg = make_config(task, algo, "paper")
            for phase in cfg.phases:
                rate = got[algo].get(phase)
                if rate is None:  # an unmeasured phase at a measured one's rate, said below
                    other, rate = next(iter(got[algo].items()))
                    if (algo, phase, other) not in stand_ins:
                        stand_ins.append((algo, phase, other))
                secs += seeds * cfg.steps / rate[0]
            steps_txt.add(f"{cfg.steps:,} x {len(cfg.phases)}")
        rate_txt = ", ".join(f"{p} {v[0]:,.3g} ({v[1]})" for p, v in got[algo].items())
        hours = hours_of[algo] = secs / 3600
        total += hours
        mark = " *" if any(a == algo for a, _, _ in stand_ins) else ""
        lines.append(f"| {col} | {algo} | {' or '.join(sorted(steps_txt))} | {rate_txt} | "
                     f"{hours:,.1f}{mark} |")
    lines += ["", f"Sum over the measured columns: {total:,.1f} hours. Per column: sum over "
                  f"tasks and phases of {seeds} x steps / (seed-steps/s), / 3600."]
    lines += [f"* {algo}: its {phase} phase was not measured; its {other} phase's rate stands in."
              for algo, phase, other in stand_ins]
    return "\n".join(lines), hours_of


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("rows", help="efficiency.py's JSON lines")
    ap.add_argument("--precision", default="default")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--paper", default=str(PAPER), help="the paper's text (its Table 1's rows)")
    ap.add_argument("--out")
    args = ap.parse_args(argv)
    rows = [json.loads(x) for x in Path(args.rows).read_text().splitlines() if x.strip()]
    text, _ = estimate(rows, args.precision, args.seeds, args.paper)
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The rule of PROTOCOL.md applied to the runs of run.sh: each setting against float32.

    python experiments/precision/compare.py [--runs runs/precision] [--out FILE.md]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

TASKS = ("ReachAvoid", "HalfCheetahVelocity")
MODES = ("default", "highest", "bf16")
METRICS = (("normalized_reward", "reward"), ("normalized_cost", "cost"))


def verdicts(results: dict) -> list[dict]:
    """results {task: {mode: results.json}} -> one row per (task, mode, metric); a setting
    passes a metric when |its seed mean - float32's| <= 2 x float32's std (ddof 0)."""
    rows = []
    for task, by_mode in results.items():
        ref = by_mode.get("default")
        if ref is None:
            continue
        for mode in MODES:
            if mode not in by_mode:
                continue
            for key, name in METRICS:
                r, m = ref[key], by_mode[mode][key]
                gap, allowed = abs(m["mean"] - r["mean"]), 2 * r["std"]
                rows.append(dict(task=task, mode=mode, metric=name, mean=m["mean"],
                                 per_seed=m["per_seed"], gap=gap, allowed=allowed,
                                 passed=gap <= allowed,
                                 wall_s=by_mode[mode].get("wall_time_s")))
    return rows


def render(rows: list[dict]) -> str:
    out = ["| task | setting | metric | seed mean | per seed | gap to float32 | allowed (2 std) "
           "| within | run wall time |", "|---|---|---|---:|---|---:|---:|---|---:|"]
    for r in rows:
        seeds = ", ".join(f"{x:.3f}" for x in r["per_seed"])
        wall = f"{r['wall_s'] / 60:.1f} min" if r["wall_s"] else ""
        out.append(f"| {r['task']} | {r['mode']} | {r['metric']} | {r['mean']:.3f} | {seeds} | "
                   f"{r['gap']:.3f} | {r['allowed']:.3f} | {'yes' if r['passed'] else 'NO'} | "
                   f"{wall} |")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", default="runs/precision")
    ap.add_argument("--out")
    args = ap.parse_args(argv)
    results = {t: {m: json.loads((Path(args.runs) / t / m / "results.json").read_text())
                   for m in MODES if (Path(args.runs) / t / m / "results.json").exists()}
               for t in TASKS}
    rows = verdicts(results)
    missing = [f"{t}/{m}" for t in TASKS for m in MODES if m not in results[t]]
    text = render(rows)
    others = [r for r in rows if r["mode"] != "default"]
    if missing:
        text += f"\n\nMissing runs: {', '.join(missing)} (no verdict yet)."
    else:
        ok = all(r["passed"] for r in others)
        text += ("\n\nEvery setting is within the criterion on both tasks." if ok else
                 "\n\nNot every setting is within the criterion (rows marked NO).")
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Windowed means of a learned-data generation's training log (`FILE.log.jsonl`, or the
archived `results_v2/TASK/FILE.log.jsonl.gz`): the figures GENERATION.md reads off each file.

    python experiments/data_factory/log_windows.py LOG [--every 0.5] [--half-width 0.25]

Prints the mean and 5th-95th percentile of the logged env steps/s over every update, then for
windows centred every `--every` M env steps the mean cost limit, episode return, episode cost
and multiplier over the updates within +-`--half-width` M steps that finished an episode.
"""
from __future__ import annotations

import argparse
import gzip
import json

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("log")
    ap.add_argument("--every", type=float, default=0.5, help="window centres, M env steps apart")
    ap.add_argument("--half-width", type=float, default=0.25, help="M env steps")
    args = ap.parse_args()
    opener = gzip.open if args.log.endswith(".gz") else open
    with opener(args.log, "rt") as f:
        rows = [json.loads(line) for line in f if line.strip()]
    if not rows:
        raise SystemExit(f"error: {args.log} holds no logged update")
    rate = np.array([r["steps_per_s"] for r in rows])
    p5, p95 = np.percentile(rate, [5, 95])
    print(f"{len(rows)} updates; env steps/s mean {rate.mean():.0f}, 5th-95th {p5:.0f}-{p95:.0f}")
    rows = [r for r in rows if r["finished"] > 0]  # updates that finished no episode log zeros
    steps = np.array([r["env_steps"] for r in rows]) / 1e6
    keys = ("cost_limit", "episode_return", "episode_cost", "multiplier")
    print("   M steps  limit  return    cost  multiplier")
    for c in np.arange(args.half_width, steps.max() + 1e-9, args.every):
        sel = [r for r, s in zip(rows, steps) if abs(s - c) <= args.half_width]
        if sel:
            m = [np.mean([r[k] for r in sel]) for k in keys]
            print(f"{c:9.2f} {m[0]:6.1f} {m[1]:7.2f} {m[2]:7.1f} {m[3]:11.2f}")


if __name__ == "__main__":
    main()

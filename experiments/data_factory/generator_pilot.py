"""A short generation run that reads the learner's own log only (no file, no agent trained): does
the episode cost follow the scheduled limit, how high does the multiplier go, how far does the
policy's noise fall? Used to choose a per-task recipe value (PROTOCOL.md's addendum of
2026-12-06: a generator change is judged by the data checks, pilots read the generator's log).

  python experiments/data_factory/generator_pilot.py --task SwimmerVelocity --budget 3000000 \
      [--ppo init_log_std=-1.5 ...] [--out runs/pilots]

Prints one JSON line: per tenth of the run, the mean limit, episode cost and return, the
multiplier and log_std, and the share of finished episodes with cost <= kappa over the last
tenth. The partial directory (log, checkpoints) stays under --out; a rerun resumes it.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def summarise(rows):
    n = len(rows)
    tenths = []
    for i in range(10):
        part = rows[i * n // 10:(i + 1) * n // 10]
        if not part:
            continue
        tenths.append({k: round(float(np.mean([r[k] for r in part])), 3)
                       for k in ("cost_limit", "episode_cost", "episode_return", "multiplier",
                                 "log_std")})
    return tenths


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", required=True)
    ap.add_argument("--budget", type=int, required=True)
    ap.add_argument("--ppo", nargs="*", default=[], help="PPOLagConfig overrides, KEY=JSON")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="runs/pilots")
    a = ap.parse_args(argv)
    from r2pac_jax.data.factory import collect, parse_recipe_values
    from r2pac_jax.tasks import get_task

    task = get_task(a.task)
    ppo = parse_recipe_values(a.ppo)
    spec = collect.make_spec(task, env_steps=a.budget, seed=a.seed, ppo=ppo)
    tag = "-".join(f"{k}{v}" for k, v in sorted(ppo.items())) or "recipe"
    d = Path(a.out) / f"{a.task}-b{a.budget}-s{a.seed}-{tag}"
    gen = collect.Generation(task, spec, d, progress=sys.stderr.isatty())
    gen.run()
    rows = [json.loads(x) for x in open(d / "log.jsonl")]
    tail = rows[-max(1, len(rows) // 10):]
    fin = sum(r["finished"] for r in tail)
    print(json.dumps(dict(task=a.task, budget=a.budget, ppo=ppo, updates=len(rows),
                          last_limit=spec.schedule.end,
                          last_tenth_share_within_last_limit=(
                              sum(r["finished_within_last_limit"] for r in tail) / fin
                              if fin else None),
                          tenths=summarise(rows))))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

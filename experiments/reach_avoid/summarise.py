"""Tables of the ReachAvoid experiment (run_all.sh), with every trained policy re-evaluated under
the three candidate-selection rules on the same evaluation keys.

    python experiments/reach_avoid/summarise.py [OUT_DIR] [--episodes 20]

Writes OUT_DIR/summary.json (all numbers; re-evaluations are cached in OUT_DIR/reeval/) and
prints the markdown tables that experiments/reach_avoid/RESULTS.md quotes.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from r2pac_jax.evaluate import evaluate_run
from r2pac_jax.io import atomic_write_json
from r2pac_jax.report import results_table

ALGOS = ["r2pac", "r2pac-no-penalty", "r2pac-no-vc", "r2pac-awr", "r2pac-awr-flow", "r2pac-hj",
         "bc-all", "bc-safe"]
RULES = ["min_qc", "first", "safe_then_reward"]
SAMPLED = {"r2pac", "r2pac-no-penalty", "r2pac-no-vc", "r2pac-awr-flow", "r2pac-hj"}


def _stats(x) -> dict:
    x = np.asarray(x, float)
    return dict(mean=float(x.mean()), std=float(x.std()), per_seed=[float(v) for v in x])


def reeval(run_dir: Path, rule: str, cache: Path, episodes: int) -> dict:
    """Per-lane normalised reward/cost of a run under a selection rule (cached)."""
    f = cache / f"{run_dir.parent.name}__{run_dir.name}__{rule}.json"
    if f.exists():
        return json.loads(f.read_text())
    out = evaluate_run(run_dir, episodes=episodes, selection=rule)
    res = dict(normalized_reward=out["normalized_reward"].tolist(),
               normalized_cost=out["normalized_cost"].tolist(), seeds=out["seeds"],
               mean_return=out["returns"].mean(-1).tolist(), mean_cost=out["costs"].mean(-1).tolist())
    atomic_write_json(f, res)
    return res


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("out", nargs="?", default="runs/reach_avoid")
    ap.add_argument("--episodes", type=int, default=20)
    args = ap.parse_args()
    out = Path(args.out)
    cache = out / "reeval"
    summary: dict = {"algos": {}, "selection": {}, "sweeps": {}}

    # 1. every algorithm as trained (training-time evaluation: min_qc for sampled critic-based
    #    actors, first sample for BC, the Gaussian mean for the AWR actor)
    cells = {}
    for algo in ALGOS:
        f = out / algo / "results.json"
        if f.exists():
            r = json.loads(f.read_text())
            cells[algo] = r
            summary["algos"][algo] = {k: r[k] for k in ("normalized_reward", "normalized_cost")}
    if cells:
        print("## All algorithms, 3 seeds x 20 episodes (training-time evaluation)\n")
        print(results_table({"ReachAvoid": cells}, [a for a in ALGOS if a in cells]))

    # 2. the selection rules on the same trained parameters
    rows = {}
    for algo in ALGOS:
        if algo not in SAMPLED or algo not in cells:
            continue
        rows[algo] = {}
        for rule in RULES:
            r = reeval(out / algo, rule, cache, args.episodes)
            rows[algo][rule] = {k: _stats(r[k]) for k in ("normalized_reward", "normalized_cost")}
    summary["selection"] = rows
    if rows:
        print("\n## Candidate selection at sampling time (same parameters, same evaluation keys)\n")
        print(results_table({f"{a}": {rule: v for rule, v in r.items()} for a, r in rows.items()},
                            RULES))

    # 3. the sweeps, every cell under every rule
    for sweep_dir in sorted(p for p in out.glob("sweep_*") if (p / "cells").is_dir()):
        recs = [json.loads(p.read_text()) for p in (sweep_dir / "cells").glob("*.json")]
        recs.sort(key=lambda r: sorted(r["axes"].items()))  # rows in grid order, not by hash
        table: dict = {}
        for rec in recs:
            run_dir = Path(rec["run_dir"])
            lanes = json.loads((run_dir / "lanes.json").read_text())
            hp = {k: v for k, v in rec["values"].items() if k in ("quantile_alpha", "penalty_c",
                                                                   "guidance_scale")}
            idx = [i for i, c in enumerate(lanes["cells"])
                   if all(abs(lanes["cell_hparams"][c][k] - v) < 1e-9 for k, v in hp.items())]
            label = ", ".join(f"{k}={v}" for k, v in sorted(rec["axes"].items()))
            table[label] = {}
            for rule in RULES:
                r = reeval(run_dir, rule, cache, args.episodes)
                table[label][rule] = {k: _stats(np.asarray(r[k])[idx])
                                      for k in ("normalized_reward", "normalized_cost")}
        summary["sweeps"][sweep_dir.name] = table
        print(f"\n## Sweep {sweep_dir.name} (each cell re-evaluated under every rule)\n")
        print(results_table(table, RULES))
    atomic_write_json(out / "summary.json", summary)


if __name__ == "__main__":
    main()

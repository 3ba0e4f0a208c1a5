"""The imitability checks of a dataset: cloners trained on it (they use the training loop, so
this module sits above it), with the data-level coverage checks of `data/checks.py`.

- imitability (skipped with --fast): `bc-safe` (chunked flow) and `bc-safe-mlp` (OSRL's one-step
  MLP) each reach a mean normalised cost < 1 over the seeds and >= 80% of the safe episodes' mean
  normalised return; `bc-all-mlp`'s mean cost lies within +-25% of the data's mean normalised
  episode cost. Quick preset, seeds 100-102 (disjoint from the quality bar's 0-2).
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Callable, Optional, Sequence

from r2pac_jax.config import field_types, make_config
from r2pac_jax.data.checks import check_coverage, coverage, finish, read_file
from r2pac_jax.data.dsrl import load_dsrl
from r2pac_jax.lanes import Lanes
from r2pac_jax.loop import Run
from r2pac_jax.tasks import TaskSpec

IMITATORS = ("bc-safe", "bc-safe-mlp", "bc-all-mlp")
DEFAULT_SEEDS = (100, 101, 102)


def imitability(task: TaskSpec, path, cov: dict, seeds: Sequence[int], out_dir,
                log: Callable[[str], None] = print, preset: str = "quick",
                overrides: Optional[dict] = None) -> dict:
    """Train the three cloners (quick preset) on the file and compare with the data itself."""
    ds = load_dsrl(path, task.obs_dim, task.act_dim, task.name)
    out = {}
    for algo in IMITATORS:
        if algo.startswith("bc-safe") and cov["safe_share"] == 0:
            # nothing to clone: the safe cloners fail their checks, with the reason recorded
            out[algo] = dict(skipped=f"no episode with cost <= kappa = {task.kappa:g}")
            log(f"{algo}: skipped, the file has no episode with cost <= kappa")
            continue

        keys = field_types(algo)
        over = {k: v for k, v in (overrides or {}).items() if k in keys}
        cfg = make_config(task, algo, preset, dict(over, seeds=len(seeds)))
        t0 = time.time()
        res = Run(cfg, task, ds, Path(out_dir) / algo, Lanes.build(cfg, list(seeds)),
                  progress=False, log=log).run(resume=True)
        out[algo] = dict(normalized_reward=res["normalized_reward"],
                         normalized_cost=res["normalized_cost"], wall_s=time.time() - t0,
                         eval_backend=res.get("eval_backend"))
        log(f"{algo}: reward {res['normalized_reward']['per_seed']}, cost "
            f"{res['normalized_cost']['per_seed']}")
    target = cov["safe_mean_normalised_return"]
    data_cost = cov["mean_normalised_cost"]
    flags = {}
    for algo in ("bc-safe", "bc-safe-mlp"):
        r = out[algo]
        if "skipped" in r:
            flags[f"{algo}_safe"] = flags[f"{algo}_return"] = False
            continue
        flags[f"{algo}_safe"] = r["normalized_cost"]["mean"] < 1.0
        flags[f"{algo}_return"] = (target is not None
                                   and r["normalized_reward"]["mean"] >= 0.8 * target)
    c = out["bc-all-mlp"]["normalized_cost"]["mean"]
    flags["bc-all-mlp_cost_matches_data"] = abs(c - data_cost) <= 0.25 * data_cost
    out["pass"] = flags
    out["targets"] = dict(safe_return_80pct=None if target is None else 0.8 * target,
                          data_mean_cost=data_cost, seeds=list(seeds), preset=preset)
    # the simulator that scored the cloners (Bullet tasks: bullet and MJX scores differ)
    out["eval_backend"] = ", ".join(sorted({out[a]["eval_backend"] for a in IMITATORS
                                            if out[a].get("eval_backend")}))
    return out


def check_file(path, task_name: Optional[str] = None, fast: bool = False,
               seeds: Sequence[int] = DEFAULT_SEEDS, work_dir=None,
               log: Callable[[str], None] = print, overrides: Optional[dict] = None) -> dict:
    """Run the checks on a file; write and return `{file}.checks.json`. `overrides`: config
    values for the cloners (tests use tiny ones; the bar is the quick preset). A file with no
    safe episode fails the safe cloners' checks without training them. fast: coverage only."""
    if fast:
        return check_coverage(path, task_name)
    path, task, ds = read_file(path, task_name)
    result = dict(file=str(path), task=task.name, date=time.strftime("%Y-%m-%d %H:%M"),
                  fast=False, coverage=coverage(task, ds))
    work = Path(work_dir) if work_dir else Path(f"{path}.checks-runs")
    result["imitability"] = imitability(task, path, result["coverage"], seeds, work, log,
                                        overrides=overrides)
    flags = dict(result["coverage"]["pass"])
    flags.update(result["imitability"]["pass"])
    return finish(path, result, flags)

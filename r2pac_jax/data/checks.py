"""Checks of a dataset itself, none involving R2PAC (the data issue's bar for usable data).

    python -m r2pac_jax.data check FILE [--task T] [--fast] [--seeds 100,101,102]

- coverage: best episode >= 0.9 normalised return, worst <= 0.1; the costliest episode >= 3 kappa;
  safe (cost <= kappa) and unsafe episodes each >= 20% of the file;
- temptation (reported, no bar): the best return overall minus the best safe return, normalised;
- imitability (skipped with --fast): `bc-safe` (chunked flow) and `bc-safe-mlp` (OSRL's one-step
  MLP) each reach a mean normalised cost < 1 over the seeds and >= 80% of the safe episodes' mean
  normalised return; `bc-all-mlp`'s mean cost lies within +-25% of the data's mean normalised
  episode cost. Quick preset, seeds 100-102 (disjoint from the quality bar's 0-2).

The result is written atomically to `{file}.checks.json` and printed; `train` warns when the
file it trains on has none.
"""
from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Callable, Optional, Sequence

import numpy as np

from r2pac_jax.data.dsrl import Dataset, DatasetError, load_dsrl
from r2pac_jax.tasks import TaskSpec, get_task

IMITATORS = ("bc-safe", "bc-safe-mlp", "bc-all-mlp")
DEFAULT_SEEDS = (100, 101, 102)


def checks_path(path) -> Path:
    return Path(f"{path}.checks.json")


def file_task(path) -> Optional[str]:
    """The task a file says it belongs to (HDF5 attribute, else its card), or None; a file
    that cannot be read as HDF5 (damaged, truncated, another format) is a DatasetError."""
    import h5py

    try:
        with h5py.File(path, "r") as f:
            if "task" in f.attrs:
                return str(f.attrs["task"])
    except OSError as e:
        raise DatasetError(f"{path}: cannot be read as HDF5 ({e}). Fix: the file is damaged or "
                           "not HDF5; download or generate it again") from e
    card = Path(path).with_suffix(".json")
    if card.exists():
        return json.loads(card.read_text()).get("task")
    return None


def normalised(task: TaskSpec, returns, costs):
    """DSRL's per-episode normalised return and cost."""
    eps = 1.0 if task.kappa == 0 else 0.0
    return ((np.asarray(returns) - task.r_min) / (task.r_max - task.r_min),
            (np.asarray(costs) + eps) / (task.kappa + eps))


def coverage(task: TaskSpec, ds: Dataset) -> dict:
    rets, costs = ds.episode_sums()
    nr, nc = normalised(task, rets, costs)
    safe = costs <= task.kappa
    out = dict(
        episodes=int(rets.size), best_normalised_return=float(nr.max()),
        worst_normalised_return=float(nr.min()), max_episode_cost=float(costs.max()),
        safe_share=float(safe.mean()), unsafe_share=float((~safe).mean()),
        mean_normalised_cost=float(nc.mean()),
        safe_mean_normalised_return=float(nr[safe].mean()) if safe.any() else None,
        temptation=float(nr.max() - (nr[safe].max() if safe.any() else nr.min())))
    out["pass"] = dict(best_return=out["best_normalised_return"] >= 0.9,
                       worst_return=out["worst_normalised_return"] <= 0.1,
                       max_cost=out["max_episode_cost"] >= 3 * task.kappa,
                       safe_share=out["safe_share"] >= 0.2,
                       unsafe_share=out["unsafe_share"] >= 0.2)
    return out


def imitability(task: TaskSpec, path, cov: dict, seeds: Sequence[int], out_dir,
                log: Callable[[str], None] = print, preset: str = "quick",
                overrides: Optional[dict] = None) -> dict:
    """Train the three cloners (quick preset) on the file and compare with the data itself."""
    from r2pac_jax.config import make_config
    from r2pac_jax.lanes import Lanes
    from r2pac_jax.loop import Run

    ds = load_dsrl(path, task.obs_dim, task.act_dim, task.name)
    out = {}
    for algo in IMITATORS:
        from r2pac_jax.config import field_types

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
    safe episode fails the safe cloners' checks without training them."""
    from r2pac_jax.io import atomic_write_json

    path = Path(path).expanduser()
    if not path.is_file():
        raise DatasetError(f"{path}: no such file" + (" (a directory)" if path.is_dir() else "")
                           + ". Fix: pass the dataset's .hdf5 file")
    name = task_name or file_task(path)
    if name is None:
        raise DatasetError(f"{path}: the file does not say its task; pass --task")
    task = get_task(name)
    ds = load_dsrl(path, task.obs_dim, task.act_dim, task.name)
    result = dict(file=str(path), task=task.name, date=time.strftime("%Y-%m-%d %H:%M"),
                  fast=fast, coverage=coverage(task, ds))
    if not fast:
        work = Path(work_dir) if work_dir else Path(f"{path}.checks-runs")
        result["imitability"] = imitability(task, path, result["coverage"], seeds, work, log,
                                            overrides=overrides)
    flags = dict(result["coverage"]["pass"])
    if not fast:
        flags.update(result["imitability"]["pass"])
    result["failed"] = sorted(k for k, v in flags.items() if not v)
    result["passed"] = not result["failed"]
    atomic_write_json(checks_path(path), result)
    return result

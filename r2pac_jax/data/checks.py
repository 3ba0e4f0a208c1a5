"""The coverage checks of a dataset (the data issue's bar for usable data), read off its
episodes alone; the imitability checks, which train cloners, live above the training loop
(`r2pac_jax/imitability.py`).

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
from typing import Optional

import numpy as np

from r2pac_jax.data.dsrl import Dataset, DatasetError, load_dsrl
from r2pac_jax.tasks import TaskSpec, get_task

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


def read_file(path, task_name: Optional[str] = None) -> tuple:
    """(path, task, dataset) of a file to check; DatasetError naming what is wrong."""
    path = Path(path).expanduser()
    if not path.is_file():
        raise DatasetError(f"{path}: no such file" + (" (a directory)" if path.is_dir() else "")
                           + ". Fix: pass the dataset's .hdf5 file")
    name = task_name or file_task(path)
    if name is None:
        raise DatasetError(f"{path}: the file does not say its task; pass --task")
    task = get_task(name)
    return path, task, load_dsrl(path, task.obs_dim, task.act_dim, task.name)


def finish(path: Path, result: dict, flags: dict) -> dict:
    """Record the failed checks in `result` and write it atomically to `{file}.checks.json`."""
    from r2pac_jax.io import atomic_write_json

    result["failed"] = sorted(k for k, v in flags.items() if not v)
    result["passed"] = not result["failed"]
    atomic_write_json(checks_path(path), result)
    return result


def check_coverage(path, task_name: Optional[str] = None) -> dict:
    """The fast checks (coverage only), written to `{file}.checks.json` and returned."""
    path, task, ds = read_file(path, task_name)
    result = dict(file=str(path), task=task.name, date=time.strftime("%Y-%m-%d %H:%M"),
                  fast=True, coverage=coverage(task, ds))
    return finish(path, result, dict(result["coverage"]["pass"]))

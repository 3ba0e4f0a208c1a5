"""results.json of a run: per cell (hyperparameter values) the per-seed and mean scores."""
from __future__ import annotations

import dataclasses
from typing import Optional

import numpy as np

from r2pac_jax.config import Config
from r2pac_jax.lanes import Lanes


def _stats(per_seed: np.ndarray) -> dict:
    """Mean and std over the seeds with finite values (diverged lanes are NaN: null in JSON)."""
    x = np.asarray(per_seed, float)
    ok = np.isfinite(x)
    return dict(mean=float(x[ok].mean()) if ok.any() else None,
                std=float(x[ok].std()) if ok.any() else None,
                per_seed=[float(v) if np.isfinite(v) else None for v in x])


def _nan_to_none(a) -> list:
    """Nested lists with null where a diverged lane has no value (NaN is not JSON)."""
    a = np.asarray(a)
    if not np.issubdtype(a.dtype, np.floating) or np.isfinite(a).all():
        return a.tolist()
    return [[float(v) if np.isfinite(v) else None for v in row] for row in a]


def run_results(cfg: Config, task_name: str, lanes: Lanes, summary: dict, ev: Optional[dict],
                wall: float, steps: int, dataset: str, physics: str,
                diverged: Optional[dict] = None, resumed_from_step: int = 0,
                eval_backend: Optional[str] = None, dataset_path=None,
                provenance: bool = False) -> dict:
    """summary: the agent's per-lane scalars ({name: [L]}); ev: LaneEvaluator's output or None.
    wall, steps: this call's seconds and training steps; a resumed call starts at
    `resumed_from_step`, recorded so that its wall_time_s reads as that part of the run only.
    `provenance`: also what the cell stands on (the simulator that scored it, `eval_backend`:
    bullet and MJX scores of a Bullet task are not interchangeable; the device that trained it;
    the machine; the RL budget of the file at `dataset_path`), so a table names rows trained
    elsewhere or on a cut budget.

    One entry per cell in `cells`; with a single cell its entries also sit at the top level."""
    out = dict(task=task_name, algo=cfg.algo, preset=cfg.preset, dataset=dataset,
               physics=physics, total_steps=cfg.total_steps, wall_time_s=wall,
               train_steps_per_s=steps / wall if wall > 0 else None,
               resumed_from_step=resumed_from_step,
               config=dataclasses.asdict(cfg), cells=[])
    summary = {k: np.asarray(v) for k, v in summary.items()}
    for c, hp in enumerate(lanes.cell_hparams):
        idx = [i for i, ci in enumerate(lanes.cells) if ci == c]
        cell = dict(hparams=hp, seeds=[lanes.seeds[i] for i in idx])
        cell.update({k: [float(v[i]) for i in idx] for k, v in summary.items()})
        if diverged:
            cell["diverged"] = [dict(diverged[i], lane=i) for i in idx if i in diverged]
        if ev is not None:
            cell.update(
                normalized_reward=_stats(ev["normalized_reward"][idx]),
                normalized_cost=_stats(ev["normalized_cost"][idx]),
                returns=_nan_to_none(ev["returns"][idx]), costs=_nan_to_none(ev["costs"][idx]),
                lengths=_nan_to_none(ev["lengths"][idx]),
                mean_return=_stats(ev["returns"][idx].mean(-1)),
                mean_cost=_stats(ev["costs"][idx].mean(-1)),
                episodes=int(ev["returns"].shape[-1]))
            if "terminal_share" in ev:  # where the episodes ended, and the policy's diagnostics
                cell.update(mean_length=_stats(ev["mean_length"][idx]),
                            terminal_share=_stats(ev["terminal_share"][idx]),
                            diagnostics={k: _stats(v[idx]) for k, v in
                                         ev.get("diagnostics", {}).items()})
            mean_cost = cell["normalized_cost"]["mean"]
            cell["safe"] = mean_cost is not None and bool(mean_cost < 1.0)
        out["cells"].append(cell)
    if len(out["cells"]) == 1:
        out.update({k: v for k, v in out["cells"][0].items() if k != "hparams"})
    if provenance:
        from r2pac_jax.data.factory import data_budget
        from r2pac_jax.machine import describe, training_device

        if eval_backend is not None:
            out["eval_backend"] = eval_backend
        out["trained_on"] = training_device()
        out["machine"] = describe()
        out["data_budget"] = data_budget(dataset_path) if dataset_path else None
    return out

"""results.json of a run: per cell (hyperparameter values) the per-seed and mean scores."""
from __future__ import annotations

import dataclasses
from typing import Optional

import numpy as np

from r2pac_jax.config import Config
from r2pac_jax.lanes import Lanes


def _stats(per_seed: np.ndarray) -> dict:
    return dict(mean=float(np.mean(per_seed)), std=float(np.std(per_seed)),
                per_seed=[float(x) for x in per_seed])


def run_results(cfg: Config, task_name: str, lanes: Lanes, summary: dict, ev: Optional[dict],
                wall: float, steps: int, dataset: str, physics: str) -> dict:
    """summary: the agent's per-lane scalars ({name: [L]}); ev: LaneEvaluator's output or None.

    One entry per cell in `cells`; with a single cell its entries also sit at the top level."""
    out = dict(task=task_name, algo=cfg.algo, preset=cfg.preset, dataset=dataset,
               physics=physics, total_steps=cfg.total_steps, wall_time_s=wall,
               train_steps_per_s=steps / wall if wall > 0 else None,
               config=dataclasses.asdict(cfg), cells=[])
    summary = {k: np.asarray(v) for k, v in summary.items()}
    for c, hp in enumerate(lanes.cell_hparams):
        idx = [i for i, ci in enumerate(lanes.cells) if ci == c]
        cell = dict(hparams=hp, seeds=[lanes.seeds[i] for i in idx])
        cell.update({k: [float(v[i]) for i in idx] for k, v in summary.items()})
        if ev is not None:
            cell.update(
                normalized_reward=_stats(ev["normalized_reward"][idx]),
                normalized_cost=_stats(ev["normalized_cost"][idx]),
                returns=ev["returns"][idx].tolist(), costs=ev["costs"][idx].tolist(),
                lengths=ev["lengths"][idx].tolist(),
                mean_return=_stats(ev["returns"][idx].mean(-1)),
                mean_cost=_stats(ev["costs"][idx].mean(-1)),
                episodes=int(ev["returns"].shape[-1]))
            cell["safe"] = bool(cell["normalized_cost"]["mean"] < 1.0)
        out["cells"].append(cell)
    if len(out["cells"]) == 1:
        out.update({k: v for k, v in out["cells"][0].items() if k != "hparams"})
    return out

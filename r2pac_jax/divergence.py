"""Lanes whose training went non-finite. A run stops at the first such block (`stop`, what a
user running one config wants: the last finite checkpoint is kept); a sweep marks the lanes
(`mark`) and lets the others finish, and a marked lane is evaluated as NaN without being run."""
from __future__ import annotations

from typing import Callable, Optional

import jax
import numpy as np

from r2pac_jax.errors import R2pacError

MODES = ("stop", "mark")
_EPISODE_KEYS = ("returns", "costs", "lengths", "terminals")
_LANE_KEYS = ("normalized_reward", "normalized_cost", "mean_length", "terminal_share")


class TrainingDiverged(R2pacError, RuntimeError):
    """A block produced non-finite metrics; the last finite checkpoint is kept."""


def check_finite(metrics: dict, bad_step: np.ndarray, last_good: Optional[int], diverged: dict,
                 mode: str, lanes, where: str, log: Callable[[str], None]) -> None:
    """metrics {name: [L]} of one block; bad_step [L]: each lane's first non-finite step in it
    (run steps). `mark`: new non-finite lanes go into `diverged` ({lane: {seed, step, terms}},
    in place) with a log line; `stop`: TrainingDiverged naming the terms, lanes and seeds."""
    bad = {k: [int(x) for x in np.flatnonzero(~np.isfinite(v)) if int(x) not in diverged]
           for k, v in metrics.items()}
    bad = {k: v for k, v in bad.items() if v}
    if bad and mode == "mark":
        for lane in sorted({ln for v in bad.values() for ln in v}):
            terms = sorted(k for k, v in bad.items() if lane in v)
            step = int(bad_step[lane])
            diverged[lane] = dict(seed=lanes.seeds[lane], step=step, terms=terms)
            log(f"lane {lane} (seed {lanes.seeds[lane]}, cell "
                f"{lanes.cell_hparams[lanes.cells[lane]]}) diverged at step {step} (non-finite "
                f"{', '.join(terms)}); it is marked and the other lanes go on")
        return
    if bad:
        bad_lanes = sorted({lane for v in bad.values() for lane in v})
        seeds = [lanes.seeds[i] for i in bad_lanes]
        kept = (f"the last checkpoint (step {last_good}) is kept" if last_good is not None
                else "no checkpoint was written")
        first = int(min(bad_step[i] for i in bad_lanes))
        raise TrainingDiverged(
            f"{where}: non-finite {', '.join(sorted(bad))} first at step {first} (lanes "
            f"{bad_lanes}, seeds {seeds}); training stopped and {kept}. Lower the learning rate "
            "(--set lr=...) or check the dataset for non-finite values")


def evaluate_lanes(evaluator, pp, keys, diverged: dict, size: int, episodes: int) -> dict:
    """The evaluator's output for `size` lanes of policy parameters `pp`; the diverged lanes'
    scores are NaN and their policies are not run (a healthy lane's parameters stand in, so that
    the batch keeps its shape)."""
    bad = sorted(diverged)
    good = [i for i in range(size) if i not in diverged]
    if bad and not good:
        res = {k: np.full((size, episodes), np.nan) for k in _EPISODE_KEYS}
        res.update({k: np.full(size, np.nan) for k in _LANE_KEYS})
        res["diagnostics"] = {}
        return res
    if bad:
        idx = np.array([good[0] if i in diverged else i for i in range(size)])
        pp = jax.tree_util.tree_map(lambda x: x[idx], pp)
    res = dict(evaluator(pp, keys))

    def blank(a):
        a = np.array(a, dtype=float)
        a[bad] = np.nan
        return a

    if bad:
        res = {k: ({n: blank(x) for n, x in v.items()} if k == "diagnostics" else blank(v))
               for k, v in res.items()}
    return res

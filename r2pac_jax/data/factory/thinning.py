"""DSRL-style thinning: a density grid over (episode cost, episode return).

DSRL kept its behaviour agents' finished trajectories and removed trajectories from crowded
regions of the cost/return plane so that no single behaviour dominates. Here: bin the plane
into a grid, then cap every cell at the same count, chosen as the largest cap that keeps at most
`target` trajectories; within a crowded cell the kept ones are drawn at random (seeded).
"""
from __future__ import annotations

import numpy as np


def thin_by_density(returns: np.ndarray, costs: np.ndarray, target: int, bins: int = 20,
                    seed: int = 0) -> np.ndarray:
    """Indices (sorted) of at most `target` trajectories, evened out over the grid.

    returns, costs: [E] per-trajectory sums. Every non-empty cell keeps at least one trajectory
    when `target` allows it, so rare behaviours (for example the few safe ones) survive.
    """
    returns = np.asarray(returns, float)
    costs = np.asarray(costs, float)
    n = returns.shape[0]
    if target >= n:
        return np.arange(n)
    if target < 1:
        raise ValueError(f"target must be >= 1, got {target}")

    def edges(x):
        lo, hi = float(x.min()), float(x.max())
        return np.linspace(lo, hi if hi > lo else lo + 1.0, bins + 1)

    ci = np.clip(np.digitize(costs, edges(costs)[1:-1]), 0, bins - 1)
    ri = np.clip(np.digitize(returns, edges(returns)[1:-1]), 0, bins - 1)
    cell = ci * bins + ri
    counts = np.bincount(cell, minlength=bins * bins)
    # largest cap with sum(min(count, cap)) <= target
    lo, hi = 0, int(counts.max())
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if np.minimum(counts, mid).sum() <= target:
            lo = mid
        else:
            hi = mid - 1
    cap = max(lo, 1)
    rng = np.random.default_rng(seed)
    keep = []
    for c in np.flatnonzero(counts):
        members = np.flatnonzero(cell == c)
        if members.size > cap:
            members = rng.choice(members, size=cap, replace=False)
        keep.append(members)
    kept = np.sort(np.concatenate(keep))
    if kept.size > target:  # cap 1 over more non-empty cells than the target: subsample
        kept = np.sort(rng.choice(kept, size=target, replace=False))
    return kept


def select_episodes(arrays: dict, keep: np.ndarray) -> dict:
    """Rows of the chosen episodes (episodes end at terminals | timeouts), in order."""
    ends = np.flatnonzero(arrays["terminals"] | arrays["timeouts"])
    starts = np.concatenate([[0], ends[:-1] + 1])
    rows = np.concatenate([np.arange(starts[e], ends[e] + 1) for e in keep])
    return {k: v[rows] for k, v in arrays.items()}

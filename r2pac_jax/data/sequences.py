"""Windows of whole episodes with returns- and costs-to-go, as OSRL's `SequenceDataset` serves
them to the Constrained Decision Transformer, and its Pareto-frontier augmentation.

A sample is one episode drawn with probability proportional to max(`cost_weight_base` - C, 0)
(C the episode's cost; OSRL's `cost_sample` with its linear transform 70 - C) and a start
index s drawn uniformly in [0, len - 1]; the window holds rows s .. s + K - 1, right-padded
with zeros (mask 0) past the episode's end. Returns-/costs-to-go are undiscounted sums from
each row to the episode's end (gamma 1), times the run's reward / cost scale.

Augmentation (OSRL's `augmentation`): the episodes' (cost, return) points are grid-filtered
(10 cost x 50 return bins, at most 10 per bin, bins of <= 2 dropped), a polynomial of degree
`deg` is fitted to their Pareto frontier (least cost, most return), and `augment_percent` x
(filtered count) new targets are drawn: costs evenly spaced over the filtered range, returns
uniform between frontier(c) + min_reward and max_reward. Each target relabels its nearest
filtered episode of no greater cost (ties spread by 1 / (distance + beta) among episodes within
`max_rew_decrease` of its return): that episode's observations and actions, with its
returns-/costs-to-go shifted so that they start at the target. Augmented episodes share rows
with their sources (an offset per episode), so they cost no memory.
"""
from __future__ import annotations

from collections import Counter
from typing import NamedTuple, Optional

import chex
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from r2pac_jax.data.dsrl import Dataset


@struct.dataclass
class SequenceData:
    """Device arrays: rows [N, ...] of the dataset, episodes [M] (originals then augmented)."""

    observations: jax.Array  # [N, obs_dim]
    actions: jax.Array  # [N, act_dim]
    returns_to_go: jax.Array  # [N] raw (unscaled) sum of rewards from the row to its episode end
    costs_to_go: jax.Array  # [N] raw
    cost_labels: jax.Array  # [N] int32 in {0, 1}: the cost-prediction target
    ep_start: jax.Array  # [M] int32 first row
    ep_len: jax.Array  # [M] int32
    ep_return_shift: jax.Array  # [M] added to returns_to_go (0 for original episodes)
    ep_cost_shift: jax.Array  # [M]
    ep_logits: jax.Array  # [M] log sampling weights (-inf: never drawn)
    target_return: jax.Array  # [] the evaluation's return target (raw)


class SequenceBatch(NamedTuple):
    states: jax.Array  # [B, K, obs_dim]
    actions: jax.Array  # [B, K, act_dim]
    returns_to_go: jax.Array  # [B, K] scaled
    costs_to_go: jax.Array  # [B, K] scaled
    time_steps: jax.Array  # [B, K] int32 steps within the episode
    mask: jax.Array  # [B, K] float32, 0 on padding
    cost_labels: jax.Array  # [B, K] int32


def episode_table(ds: Dataset) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(starts [E], lengths [E], returns [E], costs [E]) of the dataset's episodes."""
    starts, ends = ds.episode_bounds()
    ret, cost = ds.episode_sums()
    return starts, ends - starts + 1, ret, cost


def to_go(values: np.ndarray, starts: np.ndarray, lengths: np.ndarray,
          discount: float = 1.0) -> np.ndarray:
    """sum_k discount^k values[i + k] from each row i to its episode's end: [N] -> [N]
    (float64; rows outside the episodes 0)."""
    out = np.zeros(values.shape[0], np.float64)
    for s, n in zip(starts, lengths):
        if discount == 1.0:
            out[s:s + n] = np.cumsum(values[s:s + n][::-1].astype(np.float64))[::-1]
            continue
        acc = 0.0
        for i in range(s + n - 1, s - 1, -1):
            acc = values[i] + discount * acc
            out[i] = acc
    return out


def pareto_front(costs: np.ndarray, returns: np.ndarray) -> np.ndarray:
    """Indices of the points no other point dominates (cost <= and return >=, one strictly).
    Equal points are all kept, as oapackage's ParetoDoubleLong keeps them."""
    c = np.asarray(costs, np.float64)
    r = np.asarray(returns, np.float64)
    keep = []
    for i in range(c.size):
        dom = (c <= c[i]) & (r >= r[i]) & ((c < c[i]) | (r > r[i]))
        if not dom.any():
            keep.append(i)
    return np.asarray(keep, np.int64)


def grid_filter(x: np.ndarray, y: np.ndarray, xbins: int, ybins: int, max_per_bin: int,
                min_per_bin: int, rng: np.random.Generator) -> np.ndarray:
    """OSRL's grid filter over (x, y): bins of their range, at most `max_per_bin` drawn from a
    fuller bin, bins holding <= `min_per_bin` points dropped. -> kept indices."""
    x = np.asarray(x, np.float64)
    y = np.asarray(y, np.float64)
    xstep = (x.max() - x.min()) / xbins
    ystep = (y.max() - y.min()) / ybins
    # a degenerate range puts every point in bin 0 (OSRL would divide by zero)
    xi = np.zeros(x.size) if xstep == 0 else (x - x.min()) // xstep
    yi = np.zeros(y.size) if ystep == 0 else (y - y.min()) // ystep
    bins: dict[tuple, list] = {}
    for i in range(x.size):
        bins.setdefault((xi[i], yi[i]), []).append(i)
    kept = []
    for members in bins.values():
        if len(members) > max_per_bin:
            kept += sorted(rng.choice(members, max_per_bin, replace=False).tolist())
        elif len(members) > min_per_bin:
            kept += members
    return np.asarray(kept, np.int64)


def nearest_points(points: np.ndarray, targets: np.ndarray, max_rew_decrease: float,
                   beta: float, rng: np.random.Generator) -> list[int]:
    """OSRL's get_nearest_point: points [P, 2] and targets [T, 2] as (cost, return). Each target
    takes the nearest point of no greater cost; a point chosen n > 1 times keeps one and hands
    the other n - 1 to points of no greater cost within `max_rew_decrease` of its return, drawn
    with probability ~ 1 / (distance + beta). -> T point indices (grouped as OSRL returns them)."""
    first = []
    for p in targets:
        ok = np.flatnonzero(points[:, 0] <= p[0])  # non-empty: targets start at the min cost
        d = np.hypot(*(points[ok] - p).T)
        first.append(int(ok[np.argmin(d)]))
    out = []
    for idx, num in Counter(first).items():
        out.append(idx)
        if num > 1:
            p = points[idx]
            ok = np.flatnonzero((points[:, 0] <= p[0]) & (points[:, 1] >= p[1] - max_rew_decrease))
            w = 1.0 / (np.hypot(*(points[ok] - p).T) + beta)
            out.extend(ok[rng.choice(ok.size, size=num - 1, p=w / w.sum())].tolist())
    return out


def augment(costs: np.ndarray, returns: np.ndarray, deg: int, max_rew_decrease: float,
            beta: float, augment_percent: float, max_reward: float, min_reward: float,
            rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """OSRL's Pareto augmentation of episodes with (cost, return) -> (source episode [T],
    target cost [T], target return [T]) for T = int(augment_percent x filtered count)."""
    kept = grid_filter(costs, returns, 10, 50, 10, 2, rng)
    if kept.size == 0:
        return np.zeros(0, np.int64), np.zeros(0), np.zeros(0)
    c, r = np.asarray(costs, np.float64)[kept], np.asarray(returns, np.float64)[kept]
    front = pareto_front(c, r)
    # at most (distinct costs - 1) degrees: OSRL's polyfit fails on a one-cost frontier
    fit_deg = min(deg, np.unique(c[front]).size - 1)
    frontier = np.poly1d(np.polyfit(c[front], r[front], deg=fit_deg))
    n = int(augment_percent * c.size)
    if n == 0:
        return np.zeros(0, np.int64), np.zeros(0), np.zeros(0)
    tc = np.linspace(c.min(), c.max(), n)
    low = frontier(tc) + min_reward
    # OSRL draws with the legacy np.random.uniform, which takes low > high (the frontier above
    # max_reward) and draws between them; Generator.uniform refuses that, so the same formula,
    # low + (high - low) u, is written out (equal to Generator.uniform wherever low <= high)
    tr = low + (max_reward - low) * rng.random(n)
    src = nearest_points(np.stack([c, r], 1), np.stack([tc, tr], 1), max_rew_decrease, beta, rng)
    return kept[np.asarray(src, np.int64)], tc, tr


def build_sequences(ds: Dataset, keep_episodes: Optional[np.ndarray] = None,
                    augmentation: Optional[dict] = None, cost_weight_base: Optional[float] = 70.0,
                    target_return: Optional[float] = None, seed: int = 0) -> SequenceData:
    """The device view. augmentation: `augment`'s keyword values (deg, max_rew_decrease, beta,
    augment_percent, max_reward, min_reward) or None; cost_weight_base None samples episodes
    uniformly; target_return None leaves 0 (the agent sets its own)."""
    starts, lengths, ret, cost = episode_table(ds)
    keep = np.ones(starts.size, bool) if keep_episodes is None else np.asarray(keep_episodes)
    starts, lengths, ret, cost = starts[keep], lengths[keep], ret[keep], cost[keep]
    if starts.size == 0:
        raise ValueError(f"{ds.source}: no episode left after filtering")
    rng = np.random.default_rng(seed)
    src = np.arange(starts.size)
    r_shift = np.zeros(starts.size)
    c_shift = np.zeros(starts.size)
    ep_cost = cost.astype(np.float64)
    if augmentation:
        a_src, tc, tr = augment(cost, ret, rng=rng, **augmentation)
        src = np.concatenate([src, a_src])
        r_shift = np.concatenate([r_shift, tr - ret[a_src]])
        c_shift = np.concatenate([c_shift, tc - cost[a_src]])
        ep_cost = np.concatenate([ep_cost, tc])
    if cost_weight_base is None:
        logits = np.zeros(src.size)
    else:
        w = np.maximum(cost_weight_base - ep_cost, 0.0)
        if not (w > 0).any():
            raise ValueError(f"{ds.source}: every episode costs >= {cost_weight_base} "
                             "(cost_weight_base), so cost-weighted sampling draws none; set "
                             "cost_sample=false")
        with np.errstate(divide="ignore"):
            logits = np.log(w / w.sum())
    rtg = to_go(ds.rewards, starts, lengths)
    ctg = to_go(ds.costs, starts, lengths)
    labels = np.minimum(np.floor(ds.costs), 1).astype(np.int32)  # OSRL: costs.long() (0/1)
    return SequenceData(
        observations=jnp.asarray(ds.observations, jnp.float32),
        actions=jnp.asarray(ds.actions, jnp.float32),
        returns_to_go=jnp.asarray(rtg, jnp.float32), costs_to_go=jnp.asarray(ctg, jnp.float32),
        cost_labels=jnp.asarray(labels),
        ep_start=jnp.asarray(starts[src], jnp.int32), ep_len=jnp.asarray(lengths[src], jnp.int32),
        ep_return_shift=jnp.asarray(r_shift, jnp.float32),
        ep_cost_shift=jnp.asarray(c_shift, jnp.float32),
        ep_logits=jnp.asarray(logits, jnp.float32),
        target_return=jnp.float32(0.0 if target_return is None else target_return))


def sample(data: SequenceData, key: jax.Array, batch_size: int, seq_len: int,
           reward_scale: float, cost_scale: float) -> SequenceBatch:
    """`batch_size` windows of `seq_len` rows (episodes by their sampling weights, start
    uniform within the episode), on device."""
    k_ep, k_start = jax.random.split(key)
    ep = jax.random.categorical(k_ep, data.ep_logits, shape=(batch_size,))
    length = data.ep_len[ep]
    s = jax.random.randint(k_start, (batch_size,), 0, length)  # uniform in [0, len - 1]
    offs = jnp.arange(seq_len)
    mask = (s[:, None] + offs[None]) < length[:, None]  # [B, K]
    n = data.observations.shape[0]
    rows = jnp.minimum(data.ep_start[ep][:, None] + s[:, None] + offs[None], n - 1)
    m = mask.astype(jnp.float32)
    states = data.observations[rows] * m[..., None]
    actions = data.actions[rows] * m[..., None]
    rtg = (data.returns_to_go[rows] + data.ep_return_shift[ep][:, None]) * reward_scale * m
    ctg = (data.costs_to_go[rows] + data.ep_cost_shift[ep][:, None]) * cost_scale * m
    batch = SequenceBatch(states=states, actions=actions, returns_to_go=rtg, costs_to_go=ctg,
                          time_steps=(s[:, None] + offs[None]).astype(jnp.int32), mask=m,
                          cost_labels=data.cost_labels[rows] * mask.astype(jnp.int32))
    chex.assert_shape(batch.states, (batch_size, seq_len, data.observations.shape[1]))
    return batch

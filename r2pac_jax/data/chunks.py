"""h-step chunks of a dataset (docs/algorithm.md, "Data: h-step chunks"), precomputed once.

A sample for chunk length h starting at t is

    (s_t, a_{t:t+h}, R_t = sum_{k<n} g^k r_{t+k}, C_t = sum_{k<n} g^k c_{t+k}, s_{t+n}, m_t)

with n = h, except where the episode ends with a true terminal before h steps: then n stops at
the terminal, the action chunk is padded with the last action (masked out of the policy loss)
and m_t = 0. A chunk never crosses a timeout: starts whose h steps do not fit before a timeout
are not valid. Reward and cost are multiplied by the task's scales.
"""
from __future__ import annotations

from typing import NamedTuple

import chex
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from r2pac_jax.data.dsrl import Dataset
from r2pac_jax.errors import R2pacError


class ChunkError(R2pacError, ValueError):
    pass


@struct.dataclass
class ChunkedData:
    """Device arrays: transitions [N, ...] and per-valid-start chunk quantities [M]."""

    observations: jax.Array  # [N, obs_dim]
    next_observations: jax.Array  # [N, obs_dim]
    actions: jax.Array  # [N, act_dim]
    starts: jax.Array  # [M] int32, index t of each valid chunk start
    n_steps: jax.Array  # [M] int32, steps inside the chunk (h, or fewer at a terminal)
    reward_sum: jax.Array  # [M] discounted, scaled reward over the chunk
    cost_sum: jax.Array  # [M] discounted, scaled cost over the chunk
    bootstrap: jax.Array  # [M] float32 m_t: 0 where the chunk reaches a true terminal
    zmax: jax.Array  # [M] max over the chunk of z = +1 (cost > 0) / -1 (HJ variant)
    threshold_states: jax.Array  # [K] int32 fixed subset of state indices for the quantile
    chunk_len: int = struct.field(pytree_node=False)

    @property
    def num_starts(self) -> int:
        return int(self.starts.shape[0])


class Batch(NamedTuple):
    observations: jax.Array  # [B, obs_dim]
    actions: jax.Array  # [B, h, act_dim]
    action_mask: jax.Array  # [B, h] 1 on real steps, 0 on padding
    reward: jax.Array  # [B]
    cost: jax.Array  # [B]
    next_observations: jax.Array  # [B, obs_dim]
    bootstrap: jax.Array  # [B]
    zmax: jax.Array  # [B]


def check_chunk_len(ds: Dataset, h: int) -> None:
    """ChunkError unless 1 <= h <= the dataset's longest episode."""
    if h < 1:
        raise ChunkError(f"chunk length h must be >= 1, got {h}")
    starts_ep, ends_ep = ds.episode_bounds()
    longest = int((ends_ep - starts_ep + 1).max())
    if h > longest:
        raise ChunkError(f"chunk length {h} is longer than the longest episode ({longest} steps) "
                         f"of {ds.source}: choose --chunk-len <= {longest}")


def chunk_arrays(ds: Dataset, h: int, discount: float, reward_scale: float = 1.0,
                 cost_scale: float = 1.0, keep_episodes: np.ndarray | None = None) -> dict:
    """The per-start chunk quantities in numpy (used by `build_chunks`, and by tests)."""
    check_chunk_len(ds, h)
    starts_ep, ends_ep = ds.episode_bounds()
    n = ds.size
    ep_id = np.repeat(np.arange(len(ends_ep)), ends_ep - starts_ep + 1)
    ep_end = ends_ep[ep_id]  # [N] last index of each row's episode
    ends_in_terminal = ds.terminals[ep_end]
    t = np.arange(n)
    n_steps = np.minimum(h, ep_end - t + 1)
    valid = (n_steps == h) | ends_in_terminal
    if keep_episodes is not None:
        valid &= keep_episodes[ep_id]
    t = t[valid]
    n_steps = n_steps[valid]
    r = ds.rewards.astype(np.float64) * reward_scale
    c = ds.costs.astype(np.float64) * cost_scale
    z = np.where(ds.costs > 0, 1.0, -1.0)
    reward_sum = np.zeros(t.shape)
    cost_sum = np.zeros(t.shape)
    zmax = np.full(t.shape, -np.inf)
    for k in range(h):
        inside = k < n_steps
        idx = np.minimum(t + k, n - 1)
        reward_sum += np.where(inside, discount**k * r[idx], 0.0)
        cost_sum += np.where(inside, discount**k * c[idx], 0.0)
        zmax = np.where(inside, np.maximum(zmax, z[idx]), zmax)
    last = t + n_steps - 1
    bootstrap = ~ds.terminals[last]
    return dict(starts=t.astype(np.int32), n_steps=n_steps.astype(np.int32),
                reward_sum=reward_sum.astype(np.float32), cost_sum=cost_sum.astype(np.float32),
                bootstrap=bootstrap.astype(np.float32), zmax=zmax.astype(np.float32))


def build_chunks(ds: Dataset, h: int, discount: float, reward_scale: float = 1.0,
                 cost_scale: float = 1.0, keep_episodes: np.ndarray | None = None,
                 threshold_subset: int = 65536, seed: int = 0) -> ChunkedData:
    """Precompute valid starts and discounted sums; put everything on device.

    keep_episodes: optional [E] bool filter over episodes (BC-safe keeps the safe ones).
    """
    arr = chunk_arrays(ds, h, discount, reward_scale, cost_scale, keep_episodes)
    if arr["starts"].size == 0:
        raise ChunkError(f"{ds.source}: no valid chunk of length {h} (after filtering); use a "
                         "shorter --chunk-len or a dataset with more (safe) episodes")
    rng = np.random.default_rng(seed)
    k = min(threshold_subset, ds.size)
    subset = np.sort(rng.choice(ds.size, size=k, replace=False)).astype(np.int32)
    return ChunkedData(
        observations=jnp.asarray(ds.observations, jnp.float32),
        next_observations=jnp.asarray(ds.next_observations, jnp.float32),
        actions=jnp.asarray(ds.actions, jnp.float32),
        threshold_states=jnp.asarray(subset),
        chunk_len=h,
        **{k_: jnp.asarray(v) for k_, v in arr.items()},
    )


def sample(data: ChunkedData, key: jax.Array, batch_size: int) -> Batch:
    """Draw `batch_size` chunks uniformly over valid starts (on device, jittable)."""
    h = data.chunk_len
    i = jax.random.randint(key, (batch_size,), 0, data.starts.shape[0])
    t = data.starts[i]
    n = data.n_steps[i]
    steps = jnp.arange(h)
    # pad past a terminal with the last real action
    idx = t[:, None] + jnp.minimum(steps[None, :], n[:, None] - 1)
    batch = Batch(
        observations=data.observations[t],
        actions=data.actions[idx],
        action_mask=(steps[None, :] < n[:, None]).astype(jnp.float32),
        reward=data.reward_sum[i],
        cost=data.cost_sum[i],
        next_observations=data.next_observations[t + n - 1],
        bootstrap=data.bootstrap[i],
        zmax=data.zmax[i],
    )
    chex.assert_shape(batch.actions, (batch_size, h, data.actions.shape[1]))
    return batch

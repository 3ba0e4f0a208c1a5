"""One-step transitions of a dataset, as OSRL's `TransitionDataset` serves them.

The view of the one-step offline safe-RL baselines (CPQ, BCQ-Lag, COptiDICE): rows
(s_t, a_t, r_t, c_t, s_{t+1}, done_t, init_t) sampled uniformly over the dataset. OSRL sets
done = terminal OR timeout (a timeout ends the reward backup too); docs/algorithm.md's rule for the
chunk view is terminal only. Both are offered (`done_rule`), OSRL's being its algorithms'
default. Reward and cost are multiplied by the run's scales.
"""
from __future__ import annotations

from typing import NamedTuple, Optional

import chex
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from r2pac_jax.data.dsrl import Dataset

DONE_RULES = ("terminal_or_timeout", "terminal")


@struct.dataclass
class TransitionData:
    """Device arrays, all [N, ...] over the rows kept."""

    observations: jax.Array  # [N, obs_dim]
    next_observations: jax.Array  # [N, obs_dim]
    actions: jax.Array  # [N, act_dim]
    rewards: jax.Array  # [N] scaled
    costs: jax.Array  # [N] scaled
    done: jax.Array  # [N] float32 1 where the backup stops (see done_rule)
    is_init: jax.Array  # [N] float32 1 on the first step of an episode
    init_index: jax.Array  # [E] int32 rows of the episodes' first steps

    @property
    def size(self) -> int:
        return int(self.rewards.shape[0])


class TransitionBatch(NamedTuple):
    observations: jax.Array  # [B, obs_dim]
    actions: jax.Array  # [B, act_dim]
    rewards: jax.Array  # [B]
    costs: jax.Array  # [B]
    next_observations: jax.Array  # [B, obs_dim]
    done: jax.Array  # [B]
    is_init: jax.Array  # [B]
    init_observations: jax.Array  # [B, obs_dim] first states of uniformly drawn episodes


def transition_arrays(ds: Dataset, reward_scale: float = 1.0, cost_scale: float = 1.0,
                      done_rule: str = "terminal_or_timeout",
                      keep_episodes: Optional[np.ndarray] = None) -> dict:
    """The numpy arrays of `build_transitions` (also used by tests); with every row kept they
    share memory with `ds` (read them, never write to them)."""
    if done_rule not in DONE_RULES:
        raise ValueError(f"done_rule must be one of {DONE_RULES}, got {done_rule!r}")
    starts, ends = ds.episode_bounds()
    done = ds.terminals | ds.timeouts if done_rule == "terminal_or_timeout" else ds.terminals
    is_init = np.zeros(ds.size, bool)
    is_init[starts] = True
    idx = (None if keep_episodes is None or keep_episodes.all()
           else np.flatnonzero(np.repeat(keep_episodes, ends - starts + 1)))  # the kept rows

    def kept(a, dtype=np.float32):
        # every row kept: the file's own float32 arrays, not copies (a DSRL-size observation
        # array is 1.5 GB, and the device holds another copy of it)
        return (a if idx is None else a[idx]).astype(dtype, copy=False)

    return dict(observations=kept(ds.observations), next_observations=kept(ds.next_observations),
                actions=kept(ds.actions),
                rewards=(kept(ds.rewards, np.float64) * reward_scale).astype(np.float32),
                costs=(kept(ds.costs, np.float64) * cost_scale).astype(np.float32),
                done=kept(done), is_init=kept(is_init))


def build_transitions(ds: Dataset, reward_scale: float = 1.0, cost_scale: float = 1.0,
                      done_rule: str = "terminal_or_timeout",
                      keep_episodes: Optional[np.ndarray] = None) -> TransitionData:
    """Every row (of the kept episodes) on device. keep_episodes: optional [E] bool."""
    arr = transition_arrays(ds, reward_scale, cost_scale, done_rule, keep_episodes)
    if arr["rewards"].size == 0:
        raise ValueError(f"{ds.source}: no transition left after filtering")
    init_index = np.flatnonzero(arr["is_init"] > 0).astype(np.int32)
    return TransitionData(init_index=jnp.asarray(init_index),
                          **{k: jnp.asarray(v) for k, v in arr.items()})


def sample(data: TransitionData, key: jax.Array, batch_size: int) -> TransitionBatch:
    """`batch_size` rows drawn uniformly with replacement (OSRL's sampler), on device."""
    k_row, k_init = jax.random.split(key)
    i = jax.random.randint(k_row, (batch_size,), 0, data.rewards.shape[0])
    j = data.init_index[jax.random.randint(k_init, (batch_size,), 0, data.init_index.shape[0])]
    batch = TransitionBatch(observations=data.observations[i], actions=data.actions[i],
                            rewards=data.rewards[i], costs=data.costs[i],
                            next_observations=data.next_observations[i], done=data.done[i],
                            is_init=data.is_init[i], init_observations=data.observations[j])
    chex.assert_shape(batch.actions, (batch_size, data.actions.shape[1]))
    return batch

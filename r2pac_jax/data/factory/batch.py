"""Episode recording shared by the data sources: the batched C-MuJoCo recorder (navigation,
velocity) and the flattening of JAX-recorded episodes (ReachAvoid, PPO-Lagrangian).

A source supplies only its behaviour (`act`); stepping the batch, recording DSRL's arrays,
masking finished episodes, progress reporting and splitting a request into equal batches live
here once.
"""
from __future__ import annotations

from typing import Callable, Optional

import jax
import jax.numpy as jnp
import numpy as np

from r2pac_jax.data.factory.thinning import select_episodes

KEYS = ("observations", "next_observations", "actions", "rewards", "costs", "terminals",
        "timeouts")


@jax.jit
def _fold(base, idx):
    return jax.vmap(lambda i: jax.random.fold_in(base, i))(idx)


def episode_keys(seed: int, first: int, n: int) -> jax.Array:
    """Keys [n] of episodes first .. first + n - 1: episode i's key is fold_in(PRNGKey(seed), i),
    so a trajectory does not depend on the batch it was generated in."""
    return _fold(jax.random.PRNGKey(seed), jnp.arange(first, first + n))


def record_episodes(env, state, act: Callable[[int, object], np.ndarray], steps: int,
                    progress: Optional[Callable[[float], None]] = None,
                    progress_scale: float = 1.0) -> dict:
    """Step a batch of n episodes from `state` (batched C-MuJoCo env) for up to `steps` control
    steps with actions `act(t, state)` [n, act_dim]; DSRL arrays of the steps each episode
    really took, episode-major. Episodes still running after `steps` end in a timeout, so the
    arrays stay valid DSRL data. `progress` gets increments summing to n * progress_scale."""
    n = np.asarray(state.obs).shape[0]
    alive = np.ones(n, bool)
    rec = {k: [] for k in KEYS}
    valid = []
    reported = 0.0
    for t in range(steps):
        a = np.asarray(act(t, state), np.float32)
        nxt = env.step_batch(state, a)
        term = np.asarray(nxt.terminated)
        trunc = np.asarray(nxt.truncated)
        rec["observations"].append(np.asarray(state.obs))
        rec["next_observations"].append(np.asarray(nxt.obs))
        rec["actions"].append(a)
        rec["rewards"].append(np.asarray(nxt.reward))
        rec["costs"].append(np.asarray(nxt.cost))
        rec["terminals"].append(term)
        rec["timeouts"].append(trunc & ~term)
        valid.append(alive.copy())
        alive = alive & ~(term | trunc)
        state = nxt
        if progress is not None and (t + 1) % 100 == 0:
            done = n * (t + 1) / steps * progress_scale
            progress(done - reported)
            reported = done
        if not alive.any():
            break
    if progress is not None:
        progress(n * progress_scale - reported)
    rec["timeouts"][-1] = rec["timeouts"][-1] | alive  # still running: cut short by `steps`
    mask = np.stack(valid, 1)  # [n, T]
    return {k: np.stack(v, 1)[mask] for k, v in rec.items()}  # [n, T, ...] -> real steps


def keep_valid_steps(traj: dict) -> dict:
    """Episodes recorded by `envs.base.record_episode` (leaves [..., T, ...] with a `valid`
    mask [..., T]) -> DSRL arrays of the real steps only, episode-major."""
    traj = jax.tree_util.tree_map(np.asarray, traj)
    valid = traj.pop("valid")
    lead = valid.ndim
    return {k: v.reshape((-1,) + v.shape[lead:])[valid.reshape(-1)] for k, v in traj.items()}


def in_equal_batches(n: int, batch: int, run: Callable[[int, int], dict]) -> dict:
    """Episodes 0 .. n-1 as `run(first, size)` calls of equal size (one compile of the env's
    jitted functions), concatenated; the last batch's extra episodes are dropped."""
    nb = -(-n // batch)
    size = -(-n // nb)
    parts = [run(first, size) for first in range(0, n, size)]
    out = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    return select_episodes(out, np.arange(n))

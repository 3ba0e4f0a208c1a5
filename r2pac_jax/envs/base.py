"""The environment protocol: a pair of pure functions over a state pytree.

    state = env.reset(key)            # EnvState for one episode
    state = env.step(state, action)   # action [act_dim] in [-1, 1]

JAX-native environments (pure JAX, MJX) are jittable and vmappable: `JaxEnv` gives them batched
`reset_batch` / `step_batch` for free. Environments whose physics runs outside JAX (C MuJoCo)
set `is_jax = False` and implement `reset_batch(keys[B])` / `step_batch(state, actions[B, A])`
directly; `evaluate.py` then runs a Python loop over control steps instead of `lax.scan`.
"""
from __future__ import annotations

from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from r2pac_jax.errors import R2pacError


@struct.dataclass
class EnvState:
    """One episode's state. Leading batch axes are added by vmap / the batched backends."""

    obs: jax.Array  # [obs_dim] float32
    reward: jax.Array  # [] float32, reward of the last step (0 after reset)
    cost: jax.Array  # [] float32, cost of the last step
    terminated: jax.Array  # [] bool: a true terminal (no bootstrap)
    truncated: jax.Array  # [] bool: time limit reached
    t: jax.Array  # [] int32, steps taken in this episode
    key: jax.Array  # PRNG key carried by the episode (for stochastic dynamics / resets)
    physics: Any  # the env's own physical state (arrays, mjx.Data, ...)
    info: dict  # per-task extras (pytree of arrays)

    @property
    def done(self) -> jax.Array:
        return self.terminated | self.truncated


class ActionError(R2pacError, ValueError):
    pass


class BackendUnavailableError(R2pacError, RuntimeError):
    """A physics backend cannot run here (not installed, or not built for this task)."""


def check_action(action, act_dim: int, batch: int | None = None) -> np.ndarray:
    """Validate an action at a Python API border (gym wrapper, C-MuJoCo backend).

    Raises ActionError naming the problem: wrong shape or non-finite entries.
    """
    a = np.asarray(action, dtype=np.float32)
    want = (act_dim,) if batch is None else (batch, act_dim)
    if a.shape != want:
        raise ActionError(f"action has shape {a.shape}, expected {want} (act_dim={act_dim})")
    if not np.all(np.isfinite(a)):
        raise ActionError("action contains NaN or inf; the policy produced non-finite values")
    return a


class JaxEnv:
    """Base class for environments written in JAX: subclasses define `reset` and `step`."""

    is_jax = True
    name: str = "env"
    obs_dim: int
    act_dim: int
    episode_len: int

    def reset(self, key: jax.Array) -> EnvState:  # pragma: no cover - abstract
        raise NotImplementedError

    def step(self, state: EnvState, action: jax.Array) -> EnvState:  # pragma: no cover
        raise NotImplementedError

    # Batched entry points (used by Python-side callers; evaluate.py vmaps inside its own jit).
    def reset_batch(self, keys: jax.Array) -> EnvState:
        if not hasattr(self, "_reset_batch"):
            self._reset_batch = jax.jit(jax.vmap(self.reset))
        return self._reset_batch(keys)

    def step_batch(self, state: EnvState, actions: jax.Array) -> EnvState:
        if not hasattr(self, "_step_batch"):
            self._step_batch = jax.jit(jax.vmap(self.step))
        return self._step_batch(state, actions)


def record_episode(env, act: Callable[[EnvState, jax.Array], jax.Array], key: jax.Array) -> dict:
    """One episode of a JAX env under `act(state, key) -> action [A]` (jittable, vmappable):
    per-step arrays of length env.episode_len under DSRL's keys, plus `valid` [T] (False once
    the episode has ended; those steps are padding)."""
    k_reset, k_act = jax.random.split(key)

    def body(carry, k):
        s, alive = carry
        a = act(s, k)
        s2 = env.step(s, a)
        out = dict(observations=s.obs, next_observations=s2.obs, actions=a, rewards=s2.reward,
                   costs=s2.cost, terminals=s2.terminated, timeouts=s2.truncated & ~s2.terminated,
                   valid=alive)
        return (s2, alive & ~s2.done), out

    init = (env.reset(k_reset), jnp.array(True))
    _, traj = jax.lax.scan(body, init, jax.random.split(k_act, env.episode_len))
    return traj


# Row helpers for batched states stepped from Python (C MuJoCo, pybullet): a state is a pytree
# whose leaves have the episodes on their first axis.


def take_rows(state, idx: np.ndarray):
    """The episodes `idx` of a batched state (numpy leaves)."""
    return jax.tree_util.tree_map(lambda x: np.asarray(x)[idx], state)


def put_rows(full, idx: np.ndarray, part):
    """`full` (a copy, numpy leaves) with its rows `idx` replaced by `part`'s rows."""
    def put(f, p):
        f = np.array(f, copy=True)
        f[idx] = np.asarray(p)
        return f
    return jax.tree_util.tree_map(put, full, part)


def pow2_bucket(n: int) -> int:
    """The power of two >= n: batch sizes that jitted per-batch functions compile for."""
    return 1 << int(np.ceil(np.log2(max(n, 1))))


def time_limit(t: jax.Array, episode_len: int) -> jax.Array:
    """Truncation flag after `t` steps."""
    return t >= episode_len

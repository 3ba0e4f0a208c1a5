"""Flow matching with classifier-free guidance (Eq. 19-21, App. C) over flattened action chunks."""
from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp


def interpolate(a0: jax.Array, a1: jax.Array, i: jax.Array) -> jax.Array:
    """Linear path a^i = (1 - i) a^0 + i a: a0, a1 [B, D], i [B] -> [B, D]."""
    return (1.0 - i[:, None]) * a0 + i[:, None] * a1


def flow_matching_loss(v_pred, a0, a1, mask, weights=None) -> jax.Array:
    """Weighted ||v - (a - a^0)||^2 averaged over the real (unpadded) chunk steps.

    v_pred, a0, a1: [B, h, A]; mask [B, h]; weights [B] (AWR-Flow) or None -> [].
    """
    err = ((v_pred - (a1 - a0)) ** 2).mean(-1)  # [B, h]
    per_sample = (err * mask).sum(-1) / jnp.maximum(mask.sum(-1), 1.0)
    if weights is not None:
        per_sample = per_sample * jax.lax.stop_gradient(weights)
    return per_sample.mean()


def cfg_combine(v_uncond: jax.Array, v_cond: jax.Array, w) -> jax.Array:
    """vhat = v(null) + w (v(o=1) - v(null))."""
    return v_uncond + w * (v_cond - v_uncond)


def euler_sample(velocity: Callable[[jax.Array, jax.Array], jax.Array], a0: jax.Array,
                 steps: int) -> jax.Array:
    """Integrate da/di = velocity(a, i) from i = 0 to 1 in `steps` Euler steps: a <- a + v / N."""

    def body(a, n):
        i = n.astype(a.dtype) / steps
        return a + velocity(a, i) / steps, None

    a, _ = jax.lax.scan(body, a0, jnp.arange(steps))
    return a


def sample_chunks(velocity_apply: Callable, obs: jax.Array, key: jax.Array, k: int,
                  chunk_size: int, steps: int, guidance=None) -> jax.Array:
    """k candidate chunks per state from a flow policy: obs [B, o] -> [B, k, chunk_size] in [-1, 1].

    velocity_apply(a [n, D], i [n], obs [n, o], label [n] int) -> [n, D] is the velocity field
    with its parameters bound. With `guidance` (a [] scale) the field is CFG-combined from its
    o = 1 and null branches, evaluated in one batched pass; without it, the null branch alone.
    """
    from r2pac_jax.nets import NULL_LABEL

    B = obs.shape[0]
    obs_k = jnp.repeat(obs, k, axis=0)
    a0 = jax.random.normal(key, (B * k, chunk_size))
    n = B * k
    if guidance is not None:
        obs2 = jnp.concatenate([obs_k, obs_k])
        labels = jnp.concatenate([jnp.ones((n,), jnp.int32),
                                  jnp.full((n,), NULL_LABEL, jnp.int32)])

        def velocity(a, i):
            v = velocity_apply(jnp.concatenate([a, a]), jnp.full((2 * n,), i), obs2, labels)
            return cfg_combine(v[n:], v[:n], guidance)
    else:
        null = jnp.full((n,), NULL_LABEL, jnp.int32)

        def velocity(a, i):
            return velocity_apply(a, jnp.full((n,), i), obs_k, null)

    a = euler_sample(velocity, a0, steps)
    return jnp.clip(a, -1.0, 1.0).reshape(B, k, chunk_size)

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

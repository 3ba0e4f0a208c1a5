"""The AWR Gaussian actor's likelihood (the paper's "AWR actor" ablation, Eq. 40)."""
from __future__ import annotations

import jax
import jax.numpy as jnp


def chunk_log_prob(mean, log_std, x, mask) -> jax.Array:
    """log N(x | mean, exp(log_std)) summed over the real chunk steps.

    mean, x: [B, h, A]; log_std broadcastable to [B, h, A]; mask [B, h] -> [B].
    """
    z = (x - mean) * jnp.exp(-log_std)
    lp = -0.5 * z**2 - log_std - 0.5 * jnp.log(2.0 * jnp.pi)
    return (lp.sum(-1) * mask).sum(-1)


def weighted_nll(mean, log_std, x, mask, weights=None) -> jax.Array:
    """-E[w log pi(a_{t:t+h} | s)], per real step -> []."""
    lp = chunk_log_prob(mean, log_std, x, mask) / jnp.maximum(mask.sum(-1), 1.0)
    if weights is not None:
        lp = lp * jax.lax.stop_gradient(weights)
    return -lp.mean()

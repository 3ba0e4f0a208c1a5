"""Diagonal Gaussian policies' likelihood: the AWR actor (the paper's "AWR actor" ablation,
Eq. 40) and CDT's action head."""
from __future__ import annotations

import jax
import jax.numpy as jnp


def log_prob(x, mean, log_std) -> jax.Array:
    """Per-dimension log N(x | mean, exp(log_std)^2): all [..., A] -> [..., A]."""
    z = (x - mean) * jnp.exp(-log_std)
    return -0.5 * z**2 - log_std - 0.5 * jnp.log(2.0 * jnp.pi)


def entropy(log_std) -> jax.Array:
    """Per-dimension entropy of N(., exp(log_std)^2): [..., A] -> [..., A]."""
    return 0.5 + 0.5 * jnp.log(2.0 * jnp.pi) + log_std


def chunk_log_prob(mean, log_std, x, mask) -> jax.Array:
    """log N(x | mean, exp(log_std)) summed over the real chunk steps.

    mean, x: [B, h, A]; log_std broadcastable to [B, h, A]; mask [B, h] -> [B].
    """
    return (log_prob(x, mean, log_std).sum(-1) * mask).sum(-1)


def weighted_nll(mean, log_std, x, mask, weights=None) -> jax.Array:
    """-E[w log pi(a_{t:t+h} | s)], per real step -> []."""
    lp = chunk_log_prob(mean, log_std, x, mask) / jnp.maximum(mask.sum(-1), 1.0)
    if weights is not None:
        lp = lp * jax.lax.stop_gradient(weights)
    return -lp.mean()

"""Masked statistics for the diagnostics an agent logs beside its losses.

None of these is a formula of docs/algorithm.md: they describe what the critics and the policy do
(how well a critic fits a target, how labels split between safe and unsafe states, whether an
advantage tracks the reward), never feed back into training, and consume no random keys.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp


def rmse(pred: jax.Array, target: jax.Array) -> jax.Array:
    """Root mean squared error; pred [..., B] against target [B] (broadcast over an ensemble)."""
    return jnp.sqrt(jnp.mean(jnp.square(pred - target)))


def masked_mean(x: jax.Array, mask: jax.Array) -> jax.Array:
    """Mean of x[B] over mask[B] (bool); 0 where the mask is empty (logged with its count)."""
    m = mask.astype(jnp.float32)
    return jnp.sum(x * m) / jnp.maximum(jnp.sum(m), 1.0)


def masked_corr(x: jax.Array, y: jax.Array, mask: jax.Array) -> jax.Array:
    """Pearson correlation of x[B] and y[B] over mask[B]; 0 where it is undefined (fewer than
    two masked rows, or no spread)."""
    m = mask.astype(jnp.float32)
    n = jnp.maximum(jnp.sum(m), 1.0)
    dx = (x - jnp.sum(x * m) / n) * m
    dy = (y - jnp.sum(y * m) / n) * m
    den = jnp.sqrt(jnp.sum(dx * dx) * jnp.sum(dy * dy))
    return jnp.where(den > 0, jnp.sum(dx * dy) / jnp.where(den > 0, den, 1.0), 0.0)


def candidate_stats(qc: jax.Array, qr: jax.Array, idx: jax.Array) -> dict:
    """Per state, over its K candidate chunks: qc, qr [B, K], the chosen index idx [B].

    qc_spread / qr_spread: max - min of Q_c and Qbar_r; qr_given_up: the best candidate's Qbar_r
    less the chosen one's; not_first: 1 where the choice is not the first sample."""
    chosen_qr = jnp.take_along_axis(qr, idx[:, None], axis=1)[:, 0]
    return dict(qc_spread=qc.max(-1) - qc.min(-1), qr_spread=qr.max(-1) - qr.min(-1),
                qr_given_up=qr.max(-1) - chosen_qr,
                not_first=(idx != 0).astype(jnp.float32))

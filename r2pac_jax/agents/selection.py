"""Choice among sampled candidate chunks (docs/algorithm.md: 16 candidates, lowest Q_c)."""
from __future__ import annotations

import jax
import jax.numpy as jnp

RULES = ("min_qc", "safe_then_reward", "first")


def select_candidate(qc: jax.Array, qr: jax.Array, threshold, rule: str) -> jax.Array:
    """Index of the chosen candidate per state: qc, qr [B, K] -> [B] int32.

    min_qc: the lowest cost value (the paper's rejection sampling).
    safe_then_reward: among candidates with Q_c <= l the highest Qbar_r; if none, lowest Q_c.
    first: the first sample (no critic).
    """
    if rule == "min_qc":
        return jnp.argmin(qc, axis=-1).astype(jnp.int32)
    if rule == "first":
        return jnp.zeros(qc.shape[:-1], jnp.int32)
    if rule == "safe_then_reward":
        ok = qc <= threshold
        best = jnp.argmax(jnp.where(ok, qr, -jnp.inf), axis=-1)
        return jnp.where(ok.any(-1), best, jnp.argmin(qc, axis=-1)).astype(jnp.int32)
    raise ValueError(f"selection must be one of {RULES}, got {rule!r}")

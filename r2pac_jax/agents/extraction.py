"""Policy-extraction signals from the critics: CFG optimality labels (Eq. 18) and AWR weights
(Eq. 40-41). Inputs are per-sample [B] arrays; `safe` is V_c(s) <= l.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp

from r2pac_jax.nets import NULL_LABEL


def optimality_labels(safe, adv_r, adv_c, unsafe_branch: bool = True) -> jax.Array:
    """o = 1[Abar_r >= 0] in safe states, 1[A_c <= 0] in unsafe ones -> [B] int32.

    unsafe_branch=False ("w/o V_c") uses the reward advantage everywhere.
    """
    o_safe = adv_r >= 0
    if not unsafe_branch:
        return o_safe.astype(jnp.int32)
    return jnp.where(safe, o_safe, adv_c <= 0).astype(jnp.int32)


def drop_labels(key, labels, p_null: float) -> jax.Array:
    """Replace each label by null with probability p_null (the unconditional branch)."""
    return jnp.where(jax.random.bernoulli(key, p_null, labels.shape), NULL_LABEL, labels)


def awr_weights(safe, adv_r, adv_c, temperature, clip: float, unsafe_branch: bool = True):
    """1[safe] exp(a Abar_r) + 1[unsafe] exp(b (V_c - Q_c)), each exponential clipped (a = b)."""
    w_safe = jnp.minimum(jnp.exp(temperature * adv_r), clip)
    if not unsafe_branch:
        return w_safe
    w_unsafe = jnp.minimum(jnp.exp(-temperature * adv_c), clip)
    return jnp.where(safe, w_safe, w_unsafe)

"""IQL critics over action chunks (docs/algorithm.md "Critics"; the paper's Eq. 10-16 and 42).

Every target and loss of the critics is written here once; `r2pac.py` wires them together.
Arguments are per-sample arrays of shape [B] unless stated otherwise.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp


def expectile_loss(u: jax.Array, tau: float) -> jax.Array:
    """IQL's L2^tau(u) = |tau - 1(u < 0)| u^2 with u = Q - V: V moves to Q's upper expectile."""
    return jnp.where(u < 0, 1.0 - tau, tau) * u**2


def reversed_expectile_loss(u: jax.Array, tau: float) -> jax.Array:
    """Weight tau where u = Q - V < 0: V moves to Q's lower expectile (minimum cost)."""
    return jnp.where(u > 0, 1.0 - tau, tau) * u**2


def safety_threshold(vc: jax.Array, alpha: jax.Array) -> jax.Array:
    """l = alpha-quantile of V_c over states: [K] -> []."""
    return jnp.quantile(vc, alpha)


def cost_target(cost_sum, bootstrap, discount_h, vc_next):
    """Q_c target: C_t + g^h m_t V_c(s_{t+h})."""
    return cost_sum + discount_h * bootstrap * vc_next


def feasibility_target(zmax, bootstrap, discount_h, vz_next):
    """HJ target over a chunk: (1 - g^h) zmax + g^h max(zmax, V_z(s_{t+h})); zmax at a terminal."""
    boot = (1.0 - discount_h) * zmax + discount_h * jnp.maximum(zmax, vz_next)
    return jnp.where(bootstrap > 0, boot, zmax)


def penalty_value(penalty_c, discount: float, mode: str):
    """C-bar: the absorbing state's value -C / (1 - g), or the direct target -C."""
    if mode == "absorbing":
        return -penalty_c / (1.0 - discount)
    if mode == "direct":
        return -penalty_c
    raise ValueError(f"penalty_mode must be 'absorbing' or 'direct', got {mode!r}")


def penalised_reward_target(reward_sum, bootstrap, discount_h, vr_next, vc_next, threshold,
                            penalty, use_penalty: bool = True):
    """Qbar_r target (Eq. 15): C-bar where s_{t+h} is unsafe (V_c > l), else the h-step backup.

    A chunk ending in a true terminal (m = 0) has target R_t: no bootstrap and no penalty.
    With use_penalty=False ("w/o Vbar_r") it is the ordinary h-step backup everywhere.
    """
    backup = reward_sum + discount_h * bootstrap * vr_next
    if not use_penalty:
        return backup
    unsafe_next = (vc_next > threshold) & (bootstrap > 0)
    return jnp.where(unsafe_next, penalty, backup)


def q_regression_loss(q: jax.Array, target: jax.Array) -> jax.Array:
    """Mean squared error of every ensemble member: q [E, B], target [B] -> []."""
    return ((q - jax.lax.stop_gradient(target)[None]) ** 2).mean()

"""Discrete DDPM pieces (FISOR's actor): the VP noise schedule, the noising of a clean action,
and the ancestral sampler, as pure functions (jaxrl5/networks/diffusion.py of FISOR's code)."""
from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp


def vp_betas(steps: int) -> jax.Array:
    """The discrete VP schedule: beta_t = 1 - exp(-b_min / T - (b_max - b_min)(2t - 1) / (2 T^2)),
    t = 1..T, b_min 0.1, b_max 10: [T]."""
    t = jnp.arange(1, steps + 1, dtype=jnp.float32)
    b_min, b_max = 0.1, 10.0
    return 1.0 - jnp.exp(-b_min / steps - 0.5 * (b_max - b_min) * (2 * t - 1) / steps**2)


def schedule(steps: int):
    """(betas, alphas, alpha_hats), each [T]."""
    betas = vp_betas(steps)
    alphas = 1.0 - betas
    return betas, alphas, jnp.cumprod(alphas)


def noised(actions, t, noise, alpha_hats):
    """x_t = sqrt(ahat_t) a + sqrt(1 - ahat_t) eps: actions, noise [B, A]; t [B] int."""
    ah = alpha_hats[t][:, None]
    return jnp.sqrt(ah) * actions + jnp.sqrt(1.0 - ah) * noise


def sample(eps_fn: Callable, obs, act_dim: int, key, steps: int, temperature: float = 1.0,
           clip: bool = True):
    """Ancestral sampling from x_T ~ N(0, I): x <- (x - (1 - a_t) / sqrt(1 - ahat_t) eps(s, x, t))
    / sqrt(a_t) + [t > 0] sqrt(beta_t) temperature z, clipped to [-1, 1] each step (FISOR's
    clip_sampler) and at the end. eps_fn(obs [B, o], x [B, A], t [B, 1] float) -> [B, A]."""
    betas, alphas, alpha_hats = schedule(steps)
    k0, key = jax.random.split(key)
    x = jax.random.normal(k0, (obs.shape[0], act_dim))

    def step(carry, t):
        x, key = carry
        eps = eps_fn(obs, x, jnp.full((obs.shape[0], 1), t, jnp.float32))
        x = (x - (1.0 - alphas[t]) / jnp.sqrt(1.0 - alpha_hats[t]) * eps) / jnp.sqrt(alphas[t])
        key, kz = jax.random.split(key)
        x = x + (t > 0) * jnp.sqrt(betas[t]) * temperature * jax.random.normal(kz, x.shape)
        if clip:
            x = jnp.clip(x, -1.0, 1.0)
        return (x, key), None

    (x, _), _ = jax.lax.scan(step, (x, key), jnp.arange(steps - 1, -1, -1))
    return jnp.clip(x, -1.0, 1.0)

"""Networks: MLPs, critic ensembles, the flow velocity field and the Gaussian actor."""
from __future__ import annotations

from typing import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp


class MLP(nn.Module):
    hidden_dims: Sequence[int]
    out_dim: int
    layer_norm: bool = False

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        for h in self.hidden_dims:
            x = nn.Dense(h)(x)
            if self.layer_norm:
                x = nn.LayerNorm()(x)
            x = nn.gelu(x)
        return nn.Dense(self.out_dim)(x)


class QEnsemble(nn.Module):
    """Q(s, a_{t:t+h}) for `num` independent critics: obs [B, o], chunk [B, h*A] -> [num, B]."""

    hidden_dims: Sequence[int]
    num: int = 2
    layer_norm: bool = False

    @nn.compact
    def __call__(self, obs: jax.Array, chunk: jax.Array) -> jax.Array:
        x = jnp.concatenate([obs, chunk], axis=-1)
        ens = nn.vmap(MLP, variable_axes={"params": 0}, split_rngs={"params": True},
                      in_axes=None, out_axes=0, axis_size=self.num)
        return ens(self.hidden_dims, 1, self.layer_norm)(x)[..., 0]


class ValueNet(nn.Module):
    """V(s): obs [B, o] -> [B]."""

    hidden_dims: Sequence[int]
    layer_norm: bool = False

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        return MLP(self.hidden_dims, 1, self.layer_norm)(obs)[..., 0]


NULL_LABEL = 2  # optimality label o in {0, 1, null}


def time_features(i: jax.Array, dim: int) -> jax.Array:
    """Sinusoidal features of the flow time i in [0, 1]: [B] -> [B, dim]."""
    half = dim // 2
    freqs = jnp.exp(jnp.linspace(0.0, jnp.log(1000.0), half))
    ang = i[:, None] * freqs[None, :]
    return jnp.concatenate([jnp.sin(ang), jnp.cos(ang)], axis=-1)


class VelocityField(nn.Module):
    """v(a^i, i, s, o): chunk [B, h*A], time [B], obs [B, o], label [B] int -> [B, h*A]."""

    hidden_dims: Sequence[int]
    act_size: int
    time_dim: int = 16
    layer_norm: bool = False

    @nn.compact
    def __call__(self, a_i, i, obs, label):
        x = jnp.concatenate([a_i, time_features(i, self.time_dim), obs,
                             jax.nn.one_hot(label, 3)], axis=-1)
        return MLP(self.hidden_dims, self.act_size, self.layer_norm)(x)


class GaussianActor(nn.Module):
    """Diagonal Gaussian over the chunk: obs [B, o] -> (mean [B, h*A] in (-1, 1), log_std [h*A])."""

    hidden_dims: Sequence[int]
    act_size: int

    @nn.compact
    def __call__(self, obs):
        mean = jnp.tanh(MLP(self.hidden_dims, self.act_size)(obs))
        log_std = self.param("log_std", nn.initializers.zeros, (self.act_size,))
        return mean, jnp.clip(log_std, -5.0, 2.0)


def torch_linear_init(fan_in: int):
    """PyTorch nn.Linear's default init, U(-1/sqrt(fan_in), 1/sqrt(fan_in)), for weights and bias
    (so a cloner ported from OSRL starts from the same distribution)."""
    bound = 1.0 / jnp.sqrt(jnp.float32(fan_in))

    def init(key, shape, dtype=jnp.float32):
        return jax.random.uniform(key, shape, dtype, -bound, bound)

    return init


class DeterministicActor(nn.Module):
    """OSRL's MLPActor: ReLU hidden layers, tanh output. obs [B, o] -> action [B, act_dim]."""

    hidden_dims: Sequence[int]
    act_dim: int

    @nn.compact
    def __call__(self, obs):
        x = obs
        sizes = list(self.hidden_dims) + [self.act_dim]
        for n, h in enumerate(sizes):
            fan_in = x.shape[-1]
            x = nn.Dense(h, kernel_init=torch_linear_init(fan_in),
                         bias_init=torch_linear_init(fan_in))(x)
            if n < len(sizes) - 1:
                x = nn.relu(x)
        return jnp.tanh(x)

"""Diffuser's networks over trajectory windows (Janner et al. 2022, as TREBI uses them), in Flax:
a temporal 1-D convolutional U-Net that maps a noisy window x_t [B, H, D] and its step t [B] to
a window [B, H, D], and the value network (the U-Net's down half and an MLP head) that maps
them to a value [B]. Windows are (action, state) rows, channels last."""
from __future__ import annotations

import math

import flax.linen as nn
import jax
import jax.numpy as jnp


def mish(x):
    return x * jnp.tanh(jax.nn.softplus(x))


def time_embedding(t, dim: int):
    """Sinusoidal embedding of the steps t [B] (float): [B, dim]."""
    half = dim // 2
    freq = jnp.exp(-math.log(10000.0) * jnp.arange(half) / (half - 1))
    arg = t.astype(jnp.float32)[:, None] * freq[None]
    return jnp.concatenate([jnp.sin(arg), jnp.cos(arg)], -1)


class Conv(nn.Module):
    """A 1-D convolution over [B, H, C] (channels last) as one matmul of stacked shifted windows:
    nn.Conv's parameters (kernel [k, C, features], bias), names and initialisation, the same
    sums in another order. On the CPU, XLA's convolution of these few channels ran at about half
    the rate of the equal matmul (benchmarks/efficiency.py, issue 56)."""

    features: int
    kernel: int
    stride: int = 1
    padding: int = 0

    @nn.compact
    def __call__(self, x):
        k = self.param("kernel", nn.initializers.lecun_normal(),
                       (self.kernel, x.shape[-1], self.features))
        b = self.param("bias", nn.initializers.zeros, (self.features,))
        if self.padding:
            x = jnp.pad(x, ((0, 0), (self.padding, self.padding), (0, 0)))
        n = (x.shape[1] - self.kernel) // self.stride + 1
        end = self.stride * (n - 1) + 1
        cols = jnp.concatenate([x[:, i:i + end:self.stride] for i in range(self.kernel)], -1)
        return cols @ k.reshape(-1, self.features) + b


class ConvBlock(nn.Module):
    """Conv1d (same length) -> GroupNorm -> Mish."""

    features: int
    kernel: int = 5
    groups: int = 8

    @nn.compact
    def __call__(self, x):
        x = Conv(self.features, self.kernel, padding=self.kernel // 2)(x)
        return mish(nn.GroupNorm(num_groups=self.groups, epsilon=1e-5)(x))


class ResidualBlock(nn.Module):
    """Two conv blocks with the time embedding added between them, plus a (1x1) skip."""

    features: int
    kernel: int = 5

    @nn.compact
    def __call__(self, x, temb):
        h = ConvBlock(self.features, self.kernel)(x)
        h = h + nn.Dense(self.features)(mish(temb))[:, None, :]
        h = ConvBlock(self.features, self.kernel)(h)
        skip = x if x.shape[-1] == self.features else Conv(self.features, 1)(x)
        return h + skip


class TimeMLP(nn.Module):
    dim: int

    @nn.compact
    def __call__(self, t):
        e = time_embedding(t, self.dim)
        return nn.Dense(self.dim)(mish(nn.Dense(4 * self.dim)(e)))


def _down(x, features):
    return Conv(features, 3, stride=2, padding=1)(x)


def _level(x, temb, features):
    """A level's two residual blocks (made in the calling module, so parameter names are
    the same as when written out there)."""
    x = ResidualBlock(features)(x, temb)  # made in order: flax names modules as they are made
    return ResidualBlock(features)(x, temb)


class TemporalUnet(nn.Module):
    """x [B, H, D], t [B] -> [B, H, D]. H must be divisible by 2^(len(dim_mults) - 1).

    Down: at each level two residual blocks, the skip kept, then a halving (not at the last).
    Up (Diffuser's order): the deepest skips first, each level joining one, two residual blocks
    and a doubling, so that the first level's skip is not used, as in Diffuser."""

    transition_dim: int
    dim: int = 32
    dim_mults: tuple = (1, 2, 4, 8)

    @nn.compact
    def __call__(self, x, t):
        dims = [self.dim * m for m in self.dim_mults]
        temb = TimeMLP(self.dim)(t)
        skips = []
        for i, d in enumerate(dims):
            x = _level(x, temb, d)
            skips.append(x)
            if i < len(dims) - 1:
                x = _down(x, d)
        x = _level(x, temb, dims[-1])
        for d in reversed(dims[:-1]):
            x = _level(jnp.concatenate([x, skips.pop()], -1), temb, d)
            x = nn.ConvTranspose(d, (4,), strides=(2,), padding="SAME")(x)
        x = ConvBlock(self.dim)(x)
        return Conv(self.transition_dim, 1)(x)


class ValueFunction(nn.Module):
    """x [B, H, D], t [B] -> value [B]: the U-Net's down half (every level downsampled), two
    further halving blocks, then an MLP head on the flattened features and the time embedding."""

    dim: int = 32
    dim_mults: tuple = (1, 2, 4, 8)

    @nn.compact
    def __call__(self, x, t):
        dims = [self.dim * m for m in self.dim_mults]
        temb = TimeMLP(self.dim)(t)
        for d in dims:
            x = _down(_level(x, temb, d), d)
        for d in (dims[-1] // 2, dims[-1] // 4):
            x = ResidualBlock(d)(x, temb)
            x = _down(x, d)
        h = jnp.concatenate([x.reshape(x.shape[0], -1), temb], -1)
        h = mish(nn.Dense(max(h.shape[-1] // 2, 1))(h))
        return nn.Dense(1)(h)[:, 0]

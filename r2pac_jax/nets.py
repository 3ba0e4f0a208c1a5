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
    """V(s): obs [B, o] -> [B]; with `nonneg`, softplus of the last layer (a value of costs,
    which are >= 0, cannot then extrapolate below 0)."""

    hidden_dims: Sequence[int]
    layer_norm: bool = False
    nonneg: bool = False

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        v = MLP(self.hidden_dims, 1, self.layer_norm)(obs)[..., 0]
        return jax.nn.softplus(v) if self.nonneg else v


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


# ---------------------------------------------------------------------------------------------
# The networks of OSRL's baselines (osrl/common/net.py): ReLU MLPs with PyTorch's default init.

LOG_STD_MIN, LOG_STD_MAX = -20.0, 2.0  # OSRL's SquashedGaussianMLPActor clamp


def torch_dense(features: int, fan_in: int, name=None) -> nn.Dense:
    """nn.Linear(fan_in, features) as PyTorch initialises it."""
    return nn.Dense(features, kernel_init=torch_linear_init(fan_in),
                    bias_init=torch_linear_init(fan_in), name=name)


ACTIVATIONS = {"relu": nn.relu, "tanh": jnp.tanh, "none": lambda x: x}


class TorchMLP(nn.Module):
    """OSRL's `mlp`: `activation` between layers, `out_activation` after the last.
    x [B, i] -> [B, out_dim]."""

    hidden_dims: Sequence[int]
    out_dim: int
    activation: str = "relu"
    out_activation: str = "none"

    @nn.compact
    def __call__(self, x):
        sizes = list(self.hidden_dims) + [self.out_dim]
        for n, h in enumerate(sizes):
            x = torch_dense(h, x.shape[-1])(x)
            x = ACTIVATIONS[self.activation if n < len(sizes) - 1 else self.out_activation](x)
        return x


class SquashedGaussianActor(nn.Module):
    """OSRL's SquashedGaussianMLPActor: obs [B, o] -> (mu [B, A], log_std [B, A]) of the
    pre-tanh Gaussian (ReLU trunk, ReLU after its last layer too, two linear heads)."""

    hidden_dims: Sequence[int]
    act_dim: int

    @nn.compact
    def __call__(self, obs):
        x = obs
        for h in self.hidden_dims:
            x = nn.relu(torch_dense(h, x.shape[-1])(x))
        mu = torch_dense(self.act_dim, x.shape[-1], name="mu")(x)
        log_std = torch_dense(self.act_dim, x.shape[-1], name="log_std")(x)
        return mu, jnp.clip(log_std, LOG_STD_MIN, LOG_STD_MAX)


def squashed_sample(mu, log_std, key):
    """tanh(u), u ~ N(mu, std) reparameterised, with log pi(tanh u) (OSRL's formula):
    mu, log_std [B, A] -> (action [B, A], logp [B], u [B, A])."""
    u = mu + jnp.exp(log_std) * jax.random.normal(key, mu.shape)
    logp = (-0.5 * ((u - mu) / jnp.exp(log_std)) ** 2 - log_std
            - 0.5 * jnp.log(2.0 * jnp.pi)).sum(-1)
    logp = logp - (2.0 * (jnp.log(2.0) - u - jax.nn.softplus(-2.0 * u))).sum(-1)
    return jnp.tanh(u), logp, u


class TorchQEnsemble(nn.Module):
    """OSRL's EnsembleQCritic: `num` ReLU MLPs on [obs, act]: [B, o], [B, A] -> [num, B]."""

    hidden_dims: Sequence[int]
    num: int = 2

    @nn.compact
    def __call__(self, obs, act):
        x = jnp.concatenate([obs, act], axis=-1)
        ens = nn.vmap(TorchMLP, variable_axes={"params": 0}, split_rngs={"params": True},
                      in_axes=None, out_axes=0, axis_size=self.num)
        return ens(self.hidden_dims, 1)(x)[..., 0]


class VAE(nn.Module):
    """OSRL's conditional VAE of BCQ-L and CPQ: the encoder maps (s, a) to N(mean, std) over a
    latent of `latent_dim` (log std clamped to [-4, 15]); the decoder maps (s, z) to
    tanh(...) in [-1, 1]; two ReLU layers of `hidden` units each side."""

    obs_dim: int
    act_dim: int
    hidden: int
    latent_dim: int

    def setup(self):
        o, a, h, z = self.obs_dim, self.act_dim, self.hidden, self.latent_dim
        self.e1, self.e2 = torch_dense(h, o + a), torch_dense(h, h)
        self.mean, self.log_std = torch_dense(z, h), torch_dense(z, h)
        self.d1, self.d2, self.d3 = torch_dense(h, o + z), torch_dense(h, h), torch_dense(a, h)

    def encode(self, obs, act):
        """(s [B, o], a [B, A]) -> (mean [B, Z], std [B, Z])."""
        x = nn.relu(self.e2(nn.relu(self.e1(jnp.concatenate([obs, act], -1)))))
        return self.mean(x), jnp.exp(jnp.clip(self.log_std(x), -4.0, 15.0))

    def decode(self, obs, z):
        """(s [B, o], z [B, Z]) -> a [B, A]."""
        x = nn.relu(self.d2(nn.relu(self.d1(jnp.concatenate([obs, z], -1)))))
        return jnp.tanh(self.d3(x))

    def __call__(self, obs, act, key):
        """-> (reconstruction [B, A], mean [B, Z], std [B, Z]), z drawn with `key`."""
        mean, std = self.encode(obs, act)
        return self.decode(obs, mean + std * jax.random.normal(key, std.shape)), mean, std


def vae_loss(vae_net: "VAE", params, obs, act, key, beta):
    """OSRL's VAE objective: MSE reconstruction + beta x the mean KL (BCQ-L, CPQ): -> []."""
    recon, mean, std = vae_net.apply(params, obs, act, key)
    return jnp.mean((recon - act) ** 2) + beta * vae_kl(mean, std).mean()


def vae_sample_latent(key, batch: int, latent_dim: int) -> jax.Array:
    """OSRL's `VAE.decode` without z: z ~ N(0, 1) clamped to [-0.5, 0.5], [batch, latent_dim]."""
    return jnp.clip(jax.random.normal(key, (batch, latent_dim)), -0.5, 0.5)


def vae_kl(mean, std) -> jax.Array:
    """OSRL's KL term per sample, -0.5 (1 + log std^2 - mean^2 - std^2) averaged over the
    latent: [..., Z] -> [...]."""
    return -0.5 * (1.0 + jnp.log(std**2) - mean**2 - std**2).mean(-1)


# ---------------------------------------------------------------------------------------------
# FISOR's networks (jaxrl5/networks of its repository): xavier-uniform MLPs, the DDPM noise model
# on a layer-normed MLP-ResNet with learnable Fourier time features. Submodules carry jaxrl5's
# names, so that a parameter tree trained by FISOR's own code loads here unchanged.

def mish(x):
    return x * jnp.tanh(jax.nn.softplus(x))


class XavierMLP(nn.Module):
    """jaxrl5's MLP: xavier-uniform Dense layers, `act` between them (and after the last with
    `activate_final`)."""

    hidden_dims: Sequence[int]
    act: str = "relu"
    activate_final: bool = False

    @nn.compact
    def __call__(self, x):
        fn = mish if self.act == "mish" else nn.relu
        for i, h in enumerate(self.hidden_dims):
            x = nn.Dense(h, kernel_init=nn.initializers.xavier_uniform())(x)
            if i + 1 < len(self.hidden_dims) or self.activate_final:
                x = fn(x)
        return x


class XavierValue(nn.Module):
    """jaxrl5's StateActionValue body: x [B, i] -> [B] (ReLU MLP with a final ReLU, then a
    linear output)."""

    hidden_dims: Sequence[int]

    @nn.compact
    def __call__(self, x):
        x = XavierMLP(self.hidden_dims, activate_final=True, name="MLP_0")(x)
        return nn.Dense(1, kernel_init=nn.initializers.xavier_uniform())(x)[..., 0]


class XavierQEnsemble(nn.Module):
    """jaxrl5's Ensemble(StateActionValue): [B, o], [B, A] -> [num, B]."""

    hidden_dims: Sequence[int]
    num: int = 2

    @nn.compact
    def __call__(self, obs, act):
        ens = nn.vmap(XavierValue, variable_axes={"params": 0}, split_rngs={"params": True},
                      in_axes=None, out_axes=0, axis_size=self.num)
        return ens(self.hidden_dims, name="VmapStateActionValue_0")(
            jnp.concatenate([obs, act], -1))


class StateValueNet(nn.Module):
    """jaxrl5's StateValue: obs [B, o] -> [B]."""

    hidden_dims: Sequence[int]

    @nn.compact
    def __call__(self, obs):
        x = XavierMLP(self.hidden_dims, activate_final=True, name="MLP_0")(obs)
        return nn.Dense(1, kernel_init=nn.initializers.xavier_uniform(),
                        name="OutputVDense")(x)[..., 0]


class _FourierFeatures(nn.Module):
    output_size: int

    @nn.compact
    def __call__(self, t):
        w = self.param("kernel", nn.initializers.normal(0.2), (self.output_size // 2, t.shape[-1]))
        f = 2 * jnp.pi * t @ w.T
        return jnp.concatenate([jnp.cos(f), jnp.sin(f)], -1)


class _ResNetBlock(nn.Module):
    features: int
    dropout: float
    layer_norm: bool

    @nn.compact
    def __call__(self, x, training: bool):
        r = x
        if self.dropout > 0:
            x = nn.Dropout(self.dropout, deterministic=not training)(x)
        if self.layer_norm:
            x = nn.LayerNorm()(x)
        x = mish(nn.Dense(self.features * 4)(x))  # Dense_0, then Dense_1 (jaxrl5's order)
        return r + nn.Dense(self.features)(x)


class _ResNet(nn.Module):
    hidden: int
    num_blocks: int
    out_dim: int
    dropout: float
    layer_norm: bool

    @nn.compact
    def __call__(self, x, training: bool):
        x = nn.Dense(self.hidden, kernel_init=nn.initializers.xavier_uniform())(x)
        for k in range(self.num_blocks):
            x = _ResNetBlock(self.hidden, self.dropout, self.layer_norm,
                             name=f"MLPResNetBlock_{k}")(x, training)
        return nn.Dense(self.out_dim, kernel_init=nn.initializers.xavier_uniform())(mish(x))


class NoiseModel(nn.Module):
    """FISOR's DDPM eps model: learnable Fourier features of the step (time_dim), a 2 x 128 mish
    encoder of them, then an MLP-ResNet on [a_t, s, cond] (hidden, num_blocks blocks of
    dropout, LayerNorm, Dense(4 hidden), mish, Dense(hidden), residual; mish; Dense(act)).
    (s [B, o], a_t [B, A], t [B, 1] float) -> eps [B, A]."""

    act_dim: int
    hidden: int = 256
    num_blocks: int = 3
    dropout: float = 0.1
    layer_norm: bool = True
    time_dim: int = 64
    cond_dims: Sequence[int] = (128, 128)

    @nn.compact
    def __call__(self, s, a, t, training: bool = False):
        t_ff = _FourierFeatures(self.time_dim, name="FourierFeatures_0")(t)
        cond = XavierMLP(self.cond_dims, act="mish", name="MLP_0")(t_ff)
        return _ResNet(self.hidden, self.num_blocks, self.act_dim, self.dropout,
                       self.layer_norm, name="MLPResNet_0")(jnp.concatenate([a, s, cond], -1),
                                                            training)

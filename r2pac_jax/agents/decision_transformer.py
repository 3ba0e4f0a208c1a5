"""The Constrained Decision Transformer's network (OSRL's `CDT` module and its TransformerBlock).

Read off OSRL at commit 03a4586 (osrl/algorithms/cdt.py, osrl/common/net.py). Per time step the
tokens are (return-to-go, cost-to-go, state, action), each embedded linearly plus a learned
time-step embedding; LayerNorm and dropout on the embedded sequence; pre-norm causal blocks
(multi-head attention, GELU MLP of 4 E); a final LayerNorm. The action is predicted from the
state token (a diagonal Gaussian, std = exp(log_std) unclamped, as OSRL's DiagGaussianActor);
the step's cost (2 classes, log-softmax) and the next state from the action token. The
cost-to-go enters as 50 - ctg (OSRL's cost_transform). Initialisation as OSRL's: every Linear
and Embedding N(0, 0.02) with zero bias (this overrides the Gaussian head's orthogonal init,
since CDT applies its init last), LayerNorm ones / zeros, the attention's fused input
projection Xavier-uniform over [3E, E] with zero bias (PyTorch's MultiheadAttention).

Padding sits at the end of a window and attention is causal, so a valid position never sees
padding: the key-padding mask of OSRL changes nothing a loss reads, and is not applied.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import linen as nn

NORMAL = nn.initializers.normal(0.02)
COST_TRANSFORM = 50.0  # OSRL: cost_transform = lambda x: 50 - x


def _dense(features: int, name=None) -> nn.Dense:
    return nn.Dense(features, kernel_init=NORMAL, bias_init=nn.initializers.zeros, name=name)


def _layer_norm(name=None) -> nn.LayerNorm:
    return nn.LayerNorm(epsilon=1e-5, name=name)  # PyTorch's eps


class CausalSelfAttention(nn.Module):
    """PyTorch's nn.MultiheadAttention (batch_first) under a causal mask: x [B, T, E]."""

    num_heads: int
    dropout: float

    @nn.compact
    def __call__(self, x, train: bool):
        b, t, e = x.shape
        bound = jnp.sqrt(6.0 / (e + 3 * e))
        w_in = self.param("in_proj_kernel",
                          lambda k, s: jax.random.uniform(k, s, jnp.float32, -bound, bound),
                          (e, 3 * e))
        b_in = self.param("in_proj_bias", nn.initializers.zeros, (3 * e,))
        q, k, v = jnp.split(x @ w_in + b_in, 3, axis=-1)
        hd = e // self.num_heads

        def heads(z):
            return z.reshape(b, t, self.num_heads, hd).transpose(0, 2, 1, 3)

        logits = heads(q) @ heads(k).transpose(0, 1, 3, 2) / jnp.sqrt(jnp.float32(hd))
        causal = jnp.tril(jnp.ones((t, t), bool))
        w = jax.nn.softmax(jnp.where(causal, logits, -jnp.inf), axis=-1)
        w = nn.Dropout(self.dropout, deterministic=not train)(w)
        out = (w @ heads(v)).transpose(0, 2, 1, 3).reshape(b, t, e)
        return _dense(e, name="out_proj")(out)


class Block(nn.Module):
    """OSRL's TransformerBlock: x + drop(attn(ln1 x)); x + mlp(ln2 x) (dropout inside mlp)."""

    num_heads: int
    attention_dropout: float
    residual_dropout: float

    @nn.compact
    def __call__(self, x, train: bool):
        e = x.shape[-1]  # module names follow OSRL's (a state_dict maps over one to one)
        a = CausalSelfAttention(self.num_heads, self.attention_dropout, name="attention")(
            _layer_norm(name="norm1")(x), train)
        x = x + nn.Dropout(self.residual_dropout, deterministic=not train)(a)
        h = _dense(4 * e, name="mlp_0")(_layer_norm(name="norm2")(x))
        h = _dense(e, name="mlp_2")(nn.gelu(h, approximate=False))
        return x + nn.Dropout(self.residual_dropout, deterministic=not train)(h)


class DecisionTransformer(nn.Module):
    """(states [B, K, o], actions [B, K, a], rtg [B, K], ctg [B, K], time_steps [B, K]) ->
    (mu [B, K, a], log_std [B, K, a], cost log-probs [B, K, 2], next-state preds [B, K, o])."""

    obs_dim: int
    act_dim: int
    seq_len: int
    episode_len: int
    embedding_dim: int = 128
    num_layers: int = 3
    num_heads: int = 8
    attention_dropout: float = 0.1
    residual_dropout: float = 0.1
    embedding_dropout: float = 0.1

    @nn.compact
    def __call__(self, states, actions, rtg, ctg, time_steps, train: bool = False):
        b, k = states.shape[:2]
        e = self.embedding_dim
        # episode_len + seq_len rows: windows that run past an episode's end index beyond it
        t_emb = nn.Embed(self.episode_len + self.seq_len, e, embedding_init=NORMAL,
                         name="timestep_emb")(time_steps)
        tokens = [_dense(e, name="return_emb")(rtg[..., None]) + t_emb,
                  _dense(e, name="cost_emb")((COST_TRANSFORM - ctg)[..., None]) + t_emb,
                  _dense(e, name="state_emb")(states) + t_emb,
                  _dense(e, name="action_emb")(actions) + t_emb]
        x = jnp.stack(tokens, axis=2).reshape(b, 4 * k, e)  # r_0 c_0 s_0 a_0 r_1 ...
        x = nn.Dropout(self.embedding_dropout, deterministic=not train)(
            _layer_norm(name="emb_norm")(x))
        for i in range(self.num_layers):
            x = Block(self.num_heads, self.attention_dropout, self.residual_dropout,
                      name=f"block_{i}")(x, train)
        x = _layer_norm(name="out_norm")(x).reshape(b, k, 4, e)
        state_feat, action_feat = x[:, :, 2], x[:, :, 3]
        mu = _dense(self.act_dim, name="mu")(state_feat)
        log_std = _dense(self.act_dim, name="log_std")(state_feat)
        cost_logp = jax.nn.log_softmax(_dense(2, name="cost_pred")(action_feat), axis=-1)
        state_pred = _dense(self.obs_dim, name="state_pred")(action_feat)
        return mu, log_std, cost_logp, state_pred


"""Chunked flow-matching behaviour cloning (`bc-all`, `bc-safe`): R2PAC's policy class, no critics.

The flow policy of `flow.py` fitted to the dataset's h-step action chunks with no optimality
label (the null branch only), acting with the first action of one sampled chunk. It isolates
what R2PAC's critics add to the same actor. `bc-safe` trains on the episodes with cost <= kappa.
(The paper's BC column is OSRL's one-step MLP cloner: `bc_mlp.py`.)
"""
from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import optax

from r2pac_jax.agents import flow
from r2pac_jax.agents.base import (ActorState, ChunkAlgorithm, actor_only, check_act, check_obs,
                                   check_positive, check_sizes, no_hparams, no_task_values)
from r2pac_jax.agents.spec import AlgorithmSpec
from r2pac_jax.data.chunks import Batch
from r2pac_jax.errors import ConfigError
from r2pac_jax.nets import NULL_LABEL, VelocityField


@dataclasses.dataclass(frozen=True)
class BCFlowConfig:
    lr: float = 3e-4
    hidden_dims: tuple = (128, 128, 128)
    layer_norm: bool = False
    flow_steps: int = 32
    time_embed_dim: int = 16


CONFIG = BCFlowConfig
PRESETS = {"paper": dict(hidden_dims=(512, 512, 512, 512), flow_steps=32),
           "quick": dict(hidden_dims=(128, 128, 128), flow_steps=32)}
VARIANTS = {"bc-all": {}, "bc-safe": {"data_filter": "safe"}}
FIXED: dict = {}
FIXED_WHY: dict = {}
HPARAMS: tuple = ()
check_hparams = no_hparams
task_values = no_task_values
phases = actor_only


def validate(c: BCFlowConfig) -> None:
    check_positive("lr", c.lr)
    for k in ("flow_steps", "time_embed_dim"):
        if getattr(c, k) < 1:
            raise ConfigError(f"{k} must be >= 1, got {getattr(c, k)}")
    check_sizes("hidden_dims", c.hidden_dims)


class Agent(ChunkAlgorithm):
    def __init__(self, cfg, obs_dim: int, act_dim: int):
        super().__init__(cfg, obs_dim, act_dim)
        self.actor_net = VelocityField(cfg.hidden_dims, self.chunk_size, cfg.time_embed_dim,
                                       cfg.layer_norm)
        self.tx = optax.adam(cfg.lr)

    def init(self, key: jax.Array, hp: dict) -> ActorState:
        del hp
        k_net, k_state = jax.random.split(key)
        # the 5th of 5 keys: the stream of the days when the cloners shared R2PAC's initialiser
        # (its four critics took the others), so that results from then reproduce bitwise
        k_actor = jax.random.split(k_net, 5)[4]
        params = {"actor": self.actor_net.init(k_actor, jnp.zeros((1, self.chunk_size)),
                                               jnp.zeros((1,)), jnp.zeros((1, self.obs_dim)),
                                               jnp.zeros((1,), jnp.int32))}
        return ActorState(params=params, opt={"actor": self.tx.init(params["actor"])},
                          step=jnp.zeros((), jnp.int32), key=k_state)

    def update(self, state: ActorState, batch: Batch, hp: dict, phase: str):
        """One flow-matching step on the batch's chunks (null label, unweighted)."""
        key, k_actor = jax.random.split(state.key)
        B = batch.observations.shape[0]
        shape = (B, self.h, self.act_dim)
        chunk = batch.actions.reshape(B, -1)
        k0, ki = jax.random.split(k_actor)
        a0 = jax.random.normal(k0, chunk.shape)
        i = jax.random.uniform(ki, (B,))
        a_i = flow.interpolate(a0, chunk, i)
        labels = jnp.full((B,), NULL_LABEL, jnp.int32)

        def loss_fn(p):
            v_pred = self.actor_net.apply(p, a_i, i, batch.observations, labels)
            return flow.flow_matching_loss(v_pred.reshape(shape), a0.reshape(shape),
                                           batch.actions, batch.action_mask)

        loss, g = jax.value_and_grad(loss_fn)(state.params["actor"])
        updates, opt = self.tx.update(g, state.opt["actor"], state.params["actor"])
        params = {"actor": optax.apply_updates(state.params["actor"], updates)}
        return state.replace(params=params, opt={"actor": opt}, key=key,
                             step=state.step + 1), {"loss_actor": loss}

    def policy_params(self, state: ActorState, hp: dict) -> dict:
        return {"actor": state.params["actor"]}

    def act(self, pp: dict, obs: jax.Array, key: jax.Array) -> jax.Array:
        """obs [B, obs_dim] -> the first action of one sampled chunk [B, act_dim]."""
        check_obs(obs, self.obs_dim)
        B = obs.shape[0]
        cand = flow.sample_chunks(lambda *a: self.actor_net.apply(pp["actor"], *a), obs, key, 1,
                                  self.chunk_size, self.cfg.flow_steps)
        return check_act(obs, cand[:, 0].reshape(B, self.h, self.act_dim)[:, 0], self.obs_dim,
                         self.act_dim)


SPEC = AlgorithmSpec(CONFIG=CONFIG, PRESETS=PRESETS, VARIANTS=VARIANTS, FIXED=FIXED,
                     FIXED_WHY=FIXED_WHY, HPARAMS=HPARAMS, Agent=Agent,
                     check_hparams=check_hparams, phases=phases, task_values=task_values,
                     validate=validate)

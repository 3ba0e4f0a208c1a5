"""One-step MLP behaviour cloning as OSRL implements it (`bc-all-mlp`, `bc-safe-mlp`).

OSRL's BC (osrl/algorithms/bc.py with examples/configs/bc_configs.py): a 2 x 256 ReLU MLP with a
tanh output, MSE to the dataset action, Adam at 1e-3, batch 512, 100k steps, deterministic
actions; BC-Safe keeps the episodes whose cost is <= kappa (OSRL's bc_mode "safe" with gamma 1).
Weights start from PyTorch's nn.Linear distribution. It trains on transitions: the chunk view with
h = 1, so `--chunk-len` does not apply (refused when asked for). This is the paper's BC column.
"""
from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import optax

from r2pac_jax.agents.base import (ActorState, ChunkAlgorithm, actor_only, check_act, check_obs,
                                   check_positive, check_sizes, no_hparams, no_task_values)
from r2pac_jax.agents.spec import AlgorithmSpec
from r2pac_jax.data.chunks import Batch
from r2pac_jax.nets import DeterministicActor


@dataclasses.dataclass(frozen=True)
class MLPBCConfig:
    lr: float = 1e-3
    hidden_dims: tuple = (256, 256)


CONFIG = MLPBCConfig
# OSRL's values under both presets; the quick preset trains 20k steps instead of 100k.
PRESETS = {"paper": dict(steps=100_000, batch_size=512, hidden_dims=(256, 256), lr=1e-3),
           "quick": dict(steps=20_000, batch_size=512, hidden_dims=(256, 256), lr=1e-3)}
VARIANTS = {"bc-all-mlp": {}, "bc-safe-mlp": {"data_filter": "safe"}}
FIXED = {"chunk_len": 1}
FIXED_WHY = {"chunk_len": "clones one action per step"}
HPARAMS: tuple = ()
check_hparams = no_hparams
task_values = no_task_values
phases = actor_only


def validate(c: MLPBCConfig) -> None:
    check_positive("lr", c.lr)
    check_sizes("hidden_dims", c.hidden_dims)


class Agent(ChunkAlgorithm):
    def __init__(self, cfg, obs_dim: int, act_dim: int):
        super().__init__(cfg, obs_dim, act_dim)
        self.actor_net = DeterministicActor(cfg.hidden_dims, act_dim)
        self.tx = optax.adam(cfg.lr)

    def init(self, key: jax.Array, hp: dict) -> ActorState:
        del hp
        k_net, k_state = jax.random.split(key)
        params = {"actor": self.actor_net.init(k_net, jnp.zeros((1, self.obs_dim)))}
        return ActorState(params=params, opt={"actor": self.tx.init(params["actor"])},
                          step=jnp.zeros((), jnp.int32), key=k_state)

    def update(self, state: ActorState, batch: Batch, hp: dict, phase: str):
        """One MSE step: batch.actions [B, 1, act_dim] (chunks of length 1)."""
        target = batch.actions[:, 0]

        def loss_fn(p):
            return jnp.mean((self.actor_net.apply(p, batch.observations) - target) ** 2)

        loss, g = jax.value_and_grad(loss_fn)(state.params["actor"])
        updates, opt = self.tx.update(g, state.opt["actor"], state.params["actor"])
        params = {"actor": optax.apply_updates(state.params["actor"], updates)}
        return state.replace(params=params, opt={"actor": opt}, step=state.step + 1), \
            {"loss_actor": loss}

    def policy_params(self, state: ActorState, hp: dict) -> dict:
        return {"actor": state.params["actor"]}

    def act(self, pp: dict, obs: jax.Array, key: jax.Array) -> jax.Array:
        """Deterministic: obs [B, obs_dim] -> actor(obs) [B, act_dim] in (-1, 1); key unused."""
        del key
        check_obs(obs, self.obs_dim)
        return check_act(obs, self.actor_net.apply(pp["actor"], obs), self.obs_dim, self.act_dim)


SPEC = AlgorithmSpec(CONFIG=CONFIG, PRESETS=PRESETS, VARIANTS=VARIANTS, FIXED=FIXED,
                     FIXED_WHY=FIXED_WHY, HPARAMS=HPARAMS, Agent=Agent,
                     check_hparams=check_hparams, phases=phases, task_values=task_values,
                     validate=validate)

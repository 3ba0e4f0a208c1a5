"""Constrained Decision Transformer (Liu et al. 2023) as OSRL implements it (`--algo cdt`).

Read off OSRL at commit 03a4586 (osrl/algorithms/cdt.py, osrl/common/dataset.py,
examples/configs/cdt_configs.py, examples/train/train_cdt.py). One step of `update` is
`CDTTrainer.train_one_step`:

- a batch of windows (`data/sequences.py`: context 10, episodes drawn ~ max(70 - C, 0), 20%
  Pareto-augmented episodes) through the network (`decision_transformer.py`: 3 layers, 8
  heads, embedding 128, dropout 0.1);
- loss = -(mean log N(a | mu, std) + T mean entropy) over the valid positions and action
  dimensions (T = exp(log_temperature), held fixed in this loss) + 0.02 x the cost-prediction
  NLL (summed over valid positions, divided by B K as OSRL's `.mean()` does) + 0 x the
  next-state MSE; AdamW (1e-4, weight decay 1e-4 on every parameter, betas 0.9 / 0.999) after
  clipping the global gradient norm at 0.25, the rate warmed up linearly over 500 steps;
- then the temperature: Adam (1e-4) on T (entropy - target_entropy), target_entropy = -act_dim.
Batch 2048, 100k steps (`paper` preset); reward scale 0.1, cost scale 1.

Acting (OSRL's `rollout`): the policy keeps the episode's last 10 (return-to-go, cost-to-go,
state, action, time) in a memory (`memory_init` / `act_memory` / `observe`, see
`agents/base.py`); the targets start at (target_return x reward scale, target_cost x cost scale)
and fall by each scaled reward and cost received; the action is the Gaussian's mean at the
newest position, clipped to [-1, 1]. `act` alone acts as at an episode's first step.

What differs from OSRL, and why:
- The evaluation targets: target_cost = the task's kappa (an hparam: lanes may evaluate other
  cost targets); target_return = the data's best return among episodes of cost <= kappa
  (`target_rule = best_safe`) or the value `target_return` (`target_rule = value`), since
  OSRL's per-task targets are in DSRL's return units, not our data's.
- The augmentation's constants (OSRL's per-task deg, max_reward, max_rew_decrease,
  min_reward) are stored as fractions of DSRL's [R_min, R_max] and mapped onto the data's
  return range when the view is built (`augmentation_values`).
- The augmented episodes are drawn once per run (seed `augment_seed`) and shared by the
  vmapped seeds; OSRL draws them per training seed.
- Cost labels are min(floor(c), 1): OSRL's `costs.long()` fails on costs above 1.
- The frontier's polynomial degree is at most its number of distinct costs - 1: OSRL's
  `polyfit` fails when the filtered frontier is a single episode (as on CarGoal1 v2).
"""
from __future__ import annotations

import dataclasses
import warnings
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct

from r2pac_jax.agents import gaussian
from r2pac_jax.agents.base import (ChunkAlgorithm, actor_only, check_act, check_choice,
                                   check_counts, check_dataset_sizes, check_lane_hparams,
                                   check_obs, check_positive)
from r2pac_jax.agents.decision_transformer import DecisionTransformer
from r2pac_jax.agents.spec import AlgorithmSpec
from r2pac_jax.data import sequences
from r2pac_jax.data.sequences import SequenceBatch, SequenceData
from r2pac_jax.errors import ConfigError
from r2pac_jax.ranges import check_range

# OSRL's per-task augmentation constants (cdt_configs.py at 03a4586), in DSRL's return units:
# dsrl id -> (deg, max_reward, max_rew_decrease, min_reward)
OSRL_AUGMENTATION = {
    "OfflineCarCircle-v0": (4, 600.0, 100.0, 1.0),
    "OfflineAntRun-v0": (3, 1000.0, 150.0, 1.0),
    "OfflineDroneRun-v0": (1, 700.0, 100.0, 1.0),
    "OfflineDroneCircle-v0": (1, 1000.0, 100.0, 1.0),
    "OfflineCarRun-v0": (0, 600.0, 100.0, 1.0),
    "OfflineAntCircle-v0": (2, 500.0, 100.0, 1.0),
    "OfflineBallCircle-v0": (2, 1000.0, 200.0, 1.0),
    "OfflineBallRun-v0": (2, 1400.0, 200.0, 1.0),
    "OfflineCarButton1Gymnasium-v0": (0, 45.0, 10.0, 1.0),
    "OfflineCarButton2Gymnasium-v0": (0, 50.0, 10.0, 1.0),
    "OfflineCarGoal1Gymnasium-v0": (1, 50.0, 5.0, 1.0),
    "OfflineCarGoal2Gymnasium-v0": (1, 35.0, 5.0, 1.0),
    "OfflineCarPush1Gymnasium-v0": (0, 20.0, 5.0, 1.0),
    "OfflineCarPush2Gymnasium-v0": (0, 15.0, 3.0, 1.0),
    "OfflinePointButton1Gymnasium-v0": (0, 45.0, 5.0, 1.0),
    "OfflinePointButton2Gymnasium-v0": (0, 50.0, 10.0, 1.0),
    "OfflinePointGoal1Gymnasium-v0": (0, 35.0, 5.0, 1.0),
    "OfflinePointGoal2Gymnasium-v0": (1, 35.0, 5.0, 1.0),
    "OfflinePointPush1Gymnasium-v0": (0, 20.0, 5.0, 1.0),
    "OfflinePointPush2Gymnasium-v0": (0, 15.0, 3.0, 1.0),
    "OfflineAntVelocityGymnasium-v1": (1, 3000.0, 500.0, 1.0),
    "OfflineHalfCheetahVelocityGymnasium-v1": (1, 3000.0, 500.0, 1.0),
    "OfflineHopperVelocityGymnasium-v1": (1, 2000.0, 300.0, 1.0),
    "OfflineSwimmerVelocityGymnasium-v1": (1, 250.0, 50.0, 1.0),
    "OfflineWalker2dVelocityGymnasium-v1": (1, 3600.0, 800.0, 1.0),
}
# tasks OSRL has no config for (ReachAvoid) take HalfCheetahVelocity's, relative to its range
FALLBACK_AUGMENTATION = "OfflineHalfCheetahVelocityGymnasium-v1"
TARGET_RULES = ("best_safe", "value")


@dataclasses.dataclass(frozen=True)
class CDTConfig:
    seq_len: int = 10
    embedding_dim: int = 128
    num_layers: int = 3
    num_heads: int = 8
    attention_dropout: float = 0.1
    residual_dropout: float = 0.1
    embedding_dropout: float = 0.1
    lr: float = 1e-4
    weight_decay: float = 1e-4
    clip_grad: float = 0.25
    lr_warmup_steps: int = 500
    loss_cost_weight: float = 0.02
    loss_state_weight: float = 0.0
    init_temperature: float = 0.1
    temperature_lr: float = 1e-4
    entropy_reg: bool = True  # OSRL's no_entropy = False
    # sampling and augmentation (OSRL: cost_sample with 70 - C; augment_percent 0.2, beta 1)
    cost_sample: bool = True
    cost_weight_base: float = 70.0
    augment_percent: float = 0.2
    augment_beta: float = 1.0
    augment_seed: int = 0
    aug_deg: int = 1
    aug_max_reward: float = 1.07  # level, as a fraction of [R_min, R_max]
    aug_max_rew_decrease: float = 0.18  # fractions of R_max - R_min
    aug_min_reward: float = 0.0004
    # evaluation targets
    target_rule: str = "best_safe"
    target_return: float = 0.0  # raw return, used when target_rule = value
    target_cost: float = 10.0  # the task's kappa (registry)
    episode_len: int = 1000  # the time-step embedding's size (registry)


CONFIG = CDTConfig
PRESETS = {
    # OSRL's values (cdt_configs.py): batch 2048, 100k steps, reward scale 0.1
    "paper": dict(steps=100_000, batch_size=2048, reward_scale=0.1, cost_scale=1.0),
    # a 2-core CPU: embedding 64, 2 layers, 4 heads, batch 64 windows (640 steps), 10k steps;
    # fixed before any CDT score on a task's data was seen (batch 256 ran ~2 steps/s here)
    "quick": dict(steps=10_000, batch_size=64, reward_scale=0.1, cost_scale=1.0,
                  embedding_dim=64, num_layers=2, num_heads=4),
}
VARIANTS = {"cdt": {}}
FIXED = {"chunk_len": 1}
FIXED_WHY = {"chunk_len": "acts one step at a time from its context window"}
HPARAMS = ("target_cost",)
phases = actor_only


def task_values(spec) -> dict:
    """kappa as the cost target, the episode length, OSRL's augmentation constants relative to
    DSRL's return range of the task they were written for."""
    from r2pac_jax.tasks import get_task

    dsrl_id = spec.dsrl_id if spec.dsrl_id in OSRL_AUGMENTATION else FALLBACK_AUGMENTATION
    ref = get_task(dsrl_id)
    deg, max_r, dec, min_r = OSRL_AUGMENTATION[dsrl_id]
    span = ref.r_max - ref.r_min
    return dict(target_cost=float(spec.kappa), episode_len=int(spec.episode_len), aug_deg=deg,
                aug_max_reward=(max_r - ref.r_min) / span, aug_max_rew_decrease=dec / span,
                aug_min_reward=min_r / span)


def check_hparams(values: dict) -> None:
    check_lane_hparams(values, HPARAMS)


def validate(c: CDTConfig) -> None:
    for k in ("lr", "temperature_lr", "init_temperature", "clip_grad", "cost_weight_base"):
        check_positive(k, getattr(c, k))
    for k in ("weight_decay", "loss_cost_weight", "loss_state_weight", "augment_percent",
              "augment_beta", "target_cost", "aug_max_rew_decrease", "aug_min_reward"):
        check_range(k, getattr(c, k), 0)
    for k in ("attention_dropout", "residual_dropout", "embedding_dropout"):
        check_range(k, getattr(c, k), 0, 1, high_open=True)
    check_counts(c, ("seq_len", "embedding_dim", "num_layers", "num_heads", "lr_warmup_steps",
                     "episode_len"))
    if c.aug_deg < 0:
        raise ConfigError(f"aug_deg must be >= 0, got {c.aug_deg}")
    if c.embedding_dim % c.num_heads:
        raise ConfigError(f"embedding_dim {c.embedding_dim} must be a multiple of num_heads "
                          f"{c.num_heads}")
    if c.seq_len > c.episode_len:
        raise ConfigError(f"seq_len {c.seq_len} is longer than an episode ({c.episode_len} "
                          "steps); choose seq_len <= the episode length")
    check_choice("target_rule", c.target_rule, TARGET_RULES)


def augmentation_values(cfg, returns: np.ndarray) -> dict:
    """`sequences.augment`'s keywords, the relative constants mapped onto the data's returns."""
    lo, hi = float(np.min(returns)), float(np.max(returns))
    span = max(hi - lo, 1e-8)
    return dict(deg=int(cfg.aug_deg), max_reward=lo + cfg.aug_max_reward * span,
                max_rew_decrease=cfg.aug_max_rew_decrease * span,
                min_reward=cfg.aug_min_reward * span, beta=cfg.augment_beta,
                augment_percent=cfg.augment_percent)


@struct.dataclass
class CDTState:
    params: dict  # {"model": ..., "log_temperature": []}
    opt: dict
    target_return: jax.Array  # [] raw, copied from the data view (best safe return or value)
    step: jax.Array
    key: jax.Array


class Memory(NamedTuple):
    """The context of B running episodes, the newest entry at position min(t, K - 1)."""

    states: jax.Array  # [B, K, o]
    actions: jax.Array  # [B, K, a]
    rtg: jax.Array  # [B, K] scaled
    ctg: jax.Array  # [B, K] scaled
    t: jax.Array  # [B] int32 steps taken
    next_rtg: jax.Array  # [B] targets at the coming step (scaled)
    next_ctg: jax.Array  # [B]


def _warn_outside(name: str, v: float, vals) -> None:
    if not vals.min() <= v <= vals.max():
        warnings.warn(f"cdt: {name}={v:g} lies outside the data's episode range "
                      f"[{vals.min():.4g}, {vals.max():.4g}]; the transformer was never "
                      "conditioned on such a value", stacklevel=3)


class Agent(ChunkAlgorithm):
    plot_metrics = ("loss_actor", "nll", "entropy", "cost_acc")

    def __init__(self, cfg, obs_dim: int, act_dim: int):
        super().__init__(cfg, obs_dim, act_dim)
        self.k = cfg.seq_len
        self.net = DecisionTransformer(obs_dim, act_dim, cfg.seq_len, cfg.episode_len,
                                       cfg.embedding_dim, cfg.num_layers, cfg.num_heads,
                                       cfg.attention_dropout, cfg.residual_dropout,
                                       cfg.embedding_dropout)
        warm = cfg.lr_warmup_steps
        # PyTorch's LambdaLR(min((n + 1) / warmup, 1)): the first step already runs at lr / warmup
        self.tx = optax.chain(optax.clip_by_global_norm(cfg.clip_grad), optax.adamw(
            lambda n: cfg.lr * jnp.minimum((n + 1) / warm, 1.0), b1=0.9, b2=0.999, eps=1e-8,
            weight_decay=cfg.weight_decay))
        self.tx_temp = optax.adam(cfg.temperature_lr)
        self.target_entropy = -float(act_dim)

    # data ------------------------------------------------------------------------------------
    def _episodes(self, task, ds):
        """(kept [E] bool or None, lengths, returns, costs of the kept episodes)."""
        _, lengths, ret, cost = sequences.episode_table(ds)
        keep = self.keep_episodes(task, ds)
        if keep is not None:
            lengths, ret, cost = lengths[keep], ret[keep], cost[keep]
        return keep, lengths, ret, cost

    def check_data(self, task, ds) -> None:
        cfg = self.cfg
        check_dataset_sizes(task, ds)
        _, lengths, ret, cost = self._episodes(task, ds)
        if lengths.max() > cfg.episode_len:
            raise ConfigError(
                f"cdt: {ds.source} holds an episode of {int(lengths.max())} steps, longer than "
                f"{task.name}'s {cfg.episode_len}: its returns-to-go need the episode ends that "
                "the file's 'timeouts' (and 'terminals') flag; mark every episode's last step")
        if cfg.cost_sample and not (cost < cfg.cost_weight_base).any():
            raise ConfigError(f"cdt: every episode of {ds.source} costs >= cost_weight_base="
                              f"{cfg.cost_weight_base}, so cost-weighted sampling draws none; "
                              "set cost_sample=false")
        if cfg.target_rule == "best_safe" and not (cost <= task.kappa).any():
            raise ConfigError(f"cdt: {ds.source} has no episode with cost <= kappa={task.kappa} "
                              "for the return target; use target_rule=value with target_return")
        if cfg.target_rule == "value":
            _warn_outside("target_return", cfg.target_return, ret)

    def check_cells(self, task, ds, cells: list) -> None:
        """Each lane cell's cost target against the data's episode costs (a warning)."""
        _, _, _, cost = self._episodes(task, ds)
        for v in sorted({c["target_cost"] for c in cells}):
            _warn_outside("target_cost", v, cost)

    def _target_return(self, task, ret, cost) -> float:
        if self.cfg.target_rule == "value":
            return float(self.cfg.target_return)
        return float(ret[cost <= task.kappa].max())

    def target_return_of(self, task, ds) -> float:
        """The evaluation's return target on this dataset (raw return)."""
        _, _, ret, cost = self._episodes(task, ds)
        return self._target_return(task, ret, cost)

    def make_data(self, task, ds) -> SequenceData:
        cfg = self.cfg
        keep, _, ret, cost = self._episodes(task, ds)
        aug = augmentation_values(cfg, ret) if cfg.augment_percent > 0 else None
        return sequences.build_sequences(
            ds, keep_episodes=keep, augmentation=aug,
            cost_weight_base=cfg.cost_weight_base if cfg.cost_sample else None,
            target_return=self._target_return(task, ret, cost), seed=cfg.augment_seed)

    def sample(self, data: SequenceData, key: jax.Array) -> SequenceBatch:
        c = self.cfg
        return sequences.sample(data, key, c.batch_size, c.seq_len, c.reward_scale, c.cost_scale)

    def begin_block(self, state: CDTState, hp: dict, data: SequenceData) -> CDTState:
        return state.replace(target_return=data.target_return)

    # training --------------------------------------------------------------------------------
    def init(self, key: jax.Array, hp: dict) -> CDTState:
        del hp
        k_net, k_state = jax.random.split(key)
        k, o, a = self.k, self.obs_dim, self.act_dim
        model = self.net.init(k_net, jnp.zeros((1, k, o)), jnp.zeros((1, k, a)),
                              jnp.zeros((1, k)), jnp.zeros((1, k)), jnp.zeros((1, k), jnp.int32))
        log_t = jnp.log(jnp.float32(self.cfg.init_temperature))
        return CDTState(params={"model": model, "log_temperature": log_t},
                        opt={"model": self.tx.init(model), "temperature": self.tx_temp.init(log_t)},
                        target_return=jnp.zeros((), jnp.float32),
                        step=jnp.zeros((), jnp.int32), key=k_state)

    def losses(self, model, log_t, b: SequenceBatch, key):
        """OSRL's loss terms on a batch: (total, aux) with the entropy for the temperature."""
        cfg = self.cfg
        mu, log_std, cost_logp, state_pred = self.net.apply(
            model, b.states, b.actions, b.returns_to_go, b.costs_to_go, b.time_steps,
            train=True, rngs={"dropout": key})
        m = b.mask
        n_valid = jnp.maximum(m.sum(), 1.0) * self.act_dim
        log_lik = (gaussian.log_prob(b.actions, mu, log_std) * m[..., None]).sum() / n_valid
        entropy = (gaussian.entropy(log_std) * m[..., None]).sum() / n_valid
        temp = jnp.exp(log_t) * cfg.entropy_reg
        act_loss = -(log_lik + jax.lax.stop_gradient(temp) * entropy)
        nll = -jnp.take_along_axis(cost_logp, b.cost_labels[..., None], -1)[..., 0]
        cost_loss = (nll * m).mean()
        acc = ((jnp.argmax(cost_logp, -1) == b.cost_labels) * m).sum() / jnp.maximum(m.sum(), 1)
        state_loss = (((state_pred[:, :-1] - b.states[:, 1:]) ** 2)
                      * m[:, :-1, None]).mean()
        total = act_loss + cfg.loss_cost_weight * cost_loss + cfg.loss_state_weight * state_loss
        return total, dict(nll=-log_lik, entropy=entropy, loss_cost=cost_loss, cost_acc=acc,
                           loss_state=state_loss, loss_act=act_loss)

    def update(self, state: CDTState, batch: SequenceBatch, hp: dict, phase: str):
        """One OSRL step on windows [B, K, ...]: the model, then the temperature."""
        key, k_drop = jax.random.split(state.key)
        p, opt = state.params, state.opt
        (loss, aux), g = jax.value_and_grad(self.losses, has_aux=True)(
            p["model"], p["log_temperature"], batch, k_drop)
        upd, opt_m = self.tx.update(g, opt["model"], p["model"])
        model = optax.apply_updates(p["model"], upd)
        log_t = p["log_temperature"]
        if self.cfg.entropy_reg:
            gap = jax.lax.stop_gradient(aux["entropy"] - self.target_entropy)
            g_t = jax.grad(lambda lt: jnp.exp(lt) * gap)(log_t)
            upd_t, opt_t = self.tx_temp.update(g_t, opt["temperature"], log_t)
            log_t = optax.apply_updates(log_t, upd_t)
        else:
            opt_t = opt["temperature"]
        metrics = dict(loss_actor=loss, temperature=jnp.exp(log_t), **aux)
        return state.replace(params={"model": model, "log_temperature": log_t},
                             opt={"model": opt_m, "temperature": opt_t}, step=state.step + 1,
                             key=key), metrics

    # acting ----------------------------------------------------------------------------------
    def policy_params(self, state: CDTState, hp: dict) -> dict:
        return {"model": state.params["model"], "target_return": state.target_return,
                "target_cost": jnp.asarray(hp["target_cost"], jnp.float32)}

    def memory_init(self, pp: dict, obs: jax.Array) -> Memory:
        """An empty context for obs [B, obs_dim]'s episodes, targets at their start."""
        check_obs(obs, self.obs_dim)
        b, k = obs.shape[0], self.k
        c = self.cfg
        return Memory(states=jnp.zeros((b, k, self.obs_dim)), actions=jnp.zeros((b, k, self.act_dim)),
                      rtg=jnp.zeros((b, k)), ctg=jnp.zeros((b, k)), t=jnp.zeros((b,), jnp.int32),
                      next_rtg=jnp.full((b,), pp["target_return"] * c.reward_scale),
                      next_ctg=jnp.full((b,), pp["target_cost"] * c.cost_scale))

    def act_memory(self, pp: dict, obs: jax.Array, key: jax.Array, mem: Memory):
        """obs [B, obs_dim] -> (action [B, act_dim], memory with this step's entry)."""
        del key
        check_obs(obs, self.obs_dim)
        k = self.k
        full = (mem.t >= k)[:, None]

        def shift(x):  # drop the oldest entry once the window is full
            f = full.reshape(full.shape + (1,) * (x.ndim - 2))
            return jnp.where(f, jnp.roll(x, -1, axis=1), x)

        pos = jnp.minimum(mem.t, k - 1)
        here = jax.nn.one_hot(pos, k, dtype=bool)  # [B, K]

        def put(x, v):
            h = here.reshape(here.shape + (1,) * (x.ndim - 2))
            return jnp.where(h, v.reshape(v.shape[:1] + (1,) + v.shape[1:]), x)

        states = put(shift(mem.states), obs)
        actions = put(shift(mem.actions), jnp.zeros((obs.shape[0], self.act_dim)))
        rtg = put(shift(mem.rtg), mem.next_rtg)
        ctg = put(shift(mem.ctg), mem.next_ctg)
        time_steps = jnp.minimum(mem.t[:, None] - pos[:, None] + jnp.arange(k)[None],
                                 self.cfg.episode_len + k - 1)
        mu, _, _, _ = self.net.apply(pp["model"], states, actions, rtg, ctg, time_steps)
        a = jnp.clip(jnp.take_along_axis(mu, pos[:, None, None], 1)[:, 0], -1.0, 1.0)
        mem = mem._replace(states=states, actions=put(actions, a), rtg=rtg, ctg=ctg)
        return check_act(obs, a, self.obs_dim, self.act_dim), mem

    def observe(self, pp: dict, mem: Memory, reward: jax.Array, cost: jax.Array) -> Memory:
        """After a step: reward [B], cost [B] lower the targets; the clock advances."""
        c = self.cfg
        pos = jnp.minimum(mem.t, self.k - 1)
        rtg_now = jnp.take_along_axis(mem.rtg, pos[:, None], 1)[:, 0]
        ctg_now = jnp.take_along_axis(mem.ctg, pos[:, None], 1)[:, 0]
        return mem._replace(t=mem.t + 1, next_rtg=rtg_now - reward * c.reward_scale,
                            next_ctg=ctg_now - cost * c.cost_scale)

    def act(self, pp: dict, obs: jax.Array, key: jax.Array) -> jax.Array:
        """obs [B, obs_dim] -> [B, act_dim] as at the first step of an episode (evaluation
        uses the memory: `act_memory`)."""
        return self.act_memory(pp, obs, key, self.memory_init(pp, obs))[0]

    def summary(self, state: CDTState) -> dict:
        return {"target_return": state.target_return}


SPEC = AlgorithmSpec(CONFIG=CONFIG, PRESETS=PRESETS, VARIANTS=VARIANTS, FIXED=FIXED,
                     FIXED_WHY=FIXED_WHY, HPARAMS=HPARAMS, Agent=Agent,
                     check_hparams=check_hparams, phases=phases, task_values=task_values,
                     validate=validate)

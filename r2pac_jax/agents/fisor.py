"""FISOR (Zheng et al. 2024) as its JAX code does (`--algo fisor`).

Read off ZhengYinan-AIR/FISOR at commit 2097e8b (jaxrl5/agents/fisor/fisor.py,
configs/train_config.py, jaxrl5/data/dsrl_datasets.py, launcher/examples/train_offline.py).
One step of `update` is `FISOR.update`:

1. The actor twice, on the two halves of the batch (paper: 2 x 1024), with the critics as they
   were before this step: DDPM noise-prediction loss sum_A (eps_pred - eps)^2 at a uniform step
   t of T = 5 (VP schedule), weighted by the feasibility-guided weights
     infeasible (V_h > 0):            clip(exp(5 (V_h - Q_h)), 0, 150)
     feasible (V_h <= 0 and Q_h <= 0): clip(exp(3 (Q_r - V_r)), 0, 100)
     otherwise:                        0
   (Q_r min and Q_h max over their 2-ensembles of the target critics); AdamW (no decay) with a
   cosine-decayed rate over 3M steps; the EMA actor (rate 0.001, after each of the two actor
   steps) is the one acting.
2. On the first 256 rows: V_r (expectile 0.9 of target Q_r), Q_r (r + g m V_r(s')), V_h
   (reversed expectile 0.9 of target Q_h), Q_h (the HJ target
   (1 - g) h + g max(h, V_h(s')) where m = 1, h at m = 0), each critic's Polyak at 0.005.
Data as FISOR prepares them: stage cost h = +25 where the cost is > 0, else -1; rewards x
L / (R_max - R_min) (its normalize_returns with DSRL's constants); actions clipped to
1 - 1e-5; m = 0 at terminals AND timeouts (FISOR's rule; docs/algorithm.md bootstraps through
timeouts; `done_rule` switches). Acting: 16 DDPM samples per state from the EMA actor, the one
with the least Q_h (max over the target ensemble) is taken.
"""
from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import optax
from flax import struct

from r2pac_jax.agents import diffusion
from r2pac_jax.agents.base import (TransitionAlgorithm, actor_only, check_act, check_choice,
                                   check_counts, check_lane_hparams, check_obs, check_positive,
                                   check_sizes, optimizer_step, soft_update)
from r2pac_jax.agents.critics import expectile_loss, reversed_expectile_loss
from r2pac_jax.agents.spec import AlgorithmSpec
from r2pac_jax.data.transitions import DONE_RULES, TransitionBatch
from r2pac_jax.errors import ConfigError
from r2pac_jax.nets import NoiseModel, StateValueNet, XavierQEnsemble
from r2pac_jax.ranges import check_range


@dataclasses.dataclass(frozen=True)
class FISORConfig:
    actor_lr: float = 3e-4
    critic_lr: float = 3e-4
    value_lr: float = 3e-4
    critic_hidden_dims: tuple = (256, 256)
    actor_hidden: int = 256
    actor_blocks: int = 3
    actor_dropout: float = 0.1
    actor_layer_norm: bool = True
    time_dim: int = 64
    diffusion_steps: int = 5
    num_candidates: int = 16
    ddpm_temperature: float = 1.0
    clip_sampler: bool = True
    expectile: float = 0.9
    cost_expectile: float = 0.9
    reward_temperature: float = 3.0
    cost_temperature: float = 5.0
    reward_weight_clip: float = 100.0
    cost_weight_clip: float = 150.0  # FISOR's cost_ub
    stage_cost: float = 25.0  # h where the cost is > 0 (FISOR's cost_scale); -1 elsewhere
    tau: float = 0.005
    actor_tau: float = 0.001
    decay_steps: int = 3_000_000
    num_qs: int = 2
    critic_batch: int = 256
    episode_len: int = 1000  # for FISOR's reward normalisation (registry)
    r_max: float = 1.0  # DSRL's R_max / R_min (registry)
    r_min: float = 0.0
    done_rule: str = "terminal_or_timeout"


CONFIG = FISORConfig
# paper: FISOR's train_config (1M steps, batch 2048 = 2 actor halves of 1024, critics on 256)
PRESETS = {"paper": dict(steps=1_000_000, batch_size=2048),
           # quick (a 2-core CPU): actor halves of 256, a 2-block ResNet of 128, 20k steps
           "quick": dict(steps=20_000, batch_size=512, actor_hidden=128, actor_blocks=2)}
VARIANTS = {"fisor": {}}
FIXED = {"chunk_len": 1, "reward_scale": 1.0, "cost_scale": 1.0}
FIXED_WHY = {"chunk_len": "acts one step at a time",
             "reward_scale": "normalises rewards as FISOR does (L / (R_max - R_min))",
             "cost_scale": "turns costs into FISOR's stage cost (stage_cost)"}
HPARAMS = ("cost_temperature", "reward_temperature")
phases = actor_only


def task_values(spec) -> dict:
    return dict(episode_len=int(spec.episode_len), r_max=float(spec.r_max),
                r_min=float(spec.r_min))


def check_hparams(values: dict) -> None:
    check_lane_hparams(values, HPARAMS)


def validate(c: FISORConfig) -> None:
    for k in ("actor_lr", "critic_lr", "value_lr", "tau", "actor_tau", "stage_cost",
              "reward_weight_clip", "cost_weight_clip"):
        check_positive(k, getattr(c, k))
    for k in ("expectile", "cost_expectile"):
        check_range(k, getattr(c, k), 0, 1, low_open=True, high_open=True)
    check_range("actor_dropout", c.actor_dropout, 0, 1, high_open=True)
    check_range("reward_temperature", c.reward_temperature, 0)
    check_range("cost_temperature", c.cost_temperature, 0)
    check_sizes("critic_hidden_dims", c.critic_hidden_dims)
    check_counts(c, ("num_candidates", "diffusion_steps", "actor_hidden", "actor_blocks",
                     "num_qs", "critic_batch", "time_dim", "episode_len", "decay_steps"))
    if c.r_max <= c.r_min:
        raise ConfigError(f"r_max ({c.r_max}) must exceed r_min ({c.r_min})")
    check_choice("done_rule", c.done_rule, DONE_RULES)


def stage_cost(costs, value: float):
    """FISOR's HJ stage cost: +value where the cost is > 0, -1 elsewhere: [N] -> [N]."""
    return jnp.where(costs > 0, value, -1.0)


def hj_target(h, mask, discount, vh_next):
    """(1 - g) h + g max(h, V_h(s')) where m = 1, h where m = 0: all [B]."""
    return ((1.0 - discount) * h + discount * jnp.maximum(h, vh_next)) * mask + h * (1.0 - mask)


def feasibility_weights(q, v, qh, vh, reward_temperature, cost_temperature, reward_clip,
                        cost_clip):
    """FISOR's actor weights, [B]: infeasible states (V_h > 0) imitate the actions that lower
    Q_h below V_h; feasible ones (V_h <= 0, Q_h <= 0) the high-advantage actions; the rest 0."""
    unsafe = (vh > 0).astype(jnp.float32)
    safe = ((vh <= 0) & (qh <= 0)).astype(jnp.float32)
    cost_w = jnp.clip(jnp.exp((vh - qh) * cost_temperature), 0, cost_clip)
    reward_w = jnp.clip(jnp.exp((q - v) * reward_temperature), 0, reward_clip)
    return unsafe * cost_w + safe * reward_w


@struct.dataclass
class FISORState:
    params: dict  # actor, q, v, qh, vh
    target: dict  # actor (EMA), q, qh
    opt: dict
    step: jax.Array
    key: jax.Array


class Agent(TransitionAlgorithm):
    plot_metrics = ("loss_actor", "loss_q", "loss_qh", "weights")

    def __init__(self, cfg, obs_dim: int, act_dim: int):
        super().__init__(cfg, obs_dim, act_dim)
        if cfg.critic_batch > cfg.batch_size:
            raise ConfigError(f"critic_batch {cfg.critic_batch} exceeds batch_size "
                              f"{cfg.batch_size}")
        self.actor_net = NoiseModel(act_dim, cfg.actor_hidden, cfg.actor_blocks,
                                    cfg.actor_dropout, cfg.actor_layer_norm, cfg.time_dim)
        self.q_net = XavierQEnsemble(cfg.critic_hidden_dims, cfg.num_qs)
        self.v_net = StateValueNet(cfg.critic_hidden_dims)
        lr = optax.cosine_decay_schedule(cfg.actor_lr, cfg.decay_steps)
        self.tx = dict(actor=optax.adamw(lr, weight_decay=0.0), q=optax.adam(cfg.critic_lr),
                       qh=optax.adam(cfg.critic_lr), v=optax.adam(cfg.value_lr),
                       vh=optax.adam(cfg.value_lr))
        self.schedule = diffusion.schedule(cfg.diffusion_steps)

    def make_data(self, task, ds):
        cfg = self.cfg
        data = super().make_data(task, ds)
        lim = 1.0 - 1e-5
        return data.replace(
            rewards=data.rewards * (cfg.episode_len / (cfg.r_max - cfg.r_min)),
            costs=stage_cost(data.costs, cfg.stage_cost),
            actions=jnp.clip(data.actions, -lim, lim))

    def init(self, key: jax.Array, hp: dict) -> FISORState:
        del hp
        ka, kq, kv, kqh, kvh, k_state = jax.random.split(key, 6)
        o, a = jnp.zeros((1, self.obs_dim)), jnp.zeros((1, self.act_dim))
        params = dict(actor=self.actor_net.init(ka, o, a, jnp.zeros((1, 1))),
                      q=self.q_net.init(kq, o, a), v=self.v_net.init(kv, o),
                      qh=self.q_net.init(kqh, o, a), vh=self.v_net.init(kvh, o))
        return FISORState(params=params,
                          target={k: params[k] for k in ("actor", "q", "qh")},
                          opt={k: self.tx[k].init(v) for k, v in params.items()},
                          step=jnp.zeros((), jnp.int32), key=k_state)

    def _step(self, name, params, opt, loss_fn):
        return optimizer_step(self.tx, name, params, opt, loss_fn)

    def _actor_step(self, p, opt, tgt, b: TransitionBatch, hp, key):
        cfg = self.cfg
        _, _, alpha_hats = self.schedule
        kt, kn, kd = jax.random.split(key, 3)
        n = b.actions.shape[0]
        t = jax.random.randint(kt, (n,), 0, cfg.diffusion_steps)
        noise = jax.random.normal(kn, b.actions.shape)
        x_t = diffusion.noised(b.actions, t, noise, alpha_hats)
        q = self.q_net.apply(tgt["q"], b.observations, b.actions).min(0)
        v = self.v_net.apply(p["v"], b.observations)
        qh = self.q_net.apply(tgt["qh"], b.observations, b.actions).max(0)
        vh = self.v_net.apply(p["vh"], b.observations)
        w = feasibility_weights(q, v, qh, vh, hp["reward_temperature"], hp["cost_temperature"],
                                cfg.reward_weight_clip, cfg.cost_weight_clip)

        def loss_fn(ap):
            eps = self.actor_net.apply(ap, b.observations, x_t, t[:, None].astype(jnp.float32),
                                       training=True, rngs={"dropout": kd})
            return (((eps - noise) ** 2).sum(-1) * w).mean(), w.mean()

        return self._step("actor", p, opt, loss_fn)

    def update(self, state: FISORState, b: TransitionBatch, hp: dict, phase: str):
        """One FISOR step: two actor halves of the batch, then the four critics on its first
        `critic_batch` rows (obs [B, o], actions [B, A])."""
        cfg = self.cfg
        g = cfg.discount
        key, k1, k2 = jax.random.split(state.key, 3)
        p, opt, tgt = state.params, state.opt, state.target
        half = b.observations.shape[0] // 2
        first = jax.tree_util.tree_map(lambda x: x[:half], b)
        second = jax.tree_util.tree_map(lambda x: x[half:2 * half], b)
        for half_batch, k in ((first, k1), (second, k2)):  # the EMA follows each actor step
            p, opt, l_actor, w_mean = self._actor_step(p, opt, tgt, half_batch, hp, k)
            tgt = {**tgt, "actor": soft_update(tgt["actor"], p["actor"], cfg.actor_tau)}

        c = jax.tree_util.tree_map(lambda x: x[:cfg.critic_batch], b)
        mask = 1.0 - c.done
        q_t = self.q_net.apply(tgt["q"], c.observations, c.actions).min(0)
        p, opt, l_v, _ = self._step("v", p, opt, lambda vp: (expectile_loss(
            q_t - self.v_net.apply(vp, c.observations), cfg.expectile).mean(), ()))
        target_q = c.rewards + g * mask * self.v_net.apply(p["v"], c.next_observations)
        p, opt, l_q, _ = self._step("q", p, opt, lambda qp: (((
            self.q_net.apply(qp, c.observations, c.actions) - target_q[None]) ** 2).mean(), ()))
        qh_t = self.q_net.apply(tgt["qh"], c.observations, c.actions).max(0)
        p, opt, l_vh, _ = self._step("vh", p, opt, lambda vp: (reversed_expectile_loss(
            qh_t - self.v_net.apply(vp, c.observations), cfg.cost_expectile).mean(), ()))
        target_qh = hj_target(c.costs, mask, g, self.v_net.apply(p["vh"], c.next_observations))
        p, opt, l_qh, _ = self._step("qh", p, opt, lambda qp: (((
            self.q_net.apply(qp, c.observations, c.actions) - target_qh[None]) ** 2).mean(), ()))
        tgt = {**tgt, "q": soft_update(tgt["q"], p["q"], cfg.tau),
               "qh": soft_update(tgt["qh"], p["qh"], cfg.tau)}
        metrics = dict(loss_actor=l_actor, weights=w_mean, loss_v=l_v, loss_q=l_q,
                       loss_vh=l_vh, loss_qh=l_qh)
        return state.replace(params=p, opt=opt, target=tgt, step=state.step + 1, key=key), \
            metrics

    def policy_params(self, state: FISORState, hp: dict) -> dict:
        return {"actor": state.target["actor"], "qh": state.target["qh"]}

    def act(self, pp: dict, obs: jax.Array, key: jax.Array) -> jax.Array:
        """obs [B, obs_dim] -> [B, act_dim]: of `num_candidates` DDPM samples per state, the
        one with the least Q_h (max over the target ensemble)."""
        cfg = self.cfg
        check_obs(obs, self.obs_dim)
        n, bsz = cfg.num_candidates, obs.shape[0]
        rep = jnp.repeat(obs, n, axis=0)  # [B N, o], each state's candidates together

        def eps_fn(s, x, t):
            return self.actor_net.apply(pp["actor"], s, x, t, training=False)

        cand = diffusion.sample(eps_fn, rep, self.act_dim, key, cfg.diffusion_steps,
                                cfg.ddpm_temperature, cfg.clip_sampler)
        qh = self.q_net.apply(pp["qh"], rep, cand).max(0).reshape(bsz, n)
        best = jnp.argmin(qh, axis=1)
        a = cand.reshape(bsz, n, self.act_dim)[jnp.arange(bsz), best]
        return check_act(obs, a, self.obs_dim, self.act_dim)


SPEC = AlgorithmSpec(CONFIG=CONFIG, PRESETS=PRESETS, VARIANTS=VARIANTS, FIXED=FIXED,
                     FIXED_WHY=FIXED_WHY, HPARAMS=HPARAMS, Agent=Agent,
                     check_hparams=check_hparams, phases=phases, task_values=task_values,
                     validate=validate)

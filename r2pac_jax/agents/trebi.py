"""TREBI (Lin et al., ICML 2023): a guided diffusion planner with a real-time cost budget
(`--algo trebi`).

Written from the paper and Diffuser's published design (Janner et al. 2022, MIT); TREBI's
official code and its one DSRL adaptation (both without a licence) were read for settings only
(`experiments/table1/PROTOCOL.md`, addendum of 2026-12-07, names each):

- Training (one step = one batch of windows for all three networks): a diffusion model over
  windows of H (action, state) rows, z-scored, that predicts the clean window from a noisy one
  (cosine schedule, the first action weighted `action_weight`, the window's first state imposed
  by inpainting); reward and cost value networks on noisy windows at a random step, regressed on
  the discounted reward and cost from the window's start to its episode's end (`value_discount`).
  EMA copies of the three are what acts.
- Acting: `plans` windows from noise per episode; at every denoising step t, `guide_steps`
  steps x <- x + scale var_t (grad V_r - w [V_c > b] grad V_c), w = cost_grad_weight exp(clip(
  (V_c - b) / b, 0, 1)), none for t < t_stopgrad; the first action of the plan with the highest
  V_r among those with V_c <= b (the lowest V_c if none is) is executed. b, the remaining budget,
  starts at `budget` (the task's kappa) and falls by each step's cost (undiscounted): a memory
  across steps, as CDT's targets (`memory_init` / `act_memory` / `observe`).

Planning is one `lax.scan` over denoising steps, batched over plans and episodes.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct

from r2pac_jax.agents.base import (ChunkAlgorithm, actor_only, check_act, check_counts,
                                   check_dataset_sizes, check_lane_hparams, check_obs,
                                   check_positive)
from r2pac_jax.agents.spec import AlgorithmSpec
from r2pac_jax.agents.temporal_unet import TemporalUnet, ValueFunction
from r2pac_jax.data import sequences
from r2pac_jax.errors import ConfigError
from r2pac_jax.ranges import check_range


@dataclasses.dataclass(frozen=True)
class TREBIConfig:
    # the model (defaults: the quick preset)
    horizon: int = 16
    diffusion_steps: int = 5
    unet_dim: int = 16
    unet_mults: tuple = (1, 2, 4)
    action_weight: float = 10.0
    lr: float = 2e-4
    value_lr: float = 1e-3
    value_discount: float = 0.997
    ema_decay: float = 0.995
    ema_every: int = 10
    ema_start: int = 2000
    # planning
    plans: int = 8
    guide_steps: int = 1
    guide_scale: float = 0.1
    t_stopgrad: int = 2
    cost_grad_weight: float = 5.0
    budget: float = 10.0  # the task's kappa (registry); an hparam
    episode_len: int = 1000  # (registry) the horizon may not exceed it


CONFIG = TREBIConfig


def _paper(spec) -> dict:
    """Published: H 32, 20 denoising steps, 64 plans, 2 guide steps, U-Net 32 x (1, 2, 4, 8);
    200k training steps on Safety-Gymnasium's tasks, 100k on Bullet's."""
    return dict(steps=100_000 if spec.family == "bullet" else 200_000, batch_size=64,
                horizon=32, diffusion_steps=20, unet_dim=32, unet_mults=(1, 2, 4, 8), plans=64,
                guide_steps=2, reward_scale=1.0, cost_scale=1.0)


PRESETS = {
    "paper": _paper,
    # the protocol's CPU preset (about 200x cheaper per action), fixed before any TREBI score
    "quick": dict(steps=10_000, batch_size=64, horizon=16, diffusion_steps=5, unet_dim=16,
                  unet_mults=(1, 2, 4), plans=8, guide_steps=1, reward_scale=1.0,
                  cost_scale=1.0),
}
VARIANTS = {"trebi": {}}
FIXED = {"chunk_len": 1}
FIXED_WHY = {"chunk_len": "plans whole windows and executes one action of each plan"}
HPARAMS = ("budget",)


phases = actor_only


def task_values(spec) -> dict:
    return dict(budget=float(spec.kappa), episode_len=int(spec.episode_len))


def check_hparams(values: dict) -> None:
    check_lane_hparams(values, HPARAMS, positive=HPARAMS)


def validate(c: TREBIConfig) -> None:
    check_counts(c, ("horizon", "diffusion_steps", "unet_dim", "plans", "guide_steps",
                     "ema_every", "episode_len"))
    for k in ("lr", "value_lr", "budget"):
        check_positive(k, getattr(c, k))
    for k in ("action_weight", "guide_scale", "cost_grad_weight", "t_stopgrad", "ema_start"):
        check_range(k, getattr(c, k), 0)
    check_range("value_discount", c.value_discount, 0, 1)
    check_range("ema_decay", c.ema_decay, 0, 1, high_open=True)
    if not c.unet_mults or any(m < 1 for m in c.unet_mults):
        raise ConfigError(f"unet_mults must be positive integers, got {c.unet_mults}")
    if c.unet_dim % 8:
        raise ConfigError(f"unet_dim {c.unet_dim} must be a multiple of 8 (GroupNorm's 8 groups)")
    if (c.unet_dim * c.unet_mults[-1]) % 32:
        raise ConfigError(f"unet_dim x unet_mults[-1] = {c.unet_dim * c.unet_mults[-1]} must be "
                          "a multiple of 32: the value networks' last blocks have a half and a "
                          "quarter of it, each in GroupNorm's 8 groups")
    halvings = 2 ** (len(c.unet_mults) - 1)
    if c.horizon % halvings:
        raise ConfigError(f"horizon {c.horizon} must be a multiple of {halvings}: the U-Net "
                          f"halves it {len(c.unet_mults) - 1} times (unet_mults={c.unet_mults})")
    if c.horizon > c.episode_len:
        raise ConfigError(f"horizon {c.horizon} is longer than an episode ({c.episode_len} "
                          "steps); choose horizon <= the episode length")


# ---------------------------------------------------------------------------------------------
# The diffusion process (Diffuser's GaussianDiffusion with the clean window predicted)


class Schedule(NamedTuple):
    sqrt_ac: jax.Array  # [T]
    sqrt_1m_ac: jax.Array
    coef_x0: jax.Array  # posterior mean = coef_x0 x0 + coef_xt x_t
    coef_xt: jax.Array
    var: jax.Array  # posterior variance (the guide's gradient scale)
    log_var: jax.Array  # clipped at log 1e-20


def cosine_schedule(steps: int, s: float = 0.008) -> Schedule:
    """Diffuser's cosine betas (Nichol & Dhariwal), clipped at 0.999, and the DDPM posterior."""
    x = np.linspace(0, steps + 1, steps + 1)
    ac = np.cos(((x / (steps + 1)) + s) / (1 + s) * math.pi * 0.5) ** 2
    ac = ac / ac[0]
    betas = np.clip(1 - ac[1:] / ac[:-1], 0, 0.999)
    alphas = 1.0 - betas
    ac = np.cumprod(alphas)
    ac_prev = np.concatenate([[1.0], ac[:-1]])
    var = betas * (1 - ac_prev) / (1 - ac)
    f = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    return Schedule(f(np.sqrt(ac)), f(np.sqrt(1 - ac)), f(betas * np.sqrt(ac_prev) / (1 - ac)),
                    f((1 - ac_prev) * np.sqrt(alphas) / (1 - ac)), f(var),
                    f(np.log(np.maximum(var, 1e-20))))


def inpaint(x, state, act_dim: int):
    """x [N, H, A + O] with its first row's state set to state [N, O]."""
    return x.at[:, 0, act_dim:].set(state)


def guided_plan(denoise: Callable, value_r: Callable, value_c: Callable, state, budget, key,
                sched: Schedule, act_dim: int, horizon: int, plans: int, guide_steps: int,
                guide_scale: float, t_stopgrad: int, cost_grad_weight: float):
    """Plans for B episodes: state [B, O] (normalised), budget [B] -> (windows [B, P, H, A + O],
    V_r [B, P], V_c [B, P], chosen [B] int). denoise(x [N, H, D], t [N]) -> the clean window;
    value_*(x, t) -> [N]."""
    b, o = state.shape
    n, d = b * plans, act_dim + o
    s0 = jnp.repeat(state, plans, axis=0)  # [N, O], plans of an episode adjacent
    thr = jnp.repeat(budget, plans, axis=0)  # [N]
    thr_div = jnp.where(thr == 0, 1e-6, thr)

    def value_and_grad(value, x, t):
        """Each window's value [N] and its gradient [N, H, D] in one pass."""
        y, back = jax.vjp(lambda x_: value(x_, t), x)
        return y, back(jnp.ones_like(y))[0]

    k0, key = jax.random.split(key)
    x = inpaint(jax.random.normal(k0, (n, horizon, d)), s0, act_dim)

    def guide(carry, _):
        x, t, _, _ = carry
        tt = jnp.full((n,), t)
        y_r, g_r = value_and_grad(value_r, x, tt)
        y_c, g_c = value_and_grad(value_c, x, tt)
        over = y_c > thr
        w = cost_grad_weight * jnp.exp(jnp.clip((y_c - thr) / thr_div, 0.0, 1.0))
        g = g_r - (w * over)[:, None, None] * g_c
        g = jnp.where(t < t_stopgrad, 0.0, sched.var[t] * g)
        return (inpaint(x + guide_scale * g, s0, act_dim), t, y_r, y_c), None

    def step(carry, t):
        x, key, _, _ = carry
        (x, _, y_r, y_c), _ = jax.lax.scan(
            guide, (x, t, jnp.zeros(n), jnp.zeros(n)), None, length=guide_steps)
        x0 = denoise(x, jnp.full((n,), t))
        mean = sched.coef_x0[t] * x0 + sched.coef_xt[t] * x
        key, kz = jax.random.split(key)
        noise = jax.random.normal(kz, x.shape) * (t > 0)
        x = inpaint(mean + jnp.exp(0.5 * sched.log_var[t]) * noise, s0, act_dim)
        return (x, key, y_r, y_c), None

    steps = sched.var.shape[0]
    (x, _, y_r, y_c), _ = jax.lax.scan(step, (x, key, jnp.zeros(n), jnp.zeros(n)),
                                       jnp.arange(steps - 1, -1, -1))
    y_r, y_c = y_r.reshape(b, plans), y_c.reshape(b, plans)
    return x.reshape(b, plans, horizon, d), y_r, y_c, choose_plan(y_r, y_c, budget)


def choose_plan(y_r, y_c, budget):
    """y_r, y_c [B, P], budget [B] -> [B]: the highest V_r among the plans with V_c <= budget,
    the lowest V_c where none is."""
    within = y_c <= budget[:, None]
    score = jnp.where(within.any(-1, keepdims=True), jnp.where(within, y_r, y_r - 1e8), -y_c)
    return jnp.argmax(score, -1)


# ---------------------------------------------------------------------------------------------
# Data: windows of H rows and their values' targets


@struct.dataclass
class TREBIData:
    seq: sequences.SequenceData
    reward_to_go: jax.Array  # [N] discounted to the episode's end (value_discount)
    cost_to_go: jax.Array  # [N]
    obs_mean: jax.Array  # [O] the z-scores' statistics
    obs_std: jax.Array
    act_mean: jax.Array  # [A]
    act_std: jax.Array


class TREBIBatch(NamedTuple):
    x: jax.Array  # [B, H, A + O] normalised windows (rows past the episode's end: zeros)
    value_r: jax.Array  # [B] targets at the window's first row
    value_c: jax.Array  # [B]


@struct.dataclass
class TREBIState:
    params: dict  # {"model", "value_r", "value_c"}
    ema: dict
    opt: dict
    norm: dict  # the data's z-score statistics (copied from the view each block)
    step: jax.Array
    key: jax.Array


class Memory(NamedTuple):
    budget: jax.Array  # [B] what is left of each episode's cost budget


class Agent(ChunkAlgorithm):
    plot_metrics = ("loss_diffusion", "loss_value_r", "loss_value_c")

    def __init__(self, cfg, obs_dim: int, act_dim: int):
        super().__init__(cfg, obs_dim, act_dim)
        d = obs_dim + act_dim
        self.model = TemporalUnet(d, cfg.unet_dim, tuple(cfg.unet_mults))
        self.value = ValueFunction(cfg.unet_dim, tuple(cfg.unet_mults))
        self.tx = {"model": optax.adam(cfg.lr), "value_r": optax.adam(cfg.value_lr),
                   "value_c": optax.adam(cfg.value_lr)}
        self.sched = cosine_schedule(cfg.diffusion_steps)
        w = np.ones((cfg.horizon, d), np.float32)
        w[0, :act_dim] = cfg.action_weight
        self.loss_weights = jnp.asarray(w)

    # data ------------------------------------------------------------------------------------
    def check_data(self, task, ds) -> None:
        check_dataset_sizes(task, ds)
        self.keep_episodes(task, ds)

    def make_data(self, task, ds) -> TREBIData:
        keep = self.keep_episodes(task, ds)
        seq = sequences.build_sequences(ds, keep_episodes=keep, cost_weight_base=None)
        # the kept episodes' rows, the only ones a window starts in (others' values stay 0)
        starts, lengths = np.asarray(seq.ep_start), np.asarray(seq.ep_len)
        g = self.cfg.value_discount
        f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
        std = lambda a: np.maximum(a.std(0), 1e-6)  # noqa: E731
        return TREBIData(
            seq=seq,
            reward_to_go=f32(sequences.to_go(ds.rewards * self.cfg.reward_scale, starts,
                                             lengths, g)),
            cost_to_go=f32(sequences.to_go(ds.costs * self.cfg.cost_scale, starts, lengths, g)),
            obs_mean=f32(ds.observations.mean(0)), obs_std=f32(std(ds.observations)),
            act_mean=f32(ds.actions.mean(0)), act_std=f32(std(ds.actions)))

    def sample(self, data: TREBIData, key: jax.Array) -> TREBIBatch:
        """Windows of H rows: episodes uniformly, starts uniform within the episode, rows past
        its end zero (raw) as Diffuser's padding."""
        h, b, seq = self.cfg.horizon, self.cfg.batch_size, data.seq
        k_ep, k_start = jax.random.split(key)
        ep = jax.random.categorical(k_ep, seq.ep_logits, shape=(b,))
        length = seq.ep_len[ep]
        s = jax.random.randint(k_start, (b,), 0, length)
        offs = jnp.arange(h)
        m = ((s[:, None] + offs[None]) < length[:, None]).astype(jnp.float32)[..., None]
        first = seq.ep_start[ep] + s
        rows = jnp.minimum(first[:, None] + offs[None], seq.observations.shape[0] - 1)
        obs = (seq.observations[rows] * m - data.obs_mean) / data.obs_std
        act = (seq.actions[rows] * m - data.act_mean) / data.act_std
        return TREBIBatch(x=jnp.concatenate([act, obs], -1), value_r=data.reward_to_go[first],
                          value_c=data.cost_to_go[first])

    def begin_block(self, state: TREBIState, hp: dict, data: TREBIData) -> TREBIState:
        return state.replace(norm=dict(obs_mean=data.obs_mean, obs_std=data.obs_std,
                                       act_mean=data.act_mean, act_std=data.act_std))

    # training --------------------------------------------------------------------------------
    def init(self, key: jax.Array, hp: dict) -> TREBIState:
        del hp
        km, kr, kc, k_state = jax.random.split(key, 4)
        x = jnp.zeros((1, self.cfg.horizon, self.obs_dim + self.act_dim))
        t = jnp.zeros((1,), jnp.int32)
        params = {"model": self.model.init(km, x, t), "value_r": self.value.init(kr, x, t),
                  "value_c": self.value.init(kc, x, t)}
        norm = dict(obs_mean=jnp.zeros(self.obs_dim), obs_std=jnp.ones(self.obs_dim),
                    act_mean=jnp.zeros(self.act_dim), act_std=jnp.ones(self.act_dim))
        return TREBIState(params=params, ema=params,
                          opt={k: self.tx[k].init(v) for k, v in params.items()}, norm=norm,
                          step=jnp.zeros((), jnp.int32), key=k_state)

    def _noisy(self, x0, key):
        """(x_t inpainted, t [B]) at a random step."""
        kt, kn = jax.random.split(key)
        t = jax.random.randint(kt, (x0.shape[0],), 0, self.cfg.diffusion_steps)
        xt = (self.sched.sqrt_ac[t][:, None, None] * x0
              + self.sched.sqrt_1m_ac[t][:, None, None] * jax.random.normal(kn, x0.shape))
        return inpaint(xt, x0[:, 0, self.act_dim:], self.act_dim), t

    def losses(self, params: dict, batch: TREBIBatch, keys) -> tuple[jax.Array, dict]:
        """The three losses, each of its own network (their sum is differentiated once)."""
        a = self.act_dim
        xt, t = self._noisy(batch.x, keys[0])
        recon = inpaint(self.model.apply(params["model"], xt, t), batch.x[:, 0, a:], a)
        l_diff = jnp.mean(self.loss_weights * (recon - batch.x) ** 2)
        xr, tr = self._noisy(batch.x, keys[1])
        l_r = jnp.mean((self.value.apply(params["value_r"], xr, tr) - batch.value_r) ** 2)
        xc, tc = self._noisy(batch.x, keys[2])
        l_c = jnp.mean((self.value.apply(params["value_c"], xc, tc) - batch.value_c) ** 2)
        return l_diff + l_r + l_c, dict(loss_diffusion=l_diff, loss_value_r=l_r,
                                        loss_value_c=l_c)

    def update(self, state: TREBIState, batch: TREBIBatch, hp: dict, phase: str):
        cfg = self.cfg
        key, *keys = jax.random.split(state.key, 4)
        (_, metrics), g = jax.value_and_grad(self.losses, has_aux=True)(state.params, batch, keys)
        params, opt = {}, {}
        for k, p in state.params.items():
            upd, opt[k] = self.tx[k].update(g[k], state.opt[k], p)
            params[k] = optax.apply_updates(p, upd)
        # Diffuser's EMA: every ema_every steps, a copy until ema_start, then the average
        n = state.step
        avg = jax.tree_util.tree_map(lambda e, p: cfg.ema_decay * e + (1 - cfg.ema_decay) * p,
                                     state.ema, params)
        fresh = jax.tree_util.tree_map(lambda a_, p: jnp.where(n < cfg.ema_start, p, a_),
                                       avg, params)
        ema = jax.tree_util.tree_map(lambda f, e: jnp.where(n % cfg.ema_every == 0, f, e),
                                     fresh, state.ema)
        metrics["loss_actor"] = metrics["loss_diffusion"]
        return state.replace(params=params, ema=ema, opt=opt, step=n + 1, key=key), metrics

    # acting ----------------------------------------------------------------------------------
    def policy_params(self, state: TREBIState, hp: dict) -> dict:
        return {"ema": state.ema, "norm": state.norm,
                "budget": jnp.asarray(hp["budget"], jnp.float32)}

    def plan(self, pp: dict, obs: jax.Array, budget: jax.Array, key: jax.Array):
        """obs [B, O] raw, budget [B] -> guided_plan's output on the normalised state."""
        c, nm = self.cfg, pp["norm"]
        model, vr, vc = pp["ema"]["model"], pp["ema"]["value_r"], pp["ema"]["value_c"]
        return guided_plan(
            lambda x, t: self.model.apply(model, x, t),
            lambda x, t: self.value.apply(vr, x, t), lambda x, t: self.value.apply(vc, x, t),
            (obs - nm["obs_mean"]) / nm["obs_std"], budget, key, self.sched, self.act_dim,
            c.horizon, c.plans, c.guide_steps, c.guide_scale, c.t_stopgrad, c.cost_grad_weight)

    def memory_init(self, pp: dict, obs: jax.Array) -> Memory:
        check_obs(obs, self.obs_dim)
        return Memory(budget=jnp.full((obs.shape[0],), pp["budget"], jnp.float32))

    def act_memory(self, pp: dict, obs: jax.Array, key: jax.Array, mem: Memory):
        """obs [B, O] -> (action [B, A]: the chosen plan's first action, memory unchanged)."""
        check_obs(obs, self.obs_dim)
        x, _, _, chosen = self.plan(pp, obs, mem.budget, key)
        first = jnp.take_along_axis(x[:, :, 0, :self.act_dim], chosen[:, None, None], 1)[:, 0]
        a = jnp.clip(first * pp["norm"]["act_std"] + pp["norm"]["act_mean"], -1.0, 1.0)
        return check_act(obs, a, self.obs_dim, self.act_dim), mem

    def observe(self, pp: dict, mem: Memory, reward: jax.Array, cost: jax.Array) -> Memory:
        """After a step: the budget falls by its cost [B] (undiscounted, as the adaptation)."""
        del pp, reward
        return Memory(budget=mem.budget - cost)

    def act(self, pp: dict, obs: jax.Array, key: jax.Array) -> jax.Array:
        """obs [B, O] -> [B, A] as at an episode's first step (the full budget)."""
        return self.act_memory(pp, obs, key, self.memory_init(pp, obs))[0]

    def summary(self, state: TREBIState) -> dict:
        return {}


SPEC = AlgorithmSpec(CONFIG=CONFIG, PRESETS=PRESETS, VARIANTS=VARIANTS, FIXED=FIXED,
                     FIXED_WHY=FIXED_WHY, HPARAMS=HPARAMS, Agent=Agent,
                     check_hparams=check_hparams, phases=phases, task_values=task_values,
                     validate=validate)

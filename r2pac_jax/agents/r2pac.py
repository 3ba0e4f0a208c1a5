"""R2PAC and its ablations (docs/algorithm.md): state pytree, critic and policy updates, the policy.

One module serves `r2pac` and the paper's ablations (`r2pac-no-penalty`, `r2pac-no-vc`,
`r2pac-awr`, `r2pac-awr-flow`, `r2pac-hj`): each is a set of values of `R2PACConfig` that
switch small pure pieces of `critics.py`, `extraction.py`, `flow.py`, `gaussian.py` and
`selection.py`. The `Agent` object holds static structure (network definitions, optimiser);
everything that changes travels in `AgentState`.
"""
from __future__ import annotations

import dataclasses
import functools
from typing import Any

import chex
import jax
import jax.numpy as jnp
import optax
from flax import struct

from r2pac_jax.agents import critics, diagnostics, extraction, flow, gaussian
from r2pac_jax.agents.base import (ChunkAlgorithm, check_act, check_obs, check_positive,
                                   check_lane_hparams, check_sizes, optimizer_step,
                                   soft_update)
from r2pac_jax.agents.selection import select_candidate
from r2pac_jax.agents.spec import AlgorithmSpec
from r2pac_jax.data.chunks import Batch, ChunkedData
from r2pac_jax.errors import ConfigError
from r2pac_jax.nets import NULL_LABEL, GaussianActor, QEnsemble, ValueNet, VelocityField
from r2pac_jax.ranges import check_range


@dataclasses.dataclass(frozen=True)
class R2PACConfig:
    lr: float = 3e-4
    hidden_dims: tuple = (128, 128, 128)
    actor_hidden_dims: tuple = (128, 128, 128)  # the AWR Gaussian actor: a 3-layer MLP
    layer_norm: bool = False  # LayerNorm in the critics and the velocity field
    critic_layer_norm: bool = False  # LayerNorm in the critics only (Q_c, V_c, Qbar_r, V_r)
    vc_nonneg: bool = False  # V_c >= 0 (softplus output): costs are >= 0
    schedule: str = "two_phase"  # two_phase (critics, then policy) | joint
    # IQL critics
    expectile: float = 0.9
    polyak: float = 0.005
    num_critics: int = 2
    # safety threshold and penalty (alpha and C come from the task registry)
    quantile_alpha: float = 0.9
    penalty_c: float = 1.0
    penalty_mode: str = "absorbing"  # absorbing: target -C/(1-g); direct: target -C
    threshold_source: str = "dataset"  # dataset | batch
    threshold_subset: int = 65536
    # policy
    guidance_scale: float = 2.0
    cfg_dropout: float = 0.1
    flow_steps: int = 32
    num_candidates: int = 16
    selection: str = "min_qc"  # min_qc | safe_then_reward | first
    awr_temperature: float = 6.0
    awr_clip: float = 100.0
    time_embed_dim: int = 16
    # ablation switches (set by the variants below)
    actor: str = "cfg_flow"  # cfg_flow | awr_flow | awr_gaussian
    reward_penalty: bool = True  # False: "w/o Vbar_r" (unpenalised V_r in safe states)
    unsafe_branch: bool = True  # False: "w/o V_c" (reward advantage labels everywhere)
    cost_critic: str = "discounted"  # discounted | hj (feasibility, Eq. 42)


CONFIG = R2PACConfig

PRESETS = {
    # Table 3 of the paper.
    "paper": dict(hidden_dims=(512, 512, 512, 512), actor_hidden_dims=(512, 512, 512),
                  flow_steps=32, num_candidates=16),
    # 3x128 runs ~160 critic steps/s on 2 cores (3x256: ~77; benchmarks/RESULTS.md).
    "quick": dict(hidden_dims=(128, 128, 128), actor_hidden_dims=(128, 128, 128), flow_steps=32,
                  num_candidates=16, threshold_subset=16384),
}

VARIANTS = {
    "r2pac": {},
    "r2pac-no-penalty": {"reward_penalty": False},
    "r2pac-no-vc": {"unsafe_branch": False},
    "r2pac-awr": {"actor": "awr_gaussian"},
    "r2pac-awr-flow": {"actor": "awr_flow"},
    "r2pac-hj": {"cost_critic": "hj"},
}

FIXED: dict = {}
FIXED_WHY: dict = {}

HPARAMS = ("quantile_alpha", "penalty_c", "guidance_scale")

CHOICES = {
    "schedule": ("two_phase", "joint"),
    "penalty_mode": ("absorbing", "direct"),
    "threshold_source": ("dataset", "batch"),
    "selection": ("min_qc", "safe_then_reward", "first"),
    "actor": ("cfg_flow", "awr_flow", "awr_gaussian"),
    "cost_critic": ("discounted", "hj"),
}


def task_values(spec) -> dict:
    """The paper's per-task values (Table 4)."""
    return dict(quantile_alpha=spec.quantile_alpha, penalty_c=spec.penalty_c)


def phases(c: R2PACConfig) -> tuple[str, ...]:
    return ("critic", "actor") if c.schedule == "two_phase" else ("joint",)


def check_hparams(values: dict) -> None:
    """alpha in (0, 1) (a quantile), then the shared rules: known names, finite, >= 0."""
    if "quantile_alpha" in values:
        check_range("quantile_alpha", values["quantile_alpha"], 0, 1, low_open=True,
                    high_open=True)
    check_lane_hparams(values, HPARAMS)


def validate(c: R2PACConfig) -> None:
    for k, choices in CHOICES.items():
        if getattr(c, k) not in choices:
            raise ConfigError(f"{k}={getattr(c, k)!r} is not one of {choices}")
    check_hparams({k: getattr(c, k) for k in HPARAMS})
    check_range("expectile", c.expectile, 0, 1, low_open=True, high_open=True)
    check_range("polyak", c.polyak, 0, 1, low_open=True)
    check_range("cfg_dropout", c.cfg_dropout, 0, 1)
    check_range("awr_temperature", c.awr_temperature, 0)
    check_positive("lr", c.lr)
    check_positive("awr_clip", c.awr_clip)
    for k in ("flow_steps", "num_candidates", "threshold_subset", "num_critics",
              "time_embed_dim"):
        if getattr(c, k) < 1:
            raise ConfigError(f"{k} must be >= 1, got {getattr(c, k)}")
    check_sizes("hidden_dims", c.hidden_dims)
    check_sizes("actor_hidden_dims", c.actor_hidden_dims)
    if c.vc_nonneg and c.cost_critic == "hj":
        raise ConfigError("vc_nonneg=true keeps a value of costs >= 0; the HJ feasibility critic "
                          "(r2pac-hj) is signed: leave vc_nonneg out for it")


@struct.dataclass
class AgentState:
    params: dict  # networks: qc, vc, qr, vr (when critics are trained) and actor
    target: dict  # Polyak copies of qc, qr
    opt: dict  # optimiser state per network
    threshold: jax.Array  # [] safety threshold l
    step: jax.Array  # [] int32 gradient steps taken
    key: jax.Array


class Agent(ChunkAlgorithm):
    plot_metrics = ("loss_qc", "loss_qr", "threshold", "loss_actor", "qr_rmse_penalised",
                    "qr_rmse_unpenalised", "corr_adv_r_reward_safe", "label_balance_safe",
                    "label_balance_unsafe")
    unevaluated_phases = ("critic",)  # two_phase: no policy is trained until the actor phase
    progress_metrics = {"l": "threshold"}

    def __init__(self, cfg, obs_dim: int, act_dim: int):
        super().__init__(cfg, obs_dim, act_dim)
        self.threshold_subset = cfg.threshold_subset
        critic_ln = cfg.layer_norm or cfg.critic_layer_norm
        self.q_net = QEnsemble(cfg.hidden_dims, cfg.num_critics, critic_ln)
        self.v_net = ValueNet(cfg.hidden_dims, critic_ln)
        # V_c has its own module only where it differs (the parameter tree stays the same)
        self.vc_net = ValueNet(cfg.hidden_dims, critic_ln, nonneg=cfg.vc_nonneg)
        if self.is_gaussian:
            self.actor_net = GaussianActor(cfg.actor_hidden_dims, self.chunk_size)
        else:
            self.actor_net = VelocityField(cfg.hidden_dims, self.chunk_size, cfg.time_embed_dim,
                                           cfg.layer_norm)
        self.tx = optax.adam(cfg.lr)
        self.txs = dict.fromkeys(("qc", "vc", "qr", "vr", "actor"), self.tx)  # one per network
        self.discount_h = cfg.discount**cfg.chunk_len
        self.hj = cfg.cost_critic == "hj"

    # ---- structure ---------------------------------------------------------------------
    @property
    def is_gaussian(self) -> bool:
        return self.cfg.actor == "awr_gaussian"

    def init(self, key: jax.Array, hp: dict) -> AgentState:
        del hp
        k_net, k_state = jax.random.split(key)
        ks = jax.random.split(k_net, 5)
        obs = jnp.zeros((1, self.obs_dim))
        chunk = jnp.zeros((1, self.chunk_size))
        params = {}
        params["qc"] = self.q_net.init(ks[0], obs, chunk)
        params["vc"] = self.vc_net.init(ks[1], obs)
        params["qr"] = self.q_net.init(ks[2], obs, chunk)
        params["vr"] = self.v_net.init(ks[3], obs)
        if self.is_gaussian:
            params["actor"] = self.actor_net.init(ks[4], obs)
        else:
            params["actor"] = self.actor_net.init(ks[4], chunk, jnp.zeros((1,)), obs,
                                                  jnp.zeros((1,), jnp.int32))
        target = {k: params[k] for k in ("qc", "qr")}
        opt = {k: self.tx.init(v) for k, v in params.items()}
        return AgentState(params=params, target=target, opt=opt, threshold=jnp.zeros(()),
                          step=jnp.zeros((), jnp.int32), key=k_state)

    # ---- threshold -----------------------------------------------------------------------
    def dataset_threshold(self, params: dict, data: ChunkedData, hp: dict) -> jax.Array:
        """l over the fixed subset of dataset states (0 for the HJ feasibility variant)."""
        if self.hj:
            return jnp.zeros(())
        vc = self.vc_net.apply(params["vc"], data.observations[data.threshold_states])
        return critics.safety_threshold(vc, hp["quantile_alpha"])

    def begin_block(self, state: AgentState, hp: dict, data: ChunkedData) -> AgentState:
        """Refresh l once per block over the dataset subset (threshold_source=dataset)."""
        if self.cfg.threshold_source == "dataset":
            state = state.replace(threshold=self.dataset_threshold(state.params, data, hp))
        return state

    def summary(self, state: AgentState) -> dict:
        return {"threshold": state.threshold}

    # ---- updates ---------------------------------------------------------------------------
    # the critic losses (docs/algorithm.md, "Critics"): loss(params) -> (loss, output)
    def cost_value_loss(self, obs, qc_target_max):
        """V_c: the reversed expectile of the target Q_c ensemble's max (the minimum-cost
        value; the feasibility value V_z for the HJ variant). obs [B, O], qc_target_max [B]."""
        def loss(p):
            vc = self.vc_net.apply(p, obs)
            u = qc_target_max - vc
            return critics.reversed_expectile_loss(u, self.cfg.expectile).mean(), vc
        return loss

    def q_loss(self, obs, chunk, target):
        """A Q ensemble [K, B] regressed to its target [B]: Q_c to C_t + g^h m_t V_c(s_{t+h})
        (or the HJ target), Qbar_r to the penalised target (Eq. 12); one network class serves
        both (`q_net`), so one loss does."""
        def loss(p):
            qs = self.q_net.apply(p, obs, chunk)
            return critics.q_regression_loss(qs, target), qs
        return loss

    def reward_value_loss(self, obs, qr_target_min):
        """Vbar_r: the upper expectile of the target Qbar_r ensemble's min. qr_target_min [B]."""
        def loss(p):
            vr = self.v_net.apply(p, obs)
            return critics.expectile_loss(qr_target_min - vr, self.cfg.expectile).mean(), vr
        return loss

    def update_critics(self, state: AgentState, batch: Batch, hp: dict):
        """V_c, Q_c, then Vbar_r, Qbar_r, each one optimiser step (V on the target Qs, Q on the
        fresh V), then Polyak on the Qs. batch: B chunks of h actions."""
        cfg = self.cfg
        B = batch.observations.shape[0]
        chex.assert_shape(batch.actions, (B, self.h, self.act_dim))
        obs, nobs = batch.observations, batch.next_observations
        chunk = batch.actions.reshape(B, -1)
        params, opt, tgt = state.params, state.opt, state.target
        step = functools.partial(optimizer_step, self.txs)

        params, opt, l_vc, vc = step("vc", params, opt, self.cost_value_loss(
            obs, self.q_net.apply(tgt["qc"], obs, chunk).max(0)))
        vc_next = self.vc_net.apply(params["vc"], nobs)
        if self.hj:
            qc_target = critics.feasibility_target(batch.zmax, batch.bootstrap, self.discount_h,
                                                   vc_next)
        else:
            qc_target = critics.cost_target(batch.cost, batch.bootstrap, self.discount_h, vc_next)
        params, opt, l_qc, qc = step("qc", params, opt, self.q_loss(obs, chunk, qc_target))

        if self.hj:
            threshold = jnp.zeros(())
        elif cfg.threshold_source == "batch":
            threshold = critics.safety_threshold(vc, hp["quantile_alpha"])
        else:
            threshold = state.threshold

        params, opt, l_vr, vr = step("vr", params, opt, self.reward_value_loss(
            obs, self.q_net.apply(tgt["qr"], obs, chunk).min(0)))
        vr_next = self.v_net.apply(params["vr"], nobs)
        penalty = critics.penalty_value(hp["penalty_c"], cfg.discount, cfg.penalty_mode)
        qr_target = critics.penalised_reward_target(
            batch.reward, batch.bootstrap, self.discount_h, vr_next, vc_next, threshold, penalty,
            use_penalty=cfg.reward_penalty)
        params, opt, l_qr, qr = step("qr", params, opt, self.q_loss(obs, chunk, qr_target))

        target = {k: soft_update(tgt[k], params[k], cfg.polyak) for k in ("qc", "qr")}
        unsafe_next = (vc_next > threshold) & (batch.bootstrap > 0)
        # how Qbar_r fits its own (penalised) targets and the plain h-step reward targets: a
        # penalty that dominates the fit leaves little reward signal in the CFG labels
        qr_plain = critics.penalised_reward_target(
            batch.reward, batch.bootstrap, self.discount_h, vr_next, vc_next, threshold,
            penalty, use_penalty=False)
        metrics = dict(
            loss_vc=l_vc, loss_qc=l_qc, loss_vr=l_vr, loss_qr=l_qr,
            qc_mean=qc.mean(), vc_mean=vc.mean(), qr_mean=qr.mean(), vr_mean=vr.mean(),
            qr_target_mean=qr_target.mean(), threshold=threshold,
            safe_frac=(vc <= threshold).mean(), unsafe_next_frac=unsafe_next.mean(),
            vc_min=vc.min(), qr_rmse_penalised=diagnostics.rmse(qr, qr_target),
            qr_rmse_unpenalised=diagnostics.rmse(qr, qr_plain),
            chunk_reward_std=batch.reward.std(),
        )
        new = state.replace(params=params, opt=opt, target=target, threshold=threshold)
        return new, metrics

    def _advantages(self, state: AgentState, obs, chunk):
        q, v, tgt, p = self.q_net.apply, self.v_net.apply, state.target, state.params
        vc = self.vc_net.apply(p["vc"], obs)
        safe = vc <= state.threshold
        adv_r = q(tgt["qr"], obs, chunk).min(0) - v(p["vr"], obs)
        adv_c = q(tgt["qc"], obs, chunk).max(0) - vc
        return safe, adv_r, adv_c

    def update_actor(self, state: AgentState, batch: Batch, hp: dict, key: jax.Array):
        cfg = self.cfg
        B = batch.observations.shape[0]
        obs, mask = batch.observations, batch.action_mask
        chunk = batch.actions.reshape(B, -1)
        metrics: dict[str, Any] = {}
        weights = None
        labels = jnp.full((B,), NULL_LABEL, jnp.int32)
        safe, adv_r, adv_c = self._advantages(state, obs, chunk)
        metrics["actor_safe_frac"] = safe.mean()
        # does the reward advantage in safe states track the chunk's own reward?
        metrics["corr_adv_r_reward_safe"] = diagnostics.masked_corr(adv_r, batch.reward, safe)
        if cfg.actor == "cfg_flow":
            k_drop, key = jax.random.split(key)
            o = extraction.optimality_labels(safe, adv_r, adv_c, cfg.unsafe_branch)
            metrics["label_balance"] = o.mean()
            metrics["label_balance_safe"] = diagnostics.masked_mean(o, safe)
            metrics["label_balance_unsafe"] = diagnostics.masked_mean(o, ~safe)
            labels = extraction.drop_labels(k_drop, o, cfg.cfg_dropout)
        else:
            weights = extraction.awr_weights(safe, adv_r, adv_c, cfg.awr_temperature,
                                             cfg.awr_clip, cfg.unsafe_branch)
            metrics["awr_weight_mean"] = weights.mean()

        shape = (B, self.h, self.act_dim)
        if self.is_gaussian:
            def loss_fn(p):
                mean, log_std = self.actor_net.apply(p, obs)
                return gaussian.weighted_nll(mean.reshape(shape), log_std.reshape(shape[1:]),
                                             batch.actions, mask, weights)
        else:
            k0, ki = jax.random.split(key)
            a0 = jax.random.normal(k0, chunk.shape)
            i = jax.random.uniform(ki, (B,))
            a_i = flow.interpolate(a0, chunk, i)

            def loss_fn(p):
                v_pred = self.actor_net.apply(p, a_i, i, obs, labels)
                return flow.flow_matching_loss(v_pred.reshape(shape), a0.reshape(shape),
                                               batch.actions, mask, weights)

        params, opt, loss, _ = optimizer_step(self.txs, "actor", state.params, state.opt,
                                              lambda p: (loss_fn(p), None))
        metrics["loss_actor"] = loss
        return state.replace(params=params, opt=opt), metrics

    def update(self, state: AgentState, batch: Batch, hp: dict, phase: str):
        """One gradient step of the given phase ("critic", "actor" or "joint")."""
        key, k_actor = jax.random.split(state.key)
        state = state.replace(key=key)
        metrics: dict[str, Any] = {}
        if phase in ("critic", "joint"):
            state, m = self.update_critics(state, batch, hp)
            metrics.update(m)
        if phase in ("actor", "joint"):
            state, m = self.update_actor(state, batch, hp, k_actor)
            metrics.update(m)
        return state.replace(step=state.step + 1), metrics

    # ---- acting ------------------------------------------------------------------------------
    def policy_params(self, state: AgentState, hp: dict) -> dict:
        """What the policy needs: actor, target critics, threshold, guidance scale."""
        return {"actor": state.params["actor"], "guidance": jnp.asarray(hp["guidance_scale"]),
                "threshold": state.threshold, "qc": state.target["qc"], "qr": state.target["qr"]}

    def sample_chunks(self, pp: dict, obs: jax.Array, key: jax.Array, k: int) -> jax.Array:
        """k candidate chunks per state from the flow policy: obs [B, o] -> [B, k, h*A] in [-1, 1]."""
        return flow.sample_chunks(
            lambda *a: self.actor_net.apply(pp["actor"], *a), obs, key, k, self.chunk_size,
            self.cfg.flow_steps, pp["guidance"] if self.cfg.actor == "cfg_flow" else None)

    def diagnostic_params(self, state: AgentState, hp: dict) -> dict:
        """policy_params plus V_c (the share of visited states with V_c > l); evaluation in a
        run uses these, the saved policy stays policy_params."""
        return dict(self.policy_params(state, hp), vc=state.params["vc"])

    def candidates(self) -> int:
        """Candidate chunks the policy draws per state (1: no choice to diagnose)."""
        if self.is_gaussian or self.cfg.selection == "first":
            return 1
        return self.cfg.num_candidates

    def diagnostics_note(self):
        """Why the candidate statistics are missing from this policy's diagnostics, or None."""
        if self.candidates() > 1:
            return None
        why = ("the AWR Gaussian actor has no candidates" if self.is_gaussian else
               "selection=first draws one candidate")
        return f"candidate statistics skipped: {why}"

    def act(self, pp: dict, obs: jax.Array, key: jax.Array) -> jax.Array:
        """The policy: obs [B, obs_dim] -> first action of the chosen chunk [B, act_dim]."""
        return self._act(pp, obs, key, info=False)

    def act_info(self, pp: dict, obs: jax.Array, key: jax.Array):
        """`act` and, per state, its diagnostics {name: [B]} (the same action, bit for bit: the
        same computation, with statistics read off it and no extra random draw)."""
        return self._act(pp, obs, key, info=True)

    def _act(self, pp: dict, obs: jax.Array, key: jax.Array, info: bool):
        check_obs(obs, self.obs_dim)
        B = obs.shape[0]
        stats = {}
        if info and "vc" in pp:
            stats["unsafe_state"] = (self.vc_net.apply(pp["vc"], obs) > pp["threshold"]
                                     ).astype(jnp.float32)
        if self.is_gaussian:
            mean, _ = self.actor_net.apply(pp["actor"], obs)
            action = check_act(obs, mean.reshape(B, self.h, self.act_dim)[:, 0], self.obs_dim,
                               self.act_dim)
            return (action, stats) if info else action
        rule = self.cfg.selection
        k = self.candidates()
        cands = self.sample_chunks(pp, obs, key, k)
        if k == 1:
            chosen = cands[:, 0]
        else:
            obs_k = jnp.repeat(obs, k, axis=0)
            flat = cands.reshape(B * k, -1)
            qc = self.q_net.apply(pp["qc"], obs_k, flat).max(0).reshape(B, k)
            need_qr = rule == "safe_then_reward" or info
            qr = (self.q_net.apply(pp["qr"], obs_k, flat).min(0).reshape(B, k)
                  if need_qr else jnp.zeros_like(qc))
            idx = select_candidate(qc, qr if rule == "safe_then_reward" else jnp.zeros_like(qc),
                                   pp["threshold"], rule)
            chosen = jnp.take_along_axis(cands, idx[:, None, None], axis=1)[:, 0]
            if info:
                stats.update(diagnostics.candidate_stats(qc, qr, idx))
        action = check_act(obs, chosen.reshape(B, self.h, self.act_dim)[:, 0], self.obs_dim,
                           self.act_dim)
        return (action, stats) if info else action


SPEC = AlgorithmSpec(CONFIG=CONFIG, PRESETS=PRESETS, VARIANTS=VARIANTS, FIXED=FIXED,
                     FIXED_WHY=FIXED_WHY, HPARAMS=HPARAMS, Agent=Agent,
                     check_hparams=check_hparams, phases=phases, task_values=task_values,
                     validate=validate)

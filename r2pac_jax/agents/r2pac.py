"""The R2PAC agent: state pytree, one critic update, one policy update, and the policy.

All variants of ALGORITHM.md (and the BC baselines) are values of `Config`; this module only
wires the pure pieces of `critics.py`, `extraction.py`, `flow.py`, `gaussian.py` and
`selection.py` together. The `Agent` object holds static structure (network definitions,
optimiser); everything that changes travels in `AgentState`.
"""
from __future__ import annotations

from typing import Any

import chex
import jax
import jax.numpy as jnp
import optax
from flax import struct

from r2pac_jax.agents import critics, extraction, flow, gaussian
from r2pac_jax.agents.selection import select_candidate
from r2pac_jax.config import Config, HParams
from r2pac_jax.data.chunks import Batch, ChunkedData
from r2pac_jax.nets import NULL_LABEL, GaussianActor, QEnsemble, ValueNet, VelocityField


@struct.dataclass
class AgentState:
    params: dict  # networks: qc, vc, qr, vr (when critics are trained) and actor
    target: dict  # Polyak copies of qc, qr
    opt: dict  # optimiser state per network
    threshold: jax.Array  # [] safety threshold l
    step: jax.Array  # [] int32 gradient steps taken
    key: jax.Array


def _polyak(target, online, rate):
    return jax.tree_util.tree_map(lambda t, o: (1.0 - rate) * t + rate * o, target, online)


class Agent:
    def __init__(self, cfg: Config, obs_dim: int, act_dim: int):
        self.cfg = cfg
        self.obs_dim, self.act_dim, self.h = obs_dim, act_dim, cfg.chunk_len
        self.chunk_size = cfg.chunk_len * act_dim
        self.q_net = QEnsemble(cfg.hidden_dims, cfg.num_critics, cfg.layer_norm)
        self.v_net = ValueNet(cfg.hidden_dims, cfg.layer_norm)
        if self.is_gaussian:
            self.actor_net = GaussianActor(cfg.actor_hidden_dims, self.chunk_size)
        else:
            self.actor_net = VelocityField(cfg.hidden_dims, self.chunk_size, cfg.time_embed_dim,
                                           cfg.layer_norm)
        self.tx = optax.adam(cfg.lr)
        self.discount_h = cfg.discount**cfg.chunk_len
        self.hj = cfg.cost_critic == "hj"

    # ---- structure ---------------------------------------------------------------------
    @property
    def is_gaussian(self) -> bool:
        return self.cfg.actor in ("awr_gaussian", "bc_gaussian")

    @property
    def uses_critics(self) -> bool:
        return self.cfg.train_critics

    @property
    def critic_nets(self) -> tuple[str, ...]:
        return ("qc", "vc", "qr", "vr") if self.uses_critics else ()

    def init(self, key: jax.Array, hp: HParams) -> AgentState:
        del hp
        k_net, k_state = jax.random.split(key)
        ks = jax.random.split(k_net, 5)
        obs = jnp.zeros((1, self.obs_dim))
        chunk = jnp.zeros((1, self.chunk_size))
        params = {}
        if self.uses_critics:
            params["qc"] = self.q_net.init(ks[0], obs, chunk)
            params["vc"] = self.v_net.init(ks[1], obs)
            params["qr"] = self.q_net.init(ks[2], obs, chunk)
            params["vr"] = self.v_net.init(ks[3], obs)
        if self.is_gaussian:
            params["actor"] = self.actor_net.init(ks[4], obs)
        else:
            params["actor"] = self.actor_net.init(ks[4], chunk, jnp.zeros((1,)), obs,
                                                  jnp.zeros((1,), jnp.int32))
        target = {k: params[k] for k in ("qc", "qr") if k in params}
        opt = {k: self.tx.init(v) for k, v in params.items()}
        return AgentState(params=params, target=target, opt=opt, threshold=jnp.zeros(()),
                          step=jnp.zeros((), jnp.int32), key=k_state)

    def _apply_grads(self, state_params, state_opt, name, grads):
        updates, new_opt = self.tx.update(grads, state_opt[name], state_params[name])
        return optax.apply_updates(state_params[name], updates), new_opt

    # ---- threshold -----------------------------------------------------------------------
    def dataset_threshold(self, params: dict, data: ChunkedData, hp: HParams) -> jax.Array:
        """l over the fixed subset of dataset states (0 for the HJ feasibility variant)."""
        if self.hj or not self.uses_critics:
            return jnp.zeros(())
        vc = self.v_net.apply(params["vc"], data.observations[data.threshold_states])
        return critics.safety_threshold(vc, hp.quantile_alpha)

    # ---- updates ---------------------------------------------------------------------------
    def update_critics(self, state: AgentState, batch: Batch, hp: HParams):
        cfg = self.cfg
        B = batch.observations.shape[0]
        chex.assert_shape(batch.actions, (B, self.h, self.act_dim))
        obs, nobs = batch.observations, batch.next_observations
        chunk = batch.actions.reshape(B, -1)
        params, opt, tgt = dict(state.params), dict(state.opt), state.target
        q, v, tau = self.q_net.apply, self.v_net.apply, cfg.expectile

        # cost (or feasibility) value: lower expectile of the target Q_c ensemble's max
        qc_t = q(tgt["qc"], obs, chunk).max(0)

        def vc_loss(p):
            vc = v(p, obs)
            return critics.reversed_expectile_loss(qc_t - vc, tau).mean(), vc

        (l_vc, vc), g = jax.value_and_grad(vc_loss, has_aux=True)(params["vc"])
        params["vc"], opt["vc"] = self._apply_grads(params, opt, "vc", g)
        vc_next = v(params["vc"], nobs)
        if self.hj:
            qc_target = critics.feasibility_target(batch.zmax, batch.bootstrap, self.discount_h,
                                                   vc_next)
        else:
            qc_target = critics.cost_target(batch.cost, batch.bootstrap, self.discount_h, vc_next)

        def qc_loss(p):
            qs = q(p, obs, chunk)
            return critics.q_regression_loss(qs, qc_target), qs

        (l_qc, qc), g = jax.value_and_grad(qc_loss, has_aux=True)(params["qc"])
        params["qc"], opt["qc"] = self._apply_grads(params, opt, "qc", g)

        if self.hj:
            threshold = jnp.zeros(())
        elif cfg.threshold_source == "batch":
            threshold = critics.safety_threshold(vc, hp.quantile_alpha)
        else:
            threshold = state.threshold

        # penalised reward value: upper expectile of the target Qbar_r ensemble's min
        qr_t = q(tgt["qr"], obs, chunk).min(0)

        def vr_loss(p):
            vr = v(p, obs)
            return critics.expectile_loss(qr_t - vr, tau).mean(), vr

        (l_vr, vr), g = jax.value_and_grad(vr_loss, has_aux=True)(params["vr"])
        params["vr"], opt["vr"] = self._apply_grads(params, opt, "vr", g)
        vr_next = v(params["vr"], nobs)
        penalty = critics.penalty_value(hp.penalty_c, cfg.discount, cfg.penalty_mode)
        qr_target = critics.penalised_reward_target(
            batch.reward, batch.bootstrap, self.discount_h, vr_next, vc_next, threshold, penalty,
            use_penalty=cfg.reward_penalty)

        def qr_loss(p):
            qs = q(p, obs, chunk)
            return critics.q_regression_loss(qs, qr_target), qs

        (l_qr, qr), g = jax.value_and_grad(qr_loss, has_aux=True)(params["qr"])
        params["qr"], opt["qr"] = self._apply_grads(params, opt, "qr", g)

        target = {k: _polyak(tgt[k], params[k], cfg.polyak) for k in ("qc", "qr")}
        unsafe_next = (vc_next > threshold) & (batch.bootstrap > 0)
        metrics = dict(
            loss_vc=l_vc, loss_qc=l_qc, loss_vr=l_vr, loss_qr=l_qr,
            qc_mean=qc.mean(), vc_mean=vc.mean(), qr_mean=qr.mean(), vr_mean=vr.mean(),
            qr_target_mean=qr_target.mean(), threshold=threshold,
            safe_frac=(vc <= threshold).mean(), unsafe_next_frac=unsafe_next.mean(),
        )
        new = state.replace(params=params, opt=opt, target=target, threshold=threshold)
        return new, metrics

    def _advantages(self, state: AgentState, obs, chunk):
        q, v, tgt, p = self.q_net.apply, self.v_net.apply, state.target, state.params
        vc = v(p["vc"], obs)
        safe = vc <= state.threshold
        adv_r = q(tgt["qr"], obs, chunk).min(0) - v(p["vr"], obs)
        adv_c = q(tgt["qc"], obs, chunk).max(0) - vc
        return safe, adv_r, adv_c

    def update_actor(self, state: AgentState, batch: Batch, hp: HParams, key: jax.Array):
        cfg = self.cfg
        B = batch.observations.shape[0]
        obs, mask = batch.observations, batch.action_mask
        chunk = batch.actions.reshape(B, -1)
        metrics: dict[str, Any] = {}
        weights = None
        labels = jnp.full((B,), NULL_LABEL, jnp.int32)
        if cfg.actor in ("cfg_flow", "awr_flow", "awr_gaussian"):
            safe, adv_r, adv_c = self._advantages(state, obs, chunk)
            metrics["actor_safe_frac"] = safe.mean()
            if cfg.actor == "cfg_flow":
                k_drop, key = jax.random.split(key)
                o = extraction.optimality_labels(safe, adv_r, adv_c, cfg.unsafe_branch)
                metrics["label_balance"] = o.mean()
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

        loss, g = jax.value_and_grad(loss_fn)(state.params["actor"])
        params, opt = dict(state.params), dict(state.opt)
        params["actor"], opt["actor"] = self._apply_grads(params, opt, "actor", g)
        metrics["loss_actor"] = loss
        return state.replace(params=params, opt=opt), metrics

    def update(self, state: AgentState, batch: Batch, hp: HParams, phase: str):
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
    def policy_params(self, state: AgentState, hp: HParams) -> dict:
        """What the policy needs: actor, target critics, threshold, guidance scale."""
        pp = {"actor": state.params["actor"], "guidance": jnp.asarray(hp.guidance_scale),
              "threshold": state.threshold}
        if self.uses_critics:
            pp["qc"], pp["qr"] = state.target["qc"], state.target["qr"]
        return pp

    def sample_chunks(self, pp: dict, obs: jax.Array, key: jax.Array, k: int) -> jax.Array:
        """k candidate chunks per state from the flow policy: obs [B, o] -> [B, k, h*A] in [-1, 1]."""
        B = obs.shape[0]
        obs_k = jnp.repeat(obs, k, axis=0)
        a0 = jax.random.normal(key, (B * k, self.chunk_size))
        apply = self.actor_net.apply
        n = B * k
        if self.cfg.actor == "cfg_flow":
            obs2 = jnp.concatenate([obs_k, obs_k])
            labels = jnp.concatenate([jnp.ones((n,), jnp.int32),
                                      jnp.full((n,), NULL_LABEL, jnp.int32)])

            def velocity(a, i):
                # conditional and unconditional branches in one batched forward pass
                v = apply(pp["actor"], jnp.concatenate([a, a]), jnp.full((2 * n,), i), obs2,
                          labels)
                return flow.cfg_combine(v[n:], v[:n], pp["guidance"])
        else:
            null = jnp.full((n,), NULL_LABEL, jnp.int32)

            def velocity(a, i):
                return apply(pp["actor"], a, jnp.full((n,), i), obs_k, null)

        a = flow.euler_sample(velocity, a0, self.cfg.flow_steps)
        return jnp.clip(a, -1.0, 1.0).reshape(B, k, self.chunk_size)

    def act(self, pp: dict, obs: jax.Array, key: jax.Array) -> jax.Array:
        """The policy: obs [B, obs_dim] -> first action of the chosen chunk [B, act_dim]."""
        chex.assert_rank(obs, 2)
        B = obs.shape[0]
        if self.is_gaussian:
            mean, _ = self.actor_net.apply(pp["actor"], obs)
            return mean.reshape(B, self.h, self.act_dim)[:, 0]
        rule = self.cfg.selection if self.uses_critics else "first"
        k = 1 if rule == "first" else self.cfg.num_candidates
        cands = self.sample_chunks(pp, obs, key, k)
        if k == 1:
            chosen = cands[:, 0]
        else:
            obs_k = jnp.repeat(obs, k, axis=0)
            flat = cands.reshape(B * k, -1)
            qc = self.q_net.apply(pp["qc"], obs_k, flat).max(0).reshape(B, k)
            qr = (self.q_net.apply(pp["qr"], obs_k, flat).min(0).reshape(B, k)
                  if rule == "safe_then_reward" else jnp.zeros_like(qc))
            idx = select_candidate(qc, qr, pp["threshold"], rule)
            chosen = jnp.take_along_axis(cands, idx[:, None, None], axis=1)[:, 0]
        return chosen.reshape(B, self.h, self.act_dim)[:, 0]

"""BCQ-Lagrangian as OSRL implements it (`--algo bcq-lag`; OSRL's BCQL).

Read off OSRL at commit 03a4586 (osrl/algorithms/bcql.py, examples/configs/bcql_configs.py,
osrl/common/net.py); every step of `update` follows `BCQLTrainer.train_one_step`, in its order:

1. VAE on (s, a) as in CPQ (MSE + beta KL, latent 2 x act_dim, 400 hidden units).
2. Reward critics: two ensembles of `num_q` (OSRL's EnsembleDoubleQCritic; each side's value is
   the min over its ensemble). Target: for 10 decoded actions per s' (z ~ N(0, 1) clamped to
   +-0.5, decoded by the VAE just updated, perturbed by the target actor), the soft-clipped
   double Q lmbda min(Q1', Q2') + (1 - lmbda) max(Q1', Q2'), max over the 10; r + g (1 - done) *.
3. Cost critics: the same with c and without (1 - done), as OSRL writes it.
4. Actor (the perturbation xi(s, a) = clamp(a + phi tanh-MLP(s, a), -1, 1), tanh hidden layers,
   applied to one decoded action per s): minimise -min(Q1, Q2) + lambda (min(Qc1, Qc2) - qc_thres),
   lambda from OSRL's PID controller (KP, KI, KD = 0.1, 0.003, 0.001) on the batch's Q_c.
5. Polyak (tau 0.005) of both critics and the actor.

qc_thres = cost_limit (1 - g^L) / ((1 - g) L) with the task's kappa and episode length. Actions
at evaluation: the perturbed decode of one random latent per state (stochastic, as OSRL's act).
"""
from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import optax
from flax import struct

from r2pac_jax.agents.base import (TransitionAlgorithm, actor_only, check_act, check_choice,
                                   check_counts, check_lane_hparams, check_obs, check_positive,
                                   check_sizes, cost_limit_task_values, optimizer_step, osrl_presets,
                                   soft_update)
from r2pac_jax.agents.constraints import pid_multiplier, q_threshold
from r2pac_jax.agents.spec import AlgorithmSpec
from r2pac_jax.data.transitions import DONE_RULES, TransitionBatch
from r2pac_jax.errors import ConfigError
from r2pac_jax.nets import VAE, TorchMLP, TorchQEnsemble, vae_loss, vae_sample_latent
from r2pac_jax.ranges import check_range


@dataclasses.dataclass(frozen=True)
class BCQLConfig:
    actor_lr: float = 1e-3
    critic_lr: float = 1e-3
    vae_lr: float = 1e-3
    a_hidden_dims: tuple = (256, 256)
    c_hidden_dims: tuple = (256, 256)
    vae_hidden: int = 400
    sample_action_num: int = 10
    tau: float = 0.005
    phi: float = 0.05  # perturbation range
    lmbda: float = 0.75  # soft clipped double Q
    beta: float = 0.5  # KL weight of the VAE
    num_q: int = 2
    num_qc: int = 2
    pid: tuple = (0.1, 0.003, 0.001)  # KP, KI, KD
    cost_limit: float = 10.0  # the task's kappa (registry)
    episode_len: int = 1000  # the task's episode length (registry)
    done_rule: str = "terminal_or_timeout"


CONFIG = BCQLConfig
# paper: OSRL's values; quick: 2 x 128 networks and VAE (agents/base.py: osrl_presets)
PRESETS = osrl_presets(a_hidden_dims=(128, 128), c_hidden_dims=(128, 128), vae_hidden=128)
VARIANTS = {"bcq-lag": {}}
FIXED = {"chunk_len": 1}
FIXED_WHY = {"chunk_len": "learns one-step critics"}
HPARAMS = ("cost_limit",)
phases = actor_only


task_values = cost_limit_task_values


def check_hparams(values: dict) -> None:
    check_lane_hparams(values, HPARAMS)


def validate(c: BCQLConfig) -> None:
    for k in ("actor_lr", "critic_lr", "vae_lr"):
        check_positive(k, getattr(c, k))
    check_range("tau", c.tau, 0, 1, low_open=True)
    check_range("phi", c.phi, 0)
    check_range("lmbda", c.lmbda, 0, 1)
    check_range("beta", c.beta, 0)
    check_range("cost_limit", c.cost_limit, 0)
    if len(c.pid) != 3:
        raise ConfigError(f"pid must be three gains (KP, KI, KD), got {c.pid}")
    check_range("pid", c.pid, 0)
    check_sizes("a_hidden_dims", c.a_hidden_dims)
    check_sizes("c_hidden_dims", c.c_hidden_dims)
    check_counts(c, ("vae_hidden", "sample_action_num", "num_q", "num_qc", "episode_len"))
    check_choice("done_rule", c.done_rule, DONE_RULES)


def soft_clipped_double_q(q1, q2, lmbda):
    """BCQ's target value lmbda min(q1, q2) + (1 - lmbda) max(q1, q2), elementwise."""
    return lmbda * jnp.minimum(q1, q2) + (1.0 - lmbda) * jnp.maximum(q1, q2)


@struct.dataclass
class BCQLState:
    params: dict  # actor, critic, cost_critic, vae
    target: dict  # Polyak copies of actor, critic, cost_critic
    opt: dict
    pid_error: jax.Array  # [] the controller's last error
    pid_integral: jax.Array  # [] its integral term
    step: jax.Array
    key: jax.Array


class Agent(TransitionAlgorithm):
    plot_metrics = ("loss_critic", "loss_cost_critic", "loss_actor", "multiplier")

    def __init__(self, cfg, obs_dim: int, act_dim: int):
        super().__init__(cfg, obs_dim, act_dim)
        self.actor_net = TorchMLP(cfg.a_hidden_dims, act_dim, "tanh", "tanh")
        # OSRL's double critic: two ensembles of num_q, here one ensemble of 2 num_q members
        self.critic_net = TorchQEnsemble(cfg.c_hidden_dims, 2 * cfg.num_q)
        self.cost_net = TorchQEnsemble(cfg.c_hidden_dims, 2 * cfg.num_qc)
        self.latent = 2 * act_dim
        self.vae_net = VAE(obs_dim, act_dim, cfg.vae_hidden, self.latent)
        self.tx = dict(actor=optax.adam(cfg.actor_lr), critic=optax.adam(cfg.critic_lr),
                       cost_critic=optax.adam(cfg.critic_lr), vae=optax.adam(cfg.vae_lr))

    def init(self, key: jax.Array, hp: dict) -> BCQLState:
        del hp
        ka, kc, kq, kv, k_state = jax.random.split(key, 5)
        o, a = jnp.zeros((1, self.obs_dim)), jnp.zeros((1, self.act_dim))
        params = dict(actor=self.actor_net.init(ka, jnp.zeros((1, self.obs_dim + self.act_dim))),
                      critic=self.critic_net.init(kc, o, a),
                      cost_critic=self.cost_net.init(kq, o, a),
                      vae=self.vae_net.init(kv, o, a, jax.random.PRNGKey(0)))
        zero = jnp.zeros((), jnp.float32)
        return BCQLState(params=params,
                         target={k: params[k] for k in ("actor", "critic", "cost_critic")},
                         opt={k: self.tx[k].init(v) for k, v in params.items()},
                         pid_error=zero, pid_integral=zero, step=jnp.zeros((), jnp.int32),
                         key=k_state)

    def _perturb(self, actor_params, obs, act):
        """xi(s, a) = clamp(a + phi tanh-MLP([s, a]), -1, 1): [B, o], [B, A] -> [B, A]."""
        delta = self.cfg.phi * self.actor_net.apply(actor_params, jnp.concatenate([obs, act], -1))
        return jnp.clip(delta + act, -1.0, 1.0)

    def _decoded(self, vae_params, obs, key):
        z = vae_sample_latent(key, obs.shape[0], self.latent)
        return self.vae_net.apply(vae_params, obs, z, method="decode")

    @staticmethod
    def _pair(q, num):
        """[2 num, B] -> (min over the first ensemble, min over the second), each [B]."""
        return q[:num].min(0), q[num:].min(0)

    def _target(self, net, params, num, obs_rep, act_rep, bs):
        q1, q2 = self._pair(net.apply(params, obs_rep, act_rep), num)
        return soft_clipped_double_q(q1, q2, self.cfg.lmbda).reshape(bs, -1).max(1)

    def _step(self, name, params, opt, loss_fn):
        return optimizer_step(self.tx, name, params, opt, loss_fn)

    def update(self, state: BCQLState, b: TransitionBatch, hp: dict, phase: str):
        """One BCQ-L step on a batch of B transitions (obs [B, o], actions [B, A])."""
        cfg = self.cfg
        g, n = cfg.discount, cfg.sample_action_num
        qc_thres = q_threshold(hp["cost_limit"] * cfg.cost_scale, g, cfg.episode_len)
        key, k_vae, k_z1, k_z2, k_za = jax.random.split(state.key, 5)
        p, opt, tgt = state.params, state.opt, state.target
        bs = b.observations.shape[0]

        p, opt, l_vae, _ = self._step("vae", p, opt, lambda vp: (vae_loss(
            self.vae_net, vp, b.observations, b.actions, k_vae, cfg.beta), ()))
        # s' repeated per sample, row-major by state (torch.repeat_interleave)
        obs_rep = jnp.repeat(b.next_observations, n, axis=0)

        def next_actions(k):
            return self._perturb(tgt["actor"], obs_rep, self._decoded(p["vae"], obs_rep, k))

        q_next = self._target(self.critic_net, tgt["critic"], cfg.num_q, obs_rep,
                              next_actions(k_z1), bs)
        backup = b.rewards + g * (1.0 - b.done) * q_next

        def critic_loss(cp):
            q = self.critic_net.apply(cp, b.observations, b.actions)
            return ((q - jax.lax.stop_gradient(backup)[None]) ** 2).mean(-1).sum(), ()

        p, opt, l_critic, _ = self._step("critic", p, opt, critic_loss)
        qc_next = self._target(self.cost_net, tgt["cost_critic"], cfg.num_qc, obs_rep,
                               next_actions(k_z2), bs)
        qc_backup = b.costs + g * qc_next

        def cost_loss(qp):
            qc = self.cost_net.apply(qp, b.observations, b.actions)
            return ((qc - jax.lax.stop_gradient(qc_backup)[None]) ** 2).mean(-1).sum(), ()

        p, opt, l_cost, _ = self._step("cost_critic", p, opt, cost_loss)
        a_vae = self._decoded(p["vae"], b.observations, k_za)
        # the controller reads the batch's Q_c at the actor's actions before its step
        qc_now = jnp.minimum(*self._pair(self.cost_net.apply(
            p["cost_critic"], b.observations, self._perturb(p["actor"], b.observations, a_vae)),
            cfg.num_qc))
        mult, pid_error, pid_integral = pid_multiplier(qc_now, qc_thres, state.pid_error,
                                                       state.pid_integral, *cfg.pid)

        def actor_loss(ap):
            a = self._perturb(ap, b.observations, a_vae)
            q = jnp.minimum(*self._pair(self.critic_net.apply(p["critic"], b.observations, a),
                                        cfg.num_q))
            qc = jnp.minimum(*self._pair(self.cost_net.apply(p["cost_critic"], b.observations,
                                                             a), cfg.num_qc))
            penalty = ((qc - qc_thres) * jax.lax.stop_gradient(mult)).mean()
            return -q.mean() + penalty, penalty

        p, opt, l_actor, penalty = self._step("actor", p, opt, actor_loss)
        tgt = {k: soft_update(tgt[k], p[k], cfg.tau) for k in tgt}
        metrics = dict(loss_vae=l_vae, loss_critic=l_critic, loss_cost_critic=l_cost,
                       loss_actor=l_actor, qc_penalty=penalty, multiplier=mult,
                       qc_mean=qc_now.mean(), qc_thres=qc_thres)
        return state.replace(params=p, opt=opt, target=tgt, pid_error=pid_error,
                             pid_integral=pid_integral, step=state.step + 1, key=key), metrics

    def policy_params(self, state: BCQLState, hp: dict) -> dict:
        return {"actor": state.params["actor"], "vae": state.params["vae"]}

    def act(self, pp: dict, obs: jax.Array, key: jax.Array) -> jax.Array:
        """obs [B, obs_dim] -> xi(s, decode(s, z)) [B, act_dim], z drawn with `key`."""
        check_obs(obs, self.obs_dim)
        a = self._perturb(pp["actor"], obs, self._decoded(pp["vae"], obs, key))
        return check_act(obs, a, self.obs_dim, self.act_dim)


SPEC = AlgorithmSpec(CONFIG=CONFIG, PRESETS=PRESETS, VARIANTS=VARIANTS, FIXED=FIXED,
                     FIXED_WHY=FIXED_WHY, HPARAMS=HPARAMS, Agent=Agent,
                     check_hparams=check_hparams, phases=phases, task_values=task_values,
                     validate=validate)

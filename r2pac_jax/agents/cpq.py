"""CPQ, Constraints Penalized Q-learning (Xu et al. 2022), as OSRL implements it (`--algo cpq`).

Read off OSRL at commit 03a4586 (osrl/algorithms/cpq.py, examples/configs/cpq_configs.py,
osrl/common/net.py); every step of `update` follows `CPQTrainer.train_one_step`, in its order:

1. VAE on (s, a): MSE reconstruction + beta * KL (latent 2 x act_dim, 400 hidden units).
2. Reward critics (2, min over the ensemble): target r + g (1 - done) 1[Q_c'(s', a') <= q_thres]
   Q_r'(s', a'), a' ~ pi(s') (tanh-squashed sample), primes = Polyak copies.
3. Cost critics (2, min): target c + g Q_c'(s', a'), without (1 - done) as OSRL writes it. The
   OOD term: 10 pre-tanh samples of pi(s) (OSRL feeds the Gaussian sample, not its tanh, to
   the VAE and the critic), flagged OOD where the VAE's KL is >= its 0.75-quantile over the
   batch; qc_ood = the flagged samples' mean Q_c'; loss = MSE - exp(log_alpha) (qc_ood - qc_thres)
   and log_alpha += alpha_lr exp(log_alpha) (qc_thres - qc_ood), clamped to [-5, 5]. OSRL computes
   qc_ood from the target critic under no_grad, so the term moves the reported loss and alpha
   but not the critic's gradient; `ood_gradient=True` makes it differentiate through the online
   cost critic instead (the paper's intent), off by default to match OSRL.
4. Actor: maximise 1[Q_c(s, a) <= q_thres] Q_r(s, a), a ~ pi(s) reparameterised, with the
   critics just updated; no entropy term.
5. Polyak (tau 0.005) of both critics and the actor.

q_thres = cost_limit (1 - g^L) / ((1 - g) L), with cost_limit = the task's kappa and L its
episode length (registry values); qc_thres = qc_scalar q_thres. Actions at evaluation:
tanh(mu). OSRL's transition sampler and done = terminal or timeout (`done_rule`).
"""
from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import optax
from flax import struct

from r2pac_jax.agents.base import (TanhMeanPolicy, TransitionAlgorithm, actor_only, check_choice,
                                   check_counts, check_lane_hparams, check_positive, check_sizes,
                                   cost_limit_task_values, optimizer_step, osrl_presets,
                                   soft_update)
from r2pac_jax.agents.constraints import q_threshold
from r2pac_jax.agents.spec import AlgorithmSpec
from r2pac_jax.data.transitions import DONE_RULES, TransitionBatch
from r2pac_jax.nets import (VAE, SquashedGaussianActor, TorchQEnsemble, squashed_sample, vae_kl,
                           vae_loss)
from r2pac_jax.ranges import check_range


@dataclasses.dataclass(frozen=True)
class CPQConfig:
    actor_lr: float = 1e-4
    critic_lr: float = 1e-3
    alpha_lr: float = 1e-4
    vae_lr: float = 1e-3
    a_hidden_dims: tuple = (256, 256)
    c_hidden_dims: tuple = (256, 256)
    vae_hidden: int = 400
    sample_action_num: int = 10
    tau: float = 0.005
    beta: float = 0.5  # KL weight of the VAE
    num_q: int = 2
    num_qc: int = 2
    qc_scalar: float = 1.5
    ood_quantile: float = 0.75  # OSRL's constant: KL above it flags a sample out of distribution
    cost_limit: float = 10.0  # the task's kappa (registry)
    episode_len: int = 1000  # the task's episode length (registry)
    done_rule: str = "terminal_or_timeout"
    ood_gradient: bool = False


CONFIG = CPQConfig
# paper: OSRL's values; quick: 2 x 128 networks and VAE (agents/base.py: osrl_presets)
PRESETS = osrl_presets(a_hidden_dims=(128, 128), c_hidden_dims=(128, 128), vae_hidden=128)
VARIANTS = {"cpq": {}}
FIXED = {"chunk_len": 1}
FIXED_WHY = {"chunk_len": "learns one-step critics"}
HPARAMS = ("cost_limit", "qc_scalar")
phases = actor_only


task_values = cost_limit_task_values


def check_hparams(values: dict) -> None:
    check_lane_hparams(values, HPARAMS, positive=("qc_scalar",))


def validate(c: CPQConfig) -> None:
    for k in ("actor_lr", "critic_lr", "alpha_lr", "vae_lr", "tau", "qc_scalar"):
        check_positive(k, getattr(c, k))
    check_range("tau", c.tau, 0, 1, low_open=True)
    check_range("beta", c.beta, 0)
    check_range("cost_limit", c.cost_limit, 0)
    check_range("ood_quantile", c.ood_quantile, 0, 1)
    check_sizes("a_hidden_dims", c.a_hidden_dims)
    check_sizes("c_hidden_dims", c.c_hidden_dims)
    check_counts(c, ("vae_hidden", "sample_action_num", "num_q", "num_qc", "episode_len"))
    check_choice("done_rule", c.done_rule, DONE_RULES)


def reward_target(rewards, done, q_next, qc_next, q_thres, discount):
    """The constraints-penalised backup: r + g (1 - done) 1[Q_c' <= q_thres] Q_r', all [B]."""
    return rewards + discount * (1.0 - done) * (qc_next <= q_thres) * q_next


def cost_target(costs, qc_next, discount):
    """OSRL's cost backup c + g Q_c' (no (1 - done) factor, as OSRL writes it): [B]."""
    return costs + discount * qc_next


def ood_flags(kl, quantile):
    """1 where a sample's VAE KL is >= the `quantile`-quantile of all of them: [S, B]."""
    return (kl >= jnp.quantile(kl, quantile)).astype(jnp.float32)


def alpha_step(log_alpha, qc_ood, qc_thres, alpha_lr):
    """OSRL's dual step on the OOD penalty: log_alpha += lr e^log_alpha (qc_thres - qc_ood),
    clamped to [-5, 5]."""
    return jnp.clip(log_alpha + alpha_lr * jnp.exp(log_alpha) * (qc_thres - qc_ood), -5.0, 5.0)


@struct.dataclass
class CPQState:
    params: dict  # actor, critic, cost_critic, vae
    target: dict  # Polyak copies of actor, critic, cost_critic
    opt: dict
    log_alpha: jax.Array  # [] the OOD penalty's dual variable
    step: jax.Array
    key: jax.Array


class Agent(TanhMeanPolicy, TransitionAlgorithm):
    plot_metrics = ("loss_critic", "loss_cost_critic", "loss_actor", "alpha")

    def __init__(self, cfg, obs_dim: int, act_dim: int):
        super().__init__(cfg, obs_dim, act_dim)
        self.actor_net = SquashedGaussianActor(cfg.a_hidden_dims, act_dim)
        self.critic_net = TorchQEnsemble(cfg.c_hidden_dims, cfg.num_q)
        self.cost_net = TorchQEnsemble(cfg.c_hidden_dims, cfg.num_qc)
        self.vae_net = VAE(obs_dim, act_dim, cfg.vae_hidden, 2 * act_dim)
        self.tx = dict(actor=optax.adam(cfg.actor_lr), critic=optax.adam(cfg.critic_lr),
                       cost_critic=optax.adam(cfg.critic_lr), vae=optax.adam(cfg.vae_lr))

    def init(self, key: jax.Array, hp: dict) -> CPQState:
        del hp
        ka, kc, kq, kv, k_state = jax.random.split(key, 5)
        o, a = jnp.zeros((1, self.obs_dim)), jnp.zeros((1, self.act_dim))
        params = dict(actor=self.actor_net.init(ka, o), critic=self.critic_net.init(kc, o, a),
                      cost_critic=self.cost_net.init(kq, o, a),
                      vae=self.vae_net.init(kv, o, a, jax.random.PRNGKey(0)))
        return CPQState(params=params,
                        target={k: params[k] for k in ("actor", "critic", "cost_critic")},
                        opt={k: self.tx[k].init(v) for k, v in params.items()},
                        log_alpha=jnp.zeros((), jnp.float32), step=jnp.zeros((), jnp.int32),
                        key=k_state)

    def _pi(self, actor_params, obs, key):
        mu, log_std = self.actor_net.apply(actor_params, obs)
        return squashed_sample(mu, log_std, key)

    def _step(self, name, params, opt, loss_fn):
        return optimizer_step(self.tx, name, params, opt, loss_fn)

    def update(self, state: CPQState, b: TransitionBatch, hp: dict, phase: str):
        """One CPQ step on a batch of B transitions (obs [B, o], actions [B, A])."""
        cfg = self.cfg
        g = cfg.discount
        q_thres = q_threshold(hp["cost_limit"] * cfg.cost_scale, g, cfg.episode_len)
        qc_thres = hp["qc_scalar"] * q_thres
        key, k_vae, k_n1, k_n2, k_pi, k_samp = jax.random.split(state.key, 6)
        p, opt, tgt = state.params, state.opt, state.target

        p, opt, l_vae, _ = self._step("vae", p, opt, lambda vp: (vae_loss(
            self.vae_net, vp, b.observations, b.actions, k_vae, cfg.beta), ()))

        a_next, _, _ = self._pi(p["actor"], b.next_observations, k_n1)
        q_next = self.critic_net.apply(tgt["critic"], b.next_observations, a_next).min(0)
        qc_next = self.cost_net.apply(tgt["cost_critic"], b.next_observations, a_next).min(0)
        backup = reward_target(b.rewards, b.done, q_next, qc_next, q_thres, g)

        def critic_loss(cp):
            q = self.critic_net.apply(cp, b.observations, b.actions)
            return ((q - jax.lax.stop_gradient(backup)[None]) ** 2).mean(-1).sum(), ()

        p, opt, l_critic, _ = self._step("critic", p, opt, critic_loss)

        a_next2, _, _ = self._pi(p["actor"], b.next_observations, k_n2)
        qc_backup = cost_target(b.costs, self.cost_net.apply(
            tgt["cost_critic"], b.next_observations, a_next2).min(0), g)
        # OOD samples: pre-tanh draws of pi(s), [S, B, A], flattened for the networks
        mu, log_std = self.actor_net.apply(p["actor"], b.observations)
        n, bs = cfg.sample_action_num, b.observations.shape[0]
        u = mu[None] + jnp.exp(log_std)[None] * jax.random.normal(k_samp, (n,) + mu.shape)
        obs_s = jnp.broadcast_to(b.observations[None], (n,) + b.observations.shape)
        obs_s, u = obs_s.reshape(n * bs, -1), u.reshape(n * bs, -1)
        z_mean, z_std = self.vae_net.apply(p["vae"], obs_s, u, method="encode")
        kl = vae_kl(z_mean, z_std).reshape(n, bs)
        ood = ood_flags(kl, cfg.ood_quantile)
        alpha = jnp.exp(state.log_alpha)

        def cost_loss(qp):
            qc = self.cost_net.apply(qp, b.observations, b.actions)
            ood_params = qp if cfg.ood_gradient else tgt["cost_critic"]
            qc_s = self.cost_net.apply(ood_params, obs_s, u).min(0).reshape(n, bs)
            if not cfg.ood_gradient:
                qc_s = jax.lax.stop_gradient(qc_s)
            qc_ood = (ood * qc_s).mean(0).mean()
            mse = ((qc - jax.lax.stop_gradient(qc_backup)[None]) ** 2).mean(-1).sum()
            return mse - alpha * (qc_ood - qc_thres), jax.lax.stop_gradient(qc_ood)

        p, opt, l_cost, qc_ood = self._step("cost_critic", p, opt, cost_loss)
        log_alpha = alpha_step(state.log_alpha, qc_ood, qc_thres, cfg.alpha_lr)

        def actor_loss(ap):
            a, _, _ = self._pi(ap, b.observations, k_pi)
            q = self.critic_net.apply(p["critic"], b.observations, a).min(0)
            qc = self.cost_net.apply(p["cost_critic"], b.observations, a).min(0)
            return -((qc <= q_thres) * q).mean(), (qc <= q_thres).mean()

        p, opt, l_actor, safe_share = self._step("actor", p, opt, actor_loss)
        tgt = {k: soft_update(tgt[k], p[k], cfg.tau) for k in tgt}
        metrics = dict(loss_vae=l_vae, loss_critic=l_critic, loss_cost_critic=l_cost,
                       loss_actor=l_actor, alpha=jnp.exp(log_alpha), qc_ood=qc_ood,
                       q_thres=q_thres, actor_safe_share=safe_share)
        return state.replace(params=p, opt=opt, target=tgt, log_alpha=log_alpha,
                             step=state.step + 1, key=key), metrics


SPEC = AlgorithmSpec(CONFIG=CONFIG, PRESETS=PRESETS, VARIANTS=VARIANTS, FIXED=FIXED,
                     FIXED_WHY=FIXED_WHY, HPARAMS=HPARAMS, Agent=Agent,
                     check_hparams=check_hparams, phases=phases, task_values=task_values,
                     validate=validate)

"""COptiDICE (Lee et al. 2022) as OSRL implements it (`--algo coptidice`).

Read off OSRL at commit 03a4586 (osrl/algorithms/coptidice.py, examples/configs/
coptidice_configs.py, examples/train/train_coptidice.py); one step of `update` is
`COptiDICE.update`, in its order:

- lambda = softplus(lambda_raw), tau = softplus(tau_raw) (both raw scalars start at 1);
  nu, chi: ensembles of 2 state-value nets, each read as the min over its members.
- e = r - lambda c + g (1 - done) nu(s') - nu(s); w = relu(f'^-1(e / alpha)) (soft-chi^2 by
  default, alpha 0.5).
- chi (cost upper bound, cost_ub_epsilon 0.01): ell = (1 - g) chi(s) 1[init] / p_init +
  w (c + g (1 - done) chi(s') - chi(s)); weights = B softmax(ell / tau) over the batch;
  chi loss = mean(weights ell) (through the weights as well), tau loss = tau (epsilon - D_KL),
  weighted cost = mean(weights w c). With cost_ub_epsilon 0: weighted cost = mean(w c), no chi.
- nu loss = (1 - g) mean(nu(s) 1[init] / p_init) + mean(w e - alpha f(w)).
- lambda loss = lambda (qc_thres - weighted cost), one Adam step on lambda_raw.
- actor: weighted log-likelihood mean(w log N(a + eps_a | mu(s + eps_s), std)) with w from the
  nu just updated (lambda of this step), the Gaussian pre-tanh evaluated at the dataset action
  as OSRL does, noise 0.1 x the dataset's per-dimension std on states and actions.
p_init (the share of first steps) and the two stds come from the training data. Actions at
evaluation: tanh(mu). Adam throughout (actor, nu, chi 1e-4; scalars 1e-4).
"""
from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import optax
from flax import struct

from r2pac_jax.agents.base import (TanhMeanPolicy, TransitionAlgorithm, actor_only, check_choice,
                                   check_counts, check_lane_hparams, check_positive, check_sizes,
                                   cost_limit_task_values, osrl_presets)
from r2pac_jax.agents.constraints import q_threshold
from r2pac_jax.agents.spec import AlgorithmSpec
from r2pac_jax.data.transitions import DONE_RULES, TransitionBatch, TransitionData
from r2pac_jax.nets import SquashedGaussianActor, TorchQEnsemble
from r2pac_jax.ranges import check_range


@dataclasses.dataclass(frozen=True)
class COptiDICEConfig:
    actor_lr: float = 1e-4
    critic_lr: float = 1e-4
    scalar_lr: float = 1e-4
    a_hidden_dims: tuple = (256, 256)
    c_hidden_dims: tuple = (256, 256)
    alpha: float = 0.5  # f-divergence weight
    f_type: str = "softchi"
    cost_ub_epsilon: float = 0.01
    num_nu: int = 2
    num_chi: int = 2
    noise: float = 0.1  # of the dataset's std, on the actor's states and actions
    cost_limit: float = 10.0  # the task's kappa (registry)
    episode_len: int = 1000  # the task's episode length (registry)
    done_rule: str = "terminal_or_timeout"


CONFIG = COptiDICEConfig
# paper: OSRL's values; quick: 2 x 128 networks (agents/base.py: osrl_presets)
PRESETS = osrl_presets(a_hidden_dims=(128, 128), c_hidden_dims=(128, 128))
VARIANTS = {"coptidice": {}}
FIXED = {"chunk_len": 1}
FIXED_WHY = {"chunk_len": "learns one-step stationary distribution ratios"}
HPARAMS = ("cost_limit", "alpha")
phases = actor_only
F_TYPES = ("softchi", "chi2", "kl")


task_values = cost_limit_task_values


def check_hparams(values: dict) -> None:
    check_lane_hparams(values, HPARAMS, positive=("alpha",))


def validate(c: COptiDICEConfig) -> None:
    for k in ("actor_lr", "critic_lr", "scalar_lr", "alpha"):
        check_positive(k, getattr(c, k))
    check_range("cost_ub_epsilon", c.cost_ub_epsilon, 0)
    check_range("noise", c.noise, 0)
    check_range("cost_limit", c.cost_limit, 0)
    check_sizes("a_hidden_dims", c.a_hidden_dims)
    check_sizes("c_hidden_dims", c.c_hidden_dims)
    check_counts(c, ("num_nu", "num_chi", "episode_len"))
    check_choice("f_type", c.f_type, F_TYPES)
    check_choice("done_rule", c.done_rule, DONE_RULES)


def f_divergence(f_type: str):
    """(f, (f')^-1) of OSRL's get_f_div_fn: chi2, softchi (soft-chi^2), kl."""
    if f_type == "chi2":
        return (lambda x: 0.5 * (x - 1) ** 2), (lambda x: x + 1)
    if f_type == "softchi":
        return ((lambda x: jnp.where(x < 1, x * (jnp.log(x + 1e-10) - 1) + 1, 0.5 * (x - 1) ** 2)),
                (lambda x: jnp.where(x < 0, jnp.exp(jnp.minimum(x, 0.0)), x + 1)))
    if f_type == "kl":
        return (lambda x: x * jnp.log(x + 1e-10)), (lambda x: jnp.exp(x - 1))
    raise ValueError(f"f_type must be one of {F_TYPES}, got {f_type!r}")


def cost_upper_bound_weights(ell, tau):
    """B softmax(ell / tau) over the batch and D_KL = mean(w log w - w + 1): [B] -> ([B], [])."""
    n = ell.shape[0]
    logits = ell / tau
    w = jax.nn.softmax(logits) * n
    log_w = jax.nn.log_softmax(logits) + jnp.log(n)
    return w, (w * log_w - w + 1.0).mean()


@struct.dataclass
class DataStats:
    """What COptiDICE reads off its training data once (train_coptidice.py)."""

    init_proportion: jax.Array  # [] share of first steps
    obs_std: jax.Array  # [obs_dim]
    act_std: jax.Array  # [act_dim]


@struct.dataclass
class COptiDICEState:
    params: dict  # actor, nu, chi, lmbda (raw), tau (raw)
    opt: dict
    step: jax.Array
    key: jax.Array


class Agent(TanhMeanPolicy, TransitionAlgorithm):
    plot_metrics = ("loss_nu", "loss_chi", "loss_actor", "lmbda")

    def __init__(self, cfg, obs_dim: int, act_dim: int):
        super().__init__(cfg, obs_dim, act_dim)
        self.actor_net = SquashedGaussianActor(cfg.a_hidden_dims, act_dim)
        self.nu_net = TorchQEnsemble(cfg.c_hidden_dims, cfg.num_nu)
        self.chi_net = TorchQEnsemble(cfg.c_hidden_dims, cfg.num_chi)
        self.f, self.f_prime_inv = f_divergence(cfg.f_type)
        self.tx = dict(actor=optax.adam(cfg.actor_lr), nu=optax.adam(cfg.critic_lr),
                       chi=optax.adam(cfg.critic_lr), lmbda=optax.adam(cfg.scalar_lr),
                       tau=optax.adam(cfg.scalar_lr))

    def make_data(self, task, ds):
        data = super().make_data(task, ds)
        return data, DataStats(init_proportion=data.is_init.mean(),
                               obs_std=data.observations.std(0), act_std=data.actions.std(0))

    def sample(self, data: tuple[TransitionData, DataStats], key: jax.Array):
        return super().sample(data[0], key), data[1]

    def _v(self, net, params, obs):
        """A state-value ensemble read as OSRL's predict: the min over members, [B]."""
        return net.apply(params, obs, jnp.zeros(obs.shape[:-1] + (0,))).min(0)

    def init(self, key: jax.Array, hp: dict) -> COptiDICEState:
        del hp
        ka, kn, kc, k_state = jax.random.split(key, 4)
        o = jnp.zeros((1, self.obs_dim))
        params = dict(actor=self.actor_net.init(ka, o),
                      nu=self.nu_net.init(kn, o, jnp.zeros((1, 0))),
                      chi=self.chi_net.init(kc, o, jnp.zeros((1, 0))),
                      lmbda=jnp.ones((), jnp.float32), tau=jnp.ones((), jnp.float32))
        return COptiDICEState(params=params,
                              opt={k: self.tx[k].init(v) for k, v in params.items()},
                              step=jnp.zeros((), jnp.int32), key=k_state)

    def _step(self, name, params, opt, grad):
        upd, opt_n = self.tx[name].update(grad, opt[name], params[name])
        return {**params, name: optax.apply_updates(params[name], upd)}, {**opt, name: opt_n}

    def _w(self, nu_params, b: TransitionBatch, lmbda, alpha):
        """e = r - lambda c + g (1 - done) nu(s') - nu(s) and w = relu(f'^-1(e / alpha)), [B]."""
        g = self.cfg.discount
        nu_s = self._v(self.nu_net, nu_params, b.observations)
        nu_next = self._v(self.nu_net, nu_params, b.next_observations)
        e = b.rewards - lmbda * b.costs + g * (1.0 - b.done) * nu_next - nu_s
        return nu_s, e, jax.nn.relu(self.f_prime_inv(e / alpha))

    def update(self, state: COptiDICEState, batch, hp: dict, phase: str):
        """One COptiDICE step on B transitions (obs [B, o], actions [B, A]) and the data stats."""
        b, stats = batch
        cfg = self.cfg
        g, alpha = cfg.discount, hp["alpha"]
        qc_thres = q_threshold(hp["cost_limit"] * cfg.cost_scale, g, cfg.episode_len)
        key, k_obs, k_act = jax.random.split(state.key, 3)
        p, opt = state.params, state.opt
        lmbda = jax.nn.softplus(p["lmbda"])
        init_w = b.is_init / stats.init_proportion
        _, _, w0 = self._w(p["nu"], b, lmbda, alpha)
        w0 = jax.lax.stop_gradient(w0)
        metrics = dict(df=self.f(w0).mean())

        if cfg.cost_ub_epsilon > 0:
            tau = jax.nn.softplus(p["tau"])

            def chi_loss(cp):
                chi_s = self._v(self.chi_net, cp, b.observations)
                chi_next = self._v(self.chi_net, cp, b.next_observations)
                ell = (1 - g) * chi_s * init_w + w0 * (b.costs + g * (1.0 - b.done) * chi_next
                                                       - chi_s)
                weights, d_kl = cost_upper_bound_weights(ell, jax.lax.stop_gradient(tau))
                return (weights * ell).mean(), (d_kl, (weights * w0 * b.costs).mean())

            (l_chi, (d_kl, weighted_c)), g_chi = jax.value_and_grad(chi_loss, has_aux=True)(
                p["chi"])
            p, opt = self._step("chi", p, opt, g_chi)
            tau_loss, g_tau = jax.value_and_grad(
                lambda t: jax.nn.softplus(t) * (cfg.cost_ub_epsilon - d_kl))(p["tau"])
            p, opt = self._step("tau", p, opt, g_tau)
            metrics.update(loss_chi=l_chi, loss_tau=tau_loss, d_kl=d_kl, tau=tau)
        else:
            weighted_c = (w0 * b.costs).mean()
            zero = jnp.zeros((), jnp.float32)
            metrics.update(loss_chi=zero, loss_tau=zero, d_kl=zero,
                           tau=jax.nn.softplus(p["tau"]))

        def nu_loss(np_):
            nu_s, e, w = self._w(np_, b, lmbda, alpha)
            return (1 - g) * (nu_s * init_w).mean() + (w * e - alpha * self.f(w)).mean(), \
                (e**2).mean()

        (l_nu, td), g_nu = jax.value_and_grad(nu_loss, has_aux=True)(p["nu"])
        p, opt = self._step("nu", p, opt, g_nu)
        l_lmbda, g_l = jax.value_and_grad(
            lambda lr: jax.nn.softplus(lr) * (qc_thres - weighted_c))(p["lmbda"])
        p, opt = self._step("lmbda", p, opt, g_l)

        _, _, w_actor = self._w(p["nu"], b, lmbda, alpha)  # the nu just updated, this lambda
        w_actor = jax.lax.stop_gradient(w_actor)
        obs_n = b.observations + jax.random.normal(k_obs, b.observations.shape) * stats.obs_std \
            * cfg.noise
        act_n = b.actions + jax.random.normal(k_act, b.actions.shape) * stats.act_std * cfg.noise

        def actor_loss(ap):
            mu, log_std = self.actor_net.apply(ap, obs_n)
            lp = (-0.5 * ((act_n - mu) / jnp.exp(log_std)) ** 2 - log_std
                  - 0.5 * jnp.log(2.0 * jnp.pi)).sum(-1)
            return -(w_actor * lp).mean()

        l_actor, g_a = jax.value_and_grad(actor_loss)(p["actor"])
        p, opt = self._step("actor", p, opt, g_a)
        metrics.update(loss_nu=l_nu, td_error=td, loss_lmbda=l_lmbda, loss_actor=l_actor,
                       lmbda=lmbda, weighted_cost=weighted_c, qc_thres=qc_thres)
        return state.replace(params=p, opt=opt, step=state.step + 1, key=key), metrics


SPEC = AlgorithmSpec(CONFIG=CONFIG, PRESETS=PRESETS, VARIANTS=VARIANTS, FIXED=FIXED,
                     FIXED_WHY=FIXED_WHY, HPARAMS=HPARAMS, Agent=Agent,
                     check_hparams=check_hparams, phases=phases, task_values=task_values,
                     validate=validate)

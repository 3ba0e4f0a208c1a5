"""DSRL's behaviour recipe: PPO with a Lagrange multiplier under a scheduled cost limit.

DSRL trained TRPO-Lagrangian agents (PID multiplier, 128x128 networks, stochastic policies)
while moving the cost limit, and kept their trajectories along training, so the data cover the
cost/return plane from reckless to cautious behaviour of a policy that sees only the observation.
This module is the learner, shared by every backend: the networks, GAE, the PID multiplier, the
schedule and the PPO update (`make_update`), and two rollout paths that produce the same
trajectory batch ([T, N] arrays):

  - `rollout_batch`: a Python loop over control steps around the env's `reset_batch` /
    `step_batch` and a jitted policy step: C MuJoCo on a CPU (numpy state);
  - `make_jax_rollout`: one jitted `lax.scan` over T steps for JAX environments (pure JAX,
    MJX on an accelerator).

`collect.py` drives them (the schedule, trajectories kept along training, checkpoints).
PPO instead of DSRL's TRPO: one first-order update shared with the JAX path (see GENERATION.md).

Shapes: N = num_envs, T = rollout_len, O = obs_dim, A = act_dim.
"""
from __future__ import annotations

import dataclasses
import time
from typing import Callable, Optional, Sequence

import chex
import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax

from r2pac_jax.envs.base import put_rows


MEAN_SQUASH = ("tanh", "none")
# values added after files were pinned: left out of spec.json and the card at their default, so
# a generation started before them resumes and every earlier card reads the same
LATER_DEFAULTS = {"mean_squash": "tanh", "stagger_starts": False}


@dataclasses.dataclass(frozen=True)
class PPOLagConfig:
    # 10k env steps per update as DSRL's epoch; 100 envs x 100 steps rather than DSRL's 10
    # episodes per collect: stepping 100 episodes per Python step is 1.3-4x faster on the CPU
    # (GENERATION.md), and GAE bootstraps the cut fragments
    num_envs: int = 100
    rollout_len: int = 100
    epochs: int = 4  # DSRL's repeat_per_collect
    minibatches: int = 4
    lr: float = 5e-4  # DSRL's
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip: float = 0.2
    hidden: Sequence[int] = (128, 128)  # DSRL's
    init_log_std: float = -0.5  # DSRL's sigma init
    pid: Sequence[float] = (0.05, 0.005, 0.1)  # DSRL's KP, KI, KD
    # "tanh": DSRL's tanh-squashed Gaussian mean; "none": an unsquashed mean (actions are
    # clipped either way). A per-task recipe value, tried on SwimmerVelocity, whose learner
    # keeps half its mean actions in the saturated tanh: it did not bring the cost under the
    # limit there (GENERATION.md, "SwimmerVelocity: why its learner never meets the last limit")
    mean_squash: str = "tanh"
    # all envs start together, so on tasks without terminals every update sees the same phase
    # of every episode (one in ten holds the starts); true: env j's first episode starts at
    # step j x episode_len / num_envs (shortened first episodes are not kept nor counted)
    stagger_starts: bool = False

    def validate(self) -> None:
        from r2pac_jax.data.dsrl import DatasetError

        for k in ("num_envs", "rollout_len", "epochs", "minibatches"):
            if getattr(self, k) < 1:
                raise DatasetError(f"PPO-Lagrangian: {k} must be >= 1, got {getattr(self, k)}")
        if (self.num_envs * self.rollout_len) % self.minibatches:
            raise DatasetError(f"PPO-Lagrangian: num_envs x rollout_len = "
                               f"{self.num_envs * self.rollout_len} is not divisible into "
                               f"{self.minibatches} minibatches")
        if not self.lr > 0 or not 0 < self.gamma < 1 or not 0 <= self.gae_lambda <= 1:
            raise DatasetError("PPO-Lagrangian: lr must be > 0, gamma in (0, 1), gae_lambda in "
                               "[0, 1]")
        if self.mean_squash not in MEAN_SQUASH:
            raise DatasetError(f"PPO-Lagrangian: mean_squash must be one of "
                               f"{', '.join(MEAN_SQUASH)}, got {self.mean_squash!r}")
        if not isinstance(self.stagger_starts, bool):
            raise DatasetError(f"PPO-Lagrangian: stagger_starts must be true or false, got "
                               f"{self.stagger_starts!r}")
        if len(self.pid) != 3 or min(self.pid) < 0:
            raise DatasetError(f"PPO-Lagrangian: pid must be three gains >= 0, got {self.pid}")


class _MLP(nn.Module):
    hidden: Sequence[int]
    out: int

    @nn.compact
    def __call__(self, x):
        for h in self.hidden:
            x = nn.tanh(nn.Dense(h)(x))
        return nn.Dense(self.out, kernel_init=nn.initializers.orthogonal(0.01))(x)


class Actor(nn.Module):
    """obs [..., O] -> (mean [..., A], in (-1, 1) when squashed, log_std [A])."""
    act_dim: int
    hidden: Sequence[int]
    init_log_std: float
    squash: str = "tanh"

    @nn.compact
    def __call__(self, obs):
        mean = _MLP(self.hidden, self.act_dim)(obs)
        if self.squash == "tanh":
            mean = jnp.tanh(mean)
        log_std = self.param("log_std", nn.initializers.constant(self.init_log_std),
                             (self.act_dim,))
        return mean, log_std


class Critics(nn.Module):
    """obs [..., O] -> (V_r [...], V_c [...]), two separate networks."""
    hidden: Sequence[int]

    @nn.compact
    def __call__(self, obs):
        return _MLP(self.hidden, 1)(obs)[..., 0], _MLP(self.hidden, 1)(obs)[..., 0]


def _log_prob(mean, log_std, a):
    return jnp.sum(-0.5 * ((a - mean) / jnp.exp(log_std)) ** 2 - log_std
                   - 0.5 * jnp.log(2 * jnp.pi), axis=-1)


def gae(rewards, values, next_values, terminated, done, gamma, lam):
    """Generalised advantage estimates over a rollout, time-major [T, N].

    `next_values` are the values of the true next observations (before any auto-reset), so a
    time-limit cut bootstraps while a terminal does not; `done` (terminal or cut) stops the
    recursion at episode ends. Returns (advantages [T, N], value targets [T, N])."""
    chex.assert_equal_shape([rewards, values, next_values, terminated, done])
    deltas = rewards + gamma * (1.0 - terminated) * next_values - values

    def back(carry, x):
        delta, d = x
        carry = delta + gamma * lam * (1.0 - d) * carry
        return carry, carry

    _, adv = jax.lax.scan(back, jnp.zeros_like(rewards[0]), (deltas, done), reverse=True)
    return adv, adv + values


def pid_multiplier(pid_state, episode_cost, limit, gains):
    """DSRL's PID Lagrangian (fsrl / OSRL's LagrangianPIDController) on the mean episode cost.

    pid_state = (integral, previous error) -> (new state, multiplier >= 0)."""
    kp, ki, kd = gains
    integral, prev = pid_state
    error = episode_cost - limit
    diff = max(error - prev, 0.0)
    integral = max(integral + error, 0.0)
    lam = max(kp * max(error, 0.0) + ki * integral + kd * diff, 0.0)
    return (integral, error), lam


@dataclasses.dataclass(frozen=True)
class CostSchedule:
    """DSRL's cost-limit schedule over env steps: `start` until `start_step`, then linear to
    `end` at `end_step`, then `end` (DSRL: cost_limit_scheduler over epochs of 10k steps)."""

    start: float
    end: float
    start_step: int
    end_step: int

    def __post_init__(self):
        from r2pac_jax.data.dsrl import DatasetError

        if not (self.start > 0 and self.end > 0):
            raise DatasetError(f"cost schedule: limits must be > 0, got {self.start} -> {self.end}")
        if not 0 <= self.start_step < self.end_step:
            raise DatasetError(f"cost schedule: need 0 <= start_step < end_step, got "
                               f"{self.start_step}, {self.end_step}")

    def limit(self, env_steps: int) -> float:
        x = min(max(0, env_steps - self.start_step), self.end_step - self.start_step)
        return float(self.start - x * (self.start - self.end) / (self.end_step - self.start_step))


def networks(obs_dim: int, act_dim: int, cfg: PPOLagConfig):
    actor = Actor(act_dim, tuple(cfg.hidden), cfg.init_log_std, cfg.mean_squash)
    critics = Critics(tuple(cfg.hidden))
    opt = optax.chain(optax.clip_by_global_norm(0.5), optax.adam(cfg.lr))
    return actor, critics, opt


def init_params(key, obs_dim: int, actor, critics) -> dict:
    k_a, k_c = jax.random.split(key)
    obs0 = jnp.zeros((obs_dim,), jnp.float32)
    return dict(actor=actor.init(k_a, obs0), critics=critics.init(k_c, obs0))


def make_policy_step(actor, critics) -> Callable:
    """policy(params, obs [N, O], key) -> (raw [N, A], action [N, A] clipped, logp [N], V_r, V_c),
    jitted; `policy.values(params, obs) -> (V_r, V_c)`."""

    def policy(params, obs, key):
        mean, log_std = actor.apply(params["actor"], obs)
        raw = mean + jnp.exp(log_std) * jax.random.normal(key, mean.shape)
        vr, vc = critics.apply(params["critics"], obs)
        return raw, jnp.clip(raw, -1.0, 1.0), _log_prob(mean, log_std, raw), vr, vc

    fn = jax.jit(policy)
    fn.values = jax.jit(lambda params, obs: critics.apply(params["critics"], obs))
    fn.pure = policy
    return fn


def make_update(actor, critics, opt, cfg: PPOLagConfig) -> Callable:
    """`update(params, opt_state, traj, lam, key) -> (params, opt_state, metrics)`: GAE on both
    critics, then `epochs` x `minibatches` PPO steps on the Lagrangian advantage
    (A_r - lam A_c) / (1 + lam) (DSRL's rescaling). traj: [T, N] arrays obs, raw, logp, r, c,
    term, done, vr, vc, nvr, nvc."""

    def loss_fn(params, mb, lam):
        mean, log_std = actor.apply(params["actor"], mb["obs"])
        ratio = jnp.exp(_log_prob(mean, log_std, mb["raw"]) - mb["logp"])
        adv = (mb["adv_r"] - lam * mb["adv_c"]) / (1.0 + lam)
        adv = (adv - adv.mean()) / (adv.std() + 1e-8)
        pg = -jnp.minimum(ratio * adv, jnp.clip(ratio, 1 - cfg.clip, 1 + cfg.clip) * adv).mean()
        vr, vc = critics.apply(params["critics"], mb["obs"])
        vloss = ((vr - mb["tgt_r"]) ** 2).mean() + ((vc - mb["tgt_c"]) ** 2).mean()
        return pg + 0.5 * vloss, (pg, vloss)

    def update(params, opt_state, traj, lam, key):
        T, N = traj["r"].shape
        adv_r, tgt_r = gae(traj["r"], traj["vr"], traj["nvr"], traj["term"], traj["done"],
                           cfg.gamma, cfg.gae_lambda)
        adv_c, tgt_c = gae(traj["c"], traj["vc"], traj["nvc"], traj["term"], traj["done"],
                           cfg.gamma, cfg.gae_lambda)
        flat = jax.tree_util.tree_map(
            lambda x: x.reshape((T * N,) + x.shape[2:]),
            dict(obs=traj["obs"], raw=traj["raw"], logp=traj["logp"], adv_r=adv_r, adv_c=adv_c,
                 tgt_r=tgt_r, tgt_c=tgt_c))

        def epoch(c, k):
            params, opt_state = c
            perm = jax.random.permutation(k, T * N).reshape(cfg.minibatches, -1)

            def mb_step(c, idx):
                params, opt_state = c
                mb = jax.tree_util.tree_map(lambda x: x[idx], flat)
                (_, aux), grads = jax.value_and_grad(loss_fn, has_aux=True)(params, mb, lam)
                upd, opt_state = opt.update(grads, opt_state, params)
                return (optax.apply_updates(params, upd), opt_state), aux

            return jax.lax.scan(mb_step, (params, opt_state), perm)

        (params, opt_state), (pg, vl) = jax.lax.scan(epoch, (params, opt_state),
                                                     jax.random.split(key, cfg.epochs))
        return params, opt_state, dict(policy_loss=pg.mean(), value_loss=vl.mean())

    return jax.jit(update)


TRAJ_KEYS = ("obs", "nobs", "raw", "act", "logp", "r", "c", "term", "trunc", "done", "vr", "vc",
             "nvr", "nvc")


def rollout_batch(env, policy: Callable, params, state, key, T: int,
                  timing: Optional[dict] = None):
    """T control steps of a batched env from Python (C MuJoCo), resetting episodes that end.

    Returns (state after the last step, traj {[T, N] numpy}); traj["nobs"] holds the true next
    observations (before a reset), so GAE bootstraps time-limit cuts correctly. `timing`, where
    given, gets the seconds spent in the simulator (steps and resets) added to its "physics"."""
    out = {k: [] for k in TRAJ_KEYS if k not in ("nvr", "nvc")}
    keys = jax.random.split(key, T)
    t_physics = 0.0
    for t in range(T):
        k_act, k_reset = jax.random.split(keys[t])
        obs = np.asarray(state.obs)
        raw, act, logp, vr, vc = policy(params, obs, k_act)
        act = np.asarray(act)
        t0 = time.perf_counter()
        nxt = env.step_batch(state, act)
        term, trunc = np.asarray(nxt.terminated), np.asarray(nxt.truncated)
        t_physics += time.perf_counter() - t0
        done = term | trunc
        for k, v in (("obs", obs), ("nobs", nxt.obs), ("raw", raw), ("act", act), ("logp", logp),
                     ("r", nxt.reward), ("c", nxt.cost), ("term", term), ("trunc", trunc & ~term),
                     ("done", done), ("vr", vr), ("vc", vc)):
            out[k].append(np.asarray(v))
        if done.any():
            t0 = time.perf_counter()
            idx = np.flatnonzero(done)
            fresh = env.reset_batch(jax.random.split(k_reset, len(done))[idx])
            nxt = put_rows(jax.tree_util.tree_map(np.asarray, nxt), idx,
                           jax.tree_util.tree_map(np.asarray, fresh))
            t_physics += time.perf_counter() - t0
        state = nxt
    if timing is not None:
        timing["physics"] = timing.get("physics", 0.0) + t_physics
    traj = {k: np.stack(v) for k, v in out.items()}
    # values of the true next observations: the next step's values inside an episode; computed
    # afresh where an episode ended (its next observation is not the next step's) and at T - 1
    n_vr = np.concatenate([traj["vr"][1:], np.zeros_like(traj["vr"][:1])])
    n_vc = np.concatenate([traj["vc"][1:], np.zeros_like(traj["vc"][:1])])
    fresh_at = traj["done"].copy()
    fresh_at[-1] = True
    ti, ni = np.nonzero(fresh_at)
    vr_f, vc_f = policy.values(params, traj["nobs"][ti, ni])
    n_vr[ti, ni], n_vc[ti, ni] = np.asarray(vr_f), np.asarray(vc_f)
    traj["nvr"], traj["nvc"] = n_vr, n_vc
    return state, traj


def make_jax_rollout(env, policy: Callable, N: int, T: int) -> Callable:
    """`rollout(params, state, key) -> (state, traj)` as one jitted scan (JAX envs)."""
    v_reset, v_step = jax.vmap(env.reset), jax.vmap(env.step)

    pure = policy.pure

    def one(carry, key):
        params, s = carry
        k_act, k_reset = jax.random.split(key)
        raw, act, logp, vr, vc = pure(params, s.obs, k_act)
        s2 = v_step(s, act)
        done = s2.terminated | s2.truncated
        _, _, _, nvr, nvc = pure(params, s2.obs, k_act)

        def reset_ended(s2):  # only when an episode ended: a reset is costly on MJX
            fresh = v_reset(jax.random.split(k_reset, N))
            pick = lambda f, o: jnp.where(  # noqa: E731
                done.reshape(done.shape + (1,) * (f.ndim - 1)), f, o)
            return jax.tree_util.tree_map(pick, fresh, s2)

        s_next = jax.lax.cond(done.any(), reset_ended, lambda s2: s2, s2)
        step = dict(obs=s.obs, nobs=s2.obs, raw=raw, act=act, logp=logp, r=s2.reward, c=s2.cost,
                    term=s2.terminated, trunc=s2.truncated & ~s2.terminated, done=done, vr=vr,
                    vc=vc, nvr=nvr, nvc=nvc)
        return (params, s_next), step

    @jax.jit
    def rollout(params, state, key):
        (_, state), traj = jax.lax.scan(one, (params, state), jax.random.split(key, T))
        return state, traj

    return rollout


def as_update_batch(traj: dict) -> dict:
    """The float32 [T, N] arrays `update` reads."""
    out = {k: jnp.asarray(traj[k], jnp.float32) for k in ("r", "c", "vr", "vc", "nvr", "nvc",
                                                           "logp", "term", "done")}
    out["obs"] = jnp.asarray(traj["obs"], jnp.float32)
    out["raw"] = jnp.asarray(traj["raw"], jnp.float32)
    return out

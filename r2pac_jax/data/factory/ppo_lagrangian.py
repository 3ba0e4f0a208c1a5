"""DSRL's behaviour recipe in JAX: PPO with a Lagrange multiplier and an annealed cost limit.

DSRL trained Lagrangian RL agents while annealing the cost limit and kept their trajectories,
so the data cover the cost/return plane from reckless to cautious. Here one PPO-Lagrangian run
anneals its per-episode cost limit linearly from `limit_start` to `limit_end`; the actor is
snapshotted `snapshots` times along the way, and the dataset's episodes are recorded with those
snapshots (stochastic actions), an equal share each. (DSRL kept the training rollouts
themselves; recording with snapshots gives the same spread of behaviours with whole episodes.)

The whole training is one jitted `lax.scan` over updates (purejaxrl's shape), so it needs a
JAX environment: ReachAvoid (pure JAX) or the MuJoCo tasks with `physics="mjx"` (a GPU). The
C-MuJoCo backend steps outside JAX and is refused with a clear error.

Shapes: N = num_envs, T = rollout_len, O = obs_dim, A = act_dim.
"""
from __future__ import annotations

import dataclasses
from typing import Callable, Optional, Sequence

import chex
import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax

from r2pac_jax.data.factory.batch import keep_valid_steps
from r2pac_jax.data.factory.thinning import select_episodes
from r2pac_jax.envs.base import record_episode


@dataclasses.dataclass(frozen=True)
class PPOLagConfig:
    num_envs: int = 64
    rollout_len: int = 80  # steps per env between updates
    updates: int = 300
    epochs: int = 4
    minibatches: int = 4
    lr: float = 3e-4
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip: float = 0.2
    hidden: Sequence[int] = (64, 64)
    init_log_std: float = -0.5
    limit_start: float = 20.0  # per-episode cost limit at the first update ...
    limit_end: float = 1.0  # ... annealed linearly to this at the last
    lagrange_lr: float = 0.05
    snapshots: int = 10  # actors kept (evenly spaced over the updates, the last included)


class _MLP(nn.Module):
    hidden: Sequence[int]
    out: int

    @nn.compact
    def __call__(self, x):
        for h in self.hidden:
            x = nn.tanh(nn.Dense(h)(x))
        return nn.Dense(self.out, kernel_init=nn.initializers.orthogonal(0.01))(x)


class Actor(nn.Module):
    """obs [..., O] -> (mean [..., A] in (-1, 1), log_std [A])."""
    act_dim: int
    hidden: Sequence[int]
    init_log_std: float

    @nn.compact
    def __call__(self, obs):
        mean = jnp.tanh(_MLP(self.hidden, self.act_dim)(obs))
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


def lagrange_update(lam, episode_cost, limit, lr):
    """Projected gradient ascent on the multiplier: grows while the cost exceeds the limit."""
    return jnp.maximum(0.0, lam + lr * (episode_cost - limit))


def cost_limit(update, cfg: PPOLagConfig):
    frac = update / max(cfg.updates - 1, 1)
    return cfg.limit_start + frac * (cfg.limit_end - cfg.limit_start)


def make_train(env, cfg: PPOLagConfig) -> Callable:
    """`train(key) -> (actor snapshots [S, ...], metrics per update)`, pure and jittable."""
    if not getattr(env, "is_jax", False):
        raise ValueError(f"PPO-Lagrangian needs a JAX environment; {env.name!r} runs its physics "
                         "outside JAX (C MuJoCo). Use physics='mjx' (an accelerator) or the "
                         "scripted source (--source scripted)")
    actor = Actor(env.act_dim, tuple(cfg.hidden), cfg.init_log_std)
    critics = Critics(tuple(cfg.hidden))
    opt = optax.chain(optax.clip_by_global_norm(0.5), optax.adam(cfg.lr))
    N, T = cfg.num_envs, cfg.rollout_len
    snap_at = jnp.asarray(np.linspace(0, cfg.updates - 1, cfg.snapshots).round().astype(int))
    v_reset, v_step = jax.vmap(env.reset), jax.vmap(env.step)

    def rollout(params, carry, key):
        def one(c, k):
            s, ep_ret, ep_cost = c
            k_a, k_r = jax.random.split(k)
            mean, log_std = actor.apply(params["actor"], s.obs)
            raw = mean + jnp.exp(log_std) * jax.random.normal(k_a, mean.shape)
            s2 = v_step(s, jnp.clip(raw, -1.0, 1.0))
            done = s2.terminated | s2.truncated
            ep_ret, ep_cost = ep_ret + s2.reward, ep_cost + s2.cost
            vr, vc = critics.apply(params["critics"], s.obs)
            nvr, nvc = critics.apply(params["critics"], s2.obs)

            def reset_ended(s2):  # only when an episode ended: a reset is costly on MJX
                fresh = v_reset(jax.random.split(k_r, N))
                pick = lambda f, o: jnp.where(  # noqa: E731
                    done.reshape(done.shape + (1,) * (f.ndim - 1)), f, o)
                return jax.tree_util.tree_map(pick, fresh, s2)

            s_next = jax.lax.cond(done.any(), reset_ended, lambda s2: s2, s2)
            out = dict(obs=s.obs, raw=raw, logp=_log_prob(mean, log_std, raw), r=s2.reward,
                       c=s2.cost, term=s2.terminated.astype(jnp.float32),
                       done=done.astype(jnp.float32), vr=vr, vc=vc, nvr=nvr, nvc=nvc,
                       fin_ret=jnp.where(done, ep_ret, 0.0), fin_cost=jnp.where(done, ep_cost, 0.0))
            return (s_next, jnp.where(done, 0.0, ep_ret), jnp.where(done, 0.0, ep_cost)), out

        return jax.lax.scan(one, carry, jax.random.split(key, T))

    def loss_fn(params, mb, lam):
        mean, log_std = actor.apply(params["actor"], mb["obs"])
        ratio = jnp.exp(_log_prob(mean, log_std, mb["raw"]) - mb["logp"])
        adv = (mb["adv_r"] - lam * mb["adv_c"]) / (1.0 + lam)  # the Lagrangian, rescaled
        adv = (adv - adv.mean()) / (adv.std() + 1e-8)
        pg = -jnp.minimum(ratio * adv, jnp.clip(ratio, 1 - cfg.clip, 1 + cfg.clip) * adv).mean()
        vr, vc = critics.apply(params["critics"], mb["obs"])
        vloss = ((vr - mb["tgt_r"]) ** 2).mean() + ((vc - mb["tgt_c"]) ** 2).mean()
        return pg + 0.5 * vloss, (pg, vloss)

    def update(carry, i):
        params, opt_state, env_carry, lam, jc, jr, key = carry
        key, k_roll, k_perm = jax.random.split(key, 3)
        env_carry, tr = rollout(params, env_carry, k_roll)
        adv_r, tgt_r = gae(tr["r"], tr["vr"], tr["nvr"], tr["term"], tr["done"], cfg.gamma,
                           cfg.gae_lambda)
        adv_c, tgt_c = gae(tr["c"], tr["vc"], tr["nvc"], tr["term"], tr["done"], cfg.gamma,
                           cfg.gae_lambda)
        n_fin = tr["done"].sum()
        # mean cost and return of the episodes finished in this rollout (kept if none did)
        jc = jnp.where(n_fin > 0, tr["fin_cost"].sum() / jnp.maximum(n_fin, 1.0), jc)
        jr = jnp.where(n_fin > 0, tr["fin_ret"].sum() / jnp.maximum(n_fin, 1.0), jr)
        limit = cost_limit(i, cfg)
        lam = lagrange_update(lam, jc, limit, cfg.lagrange_lr)
        flat = jax.tree_util.tree_map(
            lambda x: x.reshape((T * N,) + x.shape[2:]),
            dict(obs=tr["obs"], raw=tr["raw"], logp=tr["logp"], adv_r=adv_r, adv_c=adv_c,
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
                                                     jax.random.split(k_perm, cfg.epochs))
        metrics = dict(episode_return=jr, episode_cost=jc, finished=n_fin, cost_limit=limit,
                       lagrange=lam, policy_loss=pg.mean(), value_loss=vl.mean())
        return (params, opt_state, env_carry, lam, jc, jr, key), (params["actor"], metrics)

    def train(key):
        k_a, k_c, k_env, key = jax.random.split(key, 4)
        obs0 = jnp.zeros((env.obs_dim,), jnp.float32)
        params = dict(actor=actor.init(k_a, obs0), critics=critics.init(k_c, obs0))
        s0 = v_reset(jax.random.split(k_env, N))
        zeros = jnp.zeros((N,), jnp.float32)
        z = jnp.zeros(())
        carry = (params, opt.init(params), (s0, zeros, zeros), z, z, z, key)
        _, (actors, metrics) = jax.lax.scan(update, carry, jnp.arange(cfg.updates))
        snaps = jax.tree_util.tree_map(lambda x: x[snap_at], actors)
        return snaps, metrics

    train.actor = actor
    return train


def record(env, actor: Actor, snaps, episodes_per_snapshot: int, key) -> dict:
    """Whole episodes of every snapshot (stochastic actions): DSRL arrays of the real steps,
    episode-major, snapshot by snapshot."""
    S = jax.tree_util.tree_leaves(snaps)[0].shape[0]
    E = episodes_per_snapshot

    def episode(p, k):
        def act(s, k):
            mean, log_std = actor.apply(p, s.obs)
            return jnp.clip(mean + jnp.exp(log_std) * jax.random.normal(k, mean.shape), -1.0, 1.0)

        return record_episode(env, act, k)

    per_snap = jax.vmap(episode, in_axes=(None, 0))
    run = jax.jit(jax.vmap(per_snap, in_axes=(0, 0)))
    keys = jax.random.split(key, S * E).reshape(S, E, -1)
    return keep_valid_steps(run(snaps, keys))  # [S, E, T, ...] -> real steps


def generate(task, n_trajectories: int, seed: int, physics: str = "auto",
             cfg: Optional[PPOLagConfig] = None, progress=None, log=print) -> dict:
    """Train PPO-Lagrangian on `task`'s JAX environment and record `n_trajectories` episodes
    with its snapshots (DSRL arrays). The limits default to 4 kappa -> kappa / 2."""
    if task.family == "demo":
        physics = "auto"  # pure JAX: there is no backend to choose
    elif physics == "auto":
        physics = "mjx"  # auto would pick C MuJoCo on a CPU, which make_train refuses
    env = task.make_env(physics=physics)
    cfg = cfg or PPOLagConfig(limit_start=4.0 * task.kappa, limit_end=0.5 * task.kappa)
    E = -(-n_trajectories // cfg.snapshots)
    train = make_train(env, cfg)
    k_train, k_rec = jax.random.split(jax.random.PRNGKey(seed))
    snaps, metrics = jax.jit(train)(k_train)
    m = jax.tree_util.tree_map(np.asarray, metrics)
    log(f"PPO-Lagrangian on {task.name}: {cfg.updates} updates x {cfg.num_envs * cfg.rollout_len}"
        f" steps; episode return {m['episode_return'][0]:.1f} -> {m['episode_return'][-1]:.1f}, "
        f"cost {m['episode_cost'][0]:.1f} -> {m['episode_cost'][-1]:.1f} (limit "
        f"{cfg.limit_start:g} -> {cfg.limit_end:g}), multiplier -> {m['lagrange'][-1]:.2f}")
    arrays = record(env, train.actor, snaps, E, k_rec)
    arrays = select_episodes(arrays, np.arange(n_trajectories))
    if progress is not None:
        progress(n_trajectories)
    return arrays

"""Vectorised evaluation with DSRL's scores.

A policy is `policy_fn(params, obs[B, obs_dim], key) -> action[B, act_dim]` (pure, jittable),
or a `MemoryPolicy` (init / act / observe) for policies that carry a memory across steps (CDT).
JAX environments run every episode in parallel inside one jit (vmap over episodes, scan over
steps, episodes frozen after they end); environments stepped outside JAX (C MuJoCo) run a Python
loop over control steps around the jitted policy. Both return per-episode returns, costs and
lengths, and the DSRL normalised reward and cost of the episode means.
"""
from __future__ import annotations

from typing import Callable, NamedTuple, Optional, Union

import jax
import jax.numpy as jnp
import numpy as np

from r2pac_jax.envs.base import pow2_bucket, put_rows, take_rows
from r2pac_jax.tasks import TaskSpec, get_task


class MemoryPolicy(NamedTuple):
    """A policy with memory: init(params, obs[B, o]) -> mem; act(params, obs, key, mem) ->
    (action[B, a], mem); observe(params, mem, reward[B], cost[B]) -> mem after each step."""

    init: Callable
    act: Callable
    observe: Callable


Policy = Union[Callable, MemoryPolicy]


def policy_of(agent) -> Policy:
    """What evaluation runs for an agent: its memory triple if it has one, else `act`."""
    if all(hasattr(agent, n) for n in ("memory_init", "act_memory", "observe")):
        return MemoryPolicy(agent.memory_init, agent.act_memory, agent.observe)
    return agent.act


def _as_memory_policy(policy: Policy) -> MemoryPolicy:
    """A stateless policy as a memory policy with an empty memory (the same computation)."""
    if isinstance(policy, MemoryPolicy):
        return policy
    return MemoryPolicy(init=lambda p, obs: (),
                        act=lambda p, obs, k, mem: (policy(p, obs, k), mem),
                        observe=lambda p, mem, r, c: mem)


def dsrl_scores(mean_return, mean_cost, task: TaskSpec):
    """Normalised reward (R - R_min) / (R_max - R_min) and cost (C + e) / (kappa + e).

    e = 1 only when kappa = 0 (DSRL's convention). Works on scalars or arrays of means.
    """
    eps = 1.0 if task.kappa == 0 else 0.0
    nr = (mean_return - task.r_min) / (task.r_max - task.r_min)
    nc = (mean_cost + eps) / (task.kappa + eps)
    return nr, nc


def _freeze(alive, new, old):
    """Keep `old` where an episode already ended: alive [E], leaves [E, ...]."""
    def pick(n, o):
        return jnp.where(alive.reshape(alive.shape + (1,) * (n.ndim - 1)), n, o)
    return jax.tree_util.tree_map(pick, new, old)


def rollout(policy_fn: Policy, params, env, key: jax.Array, episodes: int) -> dict:
    """All episodes of one policy in parallel (JAX env; jittable): arrays [E]."""
    pol = _as_memory_policy(policy_fn)
    k_reset, k_act = jax.random.split(key)
    state = jax.vmap(env.reset)(jax.random.split(k_reset, episodes))
    zeros = jnp.zeros((episodes,), jnp.float32)

    def body(carry, k):
        state, mem, alive, ret, cost, length = carry
        action, mem = pol.act(params, state.obs, k, mem)
        new = jax.vmap(env.step)(state, action)
        mem = pol.observe(params, mem, new.reward, new.cost)
        ret = ret + jnp.where(alive, new.reward, 0.0)
        cost = cost + jnp.where(alive, new.cost, 0.0)
        length = length + alive.astype(jnp.int32)
        state = _freeze(alive, new, state)
        return (state, mem, alive & ~new.done, ret, cost, length), None

    init = (state, pol.init(params, state.obs), jnp.ones((episodes,), bool), zeros, zeros,
            jnp.zeros((episodes,), jnp.int32))
    (_, _, _, ret, cost, length), _ = jax.lax.scan(body, init,
                                                   jax.random.split(k_act, env.episode_len))
    return dict(returns=ret, costs=cost, lengths=length)


def _step_live(env, state, actions: np.ndarray, alive: np.ndarray):
    """Step only the episodes still running (their ended rows keep their last state, which the
    caller masks anyway): rows in power-of-two buckets, so the env's jitted rules compile for
    a few batch sizes only. Each row's simulation is independent, so the live rows' steps are
    the same as when every row is stepped."""
    n = alive.shape[0]
    live = np.flatnonzero(alive)
    k = min(n, pow2_bucket(live.size))
    if k == n:
        return env.step_batch(state, actions)
    rows = np.concatenate([live, np.flatnonzero(~alive)[:k - live.size]])
    return put_rows(state, rows, env.step_batch(take_rows(state, rows), actions[rows]))


def _rollout_python(policy_lanes: MemoryPolicy, lane_params, env, keys: jax.Array,
                    episodes: int):
    """Lanes x episodes stepped from Python (non-JAX physics), the policy's three functions
    jitted and vmapped over lanes: arrays [L, E]."""
    L = keys.shape[0]
    n = L * episodes
    k_reset, k_act = jax.vmap(lambda k: jax.random.split(k), out_axes=1)(keys)
    reset_keys = jax.vmap(lambda k: jax.random.split(k, episodes))(k_reset).reshape(n, -1)
    state = env.reset_batch(reset_keys)
    alive = np.ones(n, bool)
    ret = np.zeros(n)
    cost = np.zeros(n)
    length = np.zeros(n, np.int64)
    # numpy between the jitted calls: eager jnp reshapes and indexing cost ~0.1 ms each, more
    # than a step of one live episode
    step_keys = np.asarray(jax.vmap(lambda k: jax.random.split(k, env.episode_len),
                                    out_axes=1)(k_act))
    mem = policy_lanes.init(lane_params, np.asarray(state.obs).reshape(L, episodes, -1))
    for t in range(env.episode_len):
        obs = np.asarray(state.obs).reshape(L, episodes, -1)
        action, mem = policy_lanes.act(lane_params, obs, step_keys[t], mem)
        state = _step_live(env, state, np.asarray(action).reshape(n, -1), alive)
        mem = policy_lanes.observe(lane_params, mem,
                                   np.asarray(state.reward, np.float32).reshape(L, episodes),
                                   np.asarray(state.cost, np.float32).reshape(L, episodes))
        ret += np.where(alive, np.asarray(state.reward), 0.0)
        cost += np.where(alive, np.asarray(state.cost), 0.0)
        length += alive
        alive &= ~np.asarray(state.terminated | state.truncated)
        if not alive.any():
            break
    shape = (L, episodes)
    return dict(returns=ret.reshape(shape), costs=cost.reshape(shape),
                lengths=length.reshape(shape))


class LaneEvaluator:
    """Evaluates L parameter sets ("lanes": seeds x hyperparameter cells) at once.

    `__call__(lane_params, keys[L])` returns numpy arrays `returns`, `costs`, `lengths` [L, E]
    and `normalized_reward`, `normalized_cost` [L]. Built once; the rollout compiles once.
    """

    def __init__(self, policy_fn: Policy, task: TaskSpec, episodes: int = 20, env=None,
                 physics: str = "auto"):
        self.task = task
        self.episodes = episodes
        self.env = env if env is not None else task.make_env(physics=physics)
        if self.env.is_jax:
            self._run = jax.jit(jax.vmap(
                lambda p, k: rollout(policy_fn, p, self.env, k, episodes)))
        else:
            pol = _as_memory_policy(policy_fn)
            self._policy_lanes = MemoryPolicy(*(jax.jit(jax.vmap(f)) for f in pol))
            self._run = self._run_python

    def _run_python(self, lane_params, keys):
        """Lanes in groups small enough for an env with a cap on parallel episodes (pybullet:
        one client, ~29 MiB, per episode); each lane's episodes depend on its key only, so the
        grouping changes no result."""
        L, E = keys.shape[0], self.episodes
        cap = getattr(self.env, "max_parallel", None)
        group = L if cap is None else cap // E
        if group < 1:
            raise MemoryError(f"{E} evaluation episodes at once exceed this env's limit of "
                              f"{cap} parallel episodes: evaluate fewer episodes, or raise "
                              "R2PAC_BULLET_MAX_CLIENTS if the memory is there")
        parts = []
        for lo in range(0, L, group):
            sl = slice(lo, min(L, lo + group))
            parts.append(_rollout_python(
                self._policy_lanes, jax.tree_util.tree_map(lambda x: x[sl], lane_params),
                self.env, keys[sl], E))
        return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}

    def __call__(self, lane_params, keys: jax.Array) -> dict:
        out = {k: np.asarray(v) for k, v in self._run(lane_params, keys).items()}
        nr, nc = dsrl_scores(out["returns"].mean(-1), out["costs"].mean(-1), self.task)
        out["normalized_reward"], out["normalized_cost"] = nr, nc
        return out


def evaluate(policy_fn: Callable, params, task, episodes: int = 20,
             key: Optional[jax.Array] = None, env=None, physics: str = "auto") -> dict:
    """Evaluate one policy: `returns[E]`, `costs[E]`, `lengths[E]`, normalised reward and cost."""
    task = task if isinstance(task, TaskSpec) else get_task(task)
    key = jax.random.PRNGKey(0) if key is None else key
    lane_params = jax.tree_util.tree_map(lambda x: jnp.asarray(x)[None], params)
    out = LaneEvaluator(policy_fn, task, episodes, env=env, physics=physics)(lane_params, key[None])
    res = {k: v[0] for k, v in out.items()}
    res["normalized_reward"] = float(res["normalized_reward"])
    res["normalized_cost"] = float(res["normalized_cost"])
    return res


def eval_keys(seeds, step: int) -> jax.Array:
    """[L] evaluation keys of the lanes' seeds at training step `step` (fixed per seed and step,
    independent of the training stream)."""
    return jnp.stack([jax.random.fold_in(jax.random.fold_in(jax.random.PRNGKey(s), 1), step)
                      for s in seeds])


def evaluate_run(run_dir, episodes: int = 20, selection: Optional[str] = None,
                 guidance_scale: Optional[float] = None, num_candidates: Optional[int] = None,
                 physics: str = "auto", seed: int = 123) -> dict:
    """Re-evaluate every lane of a finished run under other inference settings.

    The trained parameters are not touched: candidate selection, guidance scale and the number
    of candidates only act at sampling time (algorithms without them refuse them by name).
    Returns per-lane arrays as `LaneEvaluator` does.
    """
    from r2pac_jax.agents import make_agent
    from r2pac_jax.policy import read_run

    cfg, lanes = read_run(run_dir)
    changes = {k: v for k, v in dict(selection=selection, num_candidates=num_candidates).items()
               if v is not None}
    if changes:
        cfg = cfg.replace(**changes)
    task = get_task(cfg.task)
    task.check_physics(physics)
    agent = make_agent(cfg, task.obs_dim, task.act_dim)
    from r2pac_jax.policy import restore_policy_params

    pp, lanes = restore_policy_params(run_dir, agent)
    if guidance_scale is not None:
        if "guidance" not in pp:
            from r2pac_jax.config import ConfigError

            raise ConfigError(f"{cfg.algo} has no guidance scale to change")
        pp["guidance"] = jnp.full_like(pp["guidance"], guidance_scale)
    keys = jnp.stack([jax.random.fold_in(jax.random.PRNGKey(seed), s) for s in lanes["seeds"]])
    out = LaneEvaluator(policy_of(agent), task, episodes, physics=physics)(pp, keys)
    out["seeds"] = lanes["seeds"]
    return out


def main(argv=None) -> int:
    """`python -m r2pac_jax.evaluate RUN_DIR [--selection RULE] [--guidance W] [--episodes N]`."""
    import argparse

    ap = argparse.ArgumentParser(prog="python -m r2pac_jax.evaluate",
                                 description="Re-evaluate a finished run (all seeds) under other "
                                             "inference settings.")
    ap.add_argument("run_dir")
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--selection", choices=["min_qc", "safe_then_reward", "first"], default=None)
    ap.add_argument("--guidance", type=float, default=None)
    ap.add_argument("--candidates", type=int, default=None)
    ap.add_argument("--physics", default="auto")
    args = ap.parse_args(argv)
    import sys

    from r2pac_jax.config import ConfigError
    from r2pac_jax.tasks import EnvUnavailableError, UnknownTaskError

    try:
        if args.episodes < 1:
            raise ConfigError(f"--episodes must be >= 1, got {args.episodes}")
        if args.candidates is not None and args.candidates < 1:
            raise ConfigError(f"--candidates must be >= 1, got {args.candidates}")
        out = evaluate_run(args.run_dir, args.episodes, args.selection, args.guidance,
                           args.candidates, args.physics)
    except (ConfigError, FileNotFoundError, UnknownTaskError, EnvUnavailableError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    nr, nc = out["normalized_reward"], out["normalized_cost"]
    for s, r, c in zip(out["seeds"], nr, nc):
        print(f"seed {s}: normalized reward {r:.3f}, normalized cost {c:.3f}")
    print(f"mean: normalized reward {np.mean(nr):.3f} ± {np.std(nr):.3f}, "
          f"normalized cost {np.mean(nc):.3f} ± {np.std(nc):.3f}")
    return 0


if __name__ == "__main__":
    import sys

    sys.exit(main())

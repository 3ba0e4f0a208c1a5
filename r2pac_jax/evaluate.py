"""Vectorised evaluation with DSRL's scores.

A policy is `policy_fn(params, obs[B, obs_dim], key) -> action[B, act_dim]` (pure, jittable),
or a `MemoryPolicy` (init / act / observe) for policies that carry a memory across steps (CDT).
JAX environments run every episode in parallel inside one jit (vmap over episodes, scan over
steps, episodes frozen after they end); environments stepped outside JAX (C MuJoCo) run a Python
loop over control steps around the jitted policy. Both return per-episode returns, costs and
lengths, and the DSRL normalised reward and cost of the episode means.
"""
from __future__ import annotations

from typing import Callable, NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np

from r2pac_jax.envs.base import pow2_bucket, put_rows, take_rows
from r2pac_jax.errors import R2pacError
from r2pac_jax.policy import (InfoPolicy, MemoryPolicy, Policy, policy_of, read_run,
                              restore_policy_params)
from r2pac_jax.tasks import TaskSpec, get_task


class _Stepper(NamedTuple):
    """Every policy in one form: init(p, obs) -> mem; step(p, obs, key, mem) -> (action, mem,
    info {name: [B]}); observe(p, mem, reward, cost) -> mem."""

    init: Callable
    step: Callable
    observe: Callable


def _stepper(policy: Policy) -> _Stepper:
    """A policy of any form as a _Stepper (the same computation; no info but an InfoPolicy's)."""
    if isinstance(policy, MemoryPolicy):
        return _Stepper(policy.init, lambda p, obs, k, mem: policy.act(p, obs, k, mem) + ({},),
                        policy.observe)
    if isinstance(policy, InfoPolicy):
        def step(p, obs, k, mem):
            action, info = policy.act_info(p, obs, k)
            return action, mem, info

        return _Stepper(lambda p, obs: (), step, lambda p, mem, r, c: mem)
    return _Stepper(lambda p, obs: (), lambda p, obs, k, mem: (policy(p, obs, k), mem, {}),
                    lambda p, mem, r, c: mem)


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
    """All episodes of one policy in parallel (JAX env; jittable): arrays [E].

    returns, costs, lengths, terminals (the episode ended by a true terminal, not the time
    limit) and, for an InfoPolicy, `diag_NAME`: the sum of each diagnostic over the episode's
    states (divided by the lengths, it is a mean over visited states)."""
    pol = _stepper(policy_fn)
    k_reset, k_act = jax.random.split(key)
    state = jax.vmap(env.reset)(jax.random.split(k_reset, episodes))
    zeros = jnp.zeros((episodes,), jnp.float32)
    mem0 = pol.init(params, state.obs)
    names = jax.eval_shape(lambda: pol.step(params, state.obs, k_act, mem0)[2]).keys()

    def body(carry, k):
        state, mem, alive, ret, cost, length, term, diag = carry
        action, mem, info = pol.step(params, state.obs, k, mem)
        new = jax.vmap(env.step)(state, action)
        mem = pol.observe(params, mem, new.reward, new.cost)
        ret = ret + jnp.where(alive, new.reward, 0.0)
        cost = cost + jnp.where(alive, new.cost, 0.0)
        length = length + alive.astype(jnp.int32)
        term = term | (alive & new.terminated)
        diag = {n: diag[n] + jnp.where(alive, info[n], 0.0) for n in diag}
        state = _freeze(alive, new, state)
        return (state, mem, alive & ~new.done, ret, cost, length, term, diag), None

    init = (state, mem0, jnp.ones((episodes,), bool), zeros, zeros,
            jnp.zeros((episodes,), jnp.int32), jnp.zeros((episodes,), bool),
            {n: zeros for n in names})
    (_, _, _, ret, cost, length, term, diag), _ = jax.lax.scan(
        body, init, jax.random.split(k_act, env.episode_len))
    return dict(returns=ret, costs=cost, lengths=length, terminals=term,
                **{f"diag_{n}": v for n, v in diag.items()})


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


def _rollout_python(policy_lanes: _Stepper, lane_params, env, keys: jax.Array,
                    episodes: int):
    """Lanes x episodes stepped from Python (non-JAX physics), the policy's three functions
    jitted and vmapped over lanes: arrays [L, E], as `rollout`'s."""
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
    term = np.zeros(n, bool)
    diag: dict = {}
    mem = policy_lanes.init(lane_params, np.asarray(state.obs).reshape(L, episodes, -1))
    for t in range(env.episode_len):
        obs = np.asarray(state.obs).reshape(L, episodes, -1)
        action, mem, info = policy_lanes.step(lane_params, obs, step_keys[t], mem)
        for name, v in info.items():
            diag[name] = diag.get(name, 0.0) + np.where(alive, np.asarray(v).reshape(n), 0.0)
        state = _step_live(env, state, np.asarray(action).reshape(n, -1), alive)
        mem = policy_lanes.observe(lane_params, mem,
                                   np.asarray(state.reward, np.float32).reshape(L, episodes),
                                   np.asarray(state.cost, np.float32).reshape(L, episodes))
        ret += np.where(alive, np.asarray(state.reward), 0.0)
        cost += np.where(alive, np.asarray(state.cost), 0.0)
        length += alive
        term |= alive & np.asarray(state.terminated)
        alive &= ~np.asarray(state.terminated | state.truncated)
        if not alive.any():
            break
    shape = (L, episodes)
    return dict(returns=ret.reshape(shape), costs=cost.reshape(shape),
                lengths=length.reshape(shape), terminals=term.reshape(shape),
                **{f"diag_{k}": v.reshape(shape) for k, v in diag.items()})


class LaneEvaluator:
    """Evaluates L parameter sets ("lanes": seeds x hyperparameter cells) at once.

    `__call__(lane_params, keys[L])` returns numpy arrays `returns`, `costs`, `lengths`,
    `terminals` [L, E], `normalized_reward`, `normalized_cost`, `mean_length`,
    `terminal_share` [L] and `diagnostics` {name: [L]} (an InfoPolicy's diagnostics, each a
    mean over the states the lane's episodes visited; {} for other policies). Built once; the
    rollout compiles once.
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
            self._policy_lanes = _Stepper(*(jax.jit(jax.vmap(f)) for f in _stepper(policy_fn)))
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
        out["mean_length"] = out["lengths"].mean(-1)
        out["terminal_share"] = out["terminals"].mean(-1)
        visited = np.maximum(out["lengths"].sum(-1), 1)
        out["diagnostics"] = {k[5:]: out.pop(k).sum(-1) / visited
                              for k in [k for k in out if k.startswith("diag_")]}
        return out


def evaluate(policy_fn: Callable, params, task, episodes: int = 20,
             key: Optional[jax.Array] = None, env=None, physics: str = "auto") -> dict:
    """Evaluate one policy: `returns[E]`, `costs[E]`, `lengths[E]`, normalised reward and cost."""
    task = task if isinstance(task, TaskSpec) else get_task(task)
    key = jax.random.PRNGKey(0) if key is None else key
    lane_params = jax.tree_util.tree_map(lambda x: jnp.asarray(x)[None], params)
    out = LaneEvaluator(policy_fn, task, episodes, env=env, physics=physics)(lane_params, key[None])
    res = {k: ({n: float(x[0]) for n, x in v.items()} if k == "diagnostics" else v[0])
           for k, v in out.items()}
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
                 physics: str = "auto", seed: int = 123, diagnostics: bool = True) -> dict:
    """Re-evaluate every lane of a finished run under other inference settings.

    The trained parameters are not touched: candidate selection, guidance scale and the number
    of candidates only act at sampling time (algorithms without them refuse them by name).
    Returns per-lane arrays as `LaneEvaluator` does (with the policy's diagnostics; V_c > l is
    not among them here: the saved policy holds no V_c).
    """
    from r2pac_jax.agents import make_agent
    from r2pac_jax.config import ConfigError

    cfg, lanes = read_run(run_dir)
    if selection is not None and "selection" not in cfg.flat():
        raise ConfigError(f"--selection: {cfg.algo}'s policy draws no candidates to select "
                          "among (R2PAC's flow policies do); leave --selection out")
    changes = {k: v for k, v in dict(selection=selection, num_candidates=num_candidates).items()
               if v is not None}
    if changes:
        cfg = cfg.replace(**changes)
    task = get_task(cfg.task)
    task.check_physics(physics)
    agent = make_agent(cfg, task.obs_dim, task.act_dim)
    pp, lanes = restore_policy_params(run_dir, agent)
    if guidance_scale is not None:
        if "guidance" not in pp:
            from r2pac_jax.config import ConfigError

            raise ConfigError(f"{cfg.algo} has no guidance scale to change")
        pp["guidance"] = jnp.full_like(pp["guidance"], guidance_scale)
    keys = jnp.stack([jax.random.fold_in(jax.random.PRNGKey(seed), s) for s in lanes["seeds"]])
    out = LaneEvaluator(policy_of(agent, diagnostics), task, episodes, physics=physics)(pp, keys)
    out["seeds"] = lanes["seeds"]
    return out


def selection_rules(run_dir) -> tuple[str, ...]:
    """The selection rules a run's policy can be re-evaluated under: () for a policy without
    candidates, else the trained rule first, then the others."""
    from r2pac_jax.agents.selection import RULES

    cfg, _ = read_run(run_dir)
    flat = cfg.flat()
    if "selection" not in flat or flat.get("actor") == "awr_gaussian":
        return ()
    return (flat["selection"],) + tuple(r for r in RULES if r != flat["selection"])


def _mean_std(x) -> str:
    x = np.asarray(x, float)
    return f"{np.nanmean(x):.2f} ± {np.nanstd(x):.2f}"


def selection_table(results: dict, trained: str) -> str:
    """A markdown table of {rule: evaluate_run output}, one row per rule."""
    cols = [("not_first", "not the first"), ("qr_given_up", "Qbar_r given up"),
            ("qc_spread", "Q_c spread"), ("qr_spread", "Qbar_r spread")]
    head = ("| selection | reward | cost | ended by a terminal | episode length | "
            + " | ".join(c[1] for c in cols) + " |")
    lines = [head, "|" + "---|" * (5 + len(cols))]
    for rule, out in results.items():
        cells = [rule + (" (trained)" if rule == trained else ""),
                 _mean_std(out["normalized_reward"]), _mean_std(out["normalized_cost"]),
                 f"{np.mean(out['terminal_share']):.2f}", f"{np.mean(out['mean_length']):.1f}"]
        cells += [f"{np.mean(out['diagnostics'][k]):.3g}" if k in out["diagnostics"] else "-"
                  for k, _ in cols]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    """`python -m r2pac_jax.evaluate RUN_DIR [--selection RULE] [--guidance W] [--episodes N]`:
    without --selection, a policy with candidates is evaluated under every selection rule and
    the rules are set side by side (scores, terminals, the choice's diagnostics)."""
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

    try:
        if args.episodes < 1:
            raise ConfigError(f"--episodes must be >= 1, got {args.episodes}")
        if args.candidates is not None and args.candidates < 1:
            raise ConfigError(f"--candidates must be >= 1, got {args.candidates}")
        rules = () if args.selection else selection_rules(args.run_dir)
        results = {r: evaluate_run(args.run_dir, args.episodes, r, args.guidance,
                                   args.candidates, args.physics)
                   for r in (rules or (args.selection,))}
    except (R2pacError, FileNotFoundError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    for rule, out in results.items():
        if len(results) > 1:
            print(f"selection {rule}:")
        nr, nc = out["normalized_reward"], out["normalized_cost"]
        for s, r, c, t in zip(out["seeds"], nr, nc, out["terminal_share"]):
            print(f"seed {s}: normalized reward {r:.3f}, normalized cost {c:.3f}, episodes "
                  f"ended by a terminal {t:.2f}")
        print(f"mean: normalized reward {np.mean(nr):.3f} ± {np.std(nr):.3f}, "
              f"normalized cost {np.mean(nc):.3f} ± {np.std(nc):.3f}")
    if len(results) > 1:
        print("\n" + selection_table(results, rules[0]))
    return 0


if __name__ == "__main__":
    import sys

    sys.exit(main())

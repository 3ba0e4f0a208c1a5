"""What a policy is (an agent's act, its memory triple or its act with diagnostics, at the run's
matmul precision), and loading a trained one from a run directory as a plain jitted function."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Callable, NamedTuple, Union

import jax
import jax.numpy as jnp

from r2pac_jax.config import Config
from r2pac_jax.precision import with_matmul_precision


class MemoryPolicy(NamedTuple):
    """A policy with memory: init(params, obs[B, o]) -> mem; act(params, obs, key, mem) ->
    (action[B, a], mem); observe(params, mem, reward[B], cost[B]) -> mem after each step."""

    init: Callable
    act: Callable
    observe: Callable


class InfoPolicy(NamedTuple):
    """A stateless policy that also reports diagnostics of each state it acts in:
    act_info(params, obs[B, o], key) -> (action[B, a], {name: [B] float})."""

    act_info: Callable


Policy = Union[Callable, MemoryPolicy, InfoPolicy]


def policy_of(agent, diagnostics: bool = False) -> Policy:
    """What evaluation runs for an agent: its memory triple if it has one; with `diagnostics`,
    its `act_info` where it has one; else `act` (each at the agent's `matmul_precision`)."""
    mode = getattr(getattr(agent, "cfg", None), "matmul_precision", "default")

    def at(fn):
        return with_matmul_precision(fn, mode)

    if all(hasattr(agent, n) for n in ("memory_init", "act_memory", "observe")):
        return MemoryPolicy(at(agent.memory_init), at(agent.act_memory), at(agent.observe))
    if diagnostics and hasattr(agent, "act_info"):
        return InfoPolicy(at(agent.act_info))
    return at(agent.act)


def read_run(run_dir) -> tuple[Config, dict]:
    """The config and lanes description of a run directory (FileNotFoundError if it is none)."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise FileNotFoundError(f"{run_dir}: no such run directory")
    cfg_file, lanes_file = run_dir / "config.json", run_dir / "lanes.json"
    if not cfg_file.exists() or not lanes_file.exists():
        raise FileNotFoundError(f"{run_dir} holds no run (config.json and lanes.json are written "
                                "when training starts)")
    try:
        return (Config.from_dict(json.loads(cfg_file.read_text())),
                json.loads(lanes_file.read_text()))
    except (ValueError, KeyError, TypeError) as e:
        raise FileNotFoundError(f"{run_dir}: config.json or lanes.json is damaged ({e}); train "
                                "the run again into a new --out") from None


def restore_policy_params(run_dir, agent) -> tuple[dict, dict]:
    """The final policy parameters of every lane ([L, ...] leaves) and the lanes' description."""
    from r2pac_jax.checkpoint import restore_policy

    run_dir = Path(run_dir)
    if not (run_dir / "policy").exists() or not any((run_dir / "policy").glob("[0-9]*")):
        raise FileNotFoundError(f"{run_dir} holds no finished run (policy/ is written when "
                                "training ends): if it was killed, continue it with python -m "
                                f"r2pac_jax.train ... --resume --out {run_dir}")
    lanes = json.loads((run_dir / "lanes.json").read_text())
    return restore_policy(run_dir / "policy", agent, len(lanes["seeds"])), lanes


def load_policy(run_dir, lane: int = 0):
    """`act(obs, key) -> action` for lane `lane` of the run in `run_dir` (see loop.Run).

    obs: [obs_dim] -> action [act_dim], or [B, obs_dim] -> [B, act_dim]; actions lie in [-1, 1].
    A policy with memory (CDT) comes as `act(obs, key, memory) -> (action, memory)` with
    `act.init(obs) -> memory` at an episode's start and `act.observe(memory, reward, cost) ->
    memory` after each step (batched: obs [B, obs_dim], reward and cost [B]).
    """
    from r2pac_jax.agents import make_agent
    from r2pac_jax.tasks import get_task

    cfg, _ = read_run(run_dir)
    task = get_task(cfg.task)
    agent = make_agent(cfg, task.obs_dim, task.act_dim)
    pp, lanes = restore_policy_params(run_dir, agent)
    n = len(lanes["seeds"])
    if not 0 <= lane < n:
        raise IndexError(f"lane {lane} out of range: the run has {n} lanes")
    pp = jax.tree_util.tree_map(lambda x: x[lane], pp)
    policy = policy_of(agent)  # as evaluation runs it
    if isinstance(policy, MemoryPolicy):
        return _memory_policy(policy, pp, task)

    @jax.jit
    def act_jit(obs, key):
        obs = jnp.asarray(obs, jnp.float32)
        single = obs.ndim == 1
        a = policy(pp, obs[None] if single else obs, key)
        return a[0] if single else a

    def act(obs, key):
        _check_obs(obs, task, (1, 2))
        return act_jit(obs, key)

    return act


def _check_obs(obs, task, ndims) -> None:
    """A clear ValueError for an observation the policy cannot take (shapes are static, so this
    costs nothing per call)."""
    shape = jnp.shape(obs)
    forms = " or ".join({1: f"[{task.obs_dim}]", 2: f"[B, {task.obs_dim}]"}[n] for n in ndims)
    if len(shape) not in ndims or shape[-1] != task.obs_dim:
        raise ValueError(f"observation of shape {tuple(shape)}: the {task.name} policy takes "
                         f"observations of width {task.obs_dim} ({forms}); pass the task's "
                         "observation vector")


def _memory_policy(policy: MemoryPolicy, pp, task):
    """load_policy's form for policies with memory (batched observations only)."""

    step = jax.jit(lambda obs, key, memory: policy.act(
        pp, jnp.asarray(obs, jnp.float32), key, memory))
    init = jax.jit(lambda obs: policy.init(pp, jnp.asarray(obs, jnp.float32)))

    def act(obs, key, memory):
        _check_obs(obs, task, (2,))
        return step(obs, key, memory)

    def init_memory(obs):
        _check_obs(obs, task, (2,))
        return init(obs)

    act.init = init_memory
    act.observe = jax.jit(lambda memory, reward, cost: policy.observe(
        pp, memory, jnp.asarray(reward, jnp.float32), jnp.asarray(cost, jnp.float32)))
    return act

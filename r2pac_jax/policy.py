"""Load a trained policy from a run directory as a plain jitted function."""
from __future__ import annotations

import json
from pathlib import Path

import jax
import jax.numpy as jnp

from r2pac_jax.agents.r2pac import Agent
from r2pac_jax.config import Config, HParams
from r2pac_jax.tasks import get_task


def restore_policy_params(run_dir, agent: Agent) -> tuple[dict, dict]:
    """The final policy parameters of every lane ([L, ...] leaves) and the lanes' description."""
    from r2pac_jax.checkpoint import Checkpointer

    run_dir = Path(run_dir)
    if not (run_dir / "policy").exists():
        raise FileNotFoundError(f"{run_dir} holds no finished run (policy/ is written when "
                                "training ends)")
    lanes = json.loads((run_dir / "lanes.json").read_text())
    n = len(lanes["seeds"])
    hp = HParams.from_config(agent.cfg)
    like = jax.eval_shape(lambda k: jax.vmap(agent.policy_params)(
        jax.vmap(agent.init, in_axes=(0, None))(k, hp),
        jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (n,)), hp)),
        jnp.zeros((n, 2), jnp.uint32))
    ck = Checkpointer(run_dir / "policy", max_to_keep=1)
    pp, _ = ck.restore(ck.latest_step(), like)
    ck.close()
    return pp, lanes


def load_policy(run_dir, lane: int = 0):
    """`act(obs, key) -> action` for lane `lane` of the run in `run_dir` (see train.Run).

    obs: [obs_dim] -> action [act_dim], or [B, obs_dim] -> [B, act_dim]; actions lie in [-1, 1].
    """
    run_dir = Path(run_dir)
    cfg_file = run_dir / "config.json"
    if not cfg_file.exists():
        raise FileNotFoundError(f"{run_dir} holds no finished run (config.json and policy/ are "
                                "written when training ends)")
    cfg = Config.from_dict(json.loads(cfg_file.read_text()))
    task = get_task(cfg.task)
    agent = Agent(cfg, task.obs_dim, task.act_dim)
    pp, lanes = restore_policy_params(run_dir, agent)
    n = len(lanes["seeds"])
    if not 0 <= lane < n:
        raise IndexError(f"lane {lane} out of range: the run has {n} lanes")
    pp = jax.tree_util.tree_map(lambda x: x[lane], pp)

    @jax.jit
    def act(obs, key):
        obs = jnp.asarray(obs, jnp.float32)
        single = obs.ndim == 1
        a = agent.act(pp, obs[None] if single else obs, key)
        return a[0] if single else a

    return act

"""Helpers shared by the OSRL comparisons (osrl_bc.py, osrl_baselines.py)."""
from __future__ import annotations

import json
import os
import platform
import time
from pathlib import Path

import jax
import numpy as np


def machine() -> dict:
    return dict(machine=platform.machine(), cpus=os.cpu_count(), jax=jax.__version__,
                backend=jax.default_backend(), date=time.strftime("%Y-%m-%d %H:%M"))


def _json(path: Path, fn):
    """The JSON at `path`, computing and writing it first when it is not there."""
    if path.exists():
        return json.loads(path.read_text())
    from r2pac_jax.io import atomic_write_json

    value = fn()
    atomic_write_json(path, value)
    return value


def algo_speed(task, ds, algo: str, lanes: int, blocks: int = 5, block_steps: int = 1000,
               over: dict | None = None, preset: str = "quick") -> dict:
    """steps/s of `algo`'s compiled block at `preset`'s networks, `lanes` seeds vmapped."""
    from r2pac_jax.agents import make_agent
    from r2pac_jax.config import make_config
    from r2pac_jax.lanes import Lanes
    from r2pac_jax.loop import make_block

    cfg = make_config(task, algo, preset, dict(
        over or {}, steps=block_steps, threshold_every=block_steps, eval_every=block_steps,
        checkpoint_every=block_steps))
    agent = make_agent(cfg, task.obs_dim, task.act_dim)
    data = agent.make_data(task, ds)
    ln = Lanes.build(cfg, list(range(lanes)))
    state = jax.jit(jax.vmap(agent.init))(ln.init_keys(), ln.hp)
    fn = jax.jit(jax.vmap(make_block(agent, cfg.phases[0]), in_axes=(0, 0, None)))
    t0 = time.perf_counter()
    comp = fn.lower(state, ln.hp, data).compile()
    compile_s = time.perf_counter() - t0
    state, _ = comp(state, ln.hp, data)
    jax.block_until_ready(state)
    times = []
    for _ in range(blocks):
        t0 = time.perf_counter()
        state, _ = comp(state, ln.hp, data)
        jax.block_until_ready(state)
        times.append(time.perf_counter() - t0)
    dt = float(np.median(times))
    return dict(algo=algo, lanes=lanes, block_steps=block_steps, steps_per_s=block_steps / dt,
                seed_steps_per_s=lanes * block_steps / dt, compile_s=compile_s,
                batch=cfg.batch_size)

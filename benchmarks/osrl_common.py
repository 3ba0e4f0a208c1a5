"""Helpers shared by the OSRL comparisons (osrl_bc.py, osrl_baselines.py)."""
from __future__ import annotations

import json
from pathlib import Path


def machine() -> dict:
    """The machine a figure came from (r2pac_jax.machine.record: CPU model, CPUs, jax, ...)."""
    from r2pac_jax.machine import record

    return record()


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
    from r2pac_jax.config import make_config
    from r2pac_jax.loop import time_block

    cfg = make_config(task, algo, preset, dict(
        over or {}, steps=block_steps, block_steps=block_steps, eval_every=block_steps,
        checkpoint_every=block_steps))
    return dict(time_block(cfg, task, ds, lanes, blocks), algo=algo, batch=cfg.batch_size)

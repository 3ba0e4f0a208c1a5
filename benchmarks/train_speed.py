"""Gradient steps/s of the training block, 1 seed vs N seeds vmapped, and compile time.

    python benchmarks/train_speed.py [--presets quick,paper] [--seeds 1,4] [--blocks 3]

Times the compiled block (threshold refresh + `block_steps` critic or actor steps) on the
ReachAvoid dataset (network sizes follow the preset, so the figures transfer to any task with
similar observation/action sizes). Prints one JSON line per measurement.
"""
from __future__ import annotations

import argparse
import json

from r2pac_jax.config import make_config
from r2pac_jax.data import load_task_dataset
from r2pac_jax.tasks import get_task
from r2pac_jax.loop import time_block
from r2pac_jax.machine import record


def measure(preset: str, seeds: int, phase: str, blocks: int, block_steps: int, overrides=None):
    task = get_task("ReachAvoid")
    cfg = make_config(task, "r2pac", preset, dict(block_steps=block_steps,
                                                  eval_every=block_steps,
                                                  checkpoint_every=block_steps, steps=block_steps,
                                                  **(overrides or {})))
    ds = load_task_dataset(task, announce=lambda m: None)
    r = time_block(cfg, task, ds, seeds, blocks, phase)
    steps_per_s, seed_steps_per_s, compile_s = r["steps_per_s"], r["seed_steps_per_s"], \
        r["compile_s"]
    return dict(preset=preset, phase=phase, seeds=seeds, block_steps=block_steps,
                steps_per_s=steps_per_s, seed_steps_per_s=seed_steps_per_s,
                compile_s=compile_s, hidden=list(cfg.hidden_dims), batch=cfg.batch_size,
                **record())


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--presets", default="quick")
    ap.add_argument("--seeds", default="1,4")
    ap.add_argument("--phases", default="critic,actor")
    ap.add_argument("--blocks", type=int, default=3)
    ap.add_argument("--block-steps", type=int, default=200)
    ap.add_argument("--set", action="append", default=[], help="override key=value (ints)")
    args = ap.parse_args()
    ov = {k: (tuple(int(x) for x in v.split(",")) if "," in v else int(v))
          for k, v in (s.split("=") for s in args.set)}
    for preset in args.presets.split(","):
        for phase in args.phases.split(","):
            for s in (int(x) for x in args.seeds.split(",")):
                print(json.dumps(measure(preset, s, phase, args.blocks, args.block_steps, ov)),
                      flush=True)


if __name__ == "__main__":
    main()

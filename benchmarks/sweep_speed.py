"""A grid of G cells (alpha values x seeds) trained vmapped as one program vs one after another.

    python benchmarks/sweep_speed.py [--cells 4] [--seeds 1] [--steps 1000]

Both sides run the same pure `train(key, hp)` of `r2pac_jax.train.make_train` (quick preset
networks, ReachAvoid data, critic + actor phases of `--steps` each, no evaluation): once as
`jit(vmap(train))` over G*S lanes, once as `jit(train)` called G*S times (compiled once, reused).
Wall times include compilation; the steady-state time is a second call of each. Prints JSON.
"""
from __future__ import annotations

import argparse
import json
import time

import jax
import jax.numpy as jnp

from r2pac_jax.config import make_config
from r2pac_jax.data import load_task_dataset
from r2pac_jax.machine import record
from r2pac_jax.tasks import get_task
from r2pac_jax.train import chunk_dataset, make_train


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--cells", type=int, default=4)
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--preset", default="quick")
    args = ap.parse_args()
    task = get_task("ReachAvoid")
    cfg = make_config(task, "r2pac", args.preset, dict(steps=args.steps, block_steps=500,
                                                        eval_every=args.steps,
                                                        checkpoint_every=args.steps))
    ds = load_task_dataset(task, announce=lambda m: None)
    data = chunk_dataset(cfg, task, ds)
    train = make_train(cfg, data, task.obs_dim, task.act_dim)
    alphas = jnp.linspace(0.5, 0.95, args.cells)
    L = args.cells * args.seeds
    hp = dict(quantile_alpha=jnp.repeat(alphas, args.seeds), penalty_c=jnp.ones(L),
              guidance_scale=jnp.full(L, 2.0))
    keys = jnp.stack([jax.random.PRNGKey(s) for _ in range(args.cells) for s in range(args.seeds)])

    def timed(fn):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        return time.perf_counter() - t0

    vm = jax.jit(jax.vmap(train))
    t_vmap_first = timed(lambda: vm(keys, hp))
    t_vmap = timed(lambda: vm(keys, hp))
    single = jax.jit(train)

    def sequential():
        return [single(keys[i], jax.tree_util.tree_map(lambda x: x[i], hp)) for i in range(L)]

    t_seq_first = timed(sequential)
    t_seq = timed(sequential)
    print(json.dumps(dict(
        cells=args.cells, seeds=args.seeds, lanes=L, steps_per_phase=args.steps,
        preset=args.preset, hidden=list(cfg.hidden_dims), batch=cfg.batch_size,
        vmapped_s=t_vmap, sequential_s=t_seq, speedup=t_seq / t_vmap,
        vmapped_with_compile_s=t_vmap_first, sequential_with_compile_s=t_seq_first,
        speedup_with_compile=t_seq_first / t_vmap_first,
        **record())))


if __name__ == "__main__":
    main()

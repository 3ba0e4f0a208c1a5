"""How close each algorithm's training step comes to this machine's float32 matmul limit.

    python benchmarks/efficiency.py [--algos r2pac,cpq,...] [--presets quick,paper]
        [--task CarGoal2] [--lanes 1] [--blocks 3] [--set matmul_precision=bf16]
        [--out benchmarks/results/efficiency.jsonl]
    python benchmarks/efficiency.py --table benchmarks/results/efficiency.jsonl

For every algorithm, preset and phase: the FLOPs of one training step, from XLA's cost analysis
of a compiled *single* step (sample + update; a scanned block's loop body would be counted once,
whatever its length), plus the block's start (R2PAC's threshold refresh) amortised over the
block; the measured steps/s of the compiled block (`loop.time_block`: compile apart, one warm-up,
median of `--blocks`); and the achieved GFLOP/s as a fraction of two matmul rates measured in the
same run: a [batch, width] x [width, width] loop at the step's own sizes, and a large square one
(the machine's peak). Evaluation's cost: the policy's FLOPs per environment step (its `act` on a
batch, divided by the batch). A hand count of one ReLU MLP checks the cost analysis first.

The data are random arrays of the task's shapes (the values change no FLOP and no timing): no
dataset file is needed. Pause background jobs while it runs; each line records the machine.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from r2pac_jax.agents import make_agent
from r2pac_jax.config import default_hparams, make_config
from r2pac_jax.data.dsrl import validate
from r2pac_jax.evaluate import MemoryPolicy, policy_of
from r2pac_jax.loop import make_data, time_block
from r2pac_jax.machine import record
from r2pac_jax.tasks import get_task
from r2pac_jax.train import parse_set

ALGOS = "r2pac,bc-all,bc-all-mlp,cpq,bcq-lag,coptidice,fisor,cdt,trebi"  # one per module
BLOCK_STEPS = {"quick": 50, "paper": 5}


def cost_of(fn, *args) -> dict:
    """XLA's cost analysis of fn compiled for args (a loop body counts once): flops,
    transcendentals, bytes accessed."""
    cost = jax.jit(fn).lower(*args).compile().cost_analysis()
    cost = cost[0] if isinstance(cost, (list, tuple)) else cost
    return {k: float(cost.get(k, 0.0)) for k in ("flops", "transcendentals", "bytes accessed")}


def flops_of(fn, *args) -> float:
    """XLA's FLOP count of fn compiled for args (a loop body counts once)."""
    return cost_of(fn, *args)["flops"]


def relu_mlp_hand_count(batch: int, dims: list[int]) -> int:
    """FLOPs of a ReLU MLP forward ([batch, dims[0]] -> [batch, dims[-1]]): a multiply-add per
    weight per row (2), one add per bias, one max per hidden unit."""
    mm = sum(2 * batch * a * b for a, b in zip(dims[:-1], dims[1:]))
    return mm + batch * sum(dims[1:]) + batch * sum(dims[1:-1])


def check_cost_analysis(batch: int = 128, dims=(20, 256, 256, 1)) -> dict:
    """The cost analysis of a flax ReLU MLP against `relu_mlp_hand_count`."""
    import flax.linen as nn

    class Net(nn.Module):
        @nn.compact
        def __call__(self, x):
            for d in dims[1:-1]:
                x = nn.relu(nn.Dense(d)(x))
            return nn.Dense(dims[-1])(x)

    x = jnp.ones((batch, dims[0]))
    params = Net().init(jax.random.PRNGKey(0), x)
    xla, hand = flops_of(Net().apply, params, x), relu_mlp_hand_count(batch, list(dims))
    return dict(kind="check", batch=batch, dims=list(dims), xla_flops=xla, hand_flops=hand,
                ratio=xla / hand)


def matmul_rate(m: int, k: int, reps: int) -> float:
    """GFLOP/s of `reps` chained [m, k] x [k, k] float32 matmuls in one compiled loop."""
    w = jax.random.normal(jax.random.PRNGKey(0), (k, k)) / np.sqrt(k)
    x = jax.random.normal(jax.random.PRNGKey(1), (m, k))
    loop = jax.jit(lambda x, w: jax.lax.fori_loop(0, reps, lambda _, y: y @ w, x))
    jax.block_until_ready(loop(x, w))
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        jax.block_until_ready(loop(x, w))
        times.append(time.perf_counter() - t0)
    return 2.0 * m * k * k * reps / min(times) / 1e9


def random_dataset(task, episodes: int = 20, seed: int = 0):
    """A DSRL-format dataset of the task's shapes: random observations and actions, per-episode
    cost rates of 0-5% (some episodes safe, some not: every algorithm's data view is non-empty)."""
    rng = np.random.default_rng(seed)
    T, n = task.episode_len, episodes * task.episode_len
    obs = rng.standard_normal((episodes, T + 1, task.obs_dim), dtype=np.float32)
    rate = np.repeat(rng.uniform(0, 0.05, episodes), T)
    ends = np.zeros((episodes, T), bool)
    ends[:, -1] = True
    return validate(dict(
        observations=obs[:, :-1].reshape(n, -1), next_observations=obs[:, 1:].reshape(n, -1),
        actions=rng.uniform(-1, 1, (n, task.act_dim)).astype(np.float32),
        rewards=rng.standard_normal(n, dtype=np.float32),
        costs=(rng.random(n) < rate).astype(np.float32),
        terminals=np.zeros(n, bool), timeouts=ends.reshape(n)), f"random {task.name}")


def step_cost(agent, cfg, data, phase: str) -> tuple[dict, float]:
    """(cost_of one step of `phase`, FLOPs of the block's start) for one lane."""
    hp = default_hparams(cfg)
    state = agent.init(jax.random.PRNGKey(0), hp)

    def one(s, hp, data):
        key, k_batch = jax.random.split(s.key)
        return agent.update(s.replace(key=key), agent.sample(data, k_batch), hp, phase)

    start = flops_of(agent.begin_block, state, hp, data)
    return cost_of(one, state, hp, data), start


def policy_flops(agent, cfg, batch: int = 64) -> float:
    """The policy's FLOPs per environment step (per observation of a batch of `batch`)."""
    hp = default_hparams(cfg)
    pp = agent.policy_params(agent.init(jax.random.PRNGKey(0), hp), hp)
    obs = jnp.zeros((batch, agent.obs_dim), jnp.float32)
    key = jax.random.PRNGKey(1)
    policy = policy_of(agent)
    if isinstance(policy, MemoryPolicy):
        mem = policy.init(pp, obs)
        r = jnp.zeros((batch,), jnp.float32)
        total = flops_of(policy.act, pp, obs, key, mem) + flops_of(policy.observe, pp, mem, r, r)
    else:
        total = flops_of(policy, pp, obs, key)
    return total / batch


def widest(cfg) -> int:
    """The widest hidden layer of cfg's networks (the step's typical matmul width)."""
    best = 0
    for k, v in cfg.flat().items():
        if isinstance(v, tuple) and k.endswith("hidden_dims") and v:
            best = max(best, max(v))
        elif k in ("vae_hidden", "actor_hidden", "embedding_dim", "unet_dim") and isinstance(
                v, int):
            best = max(best, v)
    return best or 256


def measure(algo: str, preset: str, task, ds, lanes: list[int], blocks: int, sets: list[str],
            peak: float) -> list[dict]:
    """One row per phase and lane count; the FLOPs (per lane) are counted once per phase."""
    bs = BLOCK_STEPS[preset]
    overrides = parse_set(sets, [algo])
    cfg = make_config(task, algo, preset, dict(dict(steps=bs, block_steps=bs, eval_every=bs,
                                                    checkpoint_every=bs), **overrides))
    agent = make_agent(cfg, task.obs_dim, task.act_dim)
    data = make_data(cfg, task, ds)
    width = widest(cfg)
    at_size = matmul_rate(cfg.batch_size, width, 20)
    pol = policy_flops(agent, cfg)
    rows = []
    for phase in cfg.phases:
        cost, f_start = step_cost(agent, cfg, data, phase)
        f_step = cost["flops"]
        per_step = f_step + f_start / bs
        for n in lanes:
            t = time_block(cfg, task, ds, n, blocks, phase)
            achieved = per_step * t["seed_steps_per_s"] / 1e9
            rows.append(dict(
                kind="step", algo=algo, preset=preset, phase=phase, task=task.name, lanes=n,
                matmul_precision=cfg.matmul_precision, batch=cfg.batch_size, width=width,
                gflop_step=f_step / 1e9, gflop_block_start=f_start / 1e9, block_steps=bs,
                gflop_per_step=per_step / 1e9,
                mtranscendentals_step=cost["transcendentals"] / 1e6,
                flop_per_byte=f_step / max(cost["bytes accessed"], 1.0),
                steps_per_s=t["steps_per_s"], seed_steps_per_s=t["seed_steps_per_s"],
                compile_s=t["compile_s"], achieved_gflops=achieved,
                matmul_gflops_at_size=at_size, matmul_gflops_peak=peak,
                frac_of_size=achieved / at_size, frac_of_peak=achieved / peak,
                policy_mflop_per_env_step=pol / 1e6, **record()))
    return rows


def table(lines: list[dict]) -> str:
    out = ["| algorithm | preset | phase | lanes | GFLOP/step | steps/s | achieved GFLOP/s | "
           "of matmul at its size | of peak | FLOP/byte | M transc./step | policy MFLOP/env step |",
           "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in lines:
        if r.get("kind") != "step":
            continue
        algo = r["algo"] + (f" ({r['matmul_precision']})"
                            if r.get("matmul_precision", "default") != "default" else "")
        out.append(f"| {algo} | {r['preset']} | {r['phase']} | {r['lanes']} | "
                   f"{r['gflop_per_step']:.4g} "
                   f"| {r['steps_per_s']:.4g} | {r['achieved_gflops']:.3g} | "
                   f"{100 * r['frac_of_size']:.1f}% ({r['matmul_gflops_at_size']:.0f} at "
                   f"{r['batch']}x{r['width']}) | {100 * r['frac_of_peak']:.1f}% | "
                   f"{r.get('flop_per_byte', float('nan')):.3g} | "
                   f"{r.get('mtranscendentals_step', float('nan')):.3g} | "
                   f"{r['policy_mflop_per_env_step']:.3g} |")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--algos", default=ALGOS)
    ap.add_argument("--presets", default="quick,paper")
    ap.add_argument("--task", default="CarGoal2")
    ap.add_argument("--lanes", default="1", help="comma-separated lane counts (seeds vmapped)")
    ap.add_argument("--blocks", type=int, default=3)
    ap.add_argument("--peak-size", type=int, default=2048)
    ap.add_argument("--set", action="append", default=[], help="config key=value, as train's --set")
    ap.add_argument("--out", help="append JSON lines here too")
    ap.add_argument("--table", help="print the markdown table of a JSON-lines file and stop")
    args = ap.parse_args(argv)
    if args.table:
        print(table([json.loads(x) for x in Path(args.table).read_text().splitlines() if x]))
        return 0
    def emit(row):
        print(json.dumps(row), flush=True)
        if args.out:
            with open(args.out, "a") as f:
                f.write(json.dumps(row) + "\n")

    emit(check_cost_analysis())
    peak = matmul_rate(args.peak_size, args.peak_size, 5)
    emit(dict(kind="peak", size=args.peak_size, matmul_gflops=peak, **record()))
    task = get_task(args.task)
    ds = random_dataset(task)
    for preset in args.presets.split(","):
        for algo in args.algos.split(","):
            try:
                for row in measure(algo, preset, task, ds,
                                   [int(x) for x in args.lanes.split(",")], args.blocks,
                                   args.set, peak):
                    emit(row)
            except Exception as e:  # one algorithm's failure must not lose the others' rows
                emit(dict(kind="error", algo=algo, preset=preset, error=repr(e)[:500]))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""How close the memory check's estimate (r2pac_jax/memory.py) comes to what training allocates.

    python benchmarks/memory_check.py [--task ReachAvoid] [--algos r2pac,bc-all-mlp]
                                      [--lanes 32,96] [--out runs/memory_check]

For each algorithm and lane count, a child process loads the task's data, computes the check's
estimate (XLA's memory analysis of the compiled blocks: the state of all lanes, and a block's
outputs and temporaries), then allocates the state and runs one block of every phase, and reports
its RSS growth from just before the state was allocated (the resident set then, every compile
done) to its peak (ru_maxrss; large lane counts, so that training's peak is above the
compiles'). The growth between two
lane counts set against the estimates' difference is the ratio that says whether the estimate
tracks what lanes cost (the process's fixed costs cancel). Prints and writes JSON lines.
"""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
from pathlib import Path

CHILD = r"""
import json, resource, sys
import jax
from r2pac_jax.config import make_config
from r2pac_jax.data import load_task_dataset
from r2pac_jax.lanes import Lanes
from r2pac_jax.loop import compiled, make_data
from r2pac_jax.memory import block_need
from r2pac_jax.tasks import get_task

task_name, algo, lanes = sys.argv[1], sys.argv[2], int(sys.argv[3])
task = get_task(task_name)
# ten-step blocks: a block's memory does not depend on its length (one scan body)
cfg = make_config(task, algo, "quick", dict(seeds=lanes, steps=20, block_steps=10,
                                            eval_every=10, checkpoint_every=10))
ds = load_task_dataset(task, announce=lambda m: None, progress=False)
_, init, blocks, _ = compiled(cfg, task.obs_dim, task.act_dim)
data = make_data(cfg, task, ds)
ln = Lanes.build(cfg, list(range(lanes)))
need = block_need(init, blocks, ln.hp, data, lanes)   # compiles every phase's block
init.lower(ln.init_keys(), ln.hp).compile()  # init's compile too, before the baseline
import os
base = int(open("/proc/self/statm").read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
state = init(ln.init_keys(), ln.hp)
for phase in cfg.phases:
    state, m, _ = blocks[phase](state, ln.hp, data)
jax.block_until_ready(state)
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
print(json.dumps(dict(algo=algo, lanes=lanes, estimate=need.total, state=need.state,
                      step=need.step, rss_before=base, rss_peak=peak)))
"""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="benchmarks/memory_check.py")
    ap.add_argument("--task", default="ReachAvoid")
    ap.add_argument("--algos", default="r2pac,bc-all-mlp")
    ap.add_argument("--lanes", default="32,96")
    ap.add_argument("--out", default="runs/memory_check")
    args = ap.parse_args(argv)
    from r2pac_jax.machine import record

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for algo in args.algos.split(","):
        runs = []
        for lanes in [int(x) for x in args.lanes.split(",")]:
            p = subprocess.run([sys.executable, "-c", CHILD, args.task, algo, str(lanes)],
                               capture_output=True, text=True, check=True)
            r = json.loads(p.stdout.strip().splitlines()[-1])
            r["rss_growth"] = max(0, r["rss_peak"] - r["rss_before"])
            runs.append(r)
            print(json.dumps(r), flush=True)
        lo, hi = runs[0], runs[-1]
        d_est = hi["estimate"] - lo["estimate"]
        d_rss = hi["rss_growth"] - lo["rss_growth"]
        rows.append(dict(task=args.task, algo=algo, lanes=[lo["lanes"], hi["lanes"]],
                         estimate_mib=[round(x["estimate"] / 2**20, 1) for x in (lo, hi)],
                         rss_growth_mib=[round(x["rss_growth"] / 2**20, 1) for x in (lo, hi)],
                         measured_over_estimated=round(d_rss / d_est, 3) if d_est else None))
        print(json.dumps(rows[-1]), flush=True)
    result = dict(rows=rows, machine=record(), parent_maxrss_kib=resource.getrusage(
        resource.RUSAGE_SELF).ru_maxrss)
    (out / "memory_check.json").write_text(json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

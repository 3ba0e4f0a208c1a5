"""Our one-step MLP cloner (`bc-*-mlp`) against OSRL's BC on the same generated file, in one run.

    bash benchmarks/peers/install_osrl.sh ../osrl-venv        # once: OSRL's side virtualenv
    python benchmarks/osrl_bc.py --osrl-venv ../osrl-venv [--task PointGoal1] [--seeds 3]
        [--steps 20000] [--episodes 20] [--out runs/osrl_bc] [--only speed|scores]

Same file, network (2 x 256 ReLU, tanh), batch 512, Adam 1e-3, steps; deterministic actions.
1. Speed, evaluation excluded, compile time apart. Ours: the compiled block of `bc-all-mlp`
   (1,000 steps per block; median over blocks after a warm-up block), 1 seed and 3 seeds vmapped.
   Theirs (benchmarks/peers/osrl_bc_peer.py, torch at 2 threads): OSRL's own loader
   (TransitionDataset in a DataLoader) and bulk numpy batches (the update alone).
2. Scores: bc-all-mlp and bc-safe-mlp, `--steps` steps each, `--seeds` seeds (ours vmapped;
   theirs one process per seed, bulk batches), every actor evaluated in our environment with the
   same evaluation keys (`evaluate.eval_keys` of the seed at the final step), `--episodes` each.
   OSRL's actors are exported as npz and loaded into our network (W -> kernel W^T).
Each finished part is kept in OUT (a rerun skips it); OUT/summary.json and OUT/table.md at the end.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

HERE = Path(__file__).parent
sys.path.insert(0, str(HERE))
from osrl_common import _json, algo_speed, machine  # noqa: E402
MODES = {"bc-all-mlp": "all", "bc-safe-mlp": "safe"}


def ours_speed(task, ds, lanes: int, blocks: int = 5, block_steps: int = 1000) -> dict:
    r = algo_speed(task, ds, "bc-all-mlp", lanes, blocks, block_steps)
    from r2pac_jax.config import make_config

    r["hidden"] = list(make_config(task, "bc-all-mlp").hidden_dims)
    return r


def peer(osrl_python: str, file: str, mode: str, kappa: float, seed: int, steps: int,
         loader: str, out: Path, warmup: int = 200) -> dict:
    if (out.parent / (out.name + ".json")).exists():
        return json.loads((out.parent / (out.name + ".json")).read_text())
    out.parent.mkdir(parents=True, exist_ok=True)
    cmd = [osrl_python, str(HERE / "peers" / "osrl_bc_peer.py"), file, "--mode", mode,
           "--cost-limit", str(kappa), "--seed", str(seed), "--steps", str(steps),
           "--loader", loader, "--threads", "2", "--warmup", str(warmup), "--out", str(out)]
    env = dict(os.environ, WANDB_MODE="disabled", PYTHONNOUSERSITE="1")
    subprocess.run(cmd, check=True, env=env, capture_output=True, text=True)
    return json.loads((out.parent / (out.name + ".json")).read_text())


def osrl_params(npz_files: list[Path]) -> dict:
    """OSRL actors (torch Linear W [out, in], b) -> our DeterministicActor params, [L, ...]."""
    layers = []
    for f in npz_files:
        z = np.load(f)
        n = len([k for k in z.files if k.startswith("W")])
        layers.append({f"Dense_{i}": {"kernel": z[f"W{i}"].T, "bias": z[f"b{i}"]}
                       for i in range(n)})
    stacked = jax.tree_util.tree_map(lambda *x: jnp.asarray(np.stack(x)), *layers)
    return {"actor": {"params": stacked}}


def scores(args, task, ds, file: str, out: Path) -> dict:
    from r2pac_jax.agents import make_agent
    from r2pac_jax.config import make_config
    from r2pac_jax.evaluate import LaneEvaluator, eval_keys, policy_of
    from r2pac_jax.lanes import Lanes
    from r2pac_jax.loop import Run

    seeds = list(range(args.seeds))
    table = {}
    for algo, mode in MODES.items():
        over = dict(steps=args.steps, seeds=args.seeds, eval_episodes=args.episodes,
                    eval_every=args.steps, checkpoint_every=args.steps)
        cfg = make_config(task, algo, "quick", over)

        def ours():
            t0 = time.time()
            res = Run(cfg, task, ds, out / "ours" / algo, Lanes.build(cfg, seeds),
                      progress=False, log=lambda m: None).run(resume=True)
            return dict(normalized_reward=res["normalized_reward"],
                        normalized_cost=res["normalized_cost"], wall_s=time.time() - t0,
                        train_steps_per_s=res["train_steps_per_s"])

        mine = _json(out / f"ours-{algo}.json", ours)

        def theirs():
            infos = [peer(args.osrl_python, file, mode, task.kappa, s, args.steps, "bulk",
                          out / "osrl" / f"{mode}-s{s}") for s in seeds]
            agent = make_agent(cfg, task.obs_dim, task.act_dim)
            pp = osrl_params([out / "osrl" / f"{mode}-s{s}.npz" for s in seeds])
            ev = LaneEvaluator(policy_of(agent), task, args.episodes)(pp, eval_keys(seeds, cfg.total_steps))
            return dict(
                normalized_reward=dict(mean=float(np.mean(ev["normalized_reward"])),
                                       std=float(np.std(ev["normalized_reward"])),
                                       per_seed=[float(x) for x in ev["normalized_reward"]]),
                normalized_cost=dict(mean=float(np.mean(ev["normalized_cost"])),
                                     std=float(np.std(ev["normalized_cost"])),
                                     per_seed=[float(x) for x in ev["normalized_cost"]]),
                train_steps_per_s=[i["steps_per_s"] for i in infos], kept=infos[0]["kept"],
                transitions=infos[0]["transitions"], final_loss=[i["losses"][-1][1]
                                                                 for i in infos])

        table[algo] = dict(ours=mine, osrl=_json(out / f"osrl-{algo}.json", theirs))
    return table


def write_table(summary: dict, out: Path) -> str:
    from r2pac_jax.io import atomic_write_text

    lines = [f"OSRL BC vs r2pac-jax bc-*-mlp on {summary['task']} ({Path(summary['dataset']).name}); "
             f"{summary['machine']['cpus']} CPUs, jax {summary['machine']['jax']}", ""]
    sp = summary.get("speed")
    if sp:
        base = sp["osrl_loader"]["steps_per_s"]
        lines += [f"Speed ({sp['machine']['date']}; training steps only, evaluation excluded, "
                  "compile time apart):", "",
                  "| trainer | steps/s | seed-steps/s | vs OSRL's loop |", "|---|---|---|---|"]
        lines.append(f"| OSRL, its DataLoader (torch 2 threads) | {base:.0f} | {base:.0f} | 1.00 |")
        b = sp["osrl_bulk"]["steps_per_s"]
        lines.append(f"| OSRL, bulk numpy batches | {b:.0f} | {b:.0f} | {b / base:.2f} |")
        for r in sp["ours"]:
            lines.append(f"| ours, {r['lanes']} seed(s) vmapped (compile {r['compile_s']:.1f} s) | "
                         f"{r['steps_per_s']:.0f} | {r['seed_steps_per_s']:.0f} | "
                         f"{r['seed_steps_per_s'] / base:.2f} |")
        lines.append("")
    sc = summary.get("scores")
    if sc:
        lines += ["| algo | OSRL reward | OSRL cost | ours reward | ours cost | OSRL / ours cost "
                  "per seed |", "|---|---|---|---|---|---|"]
        for algo, r in sc.items():
            o, m = r["osrl"], r["ours"]
            lines.append(
                f"| {algo} | {o['normalized_reward']['mean']:.2f} ± "
                f"{o['normalized_reward']['std']:.2f} | {o['normalized_cost']['mean']:.2f} ± "
                f"{o['normalized_cost']['std']:.2f} | {m['normalized_reward']['mean']:.2f} ± "
                f"{m['normalized_reward']['std']:.2f} | {m['normalized_cost']['mean']:.2f} ± "
                f"{m['normalized_cost']['std']:.2f} | "
                f"{' '.join(f'{x:.2f}' for x in o['normalized_cost']['per_seed'])} / "
                f"{' '.join(f'{x:.2f}' for x in m['normalized_cost']['per_seed'])} |")
        lines += ["", f"{summary['seeds']} seeds, {summary['steps']} steps, {summary['episodes']} "
                  "episodes per seed in our environment, same evaluation keys."]
    text = "\n".join(lines)
    atomic_write_text(out / "table.md", text + "\n")
    return text


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--task", default="PointGoal1")
    ap.add_argument("--osrl-venv", default=str(HERE.parent.parent / "osrl-venv" / "venv"))
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--steps", type=int, default=20_000)
    ap.add_argument("--speed-steps", type=int, default=3000, help="OSRL steps timed per loader")
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--out", default="runs/osrl_bc")
    ap.add_argument("--only", choices=["speed", "scores"], default=None)
    ap.add_argument("--dataset", default=None,
                    help="a DSRL-format file (default: the task's scripted v1 file, generated "
                         "if missing: the file of the recorded figures)")
    args = ap.parse_args(argv)
    args.osrl_python = str(Path(args.osrl_venv) / "bin" / "python")
    if not Path(args.osrl_python).exists():
        print(f"error: no OSRL virtualenv at {args.osrl_venv}; make it with "
              f"bash benchmarks/peers/install_osrl.sh {args.osrl_venv}", file=sys.stderr)
        return 2
    from r2pac_jax.data import factory, load_task_dataset
    from r2pac_jax.tasks import get_task

    task = get_task(args.task)
    dataset = args.dataset or factory.find_cached(task) or factory.generate_dataset(
        task, source="scripted")
    ds = load_task_dataset(task, str(dataset), announce=print)
    file = ds.source
    out = Path(args.out) / task.name
    out.mkdir(parents=True, exist_ok=True)
    summary = dict(task=task.name, dataset=file, seeds=args.seeds, steps=args.steps,
                   episodes=args.episodes, machine=machine())
    if args.only in (None, "speed"):
        def speed():
            return dict(
                ours=[ours_speed(task, ds, n) for n in (1, args.seeds)],
                osrl_loader=peer(args.osrl_python, file, "all", task.kappa, 0, args.speed_steps,
                                 "osrl", out / "speed" / "osrl-loader"),
                osrl_bulk=peer(args.osrl_python, file, "all", task.kappa, 0, args.speed_steps,
                               "bulk", out / "speed" / "osrl-bulk"),
                machine=machine())
        summary["speed"] = _json(out / "speed.json", speed)
    elif (out / "speed.json").exists():
        summary["speed"] = json.loads((out / "speed.json").read_text())
    if args.only in (None, "scores"):
        summary["scores"] = scores(args, task, ds, file, out)
    elif all((out / f"{w}-{a}.json").exists() for w in ("ours", "osrl") for a in MODES):
        summary["scores"] = scores(args, task, ds, file, out)  # all parts kept: nothing reruns
    from r2pac_jax.io import atomic_write_json

    atomic_write_json(out / "summary.json", summary)
    print(write_table(summary, out))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Our ports of OSRL's baselines against OSRL's own code on the same file, in one run.

    bash benchmarks/peers/install_osrl.sh ../osrl-venv/venv    # once: OSRL's side virtualenv
    python benchmarks/osrl_baselines.py --algo cpq --dataset FILE.hdf5 [--task T] [--seeds 3]
        [--steps 3000] [--episodes 20] [--out runs/osrl_baselines]

Both sides at OSRL's settings for the algorithm (networks, batch, learning rates, scales: our
`paper` preset) and the
same reduced number of gradient steps (stated in the table; OSRL's CPQ runs ~10 steps/s on two
cores, so its 100k steps would take hours per seed).
1. Speed, evaluation excluded, compile time apart. Ours: the compiled block (`--block` steps;
   median over blocks after a warm-up block), 1 seed and `--seeds` seeds vmapped. Theirs: each
   scoring run's own steps/s after a warm-up (torch at 2 threads, bulk numpy batches, so only the
   update is timed), one process per seed.
2. Scores: ours through `Run` (seeds vmapped, evaluated at the last step); theirs one process per
   seed (benchmarks/peers/osrl_<algo>_peer.py), the actor exported as npz and loaded into our
   network, evaluated in our environment with the same evaluation keys and episodes.
   Agreement (the baselines issue): |mean ours - mean theirs| <= 2 x the larger seed std, for
   reward and for cost.
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

sys.path.insert(0, str(Path(__file__).parent))
from osrl_common import _json, algo_speed, machine  # noqa: E402

HERE = Path(__file__).parent


def cpq_params(npz_files: list[Path]) -> dict:
    """OSRL CPQ actors (trunk Linear layers, then mu; W [out, in]) -> our SquashedGaussianActor
    params stacked over seeds [L, ...]. The log-std head is not used by deterministic actions:
    it is filled with zeros."""
    trees = []
    for f in npz_files:
        z = np.load(f)
        n = len([k for k in z.files if k.startswith("W")])
        p = {f"Dense_{i}": {"kernel": z[f"W{i}"].T, "bias": z[f"b{i}"]} for i in range(n - 1)}
        p["mu"] = {"kernel": z[f"W{n - 1}"].T, "bias": z[f"b{n - 1}"]}
        p["log_std"] = {"kernel": np.zeros_like(z[f"W{n - 1}"].T),
                        "bias": np.zeros_like(z[f"b{n - 1}"])}
        trees.append(p)
    stacked = jax.tree_util.tree_map(lambda *x: jnp.asarray(np.stack(x)), *trees)
    return {"actor": {"params": stacked}}


def bcq_lag_params(npz_files: list[Path]) -> dict:
    """OSRL BCQ-L perturbation actors and VAEs -> our params stacked over seeds [L, ...]."""
    trees = []
    for f in npz_files:
        z = np.load(f)
        n = len([k for k in z.files if k.startswith("W")])
        actor = {f"Dense_{i}": {"kernel": z[f"W{i}"].T, "bias": z[f"b{i}"]} for i in range(n)}
        vae = {m: {"kernel": z[f"vae_{m}_W"].T, "bias": z[f"vae_{m}_b"]}
               for m in ("e1", "e2", "mean", "log_std", "d1", "d2", "d3")}
        trees.append({"actor": {"params": actor}, "vae": {"params": vae}})
    return jax.tree_util.tree_map(lambda *x: jnp.asarray(np.stack(x)), *trees)


def fisor_params(npz_files: list[Path]) -> dict:
    """FISOR's EMA actor and target Q_h ("actor/...", "qh/..." flattened in FISOR's module
    names) -> our policy params stacked over seeds [L, ...]."""
    from flax import traverse_util

    trees = []
    for f in npz_files:
        z = np.load(f)
        tree = {}
        for part in ("actor", "qh"):
            flat = {tuple(k.split("/")[1:]): z[k] for k in z.files if k.startswith(part + "/")}
            tree[part] = {"params": traverse_util.unflatten_dict(flat)}
        trees.append(tree)
    return jax.tree_util.tree_map(lambda *x: jnp.asarray(np.stack(x)), *trees)


def fisor_probe(agent, pp, npz: Path) -> dict:
    """Our FISOR networks on the peer's probe inputs, with the peer's seed-0 parameters: the
    largest absolute difference from FISOR's own outputs (eps model, Q_h ensemble)."""
    z = np.load(npz)
    p0 = jax.tree_util.tree_map(lambda x: x[0], pp)
    eps = agent.actor_net.apply(p0["actor"], z["probe/obs"], z["probe/x"], z["probe/t"])
    qh = agent.q_net.apply(p0["qh"], z["probe/obs"], z["probe/x"])
    return dict(eps=float(np.abs(np.asarray(eps) - z["probe/eps"]).max()),
                qh=float(np.abs(np.asarray(qh) - z["probe/qh"]).max()),
                eps_scale=float(np.abs(z["probe/eps"]).max()))


_CDT_NAMES = {"return_emb": "return_emb", "cost_emb": "cost_emb", "state_emb": "state_emb",
              "action_emb": "action_emb", "emb_norm": "emb_norm", "out_norm": "out_norm",
              "action_head.mu": "mu", "action_head.log_std": "log_std",
              "cost_pred_head": "cost_pred", "state_pred_head": "state_pred"}


def cdt_model(z) -> dict:
    """OSRL's CDT state_dict ("sd/NAME" in the peer's npz) -> our DecisionTransformer params."""
    sd = {k[3:]: z[k] for k in z.files if k.startswith("sd/")}
    p: dict = {"timestep_emb": {"embedding": sd["timestep_emb.weight"]}}

    def layer(torch_name):
        if torch_name.endswith("norm") or ".norm" in torch_name:
            return {"scale": sd[torch_name + ".weight"], "bias": sd[torch_name + ".bias"]}
        return {"kernel": sd[torch_name + ".weight"].T, "bias": sd[torch_name + ".bias"]}

    for t_name, name in _CDT_NAMES.items():
        p[name] = layer(t_name)
    i = 0
    while f"blocks.{i}.norm1.weight" in sd:
        b = f"blocks.{i}."
        p[f"block_{i}"] = {
            "norm1": layer(b + "norm1"), "norm2": layer(b + "norm2"),
            "mlp_0": layer(b + "mlp.0"), "mlp_2": layer(b + "mlp.2"),
            "attention": {"in_proj_kernel": sd[b + "attention.in_proj_weight"].T,
                          "in_proj_bias": sd[b + "attention.in_proj_bias"],
                          "out_proj": layer(b + "attention.out_proj")}}
        i += 1
    return {"params": p}


def cdt_params(npz_files: list[Path], targets: tuple[float, float]) -> dict:
    """The peers' CDT models with our evaluation targets (return, cost) -> policy params [L]."""
    trees = [{"model": cdt_model(np.load(f)), "target_return": np.float32(targets[0]),
              "target_cost": np.float32(targets[1])} for f in npz_files]
    return jax.tree_util.tree_map(lambda *x: jnp.asarray(np.stack(x)), *trees)


def cdt_probe(agent, pp, npz: Path) -> dict:
    """Our transformer on the peer's probe windows with its seed-0 parameters: the largest
    absolute differences from OSRL's own outputs (action mean, log-std, cost log-probs)."""
    z = np.load(npz)
    p0 = jax.tree_util.tree_map(lambda x: x[0], pp)
    mu, log_std, cost_logp, _ = agent.net.apply(
        p0["model"], z["probe/states"], z["probe/actions"], z["probe/returns"], z["probe/costs"],
        z["probe/time_steps"].astype(np.int32))
    return dict(mu=float(np.abs(np.asarray(mu) - z["probe/mu"]).max()),
                log_std=float(np.abs(np.asarray(log_std) - z["probe/log_std"]).max()),
                cost_logp=float(np.abs(np.asarray(cost_logp) - z["probe/cost_logp"]).max()),
                mu_scale=float(np.abs(z["probe/mu"]).max()))


def cdt_peer_config(cfg, task, ds, path: Path) -> Path:
    """The values the CDT peer trains with: our config's, augmentation constants in the data's
    return units (agents/cdt.py: augmentation_values)."""
    from r2pac_jax.agents.cdt import augmentation_values
    from r2pac_jax.io import atomic_write_json

    ret, _ = ds.episode_sums()
    aug = augmentation_values(cfg, ret)
    keys = ("seq_len", "embedding_dim", "num_layers", "num_heads", "attention_dropout",
            "residual_dropout", "embedding_dropout", "lr", "weight_decay", "clip_grad",
            "lr_warmup_steps", "reward_scale", "cost_scale", "batch_size", "loss_cost_weight",
            "loss_state_weight", "init_temperature", "episode_len", "cost_weight_base")
    values = {k: getattr(cfg, k) for k in keys}
    values.update(aug)
    atomic_write_json(path, values)
    return path


def _q_peer(task) -> list[str]:
    return ["--cost-limit", str(task.kappa), "--episode-len", str(task.episode_len)]


# algo -> (peer script, its extra arguments from the task, the params converter)
PEERS = {
    "cpq": ("osrl_q_peer.py", lambda task: ["--algo", "cpq", *_q_peer(task)], cpq_params),
    "bcq-lag": ("osrl_q_peer.py", lambda task: ["--algo", "bcq-lag", *_q_peer(task)],
                bcq_lag_params),
    "coptidice": ("osrl_q_peer.py", lambda task: ["--algo", "coptidice", *_q_peer(task)],
                  cpq_params),
    # FISOR's own code, in its own virtualenv (--peer-python) from a checkout (--fisor-src)
    "fisor": ("fisor_peer.py", lambda task: [
        "--episode-len", str(task.episode_len), "--r-max", str(task.r_max), "--r-min",
        str(task.r_min), "--cost-limit", str(task.kappa)], fisor_params),
    # OSRL's CDT: its values from our config (the peer's --config, written by `scores`)
    "cdt": ("osrl_cdt_peer.py", lambda task: [], cdt_params),
}


def peer(args, task, file: str, seed: int, out: Path) -> dict:
    done = out.parent / (out.name + ".json")
    if done.exists():
        return json.loads(done.read_text())
    out.parent.mkdir(parents=True, exist_ok=True)
    script, extra, _ = PEERS[args.algo]
    cmd = [args.peer_python, str(HERE / "peers" / script), file, *extra(task), "--seed",
           str(seed), "--steps", str(args.steps), "--out", str(out)]
    if args.algo == "fisor":
        cmd += ["--fisor-src", args.fisor_src]
    else:
        if args.algo == "cdt":
            cmd += ["--config", str(out.parent / "cdt_config.json")]
        cmd += ["--threads", "2"]
    env = dict(os.environ, WANDB_MODE="disabled", PYTHONNOUSERSITE="1")
    subprocess.run(cmd, check=True, env=env, capture_output=True, text=True)
    return json.loads(done.read_text())


def _stats(values) -> dict:
    v = [float(x) for x in values]
    return dict(mean=float(np.mean(v)), std=float(np.std(v)), per_seed=v)


def agree(a: dict, b: dict) -> bool:
    """The issue's rule: |mean a - mean b| <= 2 x the larger seed std."""
    return abs(a["mean"] - b["mean"]) <= 2 * max(a["std"], b["std"])


def scores(args, task, ds, file: str, out: Path) -> dict:
    from r2pac_jax.agents import make_agent
    from r2pac_jax.config import make_config
    from r2pac_jax.evaluate import LaneEvaluator, eval_keys, policy_of
    from r2pac_jax.lanes import Lanes
    from r2pac_jax.loop import Run

    seeds = list(range(args.seeds))
    over = dict(steps=args.steps, seeds=args.seeds, eval_episodes=args.episodes,
                eval_every=args.steps, checkpoint_every=args.steps, block_steps=args.block)
    if args.no_augmentation:
        over["augment_percent"] = 0.0
    cfg = make_config(task, args.algo, args.preset, over)  # paper: OSRL's settings
    if args.algo == "cdt":
        (out / "osrl").mkdir(parents=True, exist_ok=True)
        cdt_peer_config(cfg, task, ds, out / "osrl" / "cdt_config.json")

    def ours():
        t0 = time.time()
        res = Run(cfg, task, ds, out / "ours", Lanes.build(cfg, seeds), progress=False,
                  log=lambda m: None).run(resume=True)
        return dict(normalized_reward=res["normalized_reward"],
                    normalized_cost=res["normalized_cost"], wall_s=time.time() - t0,
                    train_steps_per_s=res["train_steps_per_s"])

    def theirs():
        infos = [peer(args, task, file, s, out / "osrl" / f"s{s}") for s in seeds]
        agent = make_agent(cfg, task.obs_dim, task.act_dim)
        files = [out / "osrl" / f"s{s}.npz" for s in seeds]
        if args.algo == "cdt":  # our targets (the data's best safe return, kappa) on both sides
            targets = (agent.target_return_of(task, ds), cfg.target_cost)
            pp = cdt_params(files, targets)
        else:
            pp = PEERS[args.algo][2](files)
        ev = LaneEvaluator(policy_of(agent), task, args.episodes)(pp, eval_keys(seeds, cfg.total_steps))
        res = dict(normalized_reward=_stats(ev["normalized_reward"]),
                   normalized_cost=_stats(ev["normalized_cost"]),
                   train_steps_per_s=[i["steps_per_s"] for i in infos],
                   curves=[i["curve"] for i in infos])
        if args.algo == "fisor":
            res["probe_max_abs_diff"] = fisor_probe(agent, pp, out / "osrl" / "s0.npz")
        if args.algo == "cdt":
            res["cdt_probe_max_abs_diff"] = cdt_probe(agent, pp, out / "osrl" / "s0.npz")
        return res

    mine = _json(out / "ours.json", ours)
    osrl = _json(out / "osrl.json", theirs)
    return dict(ours=mine, osrl=osrl,
                agree=dict(reward=agree(mine["normalized_reward"], osrl["normalized_reward"]),
                           cost=agree(mine["normalized_cost"], osrl["normalized_cost"])))


def write_table(s: dict, out: Path) -> str:
    from r2pac_jax.io import atomic_write_text

    them = "FISOR's code" if s["algo"] == "fisor" else "OSRL"
    lines = [f"{them} {s['algo']} vs r2pac-jax `{s['algo']}` on {s['task']} "
             f"({Path(s['dataset']).name}); our `{s.get('preset', 'paper')}` preset's values "
             f"on both sides, {s['steps']} gradient steps each side, "
             f"{s['seeds']} seeds, {s['episodes']} episodes per seed in our environment; "
             f"{s['machine']['cpus']} CPUs, jax {s['machine']['jax']}, {s['machine']['date']}", ""]
    sp, sc = s.get("speed"), s.get("scores")
    if sp and sc:
        theirs = float(np.median(sc["osrl"]["train_steps_per_s"]))
        lines += ["| trainer | steps/s | seed-steps/s | vs OSRL |", "|---|---|---|---|",
                  f"| {them} (2 threads, bulk batches; median of the seeds' runs) | "
                  f"{theirs:.1f} | {theirs:.1f} | 1.00 |"]
        for r in sp["ours"]:
            lines.append(f"| ours, {r['lanes']} seed(s) vmapped (compile {r['compile_s']:.1f} s) "
                         f"| {r['steps_per_s']:.1f} | {r['seed_steps_per_s']:.1f} | "
                         f"{r['seed_steps_per_s'] / theirs:.2f} |")
        lines.append("")
    if sc:
        o, m = sc["osrl"], sc["ours"]

        def f(x):
            return f"{x['mean']:.2f} ± {x['std']:.2f}"

        if "cdt_probe_max_abs_diff" in o:
            d = o["cdt_probe_max_abs_diff"]
            lines += [f"Our transformer on OSRL's parameters, 32 fixed windows: max |diff| "
                      f"action mean {d['mu']:.1e} (outputs up to {d['mu_scale']:.2f}), log-std "
                      f"{d['log_std']:.1e}, cost log-probs {d['cost_logp']:.1e}.", ""]
        if "probe_max_abs_diff" in o:
            d = o["probe_max_abs_diff"]
            lines += [f"Our networks on FISOR's parameters, 64 fixed inputs: max |diff| eps "
                      f"{d['eps']:.1e} (outputs up to {d['eps_scale']:.2f}), Q_h {d['qh']:.1e}.",
                      ""]
        lines += ["| side | reward | cost | cost per seed |", "|---|---|---|---|",
                  f"| {them} | {f(o['normalized_reward'])} | {f(o['normalized_cost'])} | "
                  f"{' '.join(f'{x:.2f}' for x in o['normalized_cost']['per_seed'])} |",
                  f"| ours | {f(m['normalized_reward'])} | {f(m['normalized_cost'])} | "
                  f"{' '.join(f'{x:.2f}' for x in m['normalized_cost']['per_seed'])} |", "",
                  f"Agreement (|mean diff| <= 2 x larger std): reward "
                  f"{'yes' if sc['agree']['reward'] else 'NO'}, cost "
                  f"{'yes' if sc['agree']['cost'] else 'NO'}."]
    text = "\n".join(lines)
    atomic_write_text(out / "table.md", text + "\n")
    return text


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--algo", choices=sorted(PEERS), required=True)
    ap.add_argument("--dataset", required=True, help="a DSRL-format file (its name is captioned)")
    ap.add_argument("--task", default=None, help="default: read off the file's name")
    ap.add_argument("--osrl-venv", default=str(HERE.parent.parent / "osrl-venv" / "venv"))
    ap.add_argument("--fisor-venv", default=str(HERE.parent.parent / "fisor-venv"),
                    help="FISOR's side virtualenv (its jax; how to make it: benchmarks/RESULTS.md)")
    ap.add_argument("--fisor-src", default=str(HERE.parent.parent / "fisor-src"),
                    help="a checkout of FISOR (its jaxrl5 package is imported from there)")
    ap.add_argument("--preset", default="paper", choices=["paper", "quick"],
                    help="our preset, whose values both sides use (paper: the original's)")
    ap.add_argument("--no-augmentation", action="store_true",
                    help="cdt: no Pareto augmentation on either side (OSRL's fails on data "
                         "whose filtered Pareto frontier is one episode: polyfit on one point)")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--steps", type=int, default=3000)
    ap.add_argument("--block", type=int, default=500, help="our compiled block (steps)")
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--out", default="runs/osrl_baselines")
    args = ap.parse_args(argv)
    venv = args.fisor_venv if args.algo == "fisor" else args.osrl_venv
    args.peer_python = str(Path(venv) / "bin" / "python")
    if not Path(args.peer_python).exists():
        how = ("the FISOR peer recipe in benchmarks/RESULTS.md" if args.algo == "fisor"
               else f"bash benchmarks/peers/install_osrl.sh {venv}")
        print(f"error: no peer virtualenv at {venv}; make it with {how}", file=sys.stderr)
        return 2
    if args.steps % args.block:
        print(f"error: --steps {args.steps} must be a multiple of --block {args.block}",
              file=sys.stderr)
        return 2
    from r2pac_jax.data import load_task_dataset
    from r2pac_jax.data.checks import file_task
    from r2pac_jax.tasks import get_task

    name = args.task or file_task(args.dataset)
    if name is None:
        print(f"error: cannot tell the task from {args.dataset}; pass --task", file=sys.stderr)
        return 2
    task = get_task(name)
    ds = load_task_dataset(task, args.dataset, announce=print)
    out = Path(args.out) / (f"{args.algo}-{task.name}"
                            + ("" if args.preset == "paper" else f"-{args.preset}")
                            + ("-noaug" if args.no_augmentation else ""))
    if args.no_augmentation and args.algo != "cdt":
        print("error: --no-augmentation is for --algo cdt", file=sys.stderr)
        return 2
    out.mkdir(parents=True, exist_ok=True)
    summary = dict(algo=args.algo, preset=args.preset, augmentation=not args.no_augmentation,
                   task=task.name, dataset=ds.source,
                   seeds=args.seeds,
                   steps=args.steps, episodes=args.episodes, machine=machine())
    summary["scores"] = scores(args, task, ds, ds.source, out)
    summary["speed"] = _json(out / "speed.json", lambda: dict(
        ours=[algo_speed(task, ds, args.algo, n, block_steps=args.block, preset=args.preset,
                         over=dict(augment_percent=0.0) if args.no_augmentation else None)
              for n in (1, args.seeds)], machine=machine()))
    from r2pac_jax.io import atomic_write_json

    atomic_write_json(out / "summary.json", summary)
    print(write_table(summary, out))
    return 0


if __name__ == "__main__":
    sys.exit(main())

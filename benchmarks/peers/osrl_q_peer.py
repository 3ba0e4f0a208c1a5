"""OSRL's CPQ, BCQ-L or COptiDICE on one of our DSRL-format files. Runs in OSRL's side
virtualenv only.

    $OSRL_VENV/bin/python benchmarks/peers/osrl_q_peer.py FILE.hdf5 --algo cpq|bcq-lag|coptidice \
        --cost-limit KAPPA --episode-len L --seed S --steps N [--threads 2] --out OUT

Wires osrl-lib 0.1.0's model and trainer (`CPQ` / `CPQTrainer`, `BCQL` / `BCQLTrainer`;
`COptiDICE` / `COptiDICETrainer`; `train_one_step`) as OSRL's examples/train/train_*.py do,
with examples/configs/*_configs.py's values at commit 03a4586 (CPQ: actor 1e-4, critics 1e-3,
alpha 1e-4, VAE 1e-3, beta 0.5, qc_scalar 1.5; BCQ-L: all 1e-3, phi 0.05, lmbda 0.75, beta 0.5,
PID 0.1/0.003/0.001; both: VAE 400, 10 samples, tau 0.005; COptiDICE: all 1e-4, soft-chi^2,
alpha 0.5, cost_ub_epsilon 0.01, the data's initial-state share and stds as its
TransitionDataset(state_init=True).get_dataset_states gives them; all: reward scale 0.1, cost
scale 1, batch 512, 2 x 256 networks, gamma 0.99, 2 + 2 critics), and
`osrl.common.exp_util.seed_all`. Batches: uniform with replacement over all transitions, drawn
512 at a time with numpy (OSRL's `TransitionDataset` draws the same distribution one row at a
time; done = terminal or timeout as there), so that only the update is timed.

No evaluation runs here. Writes OUT.json (steps/s after a warm-up, sizes, losses) and OUT.npz
(Linear weights W [out, in] and biases: CPQ's actor trunk in layer order then its mu head as
W{i}/b{i}; BCQ-L's perturbation actor as W{i}/b{i} and its VAE's layers as vae_<name>_W/_b).
"""
from __future__ import annotations

import argparse
import json
import os
import time

os.environ.setdefault("WANDB_MODE", "disabled")

import numpy as np  # noqa: E402
import torch  # noqa: E402
from peer_io import read_dsrl  # noqa: E402



def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("file")
    ap.add_argument("--algo", choices=["cpq", "bcq-lag", "coptidice"], required=True)
    ap.add_argument("--cost-limit", type=float, required=True)
    ap.add_argument("--episode-len", type=int, required=True)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--steps", type=int, default=100_000)
    ap.add_argument("--warmup", type=int, default=50)
    ap.add_argument("--batch-size", type=int, default=512)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", required=True, help="output path without extension")
    args = ap.parse_args()

    from fsrl.utils import DummyLogger
    from osrl.algorithms import (BCQL, CPQ, BCQLTrainer, COptiDICE, COptiDICETrainer,
                                 CPQTrainer)
    from osrl.common.exp_util import seed_all

    seed_all(args.seed)
    torch.set_num_threads(args.threads)
    data = read_dsrl(args.file, np.float32)
    n = int(data["observations"].shape[0])
    obs_dim, act_dim = data["observations"].shape[1], data["actions"].shape[1]
    t = {k: torch.as_tensor(v) for k, v in data.items()}
    done = torch.logical_or(t["terminals"] > 0, t["timeouts"] > 0).float()
    is_init = torch.cat([torch.ones(1), done[:-1]])  # TransitionDataset(state_init=True)
    base = dict(state_dim=obs_dim, action_dim=act_dim, max_action=1.0,
                a_hidden_sizes=[256, 256], c_hidden_sizes=[256, 256], gamma=0.99,
                cost_limit=args.cost_limit, episode_len=args.episode_len, device="cpu")
    common = dict(base, vae_hidden_sizes=400, sample_action_num=10, tau=0.005, beta=0.5,
                  num_q=2, num_qc=2)
    if args.algo == "coptidice":
        model = COptiDICE(f_type="softchi", init_state_propotion=float(is_init.mean()),
                          observations_std=data["observations"].std(0, keepdims=True),
                          actions_std=data["actions"].std(0, keepdims=True), alpha=0.5,
                          cost_ub_epsilon=0.01, num_nu=2, num_chi=2, **base)
        trainer = COptiDICETrainer(model, env=None, logger=DummyLogger(), actor_lr=1e-4,
                                   critic_lr=1e-4, scalar_lr=1e-4, reward_scale=0.1,
                                   cost_scale=1.0, device="cpu")
    elif args.algo == "cpq":
        model = CPQ(qc_scalar=1.5, **common)
        trainer = CPQTrainer(model, env=None, logger=DummyLogger(), actor_lr=1e-4,
                             critic_lr=1e-3, alpha_lr=1e-4, vae_lr=1e-3, reward_scale=0.1,
                             cost_scale=1.0, device="cpu")
    else:
        model = BCQL(phi=0.05, lmbda=0.75, PID=[0.1, 0.003, 0.001], **common)
        trainer = BCQLTrainer(model, env=None, logger=DummyLogger(), actor_lr=1e-3,
                              critic_lr=1e-3, vae_lr=1e-3, reward_scale=0.1, cost_scale=1.0,
                              device="cpu")
    rewards, costs = t["rewards"] * 0.1, t["costs"] * 1.0
    rng = np.random.default_rng(args.seed)

    losses = []
    t_start = None
    for step in range(args.steps):
        if step == args.warmup:
            t_start = time.perf_counter()
        i = torch.as_tensor(rng.integers(0, n, args.batch_size))
        b = (t["observations"][i], t["next_observations"][i], t["actions"][i], rewards[i],
             costs[i], done[i])
        if args.algo == "coptidice":
            stats = model.update(b + (is_init[i],))
        else:
            trainer.train_one_step(*b)
        if step % 1000 == 0 or step == args.steps - 1:
            if args.algo == "coptidice":
                losses.append((step, stats["loss/nu_loss"], stats["loss/chi_loss"],
                               stats["loss/lmbda"]))
                continue
            with torch.no_grad():
                q = model.critic.predict(t["observations"][i], t["actions"][i])[0]
                qc = model.cost_critic.predict(t["observations"][i], t["actions"][i])[0]
            dual = (float(model.log_alpha.exp()) if args.algo == "cpq"
                    else float(model.controller.error_integral))
            losses.append((step, float(q.mean()), float(qc.mean()), dual))
    wall = time.perf_counter() - t_start if t_start is not None else float("nan")
    timed = args.steps - args.warmup
    if args.algo in ("cpq", "coptidice"):
        layers = [m for m in model.actor.net if isinstance(m, torch.nn.Linear)]
        layers.append(model.actor.mu_layer)
    else:
        layers = [m for m in model.actor.pi if isinstance(m, torch.nn.Linear)]
    arrays = {f"W{i}": m.weight.detach().numpy() for i, m in enumerate(layers)}
    arrays.update({f"b{i}": m.bias.detach().numpy() for i, m in enumerate(layers)})
    if args.algo == "bcq-lag":
        for name in ("e1", "e2", "mean", "log_std", "d1", "d2", "d3"):
            m = getattr(model.vae, name)
            arrays[f"vae_{name}_W"] = m.weight.detach().numpy()
            arrays[f"vae_{name}_b"] = m.bias.detach().numpy()
    np.savez(args.out + ".npz", **arrays)
    info = dict(algo=args.algo, seed=args.seed, steps=args.steps, warmup=args.warmup,
                timed_steps=timed, wall_s=wall, steps_per_s=timed / wall if wall > 0 else None,
                threads=args.threads, torch=torch.__version__, batch_size=args.batch_size,
                transitions=n,
                curve=losses)  # (step, Q_r, Q_c, alpha | PID integral), COptiDICE: nu, chi losses, lambda
    with open(args.out + ".json", "w") as f:
        json.dump(info, f, indent=1)
    print(json.dumps({k: v for k, v in info.items() if k != "curve"}))


if __name__ == "__main__":
    main()

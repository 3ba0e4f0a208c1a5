"""OSRL's BC on one of our DSRL-format files. Runs in OSRL's side virtualenv, never in ours.

    $OSRL_VENV/bin/python benchmarks/peers/osrl_bc_peer.py FILE.hdf5 --mode all|safe \
        --cost-limit KAPPA --seed S --steps N [--loader osrl|bulk] [--threads 2] --out OUT

Wires osrl-lib 0.1.0's own pieces as OSRL's examples/train/train_bc.py does: `process_bc_dataset`
(cost limit, gamma 1: BC-Safe keeps the episodes with cost <= kappa), the `BC` model (2 x 256 ReLU,
tanh output) with `BCTrainer`'s optimiser and its update `BC.actor_loss` (MSE, Adam 1e-3; what
`BCTrainer.train_one_step` calls, less the no-op logger), batch 512, and
`osrl.common.exp_util.seed_all`. Batches come from

  - `--loader osrl`: OSRL's own `TransitionDataset` in a torch `DataLoader` (workers 0: the two
    cores run torch's two threads), one sample drawn at a time as in OSRL;
  - `--loader bulk`: the same distribution (uniform with replacement over the kept transitions)
    drawn 512 at a time with numpy, so that only the update is timed.

No evaluation runs here. Writes OUT.json (steps/s after a warm-up, loader, threads, sizes) and
OUT.npz (the actor's Linear weights W [out, in] and biases, in layer order).
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
    ap.add_argument("--mode", default="all", choices=["all", "safe"])
    ap.add_argument("--cost-limit", type=float, required=True)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--steps", type=int, default=100_000)
    ap.add_argument("--warmup", type=int, default=200)
    ap.add_argument("--batch-size", type=int, default=512)
    ap.add_argument("--loader", default="bulk", choices=["osrl", "bulk"])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", required=True, help="output path without extension")
    args = ap.parse_args()

    from osrl.algorithms import BC, BCTrainer
    from osrl.common import TransitionDataset
    from osrl.common.dataset import process_bc_dataset
    from osrl.common.exp_util import seed_all

    seed_all(args.seed)
    torch.set_num_threads(args.threads)
    # torch's Linear wants float32; OSRL reads the flags as 0/1 floats
    data = read_dsrl(args.file, np.float32)
    n_all = int(data["observations"].shape[0])
    process_bc_dataset(data, args.cost_limit, 1.0, args.mode)
    n_kept = int(data["observations"].shape[0])
    obs_dim, act_dim = data["observations"].shape[1], data["actions"].shape[1]
    model = BC(state_dim=obs_dim, action_dim=act_dim, max_action=1.0, a_hidden_sizes=[256, 256],
               episode_len=1000, device="cpu")
    # BCTrainer sets up the model's Adam optimiser (its only role here: no env, no evaluation)
    BCTrainer(model, env=None, actor_lr=1e-3, bc_mode=args.mode, cost_limit=args.cost_limit,
              device="cpu")

    if args.loader == "osrl":
        from torch.utils.data import DataLoader

        it = iter(DataLoader(TransitionDataset(data), batch_size=args.batch_size,
                             pin_memory=False, num_workers=0))

        def batch():
            b = next(it)
            return b[0], b[2]
    else:
        obs_t = torch.as_tensor(data["observations"], dtype=torch.float32)
        act_t = torch.as_tensor(data["actions"], dtype=torch.float32)
        rng = np.random.default_rng(args.seed)

        def batch():
            idx = torch.as_tensor(rng.integers(0, n_kept, args.batch_size))
            return obs_t[idx], act_t[idx]

    losses = []
    t_start = None
    for step in range(args.steps):
        if step == args.warmup:
            t_start = time.perf_counter()
        o, a = batch()
        loss, _ = model.actor_loss(o, a)
        if step % 1000 == 0 or step == args.steps - 1:
            losses.append((step, float(loss.item())))
    wall = time.perf_counter() - t_start if t_start is not None else float("nan")
    timed = args.steps - args.warmup
    layers = [m for m in model.actor.pi if isinstance(m, torch.nn.Linear)]
    np.savez(args.out + ".npz", **{f"W{i}": m.weight.detach().numpy() for i, m in
                                   enumerate(layers)},
             **{f"b{i}": m.bias.detach().numpy() for i, m in enumerate(layers)})
    info = dict(mode=args.mode, seed=args.seed, steps=args.steps, warmup=args.warmup,
                timed_steps=timed, wall_s=wall, steps_per_s=timed / wall if wall > 0 else None,
                loader=args.loader, threads=args.threads, torch=torch.__version__,
                batch_size=args.batch_size, transitions=n_all, kept=n_kept, losses=losses)
    with open(args.out + ".json", "w") as f:
        json.dump(info, f, indent=1)
    print(json.dumps({k: v for k, v in info.items() if k != "losses"}))


if __name__ == "__main__":
    main()

"""OSRL's CDT on one of our DSRL-format files. Runs in OSRL's side virtualenv only (with
oapackage, which OSRL's augmentation needs).

    $OSRL_VENV/bin/python benchmarks/peers/osrl_cdt_peer.py FILE.hdf5 --config CFG.json \
        --seed S --steps N [--threads 2] --out OUT

Wires osrl-lib 0.1.0's `CDT` / `CDTTrainer` and `SequenceDataset` as OSRL's
examples/train/train_cdt.py does, with the values in CFG.json (written by
benchmarks/osrl_baselines.py from our config, so that both sides train the same network on the
same batches' distribution, with the same augmentation constants): seq_len, embedding_dim,
num_layers, num_heads, the three dropouts, lr, weight_decay, clip_grad, lr_warmup_steps,
reward_scale, cost_scale, batch_size, loss_cost_weight, loss_state_weight, init_temperature,
episode_len, cost_weight_base (the sampling transform base - C), and the augmentation's deg,
max_reward, max_rew_decrease, min_reward, beta, augment_percent in the data's return units.
Batches come from OSRL's own `SequenceDataset` iterator (its sampler, augmentation and
padding), stacked as its DataLoader would; only `train_one_step` is timed.

No evaluation runs here. Writes OUT.json (steps/s after a warm-up, losses) and OUT.npz: the
model's state_dict (names as PyTorch gives them) and a probe: the model's outputs in eval mode
on 32 fixed windows (probe/states, probe/actions, probe/returns, probe/costs, probe/time_steps
-> probe/mu, probe/log_std, probe/cost_logp, probe/state_pred).
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
    ap.add_argument("--config", required=True, help="JSON of the values listed above")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--warmup", type=int, default=20)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", required=True, help="output path without extension")
    args = ap.parse_args()
    c = json.loads(open(args.config).read())

    from fsrl.utils import DummyLogger
    from osrl.algorithms import CDT, CDTTrainer
    from osrl.common.dataset import SequenceDataset
    from osrl.common.exp_util import seed_all

    seed_all(args.seed)
    torch.set_num_threads(args.threads)
    data = read_dsrl(args.file)
    obs_dim, act_dim = data["observations"].shape[1], data["actions"].shape[1]
    model = CDT(state_dim=obs_dim, action_dim=act_dim, max_action=1.0,
                embedding_dim=c["embedding_dim"], seq_len=c["seq_len"],
                episode_len=c["episode_len"], num_layers=c["num_layers"],
                num_heads=c["num_heads"], attention_dropout=c["attention_dropout"],
                residual_dropout=c["residual_dropout"],
                embedding_dropout=c["embedding_dropout"], time_emb=True, use_rew=True,
                use_cost=True, cost_transform=True, add_cost_feat=False, mul_cost_feat=False,
                cat_cost_feat=False, action_head_layers=1, cost_prefix=False, stochastic=True,
                init_temperature=c["init_temperature"], target_entropy=-act_dim)
    trainer = CDTTrainer(model, env=None, logger=DummyLogger(), learning_rate=c["lr"],
                         weight_decay=c["weight_decay"], betas=(0.9, 0.999),
                         clip_grad=c["clip_grad"], lr_warmup_steps=c["lr_warmup_steps"],
                         reward_scale=c["reward_scale"], cost_scale=c["cost_scale"],
                         loss_cost_weight=c["loss_cost_weight"],
                         loss_state_weight=c["loss_state_weight"], cost_reverse=False,
                         no_entropy=False, device="cpu")
    base = c["cost_weight_base"]
    dataset = SequenceDataset(
        data, seq_len=c["seq_len"], reward_scale=c["reward_scale"], cost_scale=c["cost_scale"],
        deg=c["deg"], pf_sample=False, max_rew_decrease=c["max_rew_decrease"], beta=c["beta"],
        augment_percent=c["augment_percent"], cost_reverse=False, max_reward=c["max_reward"],
        min_reward=c["min_reward"], pf_only=False, cost_sample=True,
        cost_transform=lambda x: base - x, start_sampling=False)
    it = iter(dataset)

    def batch():
        items = [next(it) for _ in range(c["batch_size"])]
        return [torch.as_tensor(np.stack([x[j] for x in items])) for j in range(8)]

    losses = []
    timed = 0.0
    for step in range(args.steps):
        b = batch()
        t0 = time.perf_counter()
        trainer.train_one_step(*b)
        if step >= args.warmup:
            timed += time.perf_counter() - t0
        if step % 200 == 0 or step == args.steps - 1:
            with torch.no_grad():
                model.eval()
                out = model(*b[:5], None, b[6])
                model.train()
                mask = b[5] > 0
                nll = -out[0].log_prob(b[1])[mask].mean()
            losses.append((step, float(nll), float(model.temperature())))

    # the probe: fixed windows from the data, the model in eval mode
    rng = np.random.default_rng(1234)
    k, n = c["seq_len"], 32
    rows = rng.integers(0, data["observations"].shape[0] - k, n)
    probe = {"states": np.stack([data["observations"][r:r + k] for r in rows]).astype(np.float32),
             "actions": np.stack([data["actions"][r:r + k] for r in rows]).astype(np.float32),
             "returns": rng.uniform(0, 50, (n, k)).astype(np.float32),
             "costs": rng.uniform(0, 40, (n, k)).astype(np.float32),
             "time_steps": (rng.integers(0, c["episode_len"], n)[:, None]
                            + np.arange(k)[None]).astype(np.int64)}
    model.eval()
    with torch.no_grad():
        dist, cost_logp, state_pred = model(*(torch.as_tensor(probe[x]) for x in (
            "states", "actions", "returns", "costs", "time_steps")), None, None)
    arrays = {f"sd/{name}": v.detach().numpy() for name, v in model.state_dict().items()}
    arrays.update({f"probe/{x}": v for x, v in probe.items()})
    arrays.update({"probe/mu": dist.mean.numpy(), "probe/log_std": dist.stddev.log().numpy(),
                   "probe/cost_logp": cost_logp.numpy(), "probe/state_pred": state_pred.numpy()})
    np.savez(args.out + ".npz", **arrays)
    n_timed = args.steps - args.warmup
    info = dict(algo="cdt", seed=args.seed, steps=args.steps, warmup=args.warmup,
                timed_steps=n_timed, wall_s=timed, steps_per_s=n_timed / timed if timed else None,
                threads=args.threads, torch=torch.__version__, batch_size=c["batch_size"],
                episodes=len(dataset.original_data), augmented=len(dataset.aug_data),
                curve=losses)  # (step, action NLL in eval mode, temperature)
    with open(args.out + ".json", "w") as f:
        json.dump(info, f, indent=1)
    print(json.dumps({k: v for k, v in info.items() if k != "curve"}))


if __name__ == "__main__":
    main()

"""FISOR's own code (ZhengYinan-AIR/FISOR) on one of our DSRL-format files, in its own side
virtualenv (its jax, not ours); never a dependency of the project.

    $FISOR_VENV/bin/python benchmarks/peers/fisor_peer.py FILE.hdf5 --fisor-src DIR \
        --episode-len L --r-max R --r-min R --cost-limit KAPPA --seed S --steps N \
        [--batch-size 2048] --out OUT

DIR is a checkout of FISOR (e.g. `git archive` of commit 2097e8b): its `jaxrl5` package is
imported from there. The data are prepared as its DSRLDataset and train_offline.py do (done =
terminal or timeout, masks = 1 - done, stage cost +25 / -1, actions clipped to 1 - 1e-5,
rewards x L / (R_max - R_min)); the agent is `FISOR.create` with configs/train_config.py's
"fisor" values; each step is `agent.update` on a batch drawn uniformly with replacement with
numpy. Writes OUT.json (steps/s after a warm-up) and OUT.npz (the EMA actor's and the target
Q_h ensemble's parameters, flattened "actor/..." and "qh/..." keys, in FISOR's own module
names, which r2pac_jax's FISOR networks share; and "probe/..." : both networks' outputs on 64
fixed inputs, for checking the port).
"""
from __future__ import annotations

import argparse
import json
import sys
import time



class _Box:
    """What FISOR.create reads of a gym space: shape and sample() (a dummy input for init)."""

    def __init__(self, dim, low, high):
        import numpy as np

        self.shape = (dim,)
        self._low, self._high = low, high
        self._rng = np.random.default_rng(0)

    def sample(self):
        return self._rng.uniform(self._low, self._high, self.shape).astype("float32")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("file")
    ap.add_argument("--fisor-src", required=True)
    ap.add_argument("--episode-len", type=int, required=True)
    ap.add_argument("--r-max", type=float, required=True)
    ap.add_argument("--r-min", type=float, required=True)
    ap.add_argument("--cost-limit", type=float, default=10.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--warmup", type=int, default=20)
    ap.add_argument("--batch-size", type=int, default=2048)
    ap.add_argument("--out", required=True)
    args = ap.parse_args()
    sys.path.insert(0, args.fisor_src)

    import jax
    import numpy as np
    from flax import traverse_util

    from jaxrl5.agents.fisor.fisor import FISOR

    from peer_io import read_dsrl

    d = read_dsrl(args.file)
    done = np.logical_or(d["terminals"], d["timeouts"]).astype(np.float32)
    data = dict(observations=d["observations"].astype(np.float32),
                next_observations=d["next_observations"].astype(np.float32),
                actions=np.clip(d["actions"], -1 + 1e-5, 1 - 1e-5).astype(np.float32),
                rewards=(d["rewards"] / (args.r_max - args.r_min) * args.episode_len)
                .astype(np.float32),
                costs=np.where(d["costs"] > 0, 25.0, -1.0).astype(np.float32),
                masks=1.0 - done)
    n, obs_dim = data["observations"].shape
    act_dim = data["actions"].shape[1]
    kw = dict(cost_limit=args.cost_limit, actor_lr=3e-4, critic_lr=3e-4, value_lr=3e-4,
              cost_temperature=5, reward_temperature=3, T=5, N=16, M=0, clip_sampler=True,
              actor_dropout_rate=0.1, actor_num_blocks=3, actor_weight_decay=None,
              decay_steps=int(3e6), actor_layer_norm=True, value_layer_norm=False,
              actor_tau=0.001, actor_architecture="ln_resnet", critic_objective="expectile",
              critic_hyperparam=0.9, cost_critic_hyperparam=0.9, critic_type="hj", cost_ub=150,
              beta_schedule="vp", actor_objective="feasibility", sampling_method="ddpm",
              extract_method="minqc", env_max_steps=args.episode_len)
    agent = FISOR.create(args.seed, _Box(obs_dim, -1, 1), _Box(act_dim, -1, 1), **kw)
    rng = np.random.default_rng(args.seed)
    t_start = None
    for step in range(args.steps):
        if step == args.warmup:
            jax.block_until_ready(agent.score_model.params)
            t_start = time.perf_counter()
        i = rng.integers(0, n, args.batch_size)
        agent, info = agent.update({k: v[i] for k, v in data.items()})
    jax.block_until_ready(agent.score_model.params)
    wall = time.perf_counter() - t_start if t_start is not None else float("nan")
    flat = {}
    for prefix, tree in (("actor", agent.target_score_model.params),
                         ("qh", agent.safe_target_critic.params)):
        for k, v in traverse_util.flatten_dict(jax.device_get(tree)).items():
            flat[prefix + "/" + "/".join(k)] = np.asarray(v)
    # a probe of the exported networks on fixed inputs: r2pac_jax's networks given these
    # parameters must give the same outputs (osrl_baselines.py reports the difference)
    pr = np.random.default_rng(123)
    p_obs = data["observations"][:64]
    p_x = pr.uniform(-1, 1, (64, act_dim)).astype(np.float32)
    p_t = pr.integers(0, 5, (64, 1)).astype(np.float32)
    flat["probe/obs"], flat["probe/x"], flat["probe/t"] = p_obs, p_x, p_t
    flat["probe/eps"] = np.asarray(agent.target_score_model.apply_fn(
        {"params": agent.target_score_model.params}, p_obs, p_x, p_t, training=False))
    flat["probe/qh"] = np.asarray(agent.safe_target_critic.apply_fn(
        {"params": agent.safe_target_critic.params}, p_obs, p_x))
    np.savez(args.out + ".npz", **flat)
    timed = args.steps - args.warmup
    out = dict(algo="fisor", seed=args.seed, steps=args.steps, warmup=args.warmup,
               timed_steps=timed, wall_s=wall, steps_per_s=timed / wall if wall > 0 else None,
               batch_size=args.batch_size, jax=jax.__version__, transitions=int(n),
               last={k: float(v) for k, v in info.items()}, curve=[])
    with open(args.out + ".json", "w") as f:
        json.dump(out, f, indent=1)
    print(json.dumps({k: v for k, v in out.items() if k != "last"}))


if __name__ == "__main__":
    main()

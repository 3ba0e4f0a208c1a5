"""Search open-loop periodic gaits for the velocity robots (cross-entropy method).

A gait: a_j(t) = clip(b_j + A_j sin(2 pi f t + phi_j) + (K obs)_j, -1, 1) for every joint j
(shared frequency f); K [J, obs_dim] is a linear feedback on the observation, searched only
with --feedback (Hopper, Walker2d fall over without one) and zero otherwise. The score is the forward speed over `horizon` control steps (root x displacement
/ time; an episode that ends early scores its displacement until then, minus 1), minus
`--penalty` times the fraction of steps with cost (a penalised search gives safe gaits). The best
gaits found are pasted into r2pac_jax/data/factory/velocity.py (GAITS); this script is the
record of how they were found:

    python experiments/data_factory/gait_search.py --task HalfCheetahVelocity --iters 12
"""
from __future__ import annotations

import argparse
import json
import time

import jax
import numpy as np

from r2pac_jax.tasks import get_task


def gait_actions(params: np.ndarray, t: float, act_dim: int, obs=None) -> np.ndarray:
    """params [P, 1 + 3 J (+ J obs_dim)] = (f, A[J], phi[J], b[J], K) -> actions [P, J] at
    time t (s), given observations obs [P, obs_dim] when K is present."""
    J = act_dim
    f = params[:, :1]
    amp, phi, bias = (params[:, 1 + i * J:1 + (i + 1) * J] for i in range(3))
    a = bias + amp * np.sin(2 * np.pi * f * t + phi)
    if params.shape[1] > 1 + 3 * J:
        K = params[:, 1 + 3 * J:].reshape(params.shape[0], J, -1)
        a = a + np.einsum("pjo,po->pj", K, obs)
    return np.clip(a, -1.0, 1.0).astype(np.float32)


def score(env, params: np.ndarray, horizon: int, dt: float, seed: int,
          penalty: float = 0.0) -> np.ndarray:
    n = params.shape[0]
    state = env.reset_batch(jax.random.split(jax.random.PRNGKey(seed), n))
    x0 = np.array(state.physics["qpos"][:, 0])
    alive = np.ones(n, bool)
    x_end = x0.copy()
    cost = np.zeros(n)
    for k in range(horizon):
        state = env.step_batch(state, gait_actions(params, k * dt, env.act_dim,
                                                   np.asarray(state.obs)))
        x = np.asarray(state.physics["qpos"][:, 0])
        x_end = np.where(alive, x, x_end)
        cost += alive * np.asarray(state.cost)
        alive &= ~np.asarray(state.terminated)
    return (x_end - x0) / (horizon * dt) - (~alive) * 1.0 - penalty * cost / horizon


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--task", required=True)
    ap.add_argument("--iters", type=int, default=10)
    ap.add_argument("--pop", type=int, default=64)
    ap.add_argument("--elite", type=int, default=8)
    ap.add_argument("--horizon", type=int, default=200)
    ap.add_argument("--fmax", type=float, default=4.0)
    ap.add_argument("--amax", type=float, default=1.0,
                    help="largest amplitude (> 1: clipped, square-ish waves)")
    ap.add_argument("--init", type=str, default="",
                    help="JSON list of params to start from (a previous run's best)")
    ap.add_argument("--init-std", type=float, default=0.15,
                    help="starting std around --init, as a fraction of each range")
    ap.add_argument("--penalty", type=float, default=0.0,
                    help="score = speed - penalty * (fraction of steps with cost): a safe gait")
    ap.add_argument("--feedback", type=float, default=0.0,
                    help="search a linear feedback K with entries in +-this (0: none)")
    args = ap.parse_args()
    spec = get_task(args.task)
    env = spec.make_env(physics="mujoco")
    J = spec.act_dim
    dt = env.task.dt
    rng = np.random.default_rng(0)
    lo = np.concatenate([[0.3], np.zeros(J), np.zeros(J), -0.5 * np.ones(J)])
    hi = np.concatenate([[args.fmax], args.amax * np.ones(J), 2 * np.pi * np.ones(J),
                         0.5 * np.ones(J)])
    if args.feedback > 0:
        nk = J * spec.obs_dim
        lo = np.concatenate([lo, -args.feedback * np.ones(nk)])
        hi = np.concatenate([hi, args.feedback * np.ones(nk)])
    mean, std = (lo + hi) / 2, (hi - lo) / 2
    if args.init:
        mean = np.clip(np.asarray(json.loads(args.init), float), lo, hi)
        std = args.init_std * (hi - lo)
    best, best_s = None, -np.inf
    t0 = time.time()
    for it in range(args.iters):
        pop = np.clip(mean + std * rng.normal(size=(args.pop, mean.size)), lo, hi)
        if best is not None:
            pop[0] = best
        s = score(env, pop, args.horizon, dt, seed=it, penalty=args.penalty)
        order = np.argsort(-s)
        elite = pop[order[:args.elite]]
        mean, std = elite.mean(0), elite.std(0) + 0.02 * (hi - lo)
        if s[order[0]] > best_s:
            best, best_s = pop[order[0]].copy(), float(s[order[0]])
        print(f"iter {it} best {s[order[0]]:.3f} elite mean {s[order[:args.elite]].mean():.3f} "
              f"(overall best {best_s:.3f}, {time.time() - t0:.0f} s)", flush=True)
    print(json.dumps(dict(task=args.task, speed=best_s, params=np.round(best, 4).tolist())))


if __name__ == "__main__":
    main()

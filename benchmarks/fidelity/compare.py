"""Replay the reference's rollouts in our environments and measure the step-by-step errors.

    python benchmarks/fidelity/compare.py [--tasks AntVelocity,...] [--steps 100,1000]
        [--seeds 0,1,2] [--physics mujoco,mjx] [--ref-python PATH]

For every task and seed: run `reference_rollout.py` in the reference virtualenv (env var
R2PAC_SG_VENV, default .venv-safety-gymnasium; build it with
../shared/reference/install-safety-gymnasium.sh), start our env from the same qpos/qvel, apply
the same actions and report the maximum absolute error of observation, reward, cost and the
agreement of the terminal flags over the first N steps. Prints one JSON line per (task, backend,
horizon).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).parent


def reference_python() -> Path:
    venv = Path(os.environ.get("R2PAC_SG_VENV", ".venv-safety-gymnasium"))
    return venv / "bin" / "python"


def reference_rollout(gym_id: str, seed: int, steps: int, python: Path) -> dict:
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "ref.npz"
        subprocess.run([str(python), str(HERE / "reference_rollout.py"), gym_id, str(seed),
                        str(steps), str(out)], check=True, capture_output=True, timeout=900)
        with np.load(out) as z:
            return {k: z[k] for k in z.files}


def replay(task_name: str, ref: dict, physics: str) -> dict:
    """Our side: the same start state and actions; per-step arrays like the reference's."""
    import jax
    import jax.numpy as jnp

    from r2pac_jax.tasks import get_task

    env = get_task(task_name).make_env(physics=physics)
    T = ref["actions"].shape[0]
    out = {k: [] for k in ("obs", "reward", "cost", "terminated", "qpos", "qvel")}
    if physics == "mujoco":
        st = env.reset_batch(jax.random.split(jax.random.PRNGKey(0), 1))
        states = env.states_from_qpos_qvel(ref["qpos0"][None], ref["qvel0"][None])
        st = env.reset_to(states, st.info, st.key)
        for t in range(T):
            st = env.step_batch(st, ref["actions"][t][None])
            for k, v in (("obs", st.obs[0]), ("reward", st.reward[0]), ("cost", st.cost[0]),
                         ("terminated", st.terminated[0]), ("qpos", st.physics["qpos"][0]),
                         ("qvel", st.physics["qvel"][0])):
                out[k].append(np.asarray(v))
    else:
        from mujoco import mjx

        st = env.reset(jax.random.PRNGKey(0))
        data = st.physics.replace(qpos=jnp.asarray(ref["qpos0"], jnp.float32),
                                  qvel=jnp.asarray(ref["qvel0"], jnp.float32))
        st = st.replace(physics=mjx.forward(env.model, data))

        def body(s, a):
            s = env.step(s, a)
            return s, (s.obs, s.reward, s.cost, s.terminated, s.physics.qpos, s.physics.qvel)

        _, traj = jax.jit(lambda s, a: jax.lax.scan(body, s, a))(
            st, jnp.asarray(ref["actions"], jnp.float32))
        for k, v in zip(out, traj):
            out[k] = list(np.asarray(v))
    return {k: np.asarray(v) for k, v in out.items()}


def errors(ref: dict, ours: dict, horizon: int) -> dict:
    n = min(horizon, ref["actions"].shape[0])
    res = dict(steps=int(n))
    for k in ("obs", "reward", "cost", "qpos", "qvel"):
        res[f"max_err_{k}"] = float(np.max(np.abs(np.asarray(ours[k][:n], np.float64)
                                                  - np.asarray(ref[k][:n], np.float64))))
    res["terminated_agree"] = bool(np.array_equal(ours["terminated"][:n].astype(bool),
                                                  ref["terminated"][:n].astype(bool)))
    return res


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--tasks", default="AntVelocity,HalfCheetahVelocity,SwimmerVelocity,"
                                       "HopperVelocity,Walker2dVelocity")
    ap.add_argument("--steps", default="100,1000")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--physics", default="mujoco")
    ap.add_argument("--ref-python", default=None)
    args = ap.parse_args()
    from r2pac_jax.tasks import get_task

    python = Path(args.ref_python) if args.ref_python else reference_python()
    if not python.exists():
        sys.exit(f"reference python {python} not found: build the reference virtualenv with "
                 "../shared/reference/install-safety-gymnasium.sh and set R2PAC_SG_VENV")
    horizons = [int(h) for h in args.steps.split(",")]
    for name in args.tasks.split(","):
        refs = [reference_rollout(get_task(name).gym_id, int(s), max(horizons), python)
                for s in args.seeds.split(",")]
        for physics in args.physics.split(","):
            ours = [replay(name, r, physics) for r in refs]
            for h in horizons:
                per = [errors(r, o, h) for r, o in zip(refs, ours)]
                row = dict(task=name, physics=physics, horizon=h, seeds=args.seeds,
                           steps=[p["steps"] for p in per],
                           terminated_agree=all(p["terminated_agree"] for p in per))
                for k in per[0]:
                    if k.startswith("max_err"):
                        row[k] = max(p[k] for p in per)
                print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()

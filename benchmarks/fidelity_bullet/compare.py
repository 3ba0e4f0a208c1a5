"""Our `bullet` backend against the original Bullet-Safety-Gym 1.4.0: the figures of
benchmarks/FIDELITY.md ("Bullet tasks").

    python benchmarks/fidelity_bullet/compare.py [--tasks BallRun,BallCircle] [--fresh]

Reads the original's recordings in tests/fixtures/bullet (`--fresh` first re-records them with
reference_dump.py in the original's virtualenv: R2PAC_BSG_VENV, default /work/bsg-venv, built by
../shared/reference/install-bullet-safety-gym.sh). Prints, per task: the replay's largest
differences (engine position, observation, reward; cost disagreements), the original-vs-original
floor, the reset distributions' KS statistics, and env steps/s of our backend (random actions,
16 episodes in parallel, policy excluded) beside the original's (one env, the same actions'
law, in its virtualenv; `--no-original` skips it).
"""
import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

import jax
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))
FIX = ROOT / "tests" / "fixtures" / "bullet"

from test_bullet import ks_statistic, replay  # noqa: E402
from r2pac_jax.envs.bullet import make_env  # noqa: E402
from r2pac_jax.tasks import get_task  # noqa: E402


VENV = Path(os.environ.get("R2PAC_BSG_VENV", "/work/bsg-venv"))
DUMP = Path(__file__).parent / "reference_dump.py"


def original_speed(task, steps=4000):
    out = subprocess.run([str(VENV / "bin" / "python"), str(DUMP), "speed", f"Safety{task}-v0",
                          str(steps)], check=True, capture_output=True, text=True)
    return float(out.stdout.strip().splitlines()[-1])


def record(task):
    venv, dump = VENV, DUMP
    env_id = f"Safety{task}-v0"
    for args in (["rollout", env_id, "0", "4", str(FIX / f"{task}_rollout.npz")],
                 ["resets", env_id, "1", "1000", str(FIX / f"{task}_resets.npz")]):
        subprocess.run([str(venv / "bin" / "python"), str(dump), *args], check=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--tasks", default="BallRun,BallCircle,CarRun,CarCircle,DroneRun,DroneCircle,"
                                       "AntRun,AntCircle")
    ap.add_argument("--fresh", action="store_true")
    ap.add_argument("--no-original", action="store_true")
    args = ap.parse_args()
    print("| task | engine position | observation | reward | cost disagreements | floor "
          "(orig vs orig) | reset KS max D (obs entries, position) | env steps/s, ours (16 episodes) | "
          "original (1 env) | original's history (consecutive vs fresh, max obs) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for task in args.tasks.split(","):
        if args.fresh:
            record(task)
        d = np.load(FIX / f"{task}_rollout.npz")
        env = make_env(get_task(task))
        err = dict(pos=0.0, obs=0.0, reward=0.0, cost=0)
        steps = 0
        for e in range(int(d["episodes"])):
            ours, _ = replay(env, d, e)
            p = f"e{e}_"
            err["pos"] = max(err["pos"], float(np.abs(ours["pos"] - d[p + "base_pos"]).max()))
            err["obs"] = max(err["obs"], float(np.abs(ours["obs"] - d[p + "obs"]).max()))
            err["reward"] = max(err["reward"],
                                float(np.abs(ours["reward"] - d[p + "reward"]).max()))
            err["cost"] += int((ours["cost"] != d[p + "cost"]).sum())
            steps += len(ours["reward"])
        floor = max(float(d["floor_pos"]), float(d["floor_obs"]), float(d["floor_reward"]))
        r = np.load(FIX / f"{task}_resets.npz")
        obs, pos = [], []
        for k in jax.random.split(jax.random.PRNGKey(7), 10):  # 1,000 resets
            st = env.reset_batch(jax.random.split(k, 100))
            obs.append(st.obs)
            pos.append(st.physics["start"])
            env.release(st)
        obs, pos = np.concatenate(obs), np.concatenate(pos)
        ks_obs = max(ks_statistic(obs[:, j], r["obs"][:, j]) for j in range(obs.shape[1])
                     if np.ptp(r["obs"][:, j]) >= 1e-5)
        ks_pos = max(ks_statistic(pos[:, j], r["pose_pos"][:, j]) for j in range(2))
        # speed: 16 parallel episodes, random actions drawn beforehand
        st = env.reset_batch(jax.random.split(jax.random.PRNGKey(0), 16))
        acts = np.random.default_rng(0).uniform(-1, 1, (env.episode_len, 16, env.act_dim))
        acts = acts.astype(np.float32)
        st = env.step_batch(st, acts[0])  # compiles the rules for this batch size
        t0 = time.perf_counter()
        for a in acts[1:]:
            st = env.step_batch(st, a)
        sps = 16 * (env.episode_len - 1) / (time.perf_counter() - t0)
        orig = "" if args.no_original else f"{original_speed(task):,.0f}"
        print(f"| {task} | {err['pos']:.1e} | {err['obs']:.1e} | {err['reward']:.1e} | "
              f"{err['cost']} / {steps} | {floor:.1e} | {ks_obs:.3f}, {ks_pos:.3f} | {sps:,.0f} | {orig} | "
              f"{', '.join(f'{x:.2g}' for x in d['consecutive_obs'])} |")


if __name__ == "__main__":
    main()

"""The MuJoCo re-creations of the Bullet tasks (`--physics mujoco` / `mjx`) against the original's
engine: the figures of benchmarks/FIDELITY.md ("Bullet tasks in MuJoCo").

    python benchmarks/fidelity_bullet/mujoco_gap.py [--tasks BallRun,AntRun] [--episodes 16]
        [--physics mujoco|mjx] [--json out.json]

The original's states come from our `bullet` backend, which reproduces the original bit for bit
(compare.py). Per task:
- one-step errors: episodes under uniform random actions on the bullet backend; every state along
  them (position, orientation, velocities, joints) is put into the MuJoCo model, which takes the
  same action for one control step; the largest observation difference (median and 95th
  percentile over states; the Ant's 0/1 foot contacts apart, as a disagreement rate), the reward
  difference (same), and how often the cost disagrees;
- episode statistics: return, cost and length (mean over episodes) on both backends under fixed
  open-loop patterns (no action, full push along the first action dimension, a sine per action
  dimension) and under random actions (the same sequences on both), from resets of the same law.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from r2pac_jax.envs.bullet import make_env, mjcf  # noqa: E402
from r2pac_jax.envs.bullet.mujoco_env import BulletMujocoEnv  # noqa: E402
from r2pac_jax.envs.bullet.tasks import BULLET_TASKS  # noqa: E402
from r2pac_jax.envs.physics import MujocoEnv  # noqa: E402
from r2pac_jax.tasks import get_task  # noqa: E402


def raw_states(env, state, mj_task) -> tuple:
    """qpos [n, nq], qvel [n, nv] (the MuJoCo model's layout, `mj_task`: a BulletMjTask) of the
    bullet backend's episodes."""
    qpos, qvel = [], []
    for w in np.asarray(state.physics["world"]):
        world = env._worlds[int(w)]
        pb, c, b = world.pb, world.cid, world.body
        pos, quat = pb.getBasePositionAndOrientation(b, physicsClientId=c)
        vel, ang = pb.getBaseVelocity(b, physicsClientId=c)
        R = np.array(pb.getMatrixFromQuaternion(quat)).reshape(3, 3)
        motors = getattr(world.robot, "motors", [])  # the Ball has none
        joints = [pb.getJointState(b, j, physicsClientId=c)[:2] for j in motors]
        jq = np.asarray(mj_task.joints_from_bullet(np.array([q for q, _ in joints])))
        jv = np.asarray(mj_task.joints_from_bullet(np.array([v for _, v in joints])))
        qpos.append(np.concatenate([pos, [quat[3], quat[0], quat[1], quat[2]], jq]))
        qvel.append(np.concatenate([vel, R.T @ np.array(ang), jv]))
    return np.array(qpos), np.array(qvel)


def actions_for(pattern: str, rng, n: int, T: int, act_dim: int) -> np.ndarray:
    """[T, n, act_dim] open-loop actions."""
    if pattern == "none":
        return np.zeros((T, n, act_dim), np.float32)
    if pattern == "push":
        a = np.zeros((T, n, act_dim), np.float32)
        a[..., 0] = 1.0
        return a
    if pattern == "sine":
        t = np.arange(T)[:, None, None]
        phase = np.arange(act_dim)[None, None, :] * np.pi / 2
        return np.broadcast_to(np.sin(2 * np.pi * t / 20 + phase), (T, n, act_dim)).astype(
            np.float32)
    return rng.uniform(-1, 1, (T, n, act_dim)).astype(np.float32)


def run_episodes(env, keys, acts) -> dict:
    state = env.reset_batch(keys)
    n = len(keys)
    ret, cost = np.zeros(n), np.zeros(n)
    length = np.zeros(n, int)
    done = np.zeros(n, bool)
    for a in acts:
        state = env.step_batch(state, a)
        live = ~done
        ret += np.where(live, np.asarray(state.reward), 0.0)
        cost += np.where(live, np.asarray(state.cost), 0.0)
        length += live
        done |= np.asarray(state.terminated) | np.asarray(state.truncated)
        if done.all():
            break
    if hasattr(env, "release"):
        env.release(state)
    return dict(ret=ret, cost=cost, length=length)


def one_step(name: str, episodes: int, seed: int) -> dict:
    spec = get_task(name)
    bullet, mj = make_env(spec, "bullet"), make_env(spec, "mujoco")
    assert isinstance(mj, BulletMujocoEnv)
    rng = np.random.default_rng(seed)
    T = spec.episode_len
    state = bullet.reset_batch(jax.random.split(jax.random.PRNGKey(seed), episodes))
    rows = dict(qpos=[], qvel=[], act=[], obs=[], reward=[], cost=[])
    done = np.zeros(episodes, bool)
    for _ in range(T):
        qpos, qvel = raw_states(bullet, state, mj.task)
        a = rng.uniform(-1, 1, (episodes, spec.act_dim)).astype(np.float32)
        nxt = bullet.step_batch(state, a)
        live = ~done
        rows["qpos"].append(qpos[live])
        rows["qvel"].append(qvel[live])
        rows["act"].append(a[live])
        for k in ("obs", "reward", "cost"):
            rows[k].append(np.asarray(getattr(nxt, k))[live])
        done |= np.asarray(nxt.terminated)
        state = nxt
        if done.all():
            break
    bullet.release(state)
    rows = {k: np.concatenate(v) for k, v in rows.items()}
    n = len(rows["act"])
    states = mj.states_from_qpos_qvel(rows["qpos"], rows["qvel"])
    extras = dict(pending=np.zeros(n, np.float32), settle=np.zeros(n, bool))
    start = MujocoEnv.reset_to(mj, states, extras, np.zeros((n, 2), np.uint32))
    out = mj.step_batch(start, rows["act"])
    drew = np.abs(np.asarray(out.reward) - rows["reward"])
    per_dim = np.abs(np.asarray(out.obs) - rows["obs"])
    flags = [i for i in range(per_dim.shape[1]) if set(np.unique(rows["obs"][:, i])) <= {0, 1}
             and spec.name.startswith("Ant") and i >= 29]  # the Ant's foot contacts
    continuous = [i for i in range(per_dim.shape[1]) if i not in flags]
    dobs = per_dim[:, continuous].max(axis=1)
    return dict(states=int(n), obs_median=float(np.median(dobs)),
                obs_p95=float(np.percentile(dobs, 95)),
                obs_worst_dim=int(np.argmax(np.median(per_dim, axis=0))),
                reward_median=float(np.median(drew)), reward_p95=float(np.percentile(drew, 95)),
                reward_scale=float(np.median(np.abs(rows["reward"]))),
                cost_disagree=float(np.mean(np.asarray(out.cost) != rows["cost"])),
                contact_disagree=float(per_dim[:, flags].mean()) if flags else None)


def episodes(name: str, n: int, seed: int, physics: str) -> dict:
    spec = get_task(name)
    # (an MJX env is a JaxEnv: its reset_batch / step_batch are the jitted vmaps)
    envs = {"bullet": make_env(spec, "bullet"), physics: make_env(spec, physics)}
    out = {}
    for pattern in ("none", "push", "sine", "random"):
        acts = actions_for(pattern, np.random.default_rng(seed), n, spec.episode_len,
                           spec.act_dim)
        keys = jax.random.split(jax.random.PRNGKey(seed + 1), n)
        out[pattern] = {}
        for b, env in envs.items():
            r = run_episodes(env, keys, acts)
            out[pattern][b] = {k: float(np.mean(v)) for k, v in r.items()}
    return out


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--tasks", default=",".join(t for t, (_, r) in BULLET_TASKS.items()
                                               if mjcf.has_model(r)))
    p.add_argument("--episodes", type=int, default=16)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--physics", default="mujoco", choices=("mujoco", "mjx"))
    p.add_argument("--json", default=None)
    args = p.parse_args()
    results = {}
    for name in args.tasks.split(","):
        t0 = time.time()
        r = dict(one_step=one_step(name, args.episodes, args.seed),
                 episodes=episodes(name, args.episodes, args.seed, args.physics))
        r["wall_s"] = time.time() - t0
        results[name] = r
        o = r["one_step"]
        print(f"{name}: one step from {o['states']} original states: obs max-diff median "
              f"{o['obs_median']:.3g} / p95 {o['obs_p95']:.3g} (worst dim {o['obs_worst_dim']}), "
              f"reward diff median {o['reward_median']:.3g} / p95 {o['reward_p95']:.3g} "
              f"(|reward| median {o['reward_scale']:.3g}), cost disagrees "
              f"{100 * o['cost_disagree']:.1f}%" + (
                  "" if o["contact_disagree"] is None else
                  f", foot contacts disagree {100 * o['contact_disagree']:.1f}%"), flush=True)
        for pattern, by in r["episodes"].items():
            print("   " + pattern + ": " + "; ".join(
                f"{b} return {v['ret']:.1f} cost {v['cost']:.1f} length {v['length']:.0f}"
                for b, v in by.items()), flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()

"""Runs INSIDE the reference virtualenv (Safety-Gymnasium 0.4.0, MuJoCo 2.3.3): rolls out seeded
uniform-random actions in the original environment and writes what it saw to an .npz file.

    REF_PY reference_rollout.py ENV_ID SEED STEPS OUT.npz [--through-terminal]
    REF_PY reference_rollout.py --model ENV_ID OUT.npz      # the compiled MjModel's arrays
    REF_PY reference_rollout.py --episodes N ENV_ID SEED OUT.npz   # N whole episodes

Rollout arrays: qpos0, qvel0, warmstart0, body_xpos0 (state after reset), actions [T, A],
obs [T, obs], reward [T], cost [T], terminated [T], truncated [T], and after each step
qpos [T, nq], qvel [T, nv], act [T, na], warmstart [T, nv] (mjData.qacc_warmstart, the solver's
warm start, which MuJoCo carries from one step to the next) and body_xpos [T, nbody, 3]
(mjData.xpos as mj_step leaves it, i.e. from the forward pass *before* the last substep's
integration; Ant's velocity is read from it). The rollout stops at the first terminal (T may be
< STEPS) unless --through-terminal is given: then it steps on (gymnasium's MuJoCo envs simulate
on after a terminal; the flags are recorded per step). The actions are drawn from numpy's
default_rng(SEED), uniform in [-1, 1], rounded to float32.

`--episodes N` plays N whole episodes (seeds SEED .. SEED+N-1, each ending at its terminal or
after 1000 steps) and writes their start states (qpos0 [N, nq], qvel0, body_xpos0), actions
[N, 1000, A] (the same draw as above, all 1000 drawn), returns, costs and lengths [N].

`--model` writes every numeric array of the compiled model (opt_* for the options) so that the
caller can diff it against the model our XML compiles to under MuJoCo 4.
"""
import sys
import warnings

warnings.filterwarnings("ignore")

import gymnasium  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402
import safety_gymnasium  # noqa: E402,F401  (registers the Safety*Gymnasium ids)


def dump_model(env_id, out):
    env = gymnasium.make(env_id)
    m = env.unwrapped.model
    arrays = {"xml_path": np.array(env.unwrapped.fullpath), "mujoco_version":
              np.array(mujoco.__version__)}
    for name in dir(m):
        if name.startswith("_"):
            continue
        try:
            v = getattr(m, name)
        except Exception:  # noqa: BLE001 - some attributes need a renderer
            continue
        if isinstance(v, np.ndarray) and v.dtype.kind in "fiub":
            arrays[name] = v
        elif isinstance(v, (int, float)) and not isinstance(v, bool):
            arrays[name] = np.array(v)
    for name in dir(m.opt):
        if not name.startswith("_"):
            v = getattr(m.opt, name)
            if isinstance(v, (int, float, np.ndarray)):
                arrays["opt_" + name] = np.asarray(v)
    np.savez(out, **arrays)


def episodes(n, env_id, seed, out):
    env = gymnasium.make(env_id)
    data = env.unwrapped.data
    T = env.spec.max_episode_steps
    rec = {k: [] for k in ("qpos0", "qvel0", "body_xpos0", "actions", "returns", "costs",
                           "lengths")}
    for k in range(n):
        env.reset(seed=seed + k)
        rng = np.random.default_rng(seed + k)
        rec["qpos0"].append(data.qpos.copy())
        rec["qvel0"].append(data.qvel.copy())
        rec["body_xpos0"].append(data.xpos.copy())
        # all T actions drawn up front (the same numbers as T draws of one action), so that a
        # replay that lives longer than this episode still has the same random policy
        acts = rng.uniform(-1, 1, (T,) + env.action_space.shape).astype(np.float32)
        acts = acts.astype(np.float64)
        ret = cost = 0.0
        for t in range(T):
            _, r, term, trunc, info = env.step(acts[t])
            ret, cost = ret + r, cost + info["cost"]
            if term or trunc:
                break
        for key, v in (("actions", acts), ("returns", ret), ("costs", cost), ("lengths", t + 1)):
            rec[key].append(v)
    np.savez(out, **{k: np.asarray(v) for k, v in rec.items()})


def main():
    if sys.argv[1] == "--model":
        return dump_model(sys.argv[2], sys.argv[3])
    if sys.argv[1] == "--episodes":
        return episodes(int(sys.argv[2]), sys.argv[3], int(sys.argv[4]), sys.argv[5])
    env_id, seed, steps, out = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
    through = "--through-terminal" in sys.argv[5:]
    # DSRL's ids (Safety...Gymnasium-vN) are the gymnasium-API versions: cost in info["cost"]
    env = gymnasium.make(env_id, max_episode_steps=max(steps, 1000))
    env.reset(seed=seed)
    data = env.unwrapped.data
    rng = np.random.default_rng(seed)
    rec = {k: [] for k in ("actions", "obs", "reward", "cost", "terminated", "truncated",
                           "qpos", "qvel", "act", "warmstart", "body_xpos")}
    start = dict(qpos0=data.qpos.copy(), qvel0=data.qvel.copy(),
                 warmstart0=data.qacc_warmstart.copy(), body_xpos0=data.xpos.copy())
    for _ in range(steps):
        # float32-representable, as our API's actions (and DSRL's) are: same ctrl on both sides
        a = rng.uniform(-1, 1, env.action_space.shape).astype(np.float32).astype(np.float64)
        obs, r, term, trunc, info = env.step(a)
        c = info["cost"]
        for k, v in zip(rec, (a, obs, r, c, term, trunc, data.qpos.copy(), data.qvel.copy(),
                              data.act.copy(), data.qacc_warmstart.copy(), data.xpos.copy())):
            rec[k].append(v)
        if term and not through:
            break
    np.savez(out, mujoco_version=np.array(mujoco.__version__), **start,
             **{k: np.asarray(v) for k, v in rec.items()})


if __name__ == "__main__":
    main()

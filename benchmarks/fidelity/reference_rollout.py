"""Runs INSIDE the reference virtualenv (Safety-Gymnasium 0.4.0, MuJoCo 2.3.3): rolls out seeded
uniform-random actions in the original environment and writes what it saw to an .npz file.

    REF_PY reference_rollout.py ENV_ID SEED STEPS OUT.npz [--through-terminal]
    REF_PY reference_rollout.py --model ENV_ID OUT.npz      # the compiled MjModel's arrays

Rollout arrays: qpos0, qvel0, warmstart0, body_xpos0 (state after reset), actions [T, A],
obs [T, obs], reward [T], cost [T], terminated [T], truncated [T], and after each step
qpos [T, nq], qvel [T, nv], act [T, na], warmstart [T, nv] (mjData.qacc_warmstart, the solver's
warm start, which MuJoCo carries from one step to the next) and body_xpos [T, nbody, 3]
(mjData.xpos as mj_step leaves it, i.e. from the forward pass *before* the last substep's
integration; Ant's velocity is read from it). The rollout stops at the first terminal (T may be
< STEPS) unless --through-terminal is given: then it steps on (gymnasium's MuJoCo envs simulate
on after a terminal; the flags are recorded per step). The actions are drawn from numpy's
default_rng(SEED), uniform in [-1, 1], rounded to float32.

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


def main():
    if sys.argv[1] == "--model":
        return dump_model(sys.argv[2], sys.argv[3])
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

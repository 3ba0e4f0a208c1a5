"""Fidelity of our navigation tasks against the original Safety-Gymnasium 0.4.0.

    python benchmarks/fidelity_nav/compare.py [--tasks CarGoal1,...] [--episodes 3]
        [--steps 300] [--layouts 1000] [--physics mujoco,mjx] [--mjx-steps 100] [--out F.json]

The original runs in its own virtualenv (env var R2PAC_SG_VENV, default .venv-safety-gymnasium
in the repo root; build it with ../shared/reference/install-safety-gymnasium.sh) as a
subprocess (`reference_dump.py`) that writes layouts, states and per-step outputs to an .npz.
Per task it measures:

1. observation: our `observe` at the original's states (its qpos, qvel, mocap, clock, layout,
   goal and button timer copied into our model, one forward pass) against its observation;
2. rules: our reward / cost / goal test on the original's consecutive states (same state
   copying) against its reward / cost / goal_met: exact agreement counts;
3. one step of physics: from the original's state at t, our C MuJoCo step with its action,
   against its state / observation at t + 1 (MuJoCo 4.0 here vs 2.3.3 there);
4. open loop: our env started from the original's first state replays the original's actions;
   only the random draws (new goal place / goal button) are copied from the original when it
   reaches a goal. Reward and cost sequences are compared step by step;
5. layouts: 1000 layouts from our sampler and from the original's sampler
   (`RandomGenerator`): counts, per-object mean / std of x, y, pairwise-distance quantiles,
   minimum clearance over keepout sums, two-sample KS statistics.
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
ROOT = HERE.parent.parent


def reference_python() -> Path:
    venv = Path(os.environ.get("R2PAC_SG_VENV", ROOT / ".venv-safety-gymnasium"))
    return venv / "bin" / "python"


def run_reference(args: list, cache_dir=None) -> dict:
    """Run reference_dump.py with `args` in the reference venv; the .npz's arrays (cached)."""
    cache_dir = Path(cache_dir or tempfile.gettempdir()) / "r2pac_nav_ref"
    cache_dir.mkdir(parents=True, exist_ok=True)
    out = cache_dir / ("_".join(str(a) for a in args) + ".npz")
    if not out.exists():
        subprocess.run([str(reference_python()), str(HERE / "reference_dump.py"), *map(str, args),
                        str(out)], check=True, capture_output=True, timeout=3600)
    with np.load(out) as z:
        return {k: z[k] for k in z.files}


def gym_id(name: str) -> str:
    return f"Safety{name}Gymnasium-v0"


# ---- copying the original's state into ours ---------------------------------------------------

def episode(ref: dict, e: int) -> dict:
    p = f"e{e}_"
    return {k[len(p):]: v for k, v in ref.items() if k.startswith(p)}


def our_state(task, ep: dict, t: int):
    """(qpos, qvel, mocap_pos, mocap_quat, time) of ours for the original's state at step t."""
    from r2pac_jax.envs.navigation.agents import rot2quat

    lv, idx = task.level, task.index
    qpos = np.array(ep["qpos"][t], np.float64)
    qvel = np.array(ep["qvel"][t], np.float64)
    if lv.agent == "point":
        # original: slide / hinge joints in a body placed at the start pose (see agents.py)
        rot0 = ep["rots"][0]
        c, s = np.cos(rot0), np.sin(rot0)
        x0, y0 = ep["layout"][0]
        q = qpos[:3].copy()
        qpos[:3] = [x0 + c * q[0] - s * q[1], y0 + s * q[0] + c * q[1], rot0 + q[2]]
        v = qvel[:3].copy()
        qvel[:3] = [c * v[0] - s * v[1], s * v[0] + c * v[1], v[2]]
    layout = np.array(ep["layout"], np.float64)
    mocap_pos = np.zeros((idx.nmocap, 3))
    mocap_quat = np.tile([1.0, 0, 0, 0], (idx.nmocap, 1))
    ref_mocap = ep["mocap_pos"][t]
    for g in lv.groups:
        if g.kind not in idx.mocap:
            continue
        sl = lv.layout_slice(g.kind)
        xy = layout[sl]
        mocap_quat[idx.mocap[g.kind]] = np.asarray(rot2quat(ep["rots"][sl]), np.float64)
        if g.kind == "gremlins":
            # original: mocap m (at the origin at reset) and weld target m + (xy, size)
            mocap_pos[idx.mocap[g.kind]] = np.concatenate(
                [xy + ref_mocap[:g.num, :2], ref_mocap[:g.num, 2:] + g.size], -1)
        else:
            z = g.height if g.kind == "pillars" else g.size
            mocap_pos[idx.mocap[g.kind]] = np.concatenate([xy, np.full((g.num, 1), z)], -1)
    return qpos, qvel, mocap_pos, mocap_quat, float(ep["time"][t])


def our_extras(task, ep: dict, t: int, pos_xy=None) -> dict:
    """Our task extras for the original's step t (layout, goal, timer, remembered distances)."""
    import jax.numpy as jnp

    lv = task.level
    layout = np.array(ep["layout"], np.float64)
    goal_xy = ep["goal_xy"][t]
    if lv.family != "button":
        layout[task._goal_row] = goal_xy
    # moving objects' rows as the original's update_layout leaves them is not needed for
    # observing; they only matter for goal re-draws, which are copied from the original
    goal = np.concatenate([goal_xy, [task._goal_z()]])
    ex = dict(rng=jnp.zeros(2, jnp.uint32), layout=layout.astype(np.float32),
              goal=goal.astype(np.float32))
    xpos = ep["xpos"][t]
    agent_pos = xpos[1]
    ex["last_dist_goal"] = np.float32(np.linalg.norm(goal_xy - agent_pos[:2]))
    if lv.family == "button":
        ex["goal_button"] = np.int32(ep["goal_button"][t])
        ex["timer"] = np.int32(ep["timer"][t])
    if lv.family == "push":
        box = xpos[list(ep_body_names(ep)).index("push_box")]
        ex["last_dist_box"] = np.float32(np.linalg.norm(box - agent_pos))
        ex["last_box_goal"] = np.float32(np.linalg.norm(box - goal))
    return ex


def ep_body_names(ep):
    return ep["_body_names"]


def stack_extras(exs: list) -> dict:
    return {k: np.stack([np.asarray(e[k]) for e in exs]) for k in exs[0]}


# ---- the checks --------------------------------------------------------------------------------

def check_static(name: str, ref: dict, episodes: int) -> dict:
    """Observation and rules on the original's states (checks 1 and 2), C MuJoCo model."""
    import jax

    from r2pac_jax.envs.navigation import make_env

    env = make_env(name, physics="mujoco")
    task = env.task
    errs = []
    agree = dict(reward=[], cost=[], goal_met=[])
    rew_err = []
    outcome = jax.jit(jax.vmap(env._outcome_one))
    for e in range(episodes):
        ep = episode(ref, e)
        ep["_body_names"] = ref["body_names"]
        T = len(ep["reward"])
        states = [our_state(task, ep, t) for t in range(T + 1)]
        exs = [our_extras(task, ep, t) for t in range(T + 1)]
        cols = list(zip(*states))
        st = env.reset_to(np.stack(cols[0]), np.stack(cols[1]), np.stack(cols[2]),
                          np.stack(cols[3]), stack_extras(exs),
                          jax.random.split(jax.random.PRNGKey(0), T + 1), time=np.array(cols[4]),
                          ctrl=_ctrls(ep))
        errs.append(np.abs(np.asarray(st.obs, np.float64) - ep["obs"]))
        # rules: transition from the extras of step t applied to the state of step t + 1
        view = dict(qpos=np.stack(cols[0])[1:], qvel=np.stack(cols[1])[1:],
                    sensordata=None, touch=None)
        sens = _sensordata(env, states[1:], _ctrls(ep)[1:])
        view["sensordata"] = sens
        view["touch"] = sens[:, env.index.touch_adr].astype(np.float32)
        before = stack_extras(exs[:-1])
        reward, cost, _, _, _ = outcome(view, before)
        reward, cost = np.asarray(reward, np.float64), np.asarray(cost)
        rew_err.append(np.abs(reward - ep["reward"]).max())
        agree["reward"].append(np.mean(np.abs(reward - ep["reward"]) < 1e-4))
        agree["cost"].append(np.mean(cost == ep["cost"]))
        # goal reached <=> the original's goal_met
        met = _goal_met(task, view, before)
        agree["goal_met"].append(np.mean(met == ep["goal_met"]))
    blocks = _obs_blocks(task)
    first = np.stack([x[0] for x in errs])  # the observation right after reset
    rest = np.concatenate([x[1:] for x in errs])
    obs = {}
    for bname, sl in blocks:
        obs[bname] = dict(max=float(rest[:, sl].max()),
                          p99=float(np.quantile(rest[:, sl].max(1), 0.99)),
                          median=float(np.median(rest[:, sl].max(1))),
                          reset_max=float(first[:, sl].max()))
    return dict(obs_abs_err=obs,
                rules_reward_max_abs_err=float(np.max(rew_err)),
                rules_agree={k: float(np.mean(v)) for k, v in agree.items()},
                steps=int(sum(len(episode(ref, e)["reward"]) for e in range(episodes))),
                goals_met=int(sum(episode(ref, e)["goal_met"].sum() for e in range(episodes))),
                cost_steps=int(sum(episode(ref, e)["cost"].sum() for e in range(episodes))))


def _obs_blocks(task):
    """(name, slice) of the observation's parts: each sensor, then all lidars together."""
    out, i = [], 0
    for name, kind in task.agent.sensors:
        n = 9 if kind == "quat2mat" else 3
        out.append((name, slice(i, i + n)))
        i += n
    out.append(("lidars", slice(i, None)))
    return out


def _ctrls(ep):
    """The controls in force at each recorded state: 0 after reset, then the step's action."""
    a = np.clip(ep["action"], -1, 1)
    return np.concatenate([np.zeros((1, a.shape[1])), a], 0)


def _sensordata(env, states, ctrls):
    import mujoco

    m, d = env.mj_model, env._scratch
    out = np.empty((len(states), m.nsensordata))
    for i, (qpos, qvel, mpos, mquat, time) in enumerate(states):
        mujoco.mj_resetData(m, d)
        d.ctrl[:] = ctrls[i]
        d.qpos[:], d.qvel[:] = qpos, qvel
        if m.nmocap:
            d.mocap_pos[:], d.mocap_quat[:] = mpos, mquat
        d.time = time
        mujoco.mj_forward(m, d)
        out[i] = d.sensordata
    return out


def _goal_met(task, view, extras):
    """Our goal test on stacked views / extras (numpy)."""
    import jax
    import jax.numpy as jnp

    from r2pac_jax.envs.navigation import agents as A

    def one(v, ex):
        pos, _ = A.pose(task.agent, v["qpos"])
        if task.level.family == "goal":
            return jnp.linalg.norm(ex["goal"][:2] - pos[:2]) <= task.group("goal").size
        if task.level.family == "push":
            box = task._free_xyz(v["qpos"], "push_box")[0]
            return jnp.linalg.norm(box - ex["goal"]) <= task.group("goal").size
        return v["touch"][task._touch_of["buttons"]][ex["goal_button"]] > 0

    return np.asarray(jax.vmap(one)(view, extras))


def check_one_step(name: str, ref: dict, episodes: int) -> dict:
    """Check 3: one C MuJoCo step from each of the original's states after its first step
    (the step out of a reset is knife-edge, see check_open_loop)."""
    import jax

    from r2pac_jax.envs.navigation import make_env

    env = make_env(name, physics="mujoco")
    task = env.task
    qpos_err, obs_err, rew_err, cost_agree = [], [], [], []
    for e in range(episodes):
        ep = episode(ref, e)
        ep["_body_names"] = ref["body_names"]
        ts = np.arange(1, len(ep["reward"]))
        states = [our_state(task, ep, t) for t in ts]
        exs = [our_extras(task, ep, t) for t in ts]
        cols = list(zip(*states))
        st = env.reset_to(np.stack(cols[0]), np.stack(cols[1]), np.stack(cols[2]),
                          np.stack(cols[3]), stack_extras(exs),
                          jax.random.split(jax.random.PRNGKey(0), len(ts)),
                          time=np.array(cols[4]))
        nxt = env.step_batch(st, ep["action"][ts].astype(np.float32))
        nq_agent = task.agent.nq
        want = np.stack([our_state(task, ep, t + 1)[0] for t in ts])
        got = nxt.physics["state"][:, env._slices["qpos"]]
        qpos_err.append(np.abs(got[:, :nq_agent] - want[:, :nq_agent]).max(1))
        obs_err.append(np.abs(np.asarray(nxt.obs, np.float64) - ep["obs"][ts + 1]).max(1))
        rew_err.append(np.abs(np.asarray(nxt.reward, np.float64) - ep["reward"][ts]))
        cost_agree.append(np.asarray(nxt.cost) == ep["cost"][ts])
    q, o, r = (np.concatenate(x) for x in (qpos_err, obs_err, rew_err))
    return dict(agent_qpos_err_median=float(np.median(q)),
                agent_qpos_err_p99=float(np.quantile(q, 0.99)), agent_qpos_err_max=float(q.max()),
                obs_err_median=float(np.median(o)), obs_err_p99=float(np.quantile(o, 0.99)),
                reward_err_median=float(np.median(r)), reward_err_max=float(r.max()),
                cost_agree=float(np.concatenate(cost_agree).mean()))


def check_open_loop(name: str, ref: dict, episodes: int, physics: str, steps=None,
                    start: int = 1) -> dict:
    """Check 4: replay the original's actions from its state at step `start`, in our env.

    start = 1 by default: right after a reset the car's wheels touch the floor at exactly zero
    distance, and whether MuJoCo counts those contacts hangs on the last bit of a distance
    (2.3.3 computes -7e-18 or 0 depending on the heading, 4.0 computes 0), which changes the
    first step; from the first step on the wheels are in contact."""
    import jax
    import jax.numpy as jnp

    from r2pac_jax.envs.navigation import agents as A
    from r2pac_jax.envs.navigation import make_env

    env = make_env(name, physics=physics)
    task = env.task
    eps = [episode(ref, e) for e in range(episodes)]
    for ep in eps:
        ep["_body_names"] = ref["body_names"]
    T = min(len(ep["reward"]) for ep in eps) - start
    if steps:
        T = min(T, steps)
    s0 = [our_state(task, ep, start) for ep in eps]
    ex0 = stack_extras([our_extras(task, ep, start) for ep in eps])
    cols = list(zip(*s0))
    keys = jax.random.split(jax.random.PRNGKey(0), episodes)
    if physics == "mujoco":
        st = env.reset_to(np.stack(cols[0]), np.stack(cols[1]), np.stack(cols[2]),
                          np.stack(cols[3]), ex0, keys, time=np.array(cols[4]))
        step = env.step_batch
    else:
        from mujoco import mjx

        def start(qpos, qvel, mpos, mquat, ex, k):
            d = mjx.make_data(env.model).replace(qpos=qpos, qvel=qvel, mocap_pos=mpos,
                                                 mocap_quat=mquat)
            d = mjx.forward(env.model, d)
            st = env.reset(k)
            return st.replace(physics=d, info=ex, obs=task.observe(env._view(d), ex))

        f32 = lambda x: jnp.asarray(np.stack(x), jnp.float32)  # noqa: E731
        st = jax.jit(jax.vmap(start))(f32(cols[0]), f32(cols[1]), f32(cols[2]), f32(cols[3]),
                                      jax.tree_util.tree_map(jnp.asarray, ex0), keys)
        step = jax.jit(jax.vmap(env.step))
    rew = np.zeros((episodes, T))
    cost = np.zeros((episodes, T))
    for j in range(T):
        t = start + j
        a = np.stack([ep["action"][t] for ep in eps]).astype(np.float32)
        st = step(st, a if physics == "mujoco" else jnp.asarray(a))
        rew[:, j] = np.asarray(st.reward)
        cost[:, j] = np.asarray(st.cost)
        # copy the original's random draws (new goal / goal button) when it reached a goal
        met = np.array([ep["goal_met"][t] for ep in eps])
        if met.any():
            info = {k: np.array(v) for k, v in st.info.items()}
            qpos = (np.asarray(st.physics["state"][:, env._slices["qpos"]])
                    if physics == "mujoco" else np.asarray(st.physics.qpos))
            for i, ep in enumerate(eps):
                if not met[i]:
                    continue
                g = ep["goal_xy"][t + 1]
                pos = np.asarray(A.pose(task.agent, jnp.asarray(qpos[i]))[0])
                info["goal"][i, :2] = g
                info["last_dist_goal"][i] = np.linalg.norm(g - pos[:2])
                if task.level.family == "button":
                    info["goal_button"][i] = ep["goal_button"][t + 1]
                else:
                    info["layout"][i, task._goal_row] = g
                if task.level.family == "push":
                    box = qpos[i][task.index.free_qpos["push_box"][0]:][:3]
                    info["last_box_goal"][i] = np.linalg.norm(box - info["goal"][i])
            info = info if physics == "mujoco" else {k: jnp.asarray(v) for k, v in info.items()}
            st = st.replace(info=info)
    ref_rew = np.stack([ep["reward"][start:start + T] for ep in eps])
    ref_cost = np.stack([ep["cost"][start:start + T] for ep in eps])
    close = np.abs(rew - ref_rew) < 1e-3
    first_div = [int(np.argmin(c)) if not c.all() else T for c in close]
    return dict(start=start, steps=T, episodes=episodes,
                reward_within_1em3=float(close.mean()),
                first_reward_divergence=first_div,
                cost_agree=float((cost == ref_cost).mean()),
                return_ours=rew.sum(1).round(4).tolist(),
                return_ref=ref_rew.sum(1).round(4).tolist(),
                cost_ours=cost.sum(1).tolist(), cost_ref=ref_cost.sum(1).tolist())


def check_layouts(name: str, n: int, seed: int = 0) -> dict:
    """Check 5: layout statistics of our sampler vs the original's over n layouts."""
    import jax

    from r2pac_jax.envs.navigation import make_task

    ref = run_reference(["layouts", gym_id(name), seed, n])
    task = make_task(name)

    def draw(k):
        qpos, _, _, _, ex = task.init(k)
        return ex["layout"]

    ours = np.asarray(jax.jit(jax.vmap(draw))(jax.random.split(jax.random.PRNGKey(seed), n)),
                      np.float64)
    theirs = ref["layout"]
    assert list(ref["names"]) == list(task.level.layout_names), (ref["names"],)
    if task.level.family == "button":
        # the button task's goal sits on a button after reset; its layout slot only keeps out
        theirs, ours = theirs, ours
    keep = np.array(task.level.keepouts)
    iu = np.triu_indices(len(keep), 1)

    def stats(lay):
        d = np.linalg.norm(lay[:, :, None] - lay[:, None, :], axis=-1)
        pair = d[:, iu[0], iu[1]]
        slack = pair - (keep[iu[0]] + keep[iu[1]])[None]
        return dict(mean_xy=lay.mean(0), std_xy=lay.std(0), pair=pair,
                    min_slack=float(slack.min()), pair_q=np.quantile(pair, [0.1, 0.5, 0.9]))

    so, sr = stats(ours), stats(theirs)
    ks_pair = _ks(so["pair"].ravel(), sr["pair"].ravel())
    ks_x = max(_ks(ours[:, i, 0], theirs[:, i, 0]) for i in range(len(keep)))
    ks_y = max(_ks(ours[:, i, 1], theirs[:, i, 1]) for i in range(len(keep)))
    ks_agent_goal = _ks(so["pair"][:, 0], sr["pair"][:, 0])
    return dict(n=n, objects=len(keep),
                counts_equal=bool(ours.shape == theirs.shape),
                mean_abs_diff_mean_xy=float(np.abs(so["mean_xy"] - sr["mean_xy"]).max()),
                max_abs_diff_std_xy=float(np.abs(so["std_xy"] - sr["std_xy"]).max()),
                pair_quantiles_ours=so["pair_q"].round(3).tolist(),
                pair_quantiles_ref=sr["pair_q"].round(3).tolist(),
                min_keepout_slack_ours=so["min_slack"], min_keepout_slack_ref=sr["min_slack"],
                ks_pairwise=ks_pair, ks_x_worst_object=ks_x, ks_y_worst_object=ks_y,
                ks_agent_to_first_object=ks_agent_goal,
                ks_critical_1pct_per_test=float(1.63 * np.sqrt(2 / n)))


def _ks(a, b) -> float:
    """Two-sample Kolmogorov-Smirnov statistic."""
    a, b = np.sort(a), np.sort(b)
    x = np.concatenate([a, b])
    fa = np.searchsorted(a, x, side="right") / len(a)
    fb = np.searchsorted(b, x, side="right") / len(b)
    return float(np.abs(fa - fb).max())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tasks", default="CarGoal1,CarGoal2,CarButton1,CarButton2,CarPush1,CarPush2,"
                                       "PointGoal1,PointGoal2,PointButton1,PointButton2,"
                                       "PointPush1,PointPush2")
    ap.add_argument("--episodes", type=int, default=3)
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--policy", default="mixed")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--layouts", type=int, default=1000)
    ap.add_argument("--physics", default="mujoco")
    ap.add_argument("--mjx-steps", type=int, default=100)
    ap.add_argument("--checks", default="static,onestep,openloop,layouts")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    if not reference_python().exists():
        print(f"reference interpreter {reference_python()} not found: build the venv with "
              "../shared/reference/install-safety-gymnasium.sh and/or set R2PAC_SG_VENV",
              file=sys.stderr)
        return 2
    checks = args.checks.split(",")
    results = {}
    for name in args.tasks.split(","):
        res = {}
        ref = run_reference(["rollout", gym_id(name), args.seed, args.episodes, args.steps,
                             args.policy])
        if "static" in checks:
            res["static"] = check_static(name, ref, args.episodes)
        if "onestep" in checks:
            res["one_step"] = check_one_step(name, ref, args.episodes)
        if "openloop" in checks:
            for ph in args.physics.split(","):
                steps = args.mjx_steps if ph == "mjx" else None
                res[f"open_loop_{ph}"] = check_open_loop(name, ref, args.episodes, ph, steps)
        if "layouts" in checks:
            res["layouts"] = check_layouts(name, args.layouts, args.seed)
        results[name] = res
        print(json.dumps({name: res}), flush=True)
    if args.out:
        Path(args.out).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())

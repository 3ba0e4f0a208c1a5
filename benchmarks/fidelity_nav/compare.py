"""Fidelity of our navigation tasks against the original Safety-Gymnasium 0.4.0.

    python benchmarks/fidelity_nav/compare.py [--tasks CarGoal1,...] [--episodes 3]
        [--steps 300] [--policy tour] [--layouts 1000] [--physics mujoco,mjx]
        [--mjx-steps 100] [--checks static,onestep,model,openloop,layouts] [--out F.json]

The original runs in its own virtualenv (env var R2PAC_SG_VENV, default .venv-safety-gymnasium
in the repo root; build it with ../shared/reference/install-safety-gymnasium.sh) as a
subprocess (`reference_dump.py`) that writes layouts, states and per-step outputs to an .npz
(cached in $TMPDIR/r2pac_nav_ref, keyed by the arguments and a digest of reference_dump.py).
Per task and per physics backend in --physics:

1. static (observation and rules at copied states): the original's qpos, qvel, mocap poses,
   clock, controls, layout, goal and button timer are copied into our model and one forward
   pass is made (C MuJoCo: mj_forward; MJX: mjx.forward, float32). Our observation is compared
   with the original's; our reward / cost / goal test, applied to the original's consecutive
   states (extras of step t, state of step t + 1), are compared with its reward, cost and
   goal_met (agreement rates);
2. onestep (one control step of physics from each copied state): agent qpos and observation
   after the step against the original's next state (MuJoCo 4.0 here, 2.3.3 there);
3. model (where a one-step gap comes from, C MuJoCo only): the same steps in the original's own
   MJCF compiled by our MuJoCo 4.0 (ours vs it: our modelling; it vs the recorded original:
   the MuJoCo version), in our MJX-variant model stepped by C MuJoCo (the cost of the MJX
   modelling choice: wheels that collide with the floor only, capsule pillars), and the steps
   where only a wheel touches a cost / goal object (lost to that choice);
4. openloop: our env started from the original's state at step 1 replays its actions; the
   original's random draws (new goal place / goal button) are copied into ours when it reaches
   a goal. Reward / cost sequences and agent XY drift are compared, beside a "twin" of the
   original (the same replay with a 1e-9 velocity kick) that measures how fast the original
   itself forgets a tiny perturbation;
5. layouts: n layouts from our sampler and from the original's (`RandomGenerator`): object
   counts, per-object mean / std of x, y, pairwise-distance quantiles, minimum clearance over
   keepout sums, two-sample KS statistics with their p-values.
"""
from __future__ import annotations

import argparse
import functools
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).parent
ROOT = HERE.parent.parent
ALL_TASKS = ("CarGoal1,CarGoal2,CarButton1,CarButton2,CarPush1,CarPush2,PointGoal1,PointGoal2,"
             "PointButton1,PointButton2,PointPush1,PointPush2")


def reference_python() -> Path:
    venv = Path(os.environ.get("R2PAC_SG_VENV", ROOT / ".venv-safety-gymnasium"))
    return venv / "bin" / "python"


def run_reference(args: list, cache_dir=None) -> dict:
    """Run reference_dump.py with `args` in the reference venv; the .npz's arrays (cached)."""
    cache_dir = Path(cache_dir or tempfile.gettempdir()) / "r2pac_nav_ref"
    cache_dir.mkdir(parents=True, exist_ok=True)
    # the file name carries a digest of reference_dump.py: editing it invalidates the cache
    digest = hashlib.sha1((HERE / "reference_dump.py").read_bytes()).hexdigest()[:10]
    out = cache_dir / ("_".join(str(a) for a in args) + f"_{digest}.npz")
    if not out.exists():
        tmp = out.with_name(out.stem + f".tmp{os.getpid()}.npz")
        proc = subprocess.run([str(reference_python()), str(HERE / "reference_dump.py"),
                               *map(str, args), str(tmp)], capture_output=True, text=True,
                              timeout=3600)
        if proc.returncode:
            raise RuntimeError(f"reference_dump.py {' '.join(map(str, args))} failed:\n"
                               f"{proc.stderr[-3000:]}")
        os.replace(tmp, out)  # atomic: a killed run leaves no half-written cache entry
    with np.load(out) as z:
        return {k: z[k] for k in z.files}


def gym_id(name: str) -> str:
    return f"Safety{name}Gymnasium-v0"


# ---- copying the original's state into ours ---------------------------------------------------

def episode(ref: dict, e: int) -> dict:
    """Episode e's arrays (prefix stripped), with the dump's body names as `_body_names`."""
    p = f"e{e}_"
    ep = {k[len(p):]: v for k, v in ref.items() if k.startswith(p)}
    ep["_body_names"] = ref["body_names"]
    return ep


def _quat_z(theta):
    """Quaternions [..., 4] of rotations about z, float64 (the original's rot2quat)."""
    theta = np.asarray(theta, np.float64)
    z = np.zeros_like(theta)
    return np.stack([np.cos(theta / 2), z, z, np.sin(theta / 2)], -1)


def our_qpos(task, ep: dict, qpos, qvel):
    """The original's (qpos, qvel) in our coordinates (Point: world-frame slide joints)."""
    qpos = np.array(qpos, np.float64)
    qvel = np.array(qvel, np.float64)
    if task.level.agent == "point":
        # original: slide / hinge joints in a body placed at the start pose (see agents.py)
        rot0 = ep["rots"][0]
        c, s = np.cos(rot0), np.sin(rot0)
        x0, y0 = ep["layout"][0]
        q = qpos[:3].copy()
        qpos[:3] = [x0 + c * q[0] - s * q[1], y0 + s * q[0] + c * q[1], rot0 + q[2]]
        v = qvel[:3].copy()
        qvel[:3] = [c * v[0] - s * v[1], s * v[0] + c * v[1], v[2]]
    return qpos, qvel


def our_state(task, ep: dict, t: int):
    """(qpos, qvel, mocap_pos, mocap_quat, time) of ours for the original's state at step t."""
    lv, idx = task.level, task.index
    qpos, qvel = our_qpos(task, ep, ep["qpos"][t], ep["qvel"][t])
    layout = np.array(ep["layout"], np.float64)
    mocap_pos = np.zeros((idx.nmocap, 3))
    mocap_quat = np.tile([1.0, 0, 0, 0], (idx.nmocap, 1))
    ref_mocap = ep["mocap_pos"][t]
    for g in lv.groups:
        if g.kind not in idx.mocap:
            continue
        sl = lv.layout_slice(g.kind)
        xy = layout[sl]
        mocap_quat[idx.mocap[g.kind]] = _quat_z(ep["rots"][sl])
        if g.kind == "gremlins":
            # original: mocap m (at the origin at reset) and weld target m + (xy, size)
            mocap_pos[idx.mocap[g.kind]] = np.concatenate(
                [xy + ref_mocap[:g.num, :2], ref_mocap[:g.num, 2:] + g.size], -1)
        else:
            z = g.height if g.kind == "pillars" else g.size
            mocap_pos[idx.mocap[g.kind]] = np.concatenate([xy, np.full((g.num, 1), z)], -1)
    return qpos, qvel, mocap_pos, mocap_quat, float(ep["time"][t])


def our_extras(task, ep: dict, t: int) -> dict:
    """Our task extras for the original's step t (layout, goal, timer, remembered distances)."""
    lv = task.level
    layout = np.array(ep["layout"], np.float64)
    goal_xy = ep["goal_xy"][t]
    if lv.family != "button":
        layout[task._goal_row] = goal_xy
    # the moving objects' rows as the original's update_layout leaves them only matter for
    # goal re-draws, which are copied from the original
    goal = np.concatenate([goal_xy, [task._goal_z()]])
    ex = dict(rng=np.zeros(2, np.uint32), layout=layout.astype(np.float32),
              goal=goal.astype(np.float32))
    agent_pos = ep["xpos"][t][1]
    ex["last_dist_goal"] = np.float32(np.linalg.norm(goal_xy - agent_pos[:2]))
    if lv.family == "button":
        ex["goal_button"] = np.int32(ep["goal_button"][t])
        ex["timer"] = np.int32(ep["timer"][t])
    if lv.family == "push":
        box = ep["xpos"][t][list(ep["_body_names"]).index("push_box")]
        ex["last_dist_box"] = np.float32(np.linalg.norm(box - agent_pos))
        ex["last_box_goal"] = np.float32(np.linalg.norm(box - goal))
    return ex


def stack_extras(exs: list) -> dict:
    return {k: np.stack([np.asarray(e[k]) for e in exs]) for k in exs[0]}


def _ctrls(ep):
    """The controls in force at each recorded state: 0 after reset, then the step's action."""
    a = np.clip(ep["action"], -1, 1)
    return np.concatenate([np.zeros((1, a.shape[1])), a], 0)


def _stack_states(states):
    """list of our_state tuples -> (qpos [n, nq], qvel, mocap_pos, mocap_quat, time [n])."""
    cols = list(zip(*states))
    return tuple(np.stack(c) for c in cols[:4]) + (np.array(cols[4]),)


def _obs_blocks(task):
    """(name, slice) of the observation's parts: each sensor, then all lidars together."""
    out, i = [], 0
    for name, kind in task.agent.sensors:
        n = 9 if kind == "quat2mat" else 3
        out.append((name, slice(i, i + n)))
        i += n
    out.append(("lidars", slice(i, None)))
    return out


def _q(x, qs=(0.5, 0.99, 1.0)):
    x = np.asarray(x, np.float64).ravel()
    return [float(np.quantile(x, q)) for q in qs] if x.size else [0.0] * len(qs)


# ---- simulators -------------------------------------------------------------------------------

def _c_forward(m, states, ctrls):
    """sensordata [n, nsensordata] and MjData contacts after mj_forward at each state."""
    import mujoco

    d = mujoco.MjData(m)
    sens, contacts = np.empty((len(states[0]), m.nsensordata)), []
    for i in range(len(states[0])):
        _c_set(m, d, [s[i] for s in states], ctrls[i])
        mujoco.mj_forward(m, d)
        sens[i] = d.sensordata
        contacts.append([(int(c.geom1), int(c.geom2)) for c in d.contact[:d.ncon]])
    return sens, contacts


def _c_set(m, d, state, ctrl):
    import mujoco

    qpos, qvel, mpos, mquat, time = state
    mujoco.mj_resetData(m, d)
    d.qpos[:], d.qvel[:] = qpos, qvel
    if m.nmocap:
        d.mocap_pos[:], d.mocap_quat[:] = mpos, mquat
    d.time = time
    d.ctrl[:] = ctrl


def _c_step(m, states, actions, move, frame_skip):
    """qpos [n, nq] after one control step from each state: `move(d)` sets the mocap poses
    before every substep (as the original's Mocap.move)."""
    import mujoco

    d = mujoco.MjData(m)
    out = np.empty((len(actions), m.nq))
    for i in range(len(actions)):
        _c_set(m, d, [s[i] for s in states], np.clip(actions[i], -1, 1))
        for _ in range(frame_skip):
            move(d)
            mujoco.mj_step(m, d)
        out[i] = d.qpos
    return out


def _our_move(task, layout):
    """Our models' mocap motion (gremlins circling) for one episode's layout."""
    def move(d):
        if task.group("gremlins") is not None:
            d.mocap_pos[:] = task.mocap_positions(layout, d.time, np)
    return move


class MjxRunner:
    """MJX entry points for copied states, jitted once per task for batches of `batch` lanes
    (inputs are padded to it, so nothing recompiles):
    probe(states, ctrl, ex_obs, ex_prev) -> obs (with ex_obs), reward / cost / goal_met of the
    transition from ex_prev into the state; begin(states, ctrl, ex) -> EnvState; step."""

    def __init__(self, name: str, batch: int):
        import jax
        import jax.numpy as jnp
        from mujoco import mjx

        from r2pac_jax.envs.base import EnvState
        from r2pac_jax.envs.navigation import make_env

        self.env = env = make_env(name, physics="mjx")
        self.task = task = env.task
        self.batch = batch

        def data(qpos, qvel, mpos, mquat, time, ctrl):
            d = mjx.make_data(env.model).replace(qpos=qpos, qvel=qvel, mocap_pos=mpos,
                                                 mocap_quat=mquat, time=time, ctrl=ctrl)
            return mjx.forward(env.model, d)

        def probe(qpos, qvel, mpos, mquat, time, ctrl, ex_obs, ex_prev):
            view = env._view(data(qpos, qvel, mpos, mquat, time, ctrl))
            reward, cost, _, _ = task.transition(view, ex_prev)
            return (task.observe(view, ex_obs), reward, cost,
                    _goal_met_one(task, view, ex_prev))

        def begin(qpos, qvel, mpos, mquat, time, ctrl, ex):
            d = data(qpos, qvel, mpos, mquat, time, ctrl)
            z = jnp.zeros((), jnp.float32)
            return EnvState(obs=task.observe(env._view(d), ex), reward=z, cost=z,
                            terminated=jnp.array(False), truncated=jnp.array(False),
                            t=jnp.zeros((), jnp.int32), key=jax.random.PRNGKey(0), physics=d,
                            info=ex)

        self._probe = jax.jit(jax.vmap(probe))
        self._begin = jax.jit(jax.vmap(begin))
        self.step = jax.jit(jax.vmap(env.step))

    def _chunks(self, n):
        for lo in range(0, n, self.batch):
            yield lo, min(lo + self.batch, n)

    def _pad(self, tree, lo, hi):
        import jax
        import jax.numpy as jnp

        def one(x):
            x = np.asarray(x)[lo:hi]
            if hi - lo < self.batch:
                x = np.concatenate([x, np.repeat(x[-1:], self.batch - (hi - lo), 0)], 0)
            return jnp.asarray(x, jnp.float32 if x.dtype == np.float64 else x.dtype)
        return jax.tree_util.tree_map(one, tree)

    def probe(self, states, ctrls, ex_obs, ex_prev):
        outs = []
        for lo, hi in self._chunks(len(ctrls)):
            args = self._pad((*states, ctrls, ex_obs, ex_prev), lo, hi)
            outs.append([np.asarray(o)[:hi - lo] for o in self._probe(*args)])
        return [np.concatenate(c) for c in zip(*outs)]

    def begin(self, states, ctrls, ex):
        """EnvStates for exactly `batch` states."""
        assert len(ctrls) == self.batch
        return self._begin(*self._pad((*states, ctrls, ex), 0, self.batch))

    def one_step(self, states, ctrls, ex, actions):
        """qpos [n, nq] and obs [n, obs] after one step from each state."""
        import jax.numpy as jnp

        qpos, obs = [], []
        for lo, hi in self._chunks(len(actions)):
            st = self._begin(*self._pad((*states, ctrls, ex), lo, hi))
            st = self.step(st, self._pad(actions, lo, hi).astype(jnp.float32))
            qpos.append(np.asarray(st.physics.qpos, np.float64)[:hi - lo])
            obs.append(np.asarray(st.obs, np.float64)[:hi - lo])
        return np.concatenate(qpos), np.concatenate(obs)


@functools.lru_cache(maxsize=None)
def mjx_runner(name: str, batch: int) -> MjxRunner:
    return MjxRunner(name, batch)


def _goal_met_one(task, view, ex):
    """Our goal test (the env's `achieved`) for one view / extras."""
    import jax.numpy as jnp

    from r2pac_jax.envs.navigation import agents as A

    pos, _ = A.pose(task.agent, view["qpos"])
    if task.level.family == "goal":
        return jnp.linalg.norm(ex["goal"][:2] - pos[:2]) <= task.group("goal").size
    if task.level.family == "push":
        box = task._free_xyz(view["qpos"], "push_box")[0]
        return jnp.linalg.norm(box - ex["goal"]) <= task.group("goal").size
    return view["touch"][task._touch_of["buttons"]][ex["goal_button"]] > 0


@functools.lru_cache(maxsize=None)
def _c_probe(task):
    import jax

    def probe(view, ex_obs, ex_prev):
        reward, cost, _, _ = task.transition(view, ex_prev)
        return task.observe(view, ex_obs), reward, cost, _goal_met_one(task, view, ex_prev)

    return jax.jit(jax.vmap(probe))


# ---- the checks --------------------------------------------------------------------------------

def check_static(name: str, ref: dict, episodes: int, physics: str = "mujoco") -> dict:
    """Check 1: observation and rules at the original's states (see the module docstring)."""
    from r2pac_jax.envs.navigation import make_env

    if physics == "mjx":
        runner = mjx_runner(name, episodes)
        task = runner.task
    else:
        env = make_env(name, physics="mujoco")
        task = env.task
    from r2pac_jax.envs.navigation.world import build_model

    m_exact, index = build_model(task.level, "exact")
    agent_geoms = set(index.agent_geoms.tolist())
    floor = {g for g in range(m_exact.ngeom) if m_exact.geom_bodyid[g] == 0}
    errs, rew_err, floor_only = [], [], []
    agree = dict(reward=[], cost=[], goal_met=[])
    for e in range(episodes):
        ep = episode(ref, e)
        T = len(ep["reward"])
        states = _stack_states([our_state(task, ep, t) for t in range(T + 1)])
        exs = [our_extras(task, ep, t) for t in range(T + 1)]
        ctrls = _ctrls(ep)
        # row t: observation of state t with extras t; transition (extras t-1) -> state t
        ex_obs = stack_extras(exs)
        ex_prev = stack_extras(exs[:1] + exs[:-1])
        # states where the agent touches nothing but the floor (C MuJoCo's contacts)
        sens, contacts = _c_forward(m_exact, states, ctrls)
        floor_only.append(np.array([all(g1 in floor or g2 in floor for g1, g2 in con
                                        if g1 in agent_geoms or g2 in agent_geoms)
                                    for con in contacts]))
        if physics == "mjx":
            obs, reward, cost, met = runner.probe(states, ctrls, ex_obs, ex_prev)
        else:
            view = dict(qpos=states[0], qvel=states[1], sensordata=sens,
                        touch=sens[:, env.index.touch_adr].astype(np.float32))
            obs, reward, cost, met = (np.asarray(x) for x in
                                      _c_probe(task)(view, ex_obs, ex_prev))
        errs.append(np.abs(np.asarray(obs, np.float64) - ep["obs"]))
        reward = np.asarray(reward, np.float64)[1:]
        rew_err.append(np.abs(reward - ep["reward"]))
        agree["reward"].append(np.abs(reward - ep["reward"]) < 1e-4)
        agree["cost"].append(np.asarray(cost)[1:] == ep["cost"])
        agree["goal_met"].append(np.asarray(met)[1:] == ep["goal_met"])
    first = np.stack([x[0] for x in errs])  # the observation right after reset
    rest = np.concatenate([x[1:] for x in errs])
    free = np.concatenate([f[1:] for f in floor_only])
    obs = {}
    for bname, sl in _obs_blocks(task):
        per_step = rest[:, sl].max(1)
        obs[bname] = dict(median=float(np.median(per_step)),
                          p99=float(np.quantile(per_step, 0.99)), max=float(per_step.max()),
                          frac_over_1em3=float(np.mean(per_step > 1e-3)),
                          reset_max=float(first[:, sl].max()))
    acc = rest[free][:, _obs_blocks(task)[0][1]].max(1) if free.any() else np.zeros(1)
    obs["accelerometer_floor_contacts_only"] = dict(
        states=int(free.sum()), median=float(np.median(acc)),
        p99=float(np.quantile(acc, 0.99)), max=float(acc.max()),
        frac_over_1em3=float(np.mean(acc > 1e-3)))
    eps = [episode(ref, e) for e in range(episodes)]
    return dict(physics=physics, obs_abs_err=obs,
                rules_reward_max_abs_err=float(np.concatenate(rew_err).max()),
                rules_agree={k: float(np.concatenate(v).mean()) for k, v in agree.items()},
                steps=int(sum(len(ep["reward"]) for ep in eps)),
                goals_met=int(sum(ep["goal_met"].sum() for ep in eps)),
                cost_steps=int(sum(ep["cost"].sum() for ep in eps)))


def _one_step_inputs(task, ref, episodes):
    """States t = 1 .. T-1 of every episode (the step out of a reset is left out: see
    check_open_loop), their extras, controls, actions, the original's next states."""
    rows = []
    for e in range(episodes):
        ep = episode(ref, e)
        for t in range(1, len(ep["reward"])):
            rows.append((ep, t))
    states = _stack_states([our_state(task, ep, t) for ep, t in rows])
    ex = stack_extras([our_extras(task, ep, t) for ep, t in rows])
    ctrls = np.stack([np.clip(ep["action"][t - 1], -1, 1) for ep, t in rows])
    actions = np.stack([ep["action"][t] for ep, t in rows]).astype(np.float32)
    want = np.stack([our_state(task, ep, t + 1)[0] for ep, t in rows])
    want_obs = np.stack([ep["obs"][t + 1] for ep, t in rows])
    want_rew = np.array([ep["reward"][t] for ep, t in rows])
    want_cost = np.array([ep["cost"][t] for ep, t in rows])
    return rows, states, ex, ctrls, actions, want, want_obs, want_rew, want_cost


def check_one_step(name: str, ref: dict, episodes: int, physics: str = "mujoco") -> dict:
    """Check 2: one control step from each of the original's states (t >= 1)."""
    import jax

    from r2pac_jax.envs.navigation import make_env
    from r2pac_jax.envs.navigation.world import build_model

    env = make_env(name, physics="mujoco")
    task = env.task
    rows, states, ex, ctrls, actions, want, want_obs, want_rew, want_cost = \
        _one_step_inputs(task, ref, episodes)
    nq = task.agent.nq
    out = dict(physics=physics, steps=len(rows))
    if physics == "mujoco":
        st = env.reset_to(*states[:4], ex, jax.random.split(jax.random.PRNGKey(0), len(rows)),
                          time=states[4], ctrl=ctrls)
        nxt = env.step_batch(st, actions)
        got = nxt.physics["state"][:, env._slices["qpos"]]
        obs = np.asarray(nxt.obs, np.float64)
        out.update(reward_abs_err=_q(np.abs(np.asarray(nxt.reward, np.float64) - want_rew)),
                   cost_agree=float(np.mean(np.asarray(nxt.cost) == want_cost)))
    else:
        got, obs = mjx_runner(name, episodes).one_step(states, ctrls, ex, actions)
        # the same model stepped by C MuJoCo in float64: what MJX's numerics add
        m_mjx, _ = build_model(task.level, "mjx")
        c_mjx = np.concatenate([
            _c_step(m_mjx, [s[i:i + 1] for s in states], actions[i:i + 1],
                    _our_move(task, np.asarray(rows[i][0]["layout"], np.float64)),
                    task.frame_skip) for i in range(len(rows))])
        out["agent_qpos_err_vs_c_mujoco_same_model"] = _q(np.abs(got - c_mjx)[:, :nq].max(1))
    out.update(agent_qpos_err=_q(np.abs(got - want)[:, :nq].max(1)),
               agent_xy_err=_q(np.linalg.norm(got[:, :2] - want[:, :2], axis=1)),
               obs_err=_q(np.abs(obs - want_obs).max(1)),
               quantiles="median, p99, max")
    return out


def check_model(name: str, ref: dict, episodes: int) -> dict:
    """Check 3: where one-step gaps come from (C MuJoCo 4.0; see the module docstring).

    Original MJCF: episode 0 only (the dump keeps that episode's XML). Agent qpos errors are
    max-abs over the agent's qpos; quantiles (median, p99, max) over the steps."""
    import mujoco

    from r2pac_jax.envs.navigation import make_env
    from r2pac_jax.envs.navigation.world import build_model

    env = make_env(name, physics="mujoco")
    task = env.task
    nq, fs = task.agent.nq, task.frame_skip
    out = {}

    # (a) the original's MJCF in MuJoCo 4.0, episode 0
    ep = episode(ref, 0)
    m = mujoco.MjModel.from_xml_string(str(ref["xml"]))
    gremlin = task.group("gremlins")
    mocap_ids = []
    if gremlin is not None:
        mocap_ids = [m.body_mocapid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY,
                                                       f"gremlin{i}mocap")]
                     for i in range(gremlin.num)]

    def their_move(d):  # Gremlins.move
        for i in mocap_ids:
            d.mocap_pos[i] = [gremlin.travel * np.sin(d.time), gremlin.travel * np.cos(d.time),
                              gremlin.size]

    ts = np.arange(1, len(ep["reward"]))
    raw = (ep["qpos"][ts], ep["qvel"][ts], ep["mocap_pos"][ts], None, ep["time"][ts])
    raw = raw[:3] + (np.tile(m.body_quat[m.body_mocapid >= 0][None], (len(ts), 1, 1))
                     if m.nmocap else np.zeros((len(ts), 0, 4)),) + raw[4:]
    theirs = _c_step(m, raw, ep["action"][ts], their_move, fs)
    theirs = np.stack([our_qpos(task, ep, q, np.zeros(m.nv))[0] for q in theirs])
    ours_states = _stack_states([our_state(task, ep, t) for t in ts])
    layout = np.asarray(ep["layout"], np.float64)
    m_exact, _ = build_model(task.level, "exact")
    ours = _c_step(m_exact, ours_states, ep["action"][ts], _our_move(task, layout), fs)
    recorded = np.stack([our_state(task, ep, t + 1)[0] for t in ts])
    e_model = np.abs(ours - theirs)[:, :nq].max(1)
    out["ours_vs_their_mjcf_in_mujoco4_agent_qpos"] = _q(e_model)
    if m.nq > nq:
        out["ours_vs_their_mjcf_in_mujoco4_objects_qpos"] = _q(np.abs(ours - theirs)[:, nq:]
                                                              .max(1))
    e_version = np.abs(theirs - recorded)[:, :nq].max(1)
    out["their_mjcf_mujoco4_vs_mujoco233_agent_qpos"] = _q(e_version)
    out["their_mjcf_mujoco4_vs_mujoco233_exact_frac"] = float(np.mean(e_version < 1e-12))
    # accelerometer at the copied states: ours vs their MJCF (both 4.0) vs recorded (2.3.3)
    ts_all = np.arange(0, len(ep["reward"]) + 1)
    ctrls = _ctrls(ep)
    raw_all = (ep["qpos"], ep["qvel"], ep["mocap_pos"],
               np.tile(m.body_quat[m.body_mocapid >= 0][None], (len(ts_all), 1, 1))
               if m.nmocap else np.zeros((len(ts_all), 0, 4)), ep["time"])
    s_their, _ = _c_forward(m, raw_all, ctrls)
    a_their = s_their[:, m.sensor_adr[m.sensor("accelerometer").id]:][:, :3]
    s_ours, _ = _c_forward(m_exact, _stack_states([our_state(task, ep, t) for t in ts_all]),
                           ctrls)
    acc = env.index.sensor_adr[0][0]
    a_ours = s_ours[:, acc:acc + 3]
    out["accelerometer_ours_vs_their_mjcf_mujoco4"] = _q(np.abs(a_ours - a_their).max(1))
    out["accelerometer_their_mjcf_mujoco4_vs_mujoco233"] = _q(
        np.abs(a_their - ep["obs"][:, :3]).max(1))

    # (b) the MJX variant of our model, stepped by C MuJoCo, against the exact one: all episodes
    rows, states, ex, ctrls1, actions, want, *_ = _one_step_inputs(task, ref, episodes)
    m_mjx, _ = build_model(task.level, "mjx")
    per = [(m_exact, []), (m_mjx, [])]
    for mm, acc_list in per:
        for i, (epi, _) in enumerate(rows):
            acc_list.append(_c_step(mm, [s[i:i + 1] for s in states], actions[i:i + 1],
                                    _our_move(task, np.asarray(epi["layout"], np.float64)),
                                    fs))
    exact_q, mjxv_q = (np.concatenate(a) for _, a in per)
    out["mjx_variant_vs_exact_agent_qpos"] = _q(np.abs(mjxv_q - exact_q)[:, :nq].max(1))
    xy_err = np.linalg.norm(mjxv_q[:, :2] - exact_q[:, :2], axis=1)
    out["mjx_variant_vs_exact_agent_xy"] = _q(xy_err)
    out["mjx_variant_vs_exact_frac_steps_xy_over_1em6"] = float(np.mean(xy_err > 1e-6))
    out["mjx_variant_vs_mujoco233_agent_qpos"] = _q(np.abs(mjxv_q - want)[:, :nq].max(1))

    # (c) states where the agent touches a cost / goal object only through wheel-box contacts,
    # which the MJX variant drops (its wheels touch the floor, buttons and pillars only)
    wheel_ids = {mujoco.mj_name2id(m_exact, mujoco.mjtObj.mjOBJ_GEOM, w)
                 for w in task.agent.wheels}
    agent_geoms = set(env.index.agent_geoms.tolist())
    touch_bodies = set(env.index.touch_body_ids.tolist())
    immovable = {b for b in range(m_exact.nbody) if m_exact.body_mocapid[b] >= 0}
    n_touch = n_lost = 0
    for e in range(episodes):
        epi = episode(ref, e)
        T = len(epi["reward"])
        st = _stack_states([our_state(task, epi, t) for t in range(T + 1)])
        _, contacts = _c_forward(m_exact, st, _ctrls(epi))
        for con in contacts:
            touching = kept = False
            for g1, g2 in con:
                for a, b in ((g1, g2), (g2, g1)):
                    body = m_exact.geom_bodyid[b]
                    if a in agent_geoms and body in touch_bodies:
                        touching = True
                        kept |= a not in wheel_ids or body in immovable
            n_touch += touching
            n_lost += touching and not kept
    out["states_touching_cost_or_goal_objects"] = n_touch
    out["of_which_lost_in_mjx_variant"] = n_lost
    out["quantiles"] = "median, p99, max"
    return out


def check_open_loop(name: str, ref: dict, episodes: int, physics: str, steps=None,
                    start: int = 1) -> dict:
    """Check 4: replay the original's actions from its state at step `start`, in our env.

    start = 1 by default: right after a reset the car's wheels touch the floor at exactly zero
    distance, and how many contacts MuJoCo counts hangs on the last bit of a distance
    (2.3.3 computes -7e-18 or 0 depending on the heading, and 4.0 differs), which changes the
    first step; from the first step on the wheels are in contact."""
    import jax
    import jax.numpy as jnp

    from r2pac_jax.envs.navigation import agents as A
    from r2pac_jax.envs.navigation import make_env

    eps = [episode(ref, e) for e in range(episodes)]
    T = min(len(ep["reward"]) for ep in eps) - start
    if steps:
        T = min(T, steps)
    if physics == "mujoco":
        env = make_env(name, physics="mujoco")
    else:
        runner = mjx_runner(name, episodes)
        env = runner.env
    task = env.task
    s0 = _stack_states([our_state(task, ep, start) for ep in eps])
    ex0 = stack_extras([our_extras(task, ep, start) for ep in eps])
    ctrl0 = np.stack([np.clip(ep["action"][start - 1], -1, 1) for ep in eps])
    if physics == "mujoco":
        st = env.reset_to(*s0[:4], ex0, jax.random.split(jax.random.PRNGKey(0), episodes),
                          time=s0[4], ctrl=ctrl0)
        step = env.step_batch
    else:
        st = runner.begin(s0, ctrl0, ex0)
        step = runner.step
    rew = np.zeros((episodes, T))
    cost = np.zeros((episodes, T))
    xy = np.zeros((episodes, T, 2))
    for j in range(T):
        t = start + j
        a = np.stack([ep["action"][t] for ep in eps]).astype(np.float32)
        st = step(st, a if physics == "mujoco" else jnp.asarray(a))
        rew[:, j] = np.asarray(st.reward)
        cost[:, j] = np.asarray(st.cost)
        qpos = (np.asarray(st.physics["state"][:, env._slices["qpos"]])
                if physics == "mujoco" else np.asarray(st.physics.qpos, np.float64))
        xy[:, j] = [np.asarray(A.pose(task.agent, jnp.asarray(q))[0])[:2] for q in qpos]
        # copy the original's random draws (new goal / goal button) when it reached a goal
        met = np.array([ep["goal_met"][t] for ep in eps])
        if met.any():
            info = {k: np.array(v) for k, v in st.info.items()}
            for i, ep in enumerate(eps):
                if not met[i]:
                    continue
                g = ep["goal_xy"][t + 1]
                info["goal"][i, :2] = g
                info["last_dist_goal"][i] = np.linalg.norm(g - xy[i, j])
                if task.level.family == "button":
                    info["goal_button"][i] = ep["goal_button"][t + 1]
                    info["timer"][i] = ep["timer"][t + 1]
                else:
                    info["layout"][i, task._goal_row] = g
                if task.level.family == "push":
                    box = task._free_xyz(qpos[i], "push_box")[0]
                    info["last_box_goal"][i] = np.linalg.norm(box - info["goal"][i])
            if physics != "mujoco":
                info = {k: jnp.asarray(v) for k, v in info.items()}
            st = st.replace(info=info)
    ref_rew = np.stack([ep["reward"][start:start + T] for ep in eps])
    ref_cost = np.stack([ep["cost"][start:start + T] for ep in eps])
    ref_xy = np.stack([ep["xpos"][start + 1:start + T + 1, 1, :2] for ep in eps])

    def first_div(close):
        return [int(np.argmin(c)) if not c.all() else T for c in close]

    def drift(a):  # agent XY distance to the original's, median over episodes, at horizons
        d = np.linalg.norm(a - ref_xy, axis=-1)
        return {str(h): float(np.median(d[:, h - 1])) for h in (10, 25, 50, 100, 200, 300)
                if h <= T}

    close = np.abs(rew - ref_rew) < 1e-3
    out = dict(physics=physics, start=start, steps=T, episodes=episodes,
               reward_within_1em3=float(close.mean()), first_reward_divergence=first_div(close),
               cost_agree=float((cost == ref_cost).mean()), agent_xy_drift=drift(xy))
    if all(len(ep.get("twin_reward", ())) >= start + T for ep in eps):
        # the original against itself after a 1e-9 velocity kick at `start`
        # (reference_dump.twin): the yardstick for the divergence of ours
        tw_rew = np.stack([ep["twin_reward"][start:start + T] for ep in eps])
        tw_cost = np.stack([ep["twin_cost"][start:start + T] for ep in eps])
        tw_xy = np.stack([ep["twin_xy"][start + 1:start + T + 1] for ep in eps])
        tclose = np.abs(tw_rew - ref_rew) < 1e-3
        out.update(twin_reward_within_1em3=float(tclose.mean()),
                   twin_first_reward_divergence=first_div(tclose),
                   twin_cost_agree=float((tw_cost == ref_cost).mean()),
                   twin_agent_xy_drift=drift(tw_xy))
    out.update(return_ours=rew.sum(1).round(4).tolist(),
               return_ref=ref_rew.sum(1).round(4).tolist(),
               cost_ours=cost.sum(1).tolist(), cost_ref=ref_cost.sum(1).tolist())
    return out


def check_layouts(name: str, n: int, seed: int = 0) -> dict:
    """Check 5: layout statistics of our sampler vs the original's over n layouts."""
    import jax

    from r2pac_jax.envs.navigation import make_task

    ref = run_reference(["layouts", gym_id(name), seed, n])
    task = make_task(name)

    def draw(k):
        return task.init(k)[4]["layout"]

    ours = np.asarray(jax.jit(jax.vmap(draw))(jax.random.split(jax.random.PRNGKey(seed), n)),
                      np.float64)
    theirs = ref["layout"]
    names = list(task.level.layout_names)
    if list(ref["names"]) != names:
        raise AssertionError(f"layout names differ: ours {names}, original {list(ref['names'])}")
    kinds = [nm.rstrip("0123456789") for nm in names]
    counts = {k: kinds.count(k) for k in dict.fromkeys(kinds)}
    keep = np.array(task.level.keepouts)
    iu = np.triu_indices(len(keep), 1)

    def stats(lay):
        d = np.linalg.norm(lay[:, :, None] - lay[:, None, :], axis=-1)
        pair = d[:, iu[0], iu[1]]
        slack = pair - (keep[iu[0]] + keep[iu[1]])[None]
        return dict(mean_xy=lay.mean(0), std_xy=lay.std(0), pair=pair,
                    min_slack=float(slack.min()), pair_q=np.quantile(pair, [0.1, 0.5, 0.9]))

    so, sr = stats(ours), stats(theirs)
    ks_xy = [(_ks(ours[:, i, c], theirs[:, i, c]), names[i] + "xy"[c])
             for i in range(len(keep)) for c in range(2)]
    worst, worst_name = max(ks_xy)
    # every pair's distance distribution (agent-goal, goal-hazard0, ...)
    ks_pairs = [_ks(so["pair"][:, j], sr["pair"][:, j]) for j in range(len(iu[0]))]
    n_tests = len(ks_xy)
    return dict(n=n, objects=len(keep), counts=counts, counts_equal=ours.shape == theirs.shape,
                max_abs_diff_mean_xy=float(np.abs(so["mean_xy"] - sr["mean_xy"]).max()),
                max_abs_diff_std_xy=float(np.abs(so["std_xy"] - sr["std_xy"]).max()),
                pair_quantiles_ours=so["pair_q"].round(3).tolist(),
                pair_quantiles_ref=sr["pair_q"].round(3).tolist(),
                min_keepout_slack_ours=so["min_slack"], min_keepout_slack_ref=sr["min_slack"],
                ks_all_pairwise_pooled=_ks(so["pair"].ravel(), sr["pair"].ravel()),
                ks_xy_worst=worst, ks_xy_worst_object=worst_name,
                ks_xy_worst_pvalue_bonferroni=min(1.0, n_tests * _ks_pvalue(worst, n, n)),
                ks_pair_worst=max(ks_pairs),
                ks_pair_worst_pvalue_bonferroni=min(1.0, len(ks_pairs) *
                                                    _ks_pvalue(max(ks_pairs), n, n)))


def _ks(a, b) -> float:
    """Two-sample Kolmogorov-Smirnov statistic."""
    a, b = np.sort(a), np.sort(b)
    x = np.concatenate([a, b])
    fa = np.searchsorted(a, x, side="right") / len(a)
    fb = np.searchsorted(b, x, side="right") / len(b)
    return float(np.abs(fa - fb).max())


def _ks_pvalue(stat: float, n: int, m: int) -> float:
    """Asymptotic two-sample KS p-value (Kolmogorov distribution, Stephens' correction)."""
    ne = n * m / (n + m)
    lam = (np.sqrt(ne) + 0.12 + 0.11 / np.sqrt(ne)) * stat
    k = np.arange(1, 101)
    return float(np.clip(2 * np.sum((-1.0) ** (k - 1) * np.exp(-2 * (k * lam) ** 2)), 0, 1))


def run(tasks, episodes=3, steps=300, policy="tour", seed=0, layouts=1000,
        physics=("mujoco",), mjx_steps=100, checks=("static", "onestep", "model", "openloop",
                                                      "layouts"), log=print) -> dict:
    """All checks for `tasks`; {task: {check: result}}."""
    results = {}
    for name in tasks:
        res = {}
        ref = run_reference(["rollout", gym_id(name), seed, episodes, steps, policy])
        for ph in physics:
            sfx = "" if ph == "mujoco" else f"_{ph}"
            if "static" in checks:
                res["static" + sfx] = check_static(name, ref, episodes, ph)
            if "onestep" in checks:
                res["one_step" + sfx] = check_one_step(name, ref, episodes, ph)
            if "openloop" in checks:
                res["open_loop" + sfx] = check_open_loop(
                    name, ref, episodes, ph, mjx_steps if ph == "mjx" else None)
        if "model" in checks:
            res["model"] = check_model(name, ref, episodes)
        if "layouts" in checks:
            res["layouts"] = check_layouts(name, layouts, seed)
        results[name] = res
        if log:
            log(json.dumps({name: res}))
    return results


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tasks", default=ALL_TASKS)
    ap.add_argument("--episodes", type=int, default=3)
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--policy", default="tour", choices=("tour", "mixed", "seek", "random"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--layouts", type=int, default=1000)
    ap.add_argument("--physics", default="mujoco", help="comma list of mujoco, mjx")
    ap.add_argument("--mjx-steps", type=int, default=100)
    ap.add_argument("--checks", default="static,onestep,model,openloop,layouts")
    ap.add_argument("--out", default=None, help="write all results to this JSON file")
    args = ap.parse_args(argv)
    if not reference_python().exists():
        print(f"reference interpreter {reference_python()} not found: build the venv with "
              "../shared/reference/install-safety-gymnasium.sh and/or set R2PAC_SG_VENV",
              file=sys.stderr)
        return 2
    physics = tuple(args.physics.split(","))
    bad = set(physics) - {"mujoco", "mjx"}
    if bad:
        ap.error(f"--physics takes mujoco and/or mjx, got {sorted(bad)}")
    results = run(args.tasks.split(","), args.episodes, args.steps, args.policy, args.seed,
                  args.layouts, physics, args.mjx_steps, tuple(args.checks.split(",")),
                  log=lambda s: print(s, flush=True))
    if args.out:
        tmp = Path(args.out).with_suffix(".tmp")
        tmp.write_text(json.dumps(results, indent=1))
        os.replace(tmp, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())

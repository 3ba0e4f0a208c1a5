"""Runs INSIDE the reference virtualenv (Safety-Gymnasium 0.4.0 on MuJoCo 2.3.3) and records what
the original navigation environments do, for `compare.py` to replay in ours.

    REF_PY reference_dump.py rollout ENV_ID SEED EPISODES STEPS POLICY OUT.npz
    REF_PY reference_dump.py layouts ENV_ID SEED N OUT.npz

`rollout`: EPISODES episodes of at most STEPS steps (reset with seed SEED + e). POLICY is
`random` (uniform actions), `seek` (a noisy steering controller that drives to the goal, the
goal button or behind the push box, so goals get reached), `mixed` (seek, with every 4th
step-block of 25 steps random) or `tour` (blocks of 25 steps, each drawn as: seek the task's
target (45%), seek one randomly chosen hazard / vase / pillar / gremlin / button (40%: so that
costs occur), uniform random actions (15%)). Per episode `e`, arrays named `e{e}_<field>`:
  layout [N, 2] (the sampled layout, `reset_layout`, names in `names`), rots [N] (rotation of
  each layout object; index 0 the agent's), goal_xy [T+1, 2] (goal body), goal_button [T+1],
  timer [T+1] (button timer, -1 if none), qpos [T+1, nq], qvel [T+1, nv], mocap_pos [T+1, m, 3],
  time [T+1], warm [T+1, nv] (qacc_warmstart), obs [T+1, obs], xpos [T+1, nbody, 3],
  xmat [T+1, 9] (agent), action [T, A], reward [T], cost [T], terminated [T], truncated [T],
  goal_met [T], cost_parts [T, K] (names in `cost_names`). Row 0 is the state after reset.
  twin_reward [T], twin_cost [T], twin_xy [T+1, 2] (agent XY): a second copy of the original,
  reset with the same seed,
  replaying the same actions, whose agent velocities get + TWIN_EPS at state TWIN_START (the
  open-loop check's start): how fast the original itself forgets a tiny perturbation.
Global: names, body_names, xml (the first episode's MJCF), cost_names.

`layouts`: N layouts drawn by the original's own sampler (`RandomGenerator.build_layout`, then
the goal re-draw `sample_goal_position` its `update_world` performs, and the agent / object
rotations `_build_world_config` draws) without compiling a MuJoCo world per reset (1.35 s
each): layout [N, n, 2] (after the goal re-draw), layout_initial [N, n, 2], names.
"""
import sys
import warnings

warnings.filterwarnings("ignore")

import gymnasium  # noqa: E402
import numpy as np  # noqa: E402
import safety_gymnasium  # noqa: E402,F401  (registers the Safety*Gymnasium ids)

COST_NAMES = ("cost_hazards", "cost_vases_contact", "cost_vases_velocity", "cost_pillars",
              "cost_buttons", "cost_gremlins")


def _ego(task, xy):
    return task._ego_xy(np.asarray(xy)[:2])


def _target(task):
    """World XY point the seek controller drives to. Push: go to a point behind the box (seen
    from the goal), and once roughly behind it, drive through the box towards the goal."""
    name = type(task).__name__
    if name.startswith("Push"):
        box = task.push_box.pos[:2]
        goal = task.goal.pos[:2]
        u = (goal - box) / (np.linalg.norm(goal - box) + 1e-9)
        v = box - task.agent.pos[:2]
        dist = np.linalg.norm(v)
        if dist < 0.5 and v @ u > 0.9 * dist:
            return box + 0.3 * u
        return box - 0.35 * u
    return task.goal.pos[:2]


OBJECT_KINDS = ("hazards", "vases", "pillars", "gremlins", "buttons")
TWIN_EPS = 1e-9
TWIN_START = 1


def _objects(task):
    """World XY positions of every hazard / vase / pillar / gremlin / button of the task."""
    out = []
    for kind in OBJECT_KINDS:
        obj = getattr(task, kind, None)
        if obj is not None and getattr(obj, "num", 0):
            out += [np.asarray(p)[:2] for p in obj.pos]
    return out


def seek_action(task, rng, target=None):
    ex, ey = _ego(task, _target(task) if target is None else target)
    if type(task.agent).__name__ == "Car":  # drives along its -y axis; (1, -1) turns left
        ang = np.arctan2(ex, -ey)
        turn = np.clip(1.5 * ang, -1, 1)
        fwd = 0.9 * max(0.0, np.cos(ang))
        a = np.array([fwd + turn, fwd - turn])
    else:  # Point: a[0] drives along +x, a[1] turns left
        ang = np.arctan2(ey, ex)
        a = np.array([max(0.0, np.cos(ang)), np.clip(2.0 * ang, -1, 1)])
    a = a + 0.3 * rng.normal(size=2)
    return np.clip(a, -1, 1)


def snapshot(env):
    task = env.unwrapped.task
    d, m = task.data, task.model
    goal_button = getattr(getattr(task, "buttons", None), "goal_button", None)
    timer = getattr(getattr(task, "buttons", None), "timer", None)
    return dict(
        goal_xy=d.body("goal").xpos[:2].copy(),
        goal_button=-1 if goal_button is None else int(goal_button),
        timer=-1 if timer is None else int(timer),
        qpos=d.qpos.copy(), qvel=d.qvel.copy(),
        mocap_pos=d.mocap_pos.copy().reshape(m.nmocap, 3),
        time=float(d.time), warm=d.qacc_warmstart.copy(),
        xpos=d.xpos.copy(), xmat=task.agent.mat.reshape(9).copy())


def rollout(env_id, seed, episodes, steps, policy, out):
    env = gymnasium.make(env_id)
    u = env.unwrapped
    rec, meta = {}, {}
    for e in range(episodes):
        rng = np.random.default_rng(1000 * seed + e)
        obs, _ = env.reset(seed=seed + e)
        task = u.task
        names = list(task.placements_conf.placements)
        wc = task.world_info.world_config_dict
        rots = [wc["agent_rot"]]
        for n in names[1:]:
            for kind in ("geoms", "free_geoms", "mocaps"):
                for key in (n, n + "obj"):
                    if key in wc[kind]:
                        rots.append(wc[kind][key]["rot"])
                        break
                else:
                    continue
                break
        assert len(rots) == len(names), (names, rots)
        layout = np.array([task.world_info.reset_layout[n] for n in names])
        snaps = [snapshot(env)]
        obs_l, act, rew, cost, term, trunc, met, parts = [obs], [], [], [], [], [], [], []
        block, obj_index = "seek", None
        for t in range(steps):
            if policy == "tour" and t % 25 == 0:
                u_ = rng.uniform()
                block = "seek" if u_ < 0.45 else ("object" if u_ < 0.85 else "random")
                obj_index = rng.integers(1 << 30)
            block_random = (policy == "random" or (policy == "mixed" and (t // 25) % 4 == 3)
                            or (policy == "tour" and block == "random"))
            if block_random:
                a = rng.uniform(-1, 1, 2)
            elif policy == "tour" and block == "object":
                objs = _objects(task)
                a = seek_action(task, rng, objs[obj_index % len(objs)])
            else:
                a = seek_action(task, rng)
            # DSRL's ids are the gymnasium-API versions: the cost comes in info["cost"]
            obs, r, te, tr, info = env.step(a)
            c = info["cost"]
            snaps.append(snapshot(env))
            obs_l.append(obs)
            act.append(a)
            rew.append(r)
            cost.append(c)
            term.append(te)
            trunc.append(tr)
            met.append(bool(info.get("goal_met", False)))
            parts.append([float(info.get(k, 0.0)) for k in COST_NAMES])
            if te or tr:
                break
        p = f"e{e}_"
        rec[p + "twin_reward"], rec[p + "twin_cost"], rec[p + "twin_xy"] = twin(
            env_id, seed + e, np.array(act))
        rec[p + "layout"] = layout
        rec[p + "rots"] = np.array(rots)
        for k in snaps[0]:
            rec[p + k] = np.array([s[k] for s in snaps])
        rec[p + "obs"] = np.array(obs_l)
        rec[p + "action"] = np.array(act)
        rec[p + "reward"] = np.array(rew)
        rec[p + "cost"] = np.array(cost)
        rec[p + "terminated"] = np.array(term)
        rec[p + "truncated"] = np.array(trunc)
        rec[p + "goal_met"] = np.array(met)
        rec[p + "cost_parts"] = np.array(parts).reshape(-1, len(COST_NAMES))
        if e == 0:
            meta["names"] = np.array(names)
            meta["xml"] = np.array(task.world.xml_string)
            m = task.model
            meta["body_names"] = np.array([m.body(i).name for i in range(m.nbody)])
    meta["cost_names"] = np.array(COST_NAMES)
    np.savez_compressed(out, **rec, **meta)


def twin(env_id, seed, actions):
    """Rewards and costs [T] of the original replaying `actions` from the same reset, with its
    agent velocities moved by TWIN_EPS at state TWIN_START."""
    env = gymnasium.make(env_id)
    env.reset(seed=seed)
    task = env.unwrapped.task
    nv_agent = task.agent.body_info.nv
    rew, cost, xy = [], [], [task.agent.pos[:2].copy()]
    for t, a in enumerate(actions):
        if t == TWIN_START:
            task.data.qvel[:nv_agent] += TWIN_EPS
        _, r, te, tr, info = env.step(a)
        rew.append(r)
        cost.append(info["cost"])
        xy.append(task.agent.pos[:2].copy())
        if te or tr:
            break
    env.close()
    return np.array(rew), np.array(cost), np.array(xy)


def layouts(env_id, seed, n, out):
    env = gymnasium.make(env_id)
    task = env.unwrapped.task
    env.reset(seed=seed)  # builds the placements table and seeds the generator
    gen = task.random_generator
    gen.set_random_seed(seed)
    names = list(task.placements_conf.placements)
    init, final, rots = [], [], []
    for _ in range(n):
        lay = gen.build_layout()
        init.append([lay[k] for k in names])
        rots.append(gen.random_rot())
        if "goal" in lay and not type(task).__name__.startswith("Button"):
            del lay["goal"]
            for _ in range(10000):
                if gen.sample_goal_position():
                    break
        final.append([gen.layout[k] for k in names])
    np.savez_compressed(out, layout=np.array(final), layout_initial=np.array(init),
                        agent_rot=np.array(rots), names=np.array(names))


def main():
    mode = sys.argv[1]
    if mode == "rollout":
        env_id, seed, episodes, steps, policy, out = sys.argv[2:8]
        rollout(env_id, int(seed), int(episodes), int(steps), policy, out)
    elif mode == "layouts":
        env_id, seed, n, out = sys.argv[2:6]
        layouts(env_id, int(seed), int(n), out)
    else:
        raise SystemExit(__doc__)


if __name__ == "__main__":
    main()

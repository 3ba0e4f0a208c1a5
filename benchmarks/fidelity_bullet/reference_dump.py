"""Runs INSIDE the reference virtualenv (Bullet-Safety-Gym 1.4.0 on pybullet 3.2.7; build it with
../shared/reference/install-bullet-safety-gym.sh) and records what the original environments do,
for our `bullet` backend to replay (tests/test_bullet_fidelity.py, compare.py).

    REF_PY reference_dump.py rollout ENV_ID SEED EPISODES OUT.npz
    REF_PY reference_dump.py resets ENV_ID SEED N OUT.npz
    REF_PY reference_dump.py speed ENV_ID STEPS      (prints env steps/s, one env, random actions)
    REF_PY reference_dump.py leak ENV_ID             (prints 4 one-step episodes of one instance)

`rollout`: EPISODES episodes, each on a fresh instance of the original (`np.random.seed(SEED + e)`
before its reset: the original's reset noise comes from the global generator), full length:
our backend builds every episode's world afresh (engine.py), which is the original's first
episode after construction. Episode e takes
actions by pattern e % 4: 0 uniform in [-1, 1]; 1 blocks of 10 steps holding one uniform action
(speed builds up, so the velocity and boundary costs occur); 2 as 1 plus N(0, 0.3) noise, then
clipped; 3 the first component at 1, the others 0 (straight ahead). Actions are float32, as a policy gives them. Per episode e, arrays `e{e}_<field>`:
  pose_pos [3], pose_quat [4] (x, y, z, w), joint_pos [J], joint_vel [J] (the agent's motor
  joints, in index order): the state the task's
  `specific_reset` leaves, before the reset's own `stepSimulation` (what our `reset_to` takes);
  obs [T+1, obs] (row 0 after reset), action [T, A], reward [T], cost [T], terminated [T],
  truncated [T], base_pos [T+1, 3], base_quat [T+1, 4], base_vel [T+1, 3], base_angvel [T+1, 3].
Global `floor_obs`, `floor_reward`, `floor_pos`: the largest differences between these episodes
and a second fresh instance of the original replaying each (np.random re-seeded, so the same
sampled positions: the injection our replay uses) -- the original-against-original floor.
`consecutive_obs` [EPISODES]: the largest observation difference of each episode replayed in
ONE instance one after another (the original's own use) against its fresh-instance record: how
much the original's history (restoreState keeps solver caches) changes an episode, over the
steps both have; `consecutive_length` [EPISODES]: the consecutive episode's length minus the
fresh one's.
`resets`: N resets, each of a fresh instance (np.random.seed(SEED + i)): obs [N, obs] (after
reset), pose_pos [N, 3], pose_quat [N, 4], joint_pos [N, J].
"""
import sys
import warnings

warnings.filterwarnings("ignore")

import gymnasium  # noqa: E402
import numpy as np  # noqa: E402
import bullet_safety_gym  # noqa: E402,F401  (registers the Safety* ids)


class Recorder:
    """Wraps the task's specific_reset to read the pre-step state it leaves."""

    def __init__(self, env):
        self.u = env.unwrapped
        self.last = None
        task = self.u.task
        orig = task.specific_reset

        def wrapped():
            orig()
            self.last = self.read_pose()

        task.specific_reset = wrapped

    def read_pose(self):
        bc, agent = self.u.bc, self.u.agent
        pos, quat = bc.getBasePositionAndOrientation(agent.body_id)
        js = [bc.getJointState(agent.body_id, j.index) for j in agent.motor_list]
        return dict(pose_pos=np.array(pos), pose_quat=np.array(quat),
                    joint_pos=np.array([j[0] for j in js]),
                    joint_vel=np.array([j[1] for j in js]))

    def base(self):
        bc, agent = self.u.bc, self.u.agent
        pos, quat = bc.getBasePositionAndOrientation(agent.body_id)
        vel, ang = bc.getBaseVelocity(agent.body_id)
        return np.array(pos), np.array(quat), np.array(vel), np.array(ang)


def actions(pattern, T, A, rng):
    if pattern == 3:  # full first action component, the rest 0: straight ahead (costs occur)
        a = np.zeros((T, A), np.float32)
        a[:, 0] = 1.0
        return a
    if pattern == 0:
        return rng.uniform(-1, 1, (T, A)).astype(np.float32)
    blocks = np.repeat(rng.uniform(-1, 1, ((T + 9) // 10, A)), 10, axis=0)[:T]
    if pattern == 2:
        blocks = np.clip(blocks + rng.normal(0, 0.3, blocks.shape), -1, 1)
    return blocks.astype(np.float32)


def play(env, rec, acts):
    """One episode from a reset already done: rows of obs, reward, cost, flags, base states."""
    rows = dict(reward=[], cost=[], terminated=[], truncated=[])
    obs, base = [], [rec.base()]
    for a in acts:
        o, r, term, trunc, info = env.step(a)
        obs.append(o)
        rows["reward"].append(r)
        rows["cost"].append(info.get("cost", 0.0))
        rows["terminated"].append(term)
        rows["truncated"].append(trunc)
        base.append(rec.base())
        if term or trunc:
            break
    return obs, rows, base


def rollout(env_id, seed, episodes, out):
    """Episode e on a fresh instance, its reset drawn after np.random.seed(seed + e); then the
    floor (a second fresh instance per episode) and the consecutive run (one instance, the
    same seeds and actions: what the original's history changes)."""
    arrays = {}
    rng = np.random.default_rng(seed + 1000)
    T = A = None
    for e in range(episodes):
        env = gymnasium.make(env_id)
        rec = Recorder(env)
        T, A = env.spec.max_episode_steps, env.action_space.shape[0]
        np.random.seed(seed + e)
        obs0, _ = env.reset()
        p = f"e{e}_"
        for k, v in rec.last.items():
            arrays[p + k] = v
        acts = actions(e % 4, T, A, rng)
        obs, rows, base = play(env, rec, acts)
        arrays[p + "obs"] = np.array([obs0] + obs)
        for k, v in rows.items():
            arrays[p + k] = np.array(v)
        arrays[p + "action"] = acts[:len(rows["reward"])]
        for i, k in enumerate(("base_pos", "base_quat", "base_vel", "base_angvel")):
            arrays[p + k] = np.array([b[i] for b in base])
        env.close()
    floor = dict(obs=0.0, reward=0.0, pos=0.0)
    consecutive = gymnasium.make(env_id)
    crec = Recorder(consecutive)
    leak, lengths = [], []
    for e in range(episodes):
        p = f"e{e}_"
        twin = gymnasium.make(env_id)
        trec = Recorder(twin)
        for env, r, fresh in ((twin, trec, True), (consecutive, crec, False)):
            np.random.seed(seed + e)
            obs0, _ = env.reset()
            obs, rows, base = play(env, r, arrays[p + "action"])
            n = min(len(obs) + 1, len(arrays[p + "obs"]))  # a history can change the length
            d_obs = float(np.abs(np.array([obs0] + obs)[:n] - arrays[p + "obs"][:n]).max())
            if fresh:
                floor["obs"] = max(floor["obs"], d_obs)
                floor["reward"] = max(floor["reward"], float(np.abs(
                    np.array(rows["reward"]) - arrays[p + "reward"]).max()))
                floor["pos"] = max(floor["pos"], float(np.abs(
                    np.array([b[0] for b in base]) - arrays[p + "base_pos"]).max()))
            else:
                leak.append(d_obs)
                lengths.append(len(obs) - len(arrays[p + "action"]))
        twin.close()
    np.savez_compressed(out, env_id=env_id, seed=seed, episodes=episodes,
                        **{f"floor_{k}": v for k, v in floor.items()},
                        consecutive_obs=np.array(leak), consecutive_length=np.array(lengths),
                        **arrays)


def resets(env_id, seed, n, out):
    """N resets, each on a fresh instance after np.random.seed(seed + i) (as our backend starts
    every episode; a long-lived instance's resets carry its history, see `rollout`)."""
    obs, pos, quat, joints = [], [], [], []
    for i in range(n):
        env = gymnasium.make(env_id)
        rec = Recorder(env)
        np.random.seed(seed + i)
        o, _ = env.reset()
        obs.append(o)
        pos.append(rec.last["pose_pos"])
        quat.append(rec.last["pose_quat"])
        joints.append(rec.last["joint_pos"])
        env.close()
    np.savez_compressed(out, env_id=env_id, seed=seed, obs=np.array(obs), pose_pos=np.array(pos),
                        pose_quat=np.array(quat), joint_pos=np.array(joints))


def speed(env_id, steps):
    import time

    env = gymnasium.make(env_id)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    t0 = time.perf_counter()
    for _ in range(steps):
        _, _, term, trunc, _ = env.step(rng.uniform(-1, 1, env.action_space.shape).astype(
            np.float32))
        if term or trunc:
            env.reset()
    print(f"{steps / (time.perf_counter() - t0):.0f}")


def leak(env_id):
    """Four episodes of one step each, the same sampled position and action: the original's
    episodes after the first restore a saved state, but pybullet keeps the contact manifold of
    the episode before, so the first step's velocity alternates."""
    env = gymnasium.make(env_id)
    a = np.array([0.3, -0.7], np.float32)
    for i in range(4):
        np.random.seed(5)
        env.reset()
        obs, *_ = env.step(a)
        print(i, "velocity after one step:", np.round(obs[2:4] / 0.2, 8))


if __name__ == "__main__":
    cmd, env_id = sys.argv[1], sys.argv[2]
    if cmd == "rollout":
        rollout(env_id, int(sys.argv[3]), int(sys.argv[4]), sys.argv[5])
    elif cmd == "resets":
        resets(env_id, int(sys.argv[3]), int(sys.argv[4]), sys.argv[5])
    elif cmd == "leak":
        leak(env_id)
    elif cmd == "speed":
        speed(env_id, int(sys.argv[3]))
    else:
        raise SystemExit(f"unknown command {cmd!r}: rollout, resets or speed")

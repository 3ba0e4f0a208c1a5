"""Runs INSIDE the reference virtualenv (Bullet-Safety-Gym 1.4.0 on pybullet 3.2.7; build it with
../shared/reference/install-bullet-safety-gym.sh) and records what the original environments do,
for our `bullet` backend to replay (tests/test_bullet_fidelity.py, compare.py).

    REF_PY reference_dump.py rollout ENV_ID SEED EPISODES OUT.npz
    REF_PY reference_dump.py resets ENV_ID SEED N OUT.npz
    REF_PY reference_dump.py speed ENV_ID STEPS      (prints env steps/s, one env, random actions)
    REF_PY reference_dump.py leak ENV_ID             (prints 4 one-step episodes of one instance)

`rollout`: EPISODES consecutive episodes of one environment instance (`np.random.seed(SEED)`,
the original's reset noise comes from the global generator), full length. Episode e takes
actions by pattern e % 3: 0 uniform in [-1, 1]; 1 blocks of 10 steps holding one uniform action
(speed builds up, so the velocity and boundary costs occur); 2 as 1 plus N(0, 0.3) noise, then
clipped. Actions are float32, as a policy gives them. Per episode e, arrays `e{e}_<field>`:
  pose_pos [3], pose_quat [4] (x, y, z, w), joint_pos [J], joint_vel [J]: the state the task's
  `specific_reset` leaves, before the reset's own `stepSimulation` (what our `reset_to` takes);
  obs [T+1, obs] (row 0 after reset), action [T, A], reward [T], cost [T], terminated [T],
  truncated [T], base_pos [T+1, 3], base_quat [T+1, 4], base_vel [T+1, 3], base_angvel [T+1, 3].
Global `floor_obs`, `floor_reward`, `floor_pos`: the largest differences between these episodes
and a second instance of the original replaying them (np.random re-seeded, so the same sampled
positions: the injection our replay uses) -- the original-against-original floor.
`resets`: N resets of one instance: obs [N, obs] (after reset), pose_pos [N, 3],
pose_quat [N, 4].
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
        n = bc.getNumJoints(agent.body_id)
        js = [bc.getJointState(agent.body_id, j) for j in range(n)]
        return dict(pose_pos=np.array(pos), pose_quat=np.array(quat),
                    joint_pos=np.array([j[0] for j in js]),
                    joint_vel=np.array([j[1] for j in js]))

    def base(self):
        bc, agent = self.u.bc, self.u.agent
        pos, quat = bc.getBasePositionAndOrientation(agent.body_id)
        vel, ang = bc.getBaseVelocity(agent.body_id)
        return np.array(pos), np.array(quat), np.array(vel), np.array(ang)


def actions(pattern, T, A, rng):
    if pattern == 0:
        return rng.uniform(-1, 1, (T, A)).astype(np.float32)
    blocks = np.repeat(rng.uniform(-1, 1, ((T + 9) // 10, A)), 10, axis=0)[:T]
    if pattern == 2:
        blocks = np.clip(blocks + rng.normal(0, 0.3, blocks.shape), -1, 1)
    return blocks.astype(np.float32)


def rollout(env_id, seed, episodes, out):
    np.random.seed(seed)
    env = gymnasium.make(env_id)
    rec = Recorder(env)
    T = env.spec.max_episode_steps
    A = env.action_space.shape[0]
    rng = np.random.default_rng(seed + 1)
    arrays = {}
    for e in range(episodes):
        obs, _ = env.reset()
        p = f"e{e}_"
        for k, v in rec.last.items():
            arrays[p + k] = v
        acts = actions(e % 3, T, A, rng)
        rows = dict(obs=[obs], reward=[], cost=[], terminated=[], truncated=[])
        base = [rec.base()]
        for t in range(T):
            obs, r, term, trunc, info = env.step(acts[t])
            rows["obs"].append(obs)
            rows["reward"].append(r)
            rows["cost"].append(info.get("cost", 0.0))
            rows["terminated"].append(term)
            rows["truncated"].append(trunc)
            base.append(rec.base())
            if term or trunc:
                break
        for k, v in rows.items():
            arrays[p + k] = np.array(v)
        arrays[p + "action"] = acts[:len(rows["reward"])]
        for i, k in enumerate(("base_pos", "base_quat", "base_vel", "base_angvel")):
            arrays[p + k] = np.array([b[i] for b in base])
    # the floor: a second instance, the same sampled positions and actions
    np.random.seed(seed)
    twin = gymnasium.make(env_id)
    twin_rec = Recorder(twin)
    floor = dict(obs=0.0, reward=0.0, pos=0.0)
    for e in range(episodes):
        p = f"e{e}_"
        obs, _ = twin.reset()
        floor["obs"] = max(floor["obs"], float(np.abs(obs - arrays[p + "obs"][0]).max()))
        for t, a in enumerate(arrays[p + "action"]):
            obs, r, *_ = twin.step(a)
            floor["obs"] = max(floor["obs"], float(np.abs(obs - arrays[p + "obs"][t + 1]).max()))
            floor["reward"] = max(floor["reward"], abs(r - arrays[p + "reward"][t]))
            floor["pos"] = max(floor["pos"], float(np.abs(
                twin_rec.base()[0] - arrays[p + "base_pos"][t + 1]).max()))
    np.savez_compressed(out, env_id=env_id, seed=seed, episodes=episodes,
                        **{f"floor_{k}": v for k, v in floor.items()}, **arrays)


def resets(env_id, seed, n, out):
    np.random.seed(seed)
    env = gymnasium.make(env_id)
    rec = Recorder(env)
    obs, pos, quat = [], [], []
    for _ in range(n):
        o, _ = env.reset()
        obs.append(o)
        pos.append(rec.last["pose_pos"])
        quat.append(rec.last["pose_quat"])
    np.savez_compressed(out, env_id=env_id, seed=seed, obs=np.array(obs), pose_pos=np.array(pos),
                        pose_quat=np.array(quat))


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

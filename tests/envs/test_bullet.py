"""The Bullet-Safety-Gym tasks on the `bullet` backend (pybullet 3.2.7, `pip install -e
'.[bullet]'`), checked against recordings of the original (tests/fixtures/bullet, made by
benchmarks/fidelity_bullet/reference_dump.py inside the original's virtualenv; see
benchmarks/FIDELITY.md, "Bullet tasks")."""
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

pytest.importorskip("pybullet", reason="pip install -e '.[bullet]' (pybullet==3.2.7)")

from r2pac_jax.envs.base import BackendUnavailableError  # noqa: E402
from r2pac_jax.envs.bullet import make_env  # noqa: E402
from r2pac_jax.envs.bullet.engine import StaleStateError  # noqa: E402
from r2pac_jax.tasks import get_task  # noqa: E402

FIX = Path(__file__).parents[1] / "fixtures" / "bullet"
PORTED = ["BallRun", "BallCircle", "CarRun", "CarCircle", "DroneRun", "DroneCircle", "AntRun",
          "AntCircle"]


def replay(env, d, e):
    """Episode e of a recording replayed in our env from the original's sampled position."""
    p = f"e{e}_"
    st = env.reset_to(dict(pos=d[p + "pose_pos"][None], joints=d[p + "joint_pos"][None]))
    out = dict(obs=[st.obs[0]], reward=[], cost=[], pos=[st.physics["pos"][0]])
    for a in d[p + "action"]:
        st = env.step_batch(st, a[None])
        out["obs"].append(st.obs[0])
        out["reward"].append(st.reward[0])
        out["cost"].append(st.cost[0])
        out["pos"].append(st.physics["pos"][0])
    return {k: np.array(v) for k, v in out.items()}, st


@pytest.mark.parametrize("task", PORTED)
def test_replay_matches_the_original(task):
    """Same engine, same calls: the simulation is the original's bit for bit; observations and
    rewards differ by float32 rounding only (the original computes them in float64). The
    recordings are fresh instances of the original; ours runs them one after another in one
    client (each episode's world is rebuilt)."""
    d = np.load(FIX / f"{task}_rollout.npz")
    assert float(d["floor_pos"]) == 0.0 and float(d["floor_obs"]) == 0.0  # original vs original
    env = make_env(get_task(task))
    costs = 0
    for e in range(int(d["episodes"])):
        ours, _ = replay(env, d, e)
        p = f"e{e}_"
        assert ours["obs"].shape == d[p + "obs"].shape
        np.testing.assert_array_equal(ours["pos"], d[p + "base_pos"])
        assert np.abs(ours["obs"] - d[p + "obs"]).max() <= 1e-6
        assert np.abs(ours["reward"] - d[p + "reward"]).max() <= 1e-5
        np.testing.assert_array_equal(ours["cost"], d[p + "cost"])
        costs += d[p + "cost"].sum()
    if task in ("BallRun", "BallCircle", "CarRun", "DroneRun", "DroneCircle"):
        assert costs > 0  # the others' open-loop recordings cost nothing (CarCircle stays in
        # |x| <= 6, the Ants stay slow): their rules are checked by test_rules


def ks_statistic(a, b):
    """Two-sample Kolmogorov-Smirnov statistic (ties handled on the pooled values)."""
    a, b = np.sort(a), np.sort(b)
    x = np.concatenate([a, b])
    return np.abs(np.searchsorted(a, x, "right") / a.size
                  - np.searchsorted(b, x, "right") / b.size).max()


# the default suite checks the four Run tasks and BallCircle (the Circle reset law is one
# sampler for every robot); the other Circle tasks and 1,000 resets each run with -m slow
SLOW = pytest.mark.slow
RESET_CASES = [pytest.param(t, 200, marks=[SLOW] if t in ("CarCircle", "DroneCircle", "AntCircle")
                            else []) for t in PORTED] + [pytest.param(t, 1000, marks=SLOW)
                                                         for t in PORTED]


@pytest.mark.parametrize("task,n", RESET_CASES)
def test_reset_distribution_matches_the_original(task, n):
    """n resets of ours against 1,000 of the original (fresh instances, global np.random there;
    JAX keys here): every observation entry, the sampled position and the robots' joints pass a
    two-sample KS test at alpha = 0.001 (critical D = 1.95 sqrt((n + 1000) / (1000 n)): 0.151
    for the default suite's 200, 0.087 for the slow run's 1,000). Entries that are zero up to
    rounding in the original (the ball's velocities after the reset's settling step, ~1e-16,
    whose noise follows the last bits of the sampled position; the Car's sin(yaw) at yaw pi,
    -8.7e-8 in our float32) are held to |x| < 1e-6 instead."""
    d = np.load(FIX / f"{task}_resets.npz")
    env = make_env(get_task(task))
    obs, pos, joints = [], [], []
    for k in jax.random.split(jax.random.PRNGKey(7), n // 100):  # x 100, clients recycled
        st = env.reset_batch(jax.random.split(k, 100))
        obs.append(st.obs)
        pos.append(st.physics["start"])
        joints.append(st.physics["start_joints"])
        env.release(st)
    obs, pos, joints = np.concatenate(obs), np.concatenate(pos), np.concatenate(joints)
    assert len(env._worlds) == 100
    m = len(d["obs"])
    crit = 1.949 * np.sqrt((len(obs) + m) / (len(obs) * m))
    for j in range(obs.shape[1]):
        if np.ptp(d["obs"][:, j]) < 1e-5:  # constant up to rounding: compare the values
            assert np.abs(obs[:, j] - d["obs"][:, j].mean()).max() < 1e-5, j
        else:
            assert ks_statistic(obs[:, j], d["obs"][:, j]) < crit, j
    for j in range(2):
        assert ks_statistic(pos[:, j], d["pose_pos"][:, j]) < crit, j
    assert joints.shape[1] == d["joint_pos"].shape[1]
    for j in range(joints.shape[1]):  # the Car's 14 joint positions U(-0.1, 0.1)
        assert ks_statistic(joints[:, j], d["joint_pos"][:, j]) < crit, j
    np.testing.assert_allclose(pos[:, 2], d["pose_pos"][0, 2])  # the robot's height
    # and the support: Run within 0.01 of the origin; Circle on the annulus 2..4
    r = np.linalg.norm(pos[:, :2], axis=1)
    if task.endswith("Run"):
        assert np.abs(pos[:, :2]).max() <= 0.01
    else:
        assert r.min() >= 2 - 1e-6 and r.max() <= 4 + 1e-6


def test_rules():
    """The task functions on hand-made views: the Run progress against float64 arithmetic,
    the Circle reward and both cost rules, the Car's heading."""
    from r2pac_jax.envs.bullet.tasks import progress

    xy = np.array([23.4567, -1.25])
    d = np.array([0.31, 0.02])
    g = np.array([1000.0, 0.0])
    want = 60 * (np.linalg.norm(xy - g) - np.linalg.norm(xy + d - g))
    assert abs(float(progress(jax.numpy.asarray(xy), jax.numpy.asarray(d))) - want) < 1e-5 * 60

    def view(pos, vel=(0, 0, 0), yaw=0.0):
        q = np.array([0, 0, np.sin(yaw / 2), np.cos(yaw / 2)])
        return {k: jax.numpy.asarray(v, jax.numpy.float32) for k, v in dict(
            pos=pos, quat=q, vel=vel, angvel=(0, 0, 0.5), dpos=(0, 0, 0)).items()}

    run = make_env(get_task("CarRun")).task
    circle = make_env(get_task("BallCircle")).task
    a = jax.numpy.zeros(2)
    e = circle.empty_extras()
    for y, v, cost in ((2.1, 0.0, 1.0), (1.9, 0.0, 0.0), (0.0, 1.6, 1.0), (0.0, 1.4, 0.0)):
        _, c, term, _ = run.transition(view((0, 0, .2)), view((5, y, .2), (v, 0, 0)), a, e)
        assert float(c) == cost and not bool(term)
    for x, cost in ((6.1, 1.0), (-6.1, 1.0), (5.9, 0.0)):
        _, c, _, _ = circle.transition(view((0, 0, .5)), view((x, 0, .5)), a, e)
        assert float(c) == cost
    # clockwise at radius 7 with speed 2: 0.1 * 7 * 2 / (1 + 0); anticlockwise is negative
    r, _, _, _ = circle.transition(view((7, 0, .5)), view((7, 0, .5), (0, -2, 0)), a, e)
    assert abs(float(r) - 1.4) < 1e-6
    r, _, _, _ = circle.transition(view((7, 0, .5)), view((7, 0, .5), (0, 2, 0)), a, e)
    assert abs(float(r) + 1.4) < 1e-6
    assert abs(float(circle.observe(view((0, 9, .5)), e)[-1]) - 0.2) < 1e-6  # (9 - 7) / 10
    obs = run.observe(view((3, 4, .2), (1, 2, 0), yaw=2.0), e)
    np.testing.assert_allclose(obs, [0.3, 0.4, 1, 2, np.sin(2.0), np.cos(2.0), 0.05], atol=1e-6)


def test_same_keys_same_episodes_whatever_the_client():
    """Determinism: the same keys give the same episodes in a fresh env and in one whose
    clients ran other episodes before (a reset restores the saved state: no history leaks)."""
    task = get_task("BallCircle")
    keys = jax.random.split(jax.random.PRNGKey(3), 3)
    acts = np.asarray(jax.random.uniform(jax.random.PRNGKey(4), (40, 3, 2), minval=-1, maxval=1))

    def run(env):
        st = env.reset_batch(keys)
        obs = [st.obs]
        for a in acts:
            st = env.step_batch(st, a)
            obs.append(st.obs)
        return np.stack(obs), st

    fresh, _ = run(make_env(task))
    used = make_env(task)
    other = used.reset_batch(jax.random.split(jax.random.PRNGKey(9), 3))
    for a in acts[::-1]:
        other = used.step_batch(other, a)
    used.release(other)
    again, st = run(used)
    assert len(used._worlds) == 3  # the same clients served both
    np.testing.assert_array_equal(fresh, again)


def test_an_episode_does_not_depend_on_the_one_before():
    """The original's reset restores a saved state but pybullet keeps the previous episode's
    contact manifold, so one-step episodes from the same position alternate there (its first
    step's velocity differs by 0.037 m/s; reference_dump.py leak). Ours rebuilds the world per
    episode: the same episode every time."""
    env = make_env(get_task("BallCircle"))
    a = np.array([[0.3, -0.7]], np.float32)
    firsts = []
    for _ in range(3):
        st = env.reset_to(dict(pos=np.array([[2.5, 1.0, 0.5]])))
        st = env.step_batch(st, a)
        firsts.append(st.physics["vel"])
        env.release(st)
    assert len(env._worlds) == 1
    np.testing.assert_array_equal(firsts[0], firsts[1])
    np.testing.assert_array_equal(firsts[0], firsts[2])


@pytest.mark.filterwarnings("ignore::UserWarning")  # check_env's notes on infinite obs bounds
@pytest.mark.parametrize("task", [pytest.param(t, marks=[] if t.startswith("Ball") else [SLOW])
                                  for t in PORTED])
def test_gymnasium_check_env(task):
    from gymnasium.utils.env_checker import check_env

    from r2pac_jax.envs import gym_env

    check_env(gym_env(task, seed=0), skip_render_check=True)


def test_stale_state_is_refused():
    env = make_env(get_task("BallRun"))
    s0 = env.reset_batch(jax.random.split(jax.random.PRNGKey(0), 2))
    env.step_batch(s0, np.zeros((2, 2), np.float32))
    with pytest.raises(StaleStateError, match="latest state"):
        env.step_batch(s0, np.zeros((2, 2), np.float32))


def test_ended_episodes_free_their_clients_and_can_still_be_stepped():
    env = make_env(get_task("BallRun"))
    st = env.reset_batch(jax.random.split(jax.random.PRNGKey(0), 2))
    for _ in range(env.episode_len):
        st = env.step_batch(st, np.ones((2, 2), np.float32))
    assert st.truncated.all() and not st.terminated.any()
    st = env.step_batch(st, np.ones((2, 2), np.float32))  # past the end, as evaluate does
    fresh = env.reset_batch(jax.random.split(jax.random.PRNGKey(1), 2))
    assert len(env._worlds) == 2  # recycled
    with pytest.raises(StaleStateError):
        env.step_batch(st, np.ones((2, 2), np.float32))
    assert fresh.t.tolist() == [0, 0]


@pytest.mark.parametrize("steps", [0, 7])
def test_revive_rebuilds_episodes_bit_for_bit(steps):
    """A state saved mid-episode and loaded by a new env (its simulations gone): each episode
    is rebuilt from its start by replaying its recorded actions, and continues as the original
    would have."""
    task = get_task("CarCircle")
    env = make_env(task)
    st = env.reset_batch(jax.random.split(jax.random.PRNGKey(5), 2))
    acts = np.asarray(jax.random.uniform(jax.random.PRNGKey(6), (steps + 3, 2, 2),
                                         minval=-1.2, maxval=1.2))
    for a in acts[:steps]:
        st = env.step_batch(st, a)
    saved = jax.tree_util.tree_map(np.asarray, st)
    other = make_env(task)
    revived = other.revive(saved)
    for a in acts[steps:]:
        st, revived = env.step_batch(st, a), other.step_batch(revived, a)
        np.testing.assert_array_equal(st.obs, revived.obs)
        np.testing.assert_array_equal(st.physics["pos"], revived.physics["pos"])


def test_bad_input():
    env = make_env(get_task("BallRun"))
    st = env.reset_batch(jax.random.split(jax.random.PRNGKey(0), 2))
    with pytest.raises(ValueError, match="shape"):
        env.step_batch(st, np.zeros((2, 3), np.float32))
    with pytest.raises(ValueError, match="NaN"):
        env.step_batch(st, np.full((2, 2), np.nan, np.float32))
    with pytest.raises(BackendUnavailableError, match="auto, bullet, mjx or mujoco"):
        get_task("BallRun").make_env(physics="jax")
    with pytest.raises(ValueError, match="not a Bullet-Safety-Gym task"):
        from r2pac_jax.envs.bullet.tasks import make_task

        make_task(get_task("CarGoal1"))


def test_too_many_clients_is_refused_and_envs_free_theirs(monkeypatch):
    import gc

    import pybullet as pb

    from r2pac_jax.envs.bullet import engine

    env = make_env(get_task("BallRun"))
    st = env.reset_batch(jax.random.split(jax.random.PRNGKey(0), 3))
    cids = [w.cid for w in env._worlds]
    monkeypatch.setenv("R2PAC_BULLET_MAX_CLIENTS", str(engine._LIVE[0] + 2))
    with pytest.raises(MemoryError, match="R2PAC_BULLET_MAX_CLIENTS"):
        make_env(get_task("BallRun")).reset_batch(jax.random.split(jax.random.PRNGKey(1), 3))
    env.release(st)
    env.reset_batch(jax.random.split(jax.random.PRNGKey(1), 3))  # recycled: no new client
    del env, st
    gc.collect()
    assert not any(pb.getConnectionInfo(c)["isConnected"] for c in cids)


def test_evaluation_groups_lanes_under_the_client_limit(monkeypatch):
    """More lanes x episodes than the process may hold clients for: the evaluator runs the
    lanes in groups, with the same scores as all at once."""
    from r2pac_jax.envs.bullet import engine
    from r2pac_jax.evaluate import LaneEvaluator

    task = get_task("BallRun")

    def act(params, obs, key):  # a fixed linear policy per lane
        return jnp.tanh(obs[:, :2] * params["w"])

    params = {"w": jnp.array([0.5, -1.0, 2.0])}
    keys = jax.random.split(jax.random.PRNGKey(4), 3)
    env = make_env(task)
    free = LaneEvaluator(act, task, episodes=2, env=env)(params, keys)
    env.close()
    monkeypatch.setenv("R2PAC_BULLET_MAX_CLIENTS", str(engine._LIVE[0] + 4))
    grouped_env = make_env(task)
    assert grouped_env.max_parallel == 4  # 3 lanes x 2 episodes = 6 > 4: groups of 2 lanes
    grouped = LaneEvaluator(act, task, episodes=2, env=grouped_env)(params, keys)
    for k in ("returns", "costs", "lengths"):
        np.testing.assert_array_equal(free[k], grouped[k])
    assert len(grouped_env._worlds) <= 4
    with pytest.raises(MemoryError, match="evaluation episodes"):
        LaneEvaluator(act, task, episodes=5, env=grouped_env)(params, keys)


def test_a_dsrl_file_of_the_wrong_width_is_refused(tmp_path):
    """A Bullet task's DSRL file whose observations do not match the task (BallCircle has 8,
    BallRun 7) is refused naming both sizes."""
    import h5py

    from r2pac_jax.data import DatasetError, load_task_dataset

    n = 4
    path = tmp_path / "SafetyBallRun-v0-80-940.hdf5"
    with h5py.File(path, "w") as f:
        for k, shape in (("observations", (n, 8)), ("next_observations", (n, 8)),
                         ("actions", (n, 2))):
            f[k] = np.zeros(shape, np.float32)
        for k in ("rewards", "costs"):
            f[k] = np.zeros(n, np.float32)
        f["terminals"] = np.zeros(n, bool)
        f["timeouts"] = np.array([False, False, False, True])
    with pytest.raises(DatasetError, match=r"observations.*size 8.*BallRun.*size 7|"
                                           r"BallRun has observations of size 7"):
        load_task_dataset(get_task("BallRun"), str(path), announce=lambda m: None)


def test_missing_pybullet_names_the_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "pybullet", None)
    with pytest.raises(BackendUnavailableError, match=r"pip install -e '\.\[bullet\]'"):
        make_env(get_task("BallRun"))


def test_gym_wrapper_and_evaluation():
    from r2pac_jax.envs import gym_env
    from r2pac_jax.evaluate import evaluate

    g = gym_env("BallRun", seed=0)
    assert g.physics == "bullet"
    obs, _ = g.reset()
    assert obs.shape == (7,)
    for _ in range(3):
        obs, r, term, trunc, info = g.step(np.array([1.0, 0.0], np.float32))
    g.reset()  # mid-episode: the client is released, not leaked
    g.reset()
    assert len(g.env._worlds) == 1

    def push(params, obs, key):
        return jax.numpy.tile(params, (obs.shape[0], 1))

    task = get_task("BallRun")
    out = evaluate(push, jax.numpy.array([1.0, 0.0]), task, episodes=2,
                   key=jax.random.PRNGKey(0))
    assert out["returns"].shape == (2,) and (out["lengths"] == task.episode_len).all()
    # full push along x: the ball passes the speed limit, so costs occur and progress is made
    assert (out["costs"] > 0).all() and (out["returns"] > 100).all()


@pytest.mark.slow
def test_train_cli_on_a_bullet_task(tmp_path):
    """`python -m r2pac_jax.train --task BallRun` end to end on a small file made by random
    actions in the bullet env: trains, evaluates through pybullet, writes its results."""
    import json

    from r2pac_jax.data import write_dsrl
    from r2pac_jax.train import main

    from conftest import random_action_arrays

    data = random_action_arrays(make_env(get_task("BallRun")), 8)
    path = write_dsrl(tmp_path / "ballrun.hdf5", data)
    out = tmp_path / "run"
    assert main(["--task", "BallRun", "--algo", "bc-all-mlp", "--seeds", "2", "--eval-episodes",
                 "2", "--baselines", "none", "--dataset", str(path), "--out", str(out),
                 "--no-progress", "--set", "steps=20", "--set", "batch_size=32"]) == 0
    res = json.loads((out / "results.json").read_text())
    assert np.asarray(res["returns"]).shape == (2, 2) and np.isfinite(res["returns"]).all()
    assert len(res["normalized_reward"]["per_seed"]) == 2 and res["eval_backend"] == "bullet"
    assert (out / "table.md").exists() and (out / "metrics.jsonl").exists()


def test_evaluation_steps_only_running_episodes_with_the_same_results(monkeypatch):
    """The Python-loop evaluation steps the episodes still running (in power-of-two buckets);
    on AntCircle, whose random-action episodes end early at different steps, the scores equal
    those of stepping every episode to the end."""
    from r2pac_jax import evaluate as ev

    def rand(params, obs, key):
        return jax.random.uniform(key, (obs.shape[0], 8), minval=-1, maxval=1) * params

    task = get_task("AntCircle")
    live = ev.evaluate(rand, jax.numpy.float32(1.0), task, episodes=4, key=jax.random.PRNGKey(2))
    assert len(set(np.asarray(live["lengths"]).tolist())) > 1  # ends at different steps
    monkeypatch.setattr(ev, "_step_live", lambda env, state, a, alive: env.step_batch(state, a))
    every = ev.evaluate(rand, jax.numpy.float32(1.0), task, episodes=4, key=jax.random.PRNGKey(2))
    for k in ("returns", "costs", "lengths"):
        np.testing.assert_array_equal(live[k], every[k])

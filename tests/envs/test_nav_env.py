"""Navigation environments through their backends: registry, rules, evaluation (C MuJoCo), and
one small MJX check."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from r2pac_jax.envs.navigation import make_env
from r2pac_jax.envs.navigation import agents as A
from r2pac_jax.tasks import get_task

import functools

NAV = ["CarGoal1", "CarGoal2", "CarButton1", "CarButton2", "CarPush1", "CarPush2",
       "PointGoal1", "PointGoal2", "PointButton1", "PointButton2", "PointPush1", "PointPush2"]


@functools.lru_cache(maxsize=None)
def c_env(name):
    """One C-MuJoCo env per task for the whole module (its jitted task functions compile once
    per batch size; the tests use batches of 2)."""
    return make_env(name, physics="mujoco")


def test_registry_attaches_the_navigation_factory():
    from r2pac_jax.tasks import navigation as nav_family

    for name in NAV:
        spec = get_task(name)
        assert spec.env_factory is nav_family.make_env
    # obs sizes follow the original: 24 car sensors / 12 point sensors + 16 per lidar group
    assert get_task("CarGoal2").obs_dim == 72 and get_task("CarButton1").obs_dim == 88
    assert get_task("PointGoal1").obs_dim == 60 and get_task("PointPush2").obs_dim == 76
    env = get_task("CarPush2").make_env(physics="mujoco")
    assert env.obs_dim == 88 and env.act_dim == 2 and not env.is_jax


def _start(env, n=2, seed=0):
    """A fresh batch, and the arrays needed to restart it with edits (numpy copies)."""
    keys = jax.random.split(jax.random.PRNGKey(seed), n)
    qpos, qvel, mpos, mquat, ex = env._init(jax.vmap(jax.random.split)(keys)[:, 1])
    ex = {k: np.array(v) for k, v in ex.items()}
    return (np.array(qpos, np.float64), np.array(qvel, np.float64), np.array(mpos, np.float64),
            np.array(mquat, np.float64), ex, keys)


def _forward_of(env, qpos):
    """World XY a little ahead of the agent (the car drives along its -y axis)."""
    pos, mat = A.pose(env.task.agent, jnp.asarray(qpos))
    fwd = -np.asarray(mat)[:, 1] if env.task.level.agent == "car" else np.asarray(mat)[:, 0]
    return np.asarray(pos)[:2], fwd[:2] / np.linalg.norm(fwd[:2])


def test_reset_is_fresh_and_step_is_deterministic():
    env = c_env("CarButton1")
    s = env.reset_batch(jax.random.split(jax.random.PRNGKey(0), 2))
    assert s.obs.shape == (2, 88) and np.isfinite(s.obs).all()
    lay = np.asarray(s.info["layout"])
    assert not np.allclose(lay[0], lay[1])  # two different layouts
    s_again = env.reset_batch(jax.random.split(jax.random.PRNGKey(1), 2))
    assert not np.allclose(np.asarray(s_again.info["layout"]), lay)
    a = np.array([[0.5, 1.0], [-1.0, 0.3]], np.float32)
    s1, s2 = env.step_batch(s, a), env.step_batch(s, a)
    np.testing.assert_array_equal(s1.obs, s2.obs)
    np.testing.assert_array_equal(s1.physics["state"], s2.physics["state"])
    assert s1.t.tolist() == [1, 1] and not s1.truncated.any()


def test_goal_reached_pays_one_and_moves_the_goal():
    env = c_env("CarGoal1")
    qpos, qvel, mpos, mquat, ex, keys = _start(env)
    hazards = env.task.level.layout_slice("hazards")
    ex["layout"][:, hazards] = 5.0  # no hazard nearby
    for i in range(2):
        xy, _ = _forward_of(env, qpos[i])
        ex["goal"][i, :2] = xy + [0.1, 0.0]  # inside the goal radius (0.3)
        ex["last_dist_goal"][i] = 0.1
    s = env.reset_to(qpos, qvel, mpos, mquat, ex, keys)
    s1 = env.step_batch(s, np.zeros((2, 2), np.float32))
    assert np.all(s1.reward > 0.9) and np.all(s1.reward < 1.2)
    new_goal = np.asarray(s1.info["goal"])[:, :2]
    agent_xy = np.asarray(s1.physics["state"])[:, 1:3]
    # the new goal keeps the agent's keepout (0.4) plus the goal's (0.305)
    assert np.all(np.linalg.norm(new_goal - agent_xy, axis=1) >= 0.705 - 1e-5)
    assert np.allclose(s1.info["last_dist_goal"], np.linalg.norm(new_goal - agent_xy, axis=1),
                       atol=1e-5)
    assert not s1.terminated.any() and np.all(s1.cost == 0)


def test_hazard_cost_and_reward_is_progress():
    env = c_env("CarGoal2")
    qpos, qvel, mpos, mquat, ex, keys = _start(env)
    hz = env.task.level.layout_slice("hazards")
    ex["layout"][:, hz] = 5.0
    ex["layout"][0, hz.start] = qpos[0, :2]  # episode 0: the agent stands in a hazard
    s = env.reset_to(qpos, qvel, mpos, mquat, ex, keys)
    s1 = env.step_batch(s, np.full((2, 2), 0.7, np.float32))
    assert s1.cost.tolist() == [1.0, 0.0]
    pos = np.asarray(s1.physics["state"])[:, 1:3]
    goal = np.asarray(s.info["goal"])[:, :2]
    progress = ex["last_dist_goal"] - np.linalg.norm(goal - pos, axis=1)
    np.testing.assert_allclose(s1.reward, progress, atol=1e-5)


@pytest.mark.parametrize("name, costly", [("CarGoal2", True), ("CarGoal1", False)])
def test_pushing_a_vase_costs_in_goal2_only(name, costly):
    env = c_env(name)
    qpos, qvel, mpos, mquat, ex, keys = _start(env)
    ex["layout"][:, env.task.level.layout_slice("hazards")] = 5.0
    adr = env.index.free_qpos["vases"][0]
    for i in range(2):
        xy, fwd = _forward_of(env, qpos[i])
        qpos[i, adr:adr + 2] = xy + 0.45 * fwd  # a vase right in front of the car
        for j in env.index.free_qpos["vases"][1:]:
            qpos[i, j:j + 2] = 5.0 + j  # the others far away
    s = env.reset_to(qpos, qvel, mpos, mquat, ex, keys)
    costs = []
    for _ in range(40):
        s = env.step_batch(s, np.ones((2, 2), np.float32))
        costs.append(np.asarray(s.cost))
    vase_moved = np.linalg.norm(np.asarray(s.physics["state"])[:, 1 + adr:3 + adr]
                                - qpos[:, adr:adr + 2], axis=1)
    assert np.all(vase_moved > 0.05)  # the car did push it
    assert (np.sum(costs) > 0) == costly


def test_button_timer_hides_buttons_and_rearms():
    env = c_env("CarButton1")
    qpos, qvel, mpos, mquat, ex, keys = _start(env)
    lv = env.task.level
    ex["layout"][:, lv.layout_slice("hazards")] = 5.0
    g = lv.layout_slice("gremlins")
    for i in range(2):
        gb = int(ex["goal_button"][i])
        xy, fwd = _forward_of(env, qpos[i])
        target = xy + 0.35 * fwd
        ex["goal"][i, :2] = target
        ex["last_dist_goal"][i] = 0.35
        # the goal button in front of the car, the other buttons and the gremlins far away
        for j, b in enumerate(env.index.mocap["buttons"]):
            place = target if j == gb else np.array([4.0 + j, 4.0])
            ex["layout"][i, lv.layout_slice("buttons").start + j] = place
            mpos[i, b, :2] = place
        ex["layout"][i, g] = [[-5.0, -5.0 - k] for k in range(g.stop - g.start)]
        for k, adr in enumerate(env.index.free_qpos["gremlins"]):
            qpos[i, adr:adr + 2] = [-5.0, -5.0 - k]
    s = env.reset_to(qpos, qvel, mpos, mquat, ex, keys)
    ns = env.task.agent.obs_dim
    assert s.obs[:, ns:ns + 16].max(1).min() > 0  # buttons visible while the timer is 0
    hit = np.full(2, -1)
    for t in range(60):
        s = env.step_batch(s, np.ones((2, 2), np.float32) * (hit < 0)[:, None])
        newly = (hit < 0) & (s.reward > 0.5)
        hit[newly] = t
        if newly.any():
            assert np.all(np.asarray(s.info["timer"])[newly] == 10)
            assert s.obs[newly, ns:ns + 16].max() == 0  # blanked while the timer runs
            assert np.all(s.cost[newly] == 0)
        if (hit >= 0).all():
            break
    assert (hit >= 0).all(), "the car never pressed the goal button"
    s = env.step_batch(s, np.zeros((2, 2), np.float32))
    for _ in range(12):
        if np.asarray(s.info["timer"]).max() == 0:
            break
        s = env.step_batch(s, np.zeros((2, 2), np.float32))
    assert np.all(np.asarray(s.info["timer"]) == 0)
    assert s.obs[:, ns:ns + 16].max(1).min() > 0


def test_gremlins_circle_their_layout_place():
    env = c_env("CarButton1")
    s = env.reset_batch(jax.random.split(jax.random.PRNGKey(4), 2))
    anchors = np.asarray(s.info["layout"])[0, env.task.level.layout_slice("gremlins")]
    adr = env.index.free_qpos["gremlins"]
    track = []
    for _ in range(40):  # 1.6 s of simulated time
        s = env.step_batch(s, np.zeros((2, 2), np.float32))
        q = np.asarray(s.physics["state"])[0, 1:]
        track.append(np.stack([q[a:a + 2] for a in adr]) - anchors)
    r = np.linalg.norm(np.stack(track), axis=-1)
    # the welded boxes follow the mocap's circle of radius 0.35 (soft weld: a little lag)
    assert np.all(np.abs(r[10:] - 0.35) < 0.05)
    spread = np.ptp(np.stack(track)[:, 0], axis=0)
    assert np.all(spread > 0.3)


def test_evaluate_runs_navigation_episodes():
    from r2pac_jax.evaluate import evaluate

    task = get_task("CarGoal1")

    def policy(params, obs, key):
        return jax.random.uniform(key, (obs.shape[0], 2), minval=-1, maxval=1)

    out = evaluate(policy, {}, task, episodes=2, key=jax.random.PRNGKey(0), physics="mujoco")
    assert out["lengths"].tolist() == [1000, 1000]
    assert np.isfinite(out["returns"]).all() and np.all(out["costs"] >= 0)
    assert np.isfinite(out["normalized_reward"])


@pytest.mark.slow
def test_mjx_backend_agrees_with_c_mujoco_over_a_few_steps():
    """The one MJX test of the default suite (its CPU compile takes about a minute)."""
    mj = make_env("PointGoal1", physics="mujoco")
    mx = make_env("PointGoal1", physics="mjx")
    acts = jnp.array([[1.0, 0.5], [0.5, -1.0], [1.0, 0.0]])

    @jax.jit
    def run(key):
        s0 = mx.reset(key)

        def one(s, a):  # a scan compiles the step once (an unrolled loop would thrice)
            s = mx.step(s, a)
            return s, s.obs

        s, obs = jax.lax.scan(one, s0, acts)
        return jnp.concatenate([s0.obs[None], obs]), s.physics.qpos

    key = jax.random.PRNGKey(7)
    obs, qpos = run(key)
    # the same episode in C MuJoCo: same layout (same key), same actions
    c = mj.reset_batch(key[None])
    np.testing.assert_allclose(c.obs[0], obs[0], atol=1e-4)
    for t, a in enumerate(np.asarray(acts)):
        c = mj.step_batch(c, a[None].astype(np.float32))
        np.testing.assert_allclose(c.obs[0], obs[t + 1], atol=5e-3, rtol=1e-3)
    np.testing.assert_allclose(np.asarray(c.physics["state"])[0, 1:1 + qpos.shape[0]], qpos,
                               atol=1e-4)


@pytest.mark.parametrize("name", ["CarButton2", "CarPush2", "CarGoal2", "PointPush2"])
def test_mjx_variant_has_a_collision_function_for_every_pair(name):
    """MJX (mujoco-mjx 3.17) has no cylinder-box collision: the MJX model keeps the car's wheels
    away from boxes, yet lets them touch the floor, buttons (spheres) and pillars (capsules)."""
    import mujoco
    from mujoco.mjx._src.collision_driver import geom_pairs, has_collision_fn

    from r2pac_jax.envs.navigation.objects import level_spec
    from r2pac_jax.envs.navigation.world import build_model

    m, _ = build_model(level_spec(name), "mjx")
    pairs = list(geom_pairs(m))
    for g1, g2, _ in pairs:
        assert has_collision_fn(m.geom_type[g1], m.geom_type[g2]), (
            m.geom(g1).name, m.geom(g2).name)
    if name.startswith("Car"):
        wheel = {m.geom("left").id, m.geom("right").id}
        partners = {int(m.geom_type[g2 if g1 in wheel else g1])
                    for g1, g2, _ in pairs if {g1, g2} & wheel}
        T = mujoco.mjtGeom
        want = {int(T.mjGEOM_PLANE)} | ({int(T.mjGEOM_SPHERE)} if "Button" in name else set())
        want |= {int(T.mjGEOM_CAPSULE)} if "Push" in name else set()
        assert partners == want
        # the exact model (C MuJoCo) keeps the original's rule: wheels collide with boxes too
        me, _ = build_model(level_spec(name), "exact")
        wheel_e = {me.geom("left").id, me.geom("right").id}
        assert any(me.geom_type[g2 if g1 in wheel_e else g1] == T.mjGEOM_BOX
                   for g1, g2, _ in geom_pairs(me) if {g1, g2} & wheel_e)

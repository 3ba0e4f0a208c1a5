"""The data factory's sources for the environment tasks (navigation.py, velocity.py)."""
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from r2pac_jax.data import factory
from r2pac_jax.data.dsrl import validate
from r2pac_jax.data.factory import navigation as nav
from r2pac_jax.data.factory.batch import episode_keys
from r2pac_jax.tasks import get_task


@pytest.fixture(scope="module")
def point_goal():
    """PointGoal1 on C MuJoCo (the cheapest navigation task), its scene and controller."""
    env = get_task("PointGoal1").make_env(physics="mujoco")
    scene = nav.NavScene(env)
    return env, scene, nav.make_controller(scene)


def _knobs(n, risk, **kw):
    base = dict(speed=1.0, noise=0.0, gain=1.0, wander=0.0)
    base.update(kw)
    f = lambda v: jnp.full((n,), v, jnp.float32)  # noqa: E731
    return nav.Knobs(f(risk), f(base["speed"]), f(base["noise"]), f(base["gain"]),
                     f(base["wander"]), jnp.zeros((n,), bool))


def test_navigation_rollout_is_valid_dsrl_data_and_deterministic(point_goal):
    env, scene, control = point_goal
    task = get_task("PointGoal1")
    keys = episode_keys(7, 0, 3)
    a = nav.rollout(env, scene, control, keys, steps=25)
    b = nav.rollout(env, scene, control, keys, steps=25)
    ds = validate(a, "PointGoal1 rollout", task.obs_dim, task.act_dim, task.name)
    assert ds.size == 3 * 25 and len(ds.episode_sums()[0]) == 3
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    # a different seed gives other layouts
    c = nav.rollout(env, scene, control, episode_keys(8, 0, 3), steps=25)
    assert not np.array_equal(a["observations"], c["observations"])
    # actions respect the motors' limits (forward force saturates at 0.05 of the range)
    assert np.abs(a["actions"]).max() <= 1.0


def _easy_layout(env, n):
    """n copies of one hand-built PointGoal1 episode: the agent at (-1, 0) facing +x, the goal at
    (1.1, 0), one hazard at (0, 0) on the straight line, every other object far off to the side."""
    task = env.task
    lv = task.level
    qpos, qvel, mpos, mquat, extras = jax.vmap(task.init)(jax.random.split(
        jax.random.PRNGKey(0), n))
    qpos = np.array(qpos, np.float64)
    qpos[:, :3] = (-1.0, 0.0, 0.0)  # Point: x, y, heading
    layout = np.array(extras["layout"])
    hz = lv.layout_slice("hazards")
    far = np.stack([np.linspace(-1.3, 1.3, hz.stop - hz.start), np.full(hz.stop - hz.start, 1.3)],
                   -1)
    layout[:, hz] = far
    layout[:, hz.start] = (0.0, 0.0)
    layout[:, 0] = (-1.0, 0.0)
    goal_row = lv.layout_names.index("goal")
    layout[:, goal_row] = (1.1, 0.0)
    vase = task.index.free_qpos["vases"][0]
    qpos[:, vase:vase + 2] = (-1.3, -1.3)
    extras = dict(extras, layout=jnp.asarray(layout, jnp.float32),
                  goal=extras["goal"].at[:, :2].set(jnp.array([1.1, 0.0])),
                  last_dist_goal=jnp.full((n,), 2.1, jnp.float32))
    keys = jax.random.split(jax.random.PRNGKey(1), n)
    return env.reset_to(qpos, np.array(qvel, np.float64), np.array(mpos, np.float64),
                        np.array(mquat, np.float64), extras, keys)


def _run(env, scene, control, state, knobs, steps):
    n = state.obs.shape[0]
    _, _, k_steps = nav._split_keys(jax.random.split(jax.random.PRNGKey(2), n))
    wander_xy, wandering = jnp.zeros((n, 2)), jnp.zeros((n,), bool)
    reward, cost = np.zeros(n), np.zeros(n)
    for t in range(steps):
        a, wander_xy, wandering = control(scene.read(state), knobs, wander_xy, wandering,
                                          k_steps, jnp.int32(t))
        state = env.step_batch(state, np.asarray(a))
        reward += state.reward
        cost += state.cost
    return reward, cost


def test_careful_controller_reaches_the_goal_around_the_hazard(point_goal):
    env, scene, control = point_goal
    state = _easy_layout(env, 2)
    knobs = nav.Knobs(*(jnp.concatenate([x, y]) for x, y in zip(_knobs(1, 0.0), _knobs(1, 1.0))))
    reward, cost = _run(env, scene, control, state, knobs, 200)
    # risk 0 reaches the goal (reward > 1: the distance travelled plus the goal's bonus) and
    # never enters the hazard; risk 1 drives straight through it
    assert reward[0] > 1.5, reward
    assert cost[0] == 0, cost
    assert cost[1] > 0, cost


def test_every_navigation_task_has_a_source_with_its_sizes():
    srcs = factory._sources()
    for name in nav.NAV_TASKS:
        spec = get_task(name)
        assert spec.has_env and name in srcs
        assert srcs[name]["default_trajectories"] >= 100
        assert srcs[name]["oversample"] >= 2


def test_data_cli_unknown_task_and_unwritable_cache(tmp_path, monkeypatch, capsys):
    from r2pac_jax.data.__main__ import main

    assert main(["make", "--task", "CarGoal9"]) == 2
    assert "unknown task 'CarGoal9'" in capsys.readouterr().err
    import dataclasses

    from r2pac_jax import tasks as registry

    monkeypatch.setitem(registry.TASKS, "CarRun",  # registered, but no environment / source
                        dataclasses.replace(registry.get_task("CarRun"), env_factory=None))
    assert main(["make", "--task", "CarRun"]) == 2
    err = capsys.readouterr().err
    assert "no data source for task 'CarRun'" in err and "--dataset FILE" in err
    monkeypatch.undo()
    assert main(["make", "--task", "CarRun", "--source", "scripted"]) == 2  # learned only
    assert "no scripted data source" in capsys.readouterr().err
    # without --source: the learned recipe everywhere but the demonstration task
    assert factory.default_source(registry.get_task("CarGoal1")) == "ppo-lagrangian"
    assert factory.default_source(registry.get_task("HopperVelocity")) == "ppo-lagrangian"
    assert factory.default_source(registry.get_task("CarRun")) == "ppo-lagrangian"
    assert factory.default_source(registry.get_task("ReachAvoid")) == "scripted"
    blocker = tmp_path / "file"
    blocker.write_text("")
    monkeypatch.setenv("R2PAC_DATA_DIR", str(blocker / "sub"))
    assert main(["make", "--task", "CarGoal2", "--trajectories", "3"]) == 2
    err = capsys.readouterr().err
    assert "not writable" in err and "R2PAC_DATA_DIR" in err


@pytest.mark.slow
@pytest.mark.parametrize("name", nav.NAV_TASKS)
def test_every_navigation_source_makes_valid_data(name):
    """Two short episodes per task: valid arrays of the task's sizes, same seed same arrays."""
    task = get_task(name)
    env = task.make_env(physics="mujoco")
    scene = nav.NavScene(env)
    control = nav.make_controller(scene)
    keys = episode_keys(0, 0, 2)
    a = nav.rollout(env, scene, control, keys, steps=40)
    validate(a, name, task.obs_dim, task.act_dim, task.name)
    b = nav.rollout(env, scene, control, keys, steps=40)
    np.testing.assert_array_equal(a["actions"], b["actions"])


@pytest.mark.slow
def test_generated_navigation_dataset_is_carded_and_thinned(data_dir):
    task = get_task("PointGoal1")
    path = factory.generate_dataset(task, 3, seed=1, source="scripted")
    card = __import__("json").loads(factory.card_path(path).read_text())
    assert card["trajectories"] == 3 and card["thinning"]["generated"] == 3 * nav.OVERSAMPLE
    assert path.with_suffix(".png").exists()
    assert card["safe_trajectories"] + card["unsafe_trajectories"] == 3


def test_every_task_with_an_environment_has_a_source():
    from r2pac_jax.tasks import TASKS

    missing = [n for n, spec in TASKS.items() if spec.has_env and not factory.has_source(spec)]
    assert not missing, f"tasks with an environment but no data source: {missing}"


def test_velocity_rollout_is_valid_and_deterministic():
    from r2pac_jax.data.factory import velocity as vel

    task = get_task("HalfCheetahVelocity")
    env = task.make_env(physics="mujoco")
    a = vel.rollout(env, task.name, seed=3, first=0, n=3, steps=20)
    b = vel.rollout(env, task.name, seed=3, first=0, n=3, steps=20)
    ds = validate(a, "cheetah rollout", task.obs_dim, task.act_dim, task.name)
    assert ds.size == 60
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    # trajectory i depends on (seed, i) only: a batch starting at 1 repeats trajectories 1, 2
    c = vel.rollout(env, task.name, seed=3, first=1, n=2, steps=20)
    np.testing.assert_array_equal(c["actions"], a["actions"][20:])


def test_gait_speed_level_raises_speed_and_cost():
    """HalfCheetah's gait at a low speed level stays under the velocity limit, at a high one
    it runs above it (the knob that spreads the data over the cost axis)."""
    from r2pac_jax.data.factory import velocity as vel

    task = get_task("HalfCheetahVelocity")
    env = task.make_env(physics="mujoco")
    plan = vel.Plan(0, 0, 2, task.name, 150, task.act_dim)
    plan.gait[:], plan.switch[:], plan.noise[:] = 0, 150, 0.0
    plan.level[:] = np.array([[0.3], [0.8]])
    out = vel.rollout(env, task.name, 0, 0, 2, steps=150, plan=plan)
    rewards = out["rewards"].reshape(2, 150)
    costs = out["costs"].reshape(2, 150)
    assert costs[0].sum() == 0 and costs[1, 50:].sum() > 20, costs.sum(1)
    assert rewards[1].sum() > rewards[0].sum() + 100


def test_scripted_data_only_when_named_and_carded_with_their_failed_checks(data_dir, capsys):
    """Data issue, item 6: `data make` never picks the scripted controllers by itself; named,
    they warn, and the card lists the checks the file fails (coverage, measured on the file)
    and what the v1 quality bar measured of their imitability."""
    import json

    from r2pac_jax.data.__main__ import main

    assert main(["make", "--task", "HalfCheetahVelocity", "--source", "scripted",
                 "--trajectories", "2"]) == 0
    err = capsys.readouterr().err
    assert "warning: scripted controllers" in err and "data v1" in err and "0.78" in err
    path = factory.dataset_path(get_task("HalfCheetahVelocity"), 0, 2, "scripted")
    card = json.loads(factory.card_path(path).read_text())
    checks = json.loads(Path(f"{path}.checks.json").read_text())
    assert card["data_version"] == 1 and "not reliably imitable" in card["known_limits"]
    assert card["checks"]["failed"] == checks["failed"] and checks["fast"]
    # the demonstration task's scripted data carry no such warning
    assert factory.scripted_limits(get_task("ReachAvoid")) is None

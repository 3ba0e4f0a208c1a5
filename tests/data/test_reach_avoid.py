import jax
import jax.numpy as jnp
import numpy as np

from r2pac_jax.data import factory
from r2pac_jax.data.dsrl import load_dsrl
from r2pac_jax.envs import reach_avoid as ra
from r2pac_jax.tasks import get_task


def _scripted_return(height, speed, noise=0.0, exact_start=True):
    env = ra.ReachAvoidEnv()
    b = ra.Behaviour(jnp.float32(height), jnp.float32(1), jnp.float32(speed), jnp.float32(noise),
                     jnp.array(False))
    s = env.reset(jax.random.PRNGKey(0))
    if exact_start:
        phys = ra.Physics(jnp.asarray(ra.START, jnp.float32), jnp.zeros(2, jnp.float32))
        s = s.replace(physics=phys, obs=ra._obs(phys))
    R = C = 0.0
    step = jax.jit(env.step)
    for t in range(env.episode_len):
        s = step(s, ra.scripted_action(b, s, jax.random.PRNGKey(t)))
        R += float(s.reward)
        C += float(s.cost)
    return R, C


def test_registry_constants_come_from_the_task_design():
    task = get_task("ReachAvoid")
    r, c = _scripted_return(0.0, 1.0)  # straight through the hazard at full speed
    assert abs(r - task.r_max) < 1e-3 and c == 10.0
    # standing still: no progress, never at the goal
    env = ra.ReachAvoidEnv()
    s = env.reset(jax.random.PRNGKey(1))
    total = 0.0
    for _ in range(10):
        s = env.step(s, jnp.zeros(2))
        total += float(s.reward)
    assert total == task.r_min == 0.0


def test_tight_detour_is_safe_and_beats_slow_ones():
    r_tight, c_tight = _scripted_return(0.65, 1.0)
    r_wide, c_wide = _scripted_return(1.2, 1.0)
    r_slow, c_slow = _scripted_return(0.65, 0.5)
    assert c_tight == c_wide == c_slow == 0.0
    assert r_tight > r_wide > r_slow


def test_hazard_cost_and_arena_terminal():
    env = ra.ReachAvoidEnv()
    s = env.reset(jax.random.PRNGKey(0))
    s = s.replace(physics=ra.Physics(jnp.array([0.0, 0.05]), jnp.zeros(2)))
    s = env.step(s, jnp.zeros(2))
    assert float(s.cost) == 1.0 and not bool(s.terminated)
    s = s.replace(physics=ra.Physics(jnp.array([2.49, 0.0]), jnp.array([0.1, 0.0])))
    s = env.step(s, jnp.array([1.0, 0.0]))
    assert bool(s.terminated)


def test_env_is_vmappable_and_truncates():
    env = ra.ReachAvoidEnv()
    s = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(0), 3))

    def body(st, _):
        return jax.vmap(env.step)(st, jnp.zeros((3, 2))), None

    s, _ = jax.lax.scan(body, s, None, length=env.episode_len)
    assert s.obs.shape == (3, 6) and bool(s.truncated.all())


def test_generated_dataset_is_deterministic_and_carded(data_dir):
    task = get_task("ReachAvoid")
    p1 = factory.generate_dataset(task, 40, seed=5, plot=False)
    card = __import__("json").loads(factory.card_path(p1).read_text())
    ds = load_dsrl(p1, 6, 2, "ReachAvoid")
    assert card["trajectories"] == 40 and card["transitions"] == ds.size
    assert card["safe_trajectories"] + card["unsafe_trajectories"] == 40
    assert p1.name == "ReachAvoid-generated-s5-n40.hdf5"
    arrays = factory._sources()["ReachAvoid"]["generate"](40, 5)
    np.testing.assert_array_equal(arrays["observations"], ds.observations)
    other = factory._sources()["ReachAvoid"]["generate"](40, 6)
    assert not np.array_equal(other["observations"][:50], ds.observations[:50])
    # both safe and unsafe behaviour is present
    rets, costs = ds.episode_sums()
    assert (costs <= task.kappa).any() and (costs > task.kappa).any()


def test_unwritable_cache_dir_is_a_clear_error(tmp_path, monkeypatch):
    import pytest

    blocker = tmp_path / "file"
    blocker.write_text("")
    monkeypatch.setenv("R2PAC_DATA_DIR", str(blocker / "sub"))
    with pytest.raises(factory.FactoryError, match="not writable.*R2PAC_DATA_DIR"):
        factory.generate_dataset(get_task("ReachAvoid"), 5, seed=0, plot=False)

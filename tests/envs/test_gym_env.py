"""The gymnasium wrapper: API conformance, equality with the env's own rollout, errors."""
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from r2pac_jax.envs import gym_env
from r2pac_jax.envs.base import ActionError
from r2pac_jax.envs.gym import ResetNeeded
from r2pac_jax.tasks import EnvUnavailableError, UnknownTaskError, get_task


def _gym_episode(env, seed, actions):
    obs, info = env.reset(seed=seed)
    assert info == {}
    out = dict(obs=[obs], reward=[], cost=[], terminated=[], truncated=[])
    for a in actions:
        obs, r, term, trunc, info = env.step(a)
        for k, v in zip(out, (obs, r, info["cost"], term, trunc)):
            out[k].append(v)
        if term or trunc:
            break
    return {k: np.asarray(v) for k, v in out.items()}


@pytest.mark.filterwarnings("ignore::UserWarning")  # check_env's notes on infinite obs bounds
def test_reach_avoid_passes_check_env_and_matches_the_jax_rollout():
    env = gym_env("ReachAvoid")
    check_env(env, skip_render_check=True)
    assert env.action_space.shape == (2,) and env.observation_space.shape == (6,)
    assert float(env.action_space.low.min()) == -1.0 and float(env.action_space.high.max()) == 1.0

    actions = np.asarray(jax.random.uniform(jax.random.PRNGKey(3), (80, 2), minval=-1, maxval=1))
    ep = _gym_episode(env, 11, actions)
    assert len(ep["reward"]) == 80 and ep["truncated"][-1] and not ep["terminated"].any()

    # the same episode with the env's own functions: reset(seed=s) == reset(PRNGKey(s))
    ra = get_task("ReachAvoid").make_env()

    def body(s, a):
        s = ra.step(s, a)
        return s, (s.obs, s.reward, s.cost)

    s0 = ra.reset(jax.random.PRNGKey(11))
    _, (obs, rew, cost) = jax.lax.scan(body, s0, jnp.asarray(actions))
    np.testing.assert_array_equal(ep["obs"][0], np.asarray(s0.obs))
    np.testing.assert_allclose(ep["obs"][1:], np.asarray(obs), atol=1e-6)
    np.testing.assert_allclose(ep["reward"], np.asarray(rew), atol=1e-6)
    np.testing.assert_array_equal(ep["cost"], np.asarray(cost))
    assert ep["reward"].sum() == pytest.approx(float(rew.sum()), abs=1e-4)

    # seeding: the same seed gives the same episode start, unseeded resets move on
    o1, _ = env.reset(seed=5)
    o2, _ = env.reset(seed=5)
    o3, _ = env.reset()
    np.testing.assert_array_equal(o1, o2)
    assert not np.array_equal(o1, o3)
    o4, _ = gym_env("ReachAvoid", seed=5).reset()  # the constructor's seed seeds the first reset
    np.testing.assert_array_equal(o1, o4)


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_mujoco_task_passes_check_env_and_matches_the_batched_rollout():
    env = gym_env("HopperVelocity", physics="mujoco")
    assert env.physics == "mujoco"
    check_env(env, skip_render_check=True)
    assert env.observation_space.shape == (11,) and env.action_space.shape == (3,)

    # random actions make the hopper fall: the episode ends with terminated
    actions = np.random.default_rng(0).uniform(-1, 1, (1000, 3)).astype(np.float32)
    ep = _gym_episode(env, 4, actions)
    n = len(ep["reward"])
    assert ep["terminated"][-1] and n < 1000

    # the env's own batched rollout from the same key, episode 0 of a batch of two
    mj = env.env
    s = mj.reset_batch(jnp.stack([jax.random.PRNGKey(4), jax.random.PRNGKey(9)]))
    np.testing.assert_allclose(ep["obs"][0], s.obs[0], atol=1e-6)
    rewards, costs = [], []
    for t in range(n):
        s = mj.step_batch(s, np.stack([actions[t], actions[t]]))
        np.testing.assert_allclose(ep["obs"][t + 1], s.obs[0], atol=1e-5)
        rewards.append(s.reward[0])
        costs.append(s.cost[0])
    assert bool(s.terminated[0])
    np.testing.assert_allclose(ep["reward"], rewards, atol=1e-5)
    assert ep["reward"].sum() == pytest.approx(float(np.sum(rewards)), abs=1e-4)
    np.testing.assert_array_equal(ep["cost"], costs)

    # an ended episode needs a reset
    with pytest.raises(ResetNeeded, match="call env.reset"):
        env.step(actions[0])


def test_navigation_task_through_gym():
    env = gym_env("OfflineCarGoal1Gymnasium-v0", physics="mujoco", seed=0)  # DSRL ids resolve
    obs, _ = env.reset()
    assert obs.shape == (72,) and obs.dtype == np.float32
    obs, r, term, trunc, info = env.step(np.array([1.0, 1.0], np.float32))
    assert env.observation_space.contains(obs)
    assert isinstance(r, float) and isinstance(info["cost"], float) and not (term or trunc)


def test_errors_are_clear():
    with pytest.raises(UnknownTaskError, match="known tasks: .*CarGoal2"):
        gym_env("NoSuchTask")
    import dataclasses

    no_env = dataclasses.replace(get_task("AntRun"), env_factory=None)  # constants, no port
    with pytest.raises(EnvUnavailableError, match="no environment port"):
        gym_env(no_env)
    with pytest.raises(ValueError, match="pure JAX"):
        gym_env("ReachAvoid", physics="mujoco")
    env = gym_env("ReachAvoid")
    with pytest.raises(ResetNeeded, match="before reset"):
        env.step(np.zeros(2))
    env.reset(seed=0)
    with pytest.raises(ActionError, match=r"shape \(3,\), expected \(2,\)"):
        env.step(np.zeros(3))
    with pytest.raises(ActionError, match="NaN"):
        env.step(np.array([np.nan, 0.0]))


def test_importing_envs_is_light():
    code = ("import sys, r2pac_jax.envs as e; "
            "assert callable(e.gym_env); "
            "heavy = [m for m in ('gymnasium', 'mujoco', 'jax') if m in sys.modules]; "
            "assert not heavy, heavy")
    subprocess.run([sys.executable, "-c", code], check=True)

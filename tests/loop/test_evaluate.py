import jax
import jax.numpy as jnp
import numpy as np

from r2pac_jax.envs import reach_avoid as ra
from r2pac_jax.evaluate import dsrl_scores, evaluate
from r2pac_jax.tasks import get_task


def test_dsrl_scores_formula():
    task = get_task("CarGoal2")
    nr, nc = dsrl_scores(task.r_max, 5.0, task)
    assert abs(nr - 1.0) < 1e-12 and nc == 0.5
    nr, _ = dsrl_scores(task.r_min, 0.0, task)
    assert nr == 0.0


def _straight(params, obs, key):
    # head for the goal at full speed: obs[:, 4:6] is goal - position
    d = obs[:, 4:6]
    return d / jnp.maximum(jnp.linalg.norm(d, axis=-1, keepdims=True), 1e-6) * params["speed"]


def test_evaluate_matches_a_manual_loop():
    task = get_task("ReachAvoid")
    params = {"speed": jnp.float32(1.0)}
    out = evaluate(_straight, params, task, episodes=4, key=jax.random.PRNGKey(0))
    assert out["returns"].shape == (4,) and (out["lengths"] == 80).all()
    # manual single-episode loop with the same reset keys
    env = ra.ReachAvoidEnv()
    k_reset, _ = jax.random.split(jax.random.PRNGKey(0))
    for e, k in enumerate(jax.random.split(k_reset, 4)):
        s = env.reset(k)
        R = C = 0.0
        for _ in range(80):
            s = env.step(s, _straight(params, s.obs[None], None)[0])
            R += float(s.reward)
            C += float(s.cost)
        assert abs(R - out["returns"][e]) < 1e-3 and C == out["costs"][e]
    nr, nc = dsrl_scores(out["returns"].mean(), out["costs"].mean(), task)
    assert abs(out["normalized_reward"] - nr) < 1e-6 and out["normalized_cost"] == nc
    assert out["normalized_cost"] > 1.0  # the straight line is unsafe


def test_episodes_freeze_after_terminal():
    task = get_task("ReachAvoid")

    def run_away(params, obs, key):
        return jnp.tile(jnp.array([[-1.0, 0.0]]), (obs.shape[0], 1))

    out = evaluate(run_away, {}, task, episodes=3, key=jax.random.PRNGKey(0))
    # leaves the arena at x < -2.5 well before 80 steps; nothing accrues afterwards
    assert (out["lengths"] < 80).all()
    assert np.all(out["returns"] < 0)


class _ViaPython:
    """ReachAvoid stepped through the batch interface from Python (the C-MuJoCo path)."""

    is_jax = False

    def __init__(self, env):
        self.env, self.episode_len = env, env.episode_len

    def reset_batch(self, keys):
        return self.env.reset_batch(keys)

    def step_batch(self, state, actions):
        return self.env.step_batch(state, jnp.asarray(actions))


def _memory_policy():
    """Slows down as the reward it has received grows: the memory decides the action."""
    from r2pac_jax.evaluate import MemoryPolicy

    def init(params, obs):
        return jnp.zeros(obs.shape[0])

    def act(params, obs, key, mem):
        speed = params["speed"] / (1.0 + jnp.maximum(mem, 0.0))
        return _straight({"speed": 1.0}, obs, key) * speed[:, None], mem

    def observe(params, mem, reward, cost):
        return mem + reward

    return MemoryPolicy(init, act, observe)


def test_a_policy_with_memory_runs_alike_in_jax_and_python_rollouts():
    from r2pac_jax.evaluate import LaneEvaluator

    task = get_task("ReachAvoid")
    pol = _memory_policy()
    params = {"speed": jnp.array([1.0, 0.7])}
    keys = jnp.stack([jax.random.PRNGKey(0), jax.random.PRNGKey(1)])
    env = ra.ReachAvoidEnv()
    a = LaneEvaluator(pol, task, 3, env=env)(params, keys)
    b = LaneEvaluator(pol, task, 3, env=_ViaPython(env))(params, keys)
    np.testing.assert_allclose(a["returns"], b["returns"], rtol=1e-4, atol=1e-4)
    np.testing.assert_array_equal(a["costs"], b["costs"])
    # the memory matters: without it (full speed throughout) the returns differ
    c = LaneEvaluator(lambda p, o, k: _straight(p, o, k), task, 3, env=env)(params, keys)
    assert not np.allclose(a["returns"], c["returns"])

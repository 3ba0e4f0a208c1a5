"""Navigation tasks, pure-JAX parts: pseudo-lidar, keepout layouts, goal re-draws, levels."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from r2pac_jax.envs.navigation.layout import sample_goal, sample_layout
from r2pac_jax.envs.navigation.lidar import grouped_lidar, pseudo_lidar
from r2pac_jax.envs.navigation.objects import LEVELS


def lidar_loop(agent_pos, agent_mat, positions, num_bins=16, max_dist=3.0):
    """The original's per-object loop (BaseTask._obs_lidar_pseudo), transcribed as the oracle."""
    obs = np.zeros(num_bins)
    for pos in positions:
        world = np.concatenate([pos[:2], [0.0]]) - agent_pos
        ego = world @ agent_mat
        z = complex(ego[0], ego[1])
        dist = np.abs(z)
        angle = np.angle(z) % (np.pi * 2)
        bin_size = (np.pi * 2) / num_bins
        b = int(angle / bin_size)
        sensor = max(0, max_dist - dist) / max_dist
        obs[b] = max(obs[b], sensor)
        alias = (angle - bin_size * b) / bin_size
        obs[(b + 1) % num_bins] = max(obs[(b + 1) % num_bins], alias * sensor)
        obs[(b - 1) % num_bins] = max(obs[(b - 1) % num_bins], (1 - alias) * sensor)
    return obs


def random_rotation(rng, tilt):
    """A heading about z composed with a small tilt (the car rocks on its wheels)."""
    th = rng.uniform(0, 2 * np.pi)
    rz = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])
    a = rng.normal(size=3) * tilt
    th = np.linalg.norm(a)
    if th == 0:
        return rz
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]]) / th
    return rz @ (np.eye(3) + np.sin(th) * k + (1 - np.cos(th)) * k @ k)  # Rodrigues


@pytest.mark.parametrize("tilt", [0.0, 0.2])
def test_lidar_matches_the_original_loop(tilt):
    rng = np.random.default_rng(0)
    lidar = jax.jit(pseudo_lidar)
    for k in (1, 4, 11):
        for _ in range(12):
            agent_pos = np.array([*rng.uniform(-2, 2, 2), 0.1])
            mat = random_rotation(rng, tilt)
            objs = rng.uniform(-4, 4, (k, 2))
            want = lidar_loop(agent_pos, mat, objs)
            got = np.asarray(lidar(jnp.asarray(agent_pos, jnp.float32),
                                   jnp.asarray(mat, jnp.float32),
                                   jnp.asarray(objs, jnp.float32)))
            np.testing.assert_allclose(got, want, atol=2e-5)


def test_lidar_reads_nearest_and_aliases():
    pos, mat = jnp.zeros(3), jnp.eye(3)
    # object straight ahead (angle 0: bin 0, alias 0 -> bin 15 gets the full reading)
    far_near = jnp.array([[2.0, 0.0], [1.0, 0.0]])
    out = np.asarray(pseudo_lidar(pos, mat, far_near))
    np.testing.assert_allclose(out[0], (3 - 1) / 3, rtol=1e-6)  # the nearer one wins
    np.testing.assert_allclose(out[15], (3 - 1) / 3, rtol=1e-6)
    assert out[1] == 0 and out[2:15].max() == 0
    # half way into bin 3: both neighbours get half the reading
    ang = 2 * np.pi / 16 * 3.5
    out = np.asarray(pseudo_lidar(pos, mat, jnp.array([[np.cos(ang), np.sin(ang)]])))
    np.testing.assert_allclose(out[[2, 3, 4]], [1 / 3, 2 / 3, 1 / 3], rtol=1e-4)
    # beyond max_dist nothing is seen
    assert np.asarray(pseudo_lidar(pos, mat, jnp.array([[0.0, 3.5]]))).max() == 0


def test_grouped_lidar_equals_separate_lidars():
    rng = np.random.default_rng(1)
    pos = jnp.array([0.3, -0.2, 0.1])
    mat = jnp.asarray(random_rotation(rng, 0.1), jnp.float32)
    groups = [rng.uniform(-3, 3, (n, 2)).astype(np.float32) for n in (1, 8, 3)]
    group_of = np.concatenate([np.full(len(g), i) for i, g in enumerate(groups)])
    got = grouped_lidar(pos, mat, jnp.asarray(np.concatenate(groups)), group_of, 3)
    for i, g in enumerate(groups):
        np.testing.assert_allclose(got[i], pseudo_lidar(pos, mat, jnp.asarray(g)), atol=1e-7)


@pytest.mark.parametrize("name", ["CarGoal2", "CarPush1"])
def test_layouts_respect_keepouts_and_extents(name):
    lv = LEVELS[name]
    keep = np.array(lv.keepouts)
    xy, ok = jax.jit(jax.vmap(lambda k: sample_layout(k, keep, lv.extent)))(
        jax.random.split(jax.random.PRNGKey(0), 64))
    xy, ok = np.asarray(xy), np.asarray(ok)
    assert ok.all()
    assert xy.shape == (64, len(keep), 2)
    # every object lies inside the extents shrunk by its own keepout
    assert np.all(np.abs(xy) <= lv.extent - keep[None, :, None] + 1e-6)
    d = np.linalg.norm(xy[:, :, None] - xy[:, None, :], axis=-1)
    need = keep[:, None] + keep[None, :]
    off = ~np.eye(len(keep), dtype=bool)
    assert np.all(d[:, off] >= need[off] - 1e-6)
    # fresh layouts: different keys give different layouts
    assert np.unique(xy[:, 0, 0]).size == 64


def test_layout_search_restarts_when_an_object_cannot_be_placed():
    # four objects that need 0.8 between them in a 1.6 x 1.6 square: single attempts often
    # fail (the first three can leave no room), so success relies on whole-layout restarts
    from r2pac_jax.envs.navigation.layout import _one_layout

    keep = jnp.array([0.4, 0.4, 0.4, 0.4])
    keys = jax.random.split(jax.random.PRNGKey(3), 64)
    _, first_ok = jax.vmap(lambda k: _one_layout(k, keep, 1.2, 0.0))(keys)
    assert 0 < np.asarray(first_ok).mean() < 1
    xy, ok = jax.vmap(lambda k: sample_layout(k, keep, 1.2))(keys)
    assert np.asarray(ok).all()
    d = np.linalg.norm(np.asarray(xy)[:, :, None] - np.asarray(xy)[:, None, :], axis=-1)
    iu = np.triu_indices(4, 1)
    assert np.all(d[:, iu[0], iu[1]] >= 0.8 - 1e-6)


def test_goal_redraw_keeps_clear_and_only_when_needed():
    keep = jnp.array([0.4, 0.305, 0.18, 0.18])
    xy = jnp.array([[0.0, 0.0], [9.0, 9.0], [0.8, 0.0], [-0.8, 0.5]])
    others = jnp.array([True, False, True, True])  # the goal's own slot does not count
    goals, ok = jax.vmap(lambda k: sample_goal(k, xy, keep, others, 0.305, 1.5))(
        jax.random.split(jax.random.PRNGKey(0), 100))
    assert np.asarray(ok).all()
    d = np.linalg.norm(np.asarray(goals)[:, None, :] - np.asarray(xy)[None, [0, 2, 3]], axis=-1)
    assert np.all(d >= np.asarray(keep)[[0, 2, 3]] + 0.305 - 1e-6)
    g, ok = sample_goal(jax.random.PRNGKey(0), xy, keep, others, 0.305, 1.5, need=False)
    assert not bool(ok)
    # no room at all: the draw fails after its 10000 tries
    g, ok = sample_goal(jax.random.PRNGKey(0), xy, jnp.array([5.0, 0, 0, 0]), others, 0.3, 1.5)
    assert not bool(ok)


def test_levels_follow_the_original_order_and_sizes():
    lv = LEVELS["CarButton1"]
    assert [g.kind for g in lv.groups] == ["buttons", "goal", "hazards", "gremlins"]
    assert lv.layout_names[:6] == ("agent", "button0", "button1", "button2", "button3", "goal")
    assert [g.kind for g in LEVELS["CarPush2"].groups] == ["goal", "hazards", "pillars",
                                                           "push_box"]
    assert LEVELS["CarPush2"].group("push_box").size == 0.125
    assert LEVELS["PointPush2"].group("push_box").size == 0.2
    assert LEVELS["CarGoal1"].group("vases").constrained is False
    assert LEVELS["CarGoal2"].group("vases").constrained is True
    assert len(LEVELS) == 12

import chex
import jax
import numpy as np
import pytest

from conftest import toy_arrays
from r2pac_jax.data.chunks import ChunkError, build_chunks, chunk_arrays, sample
from r2pac_jax.data.dsrl import validate


def _ds(episodes):
    return validate(toy_arrays(episodes), "toy")


def test_valid_starts_respect_timeouts_and_terminals():
    # episode A: 4 steps ending in a timeout (rows 0-3); B: 3 steps ending in a terminal (4-6)
    ds = _ds(((4, "timeout"), (3, "terminal")))
    arr = chunk_arrays(ds, h=3, discount=0.5)
    # A: starts 0, 1 fit 3 steps before the timeout; 2, 3 do not (no chunk crosses a timeout)
    # B: every start is valid; the chunks from 5 and 6 are cut at the terminal
    np.testing.assert_array_equal(arr["starts"], [0, 1, 4, 5, 6])
    np.testing.assert_array_equal(arr["n_steps"], [3, 3, 3, 2, 1])
    # bootstrap m_t = 0 exactly where the chunk contains the terminal
    np.testing.assert_array_equal(arr["bootstrap"], [1, 1, 0, 0, 0])


def test_discounted_sums_and_scales():
    ds = _ds(((4, "timeout"), (3, "terminal")))
    g = 0.5
    arr = chunk_arrays(ds, h=3, discount=g, reward_scale=2.0, cost_scale=3.0)
    r, c = ds.rewards, ds.costs
    for j, (t, n) in enumerate(zip(arr["starts"], arr["n_steps"])):
        want_r = sum(g**k * r[t + k] for k in range(n)) * 2.0
        want_c = sum(g**k * c[t + k] for k in range(n)) * 3.0
        assert abs(arr["reward_sum"][j] - want_r) < 1e-5
        assert abs(arr["cost_sum"][j] - want_c) < 1e-5
        z = np.where(c[t:t + n] > 0, 1.0, -1.0)
        assert arr["zmax"][j] == z.max()


def test_sampled_batch_pads_and_masks_after_terminal():
    ds = _ds(((4, "timeout"), (3, "terminal")))
    data = build_chunks(ds, h=3, discount=0.9, threshold_subset=4)
    b = sample(data, jax.random.PRNGKey(0), 256)
    chex.assert_shape(b.actions, (256, 3, 2))
    chex.assert_shape(b.action_mask, (256, 3))
    acts = np.asarray(ds.actions)
    obs = np.asarray(ds.observations)
    for i in range(256):
        t = int(np.flatnonzero((obs == np.asarray(b.observations[i])).all(1))[0])
        n = int(np.asarray(b.action_mask[i]).sum())
        np.testing.assert_allclose(b.actions[i, :n], acts[t:t + n])
        # padding repeats the last real action
        for k in range(n, 3):
            np.testing.assert_allclose(b.actions[i, k], acts[t + n - 1])
        # s_{t+n} is the next observation of the chunk's last step
        np.testing.assert_allclose(b.next_observations[i], ds.next_observations[t + n - 1])
    assert set(np.unique(np.asarray(b.action_mask).sum(1)).tolist()) <= {1.0, 2.0, 3.0}


def test_h1_is_one_step():
    ds = _ds(((4, "timeout"), (3, "terminal")))
    arr = chunk_arrays(ds, h=1, discount=0.99)
    np.testing.assert_array_equal(arr["starts"], np.arange(7))
    np.testing.assert_allclose(arr["reward_sum"], ds.rewards, rtol=1e-6)
    np.testing.assert_array_equal(arr["bootstrap"], [1, 1, 1, 1, 1, 1, 0])


def test_chunk_longer_than_episode_is_an_error():
    ds = _ds(((4, "timeout"), (3, "timeout")))
    with pytest.raises(ChunkError, match="longer than the longest episode"):
        chunk_arrays(ds, h=5, discount=0.99)
    with pytest.raises(ChunkError, match=">= 1"):
        chunk_arrays(ds, h=0, discount=0.99)


def test_episode_filter_keeps_only_chosen_episodes():
    ds = _ds(((4, "timeout"), (3, "terminal")))
    arr = chunk_arrays(ds, h=2, discount=0.9, keep_episodes=np.array([False, True]))
    assert arr["starts"].min() >= 4

import numpy as np
import pytest

from conftest import toy_arrays
from r2pac_jax.data.factory.thinning import select_episodes, thin_by_density


def test_thinning_evens_out_a_crowded_region():
    rng = np.random.default_rng(0)
    # 900 trajectories crowded at (cost 20, return 30), 100 spread out
    costs = np.concatenate([rng.normal(20, 0.5, 900), rng.uniform(0, 40, 100)])
    rets = np.concatenate([rng.normal(30, 0.5, 900), rng.uniform(0, 40, 100)])
    keep = thin_by_density(rets, costs, target=300, bins=10, seed=0)
    assert 250 <= keep.size <= 300
    crowded = (np.abs(costs - 20) < 2) & (np.abs(rets - 30) < 2)
    assert crowded[keep].mean() < crowded.mean()  # the crowd lost most of its weight
    assert (~crowded)[keep].sum() >= 0.8 * (~crowded).sum()  # the spread-out ones survive
    assert np.array_equal(keep, thin_by_density(rets, costs, 300, 10, seed=0))  # seeded
    assert np.array_equal(np.sort(keep), keep) and len(set(keep)) == keep.size


def test_thinning_keeps_everything_under_target_and_rejects_zero():
    assert np.array_equal(thin_by_density(np.arange(5.0), np.arange(5.0), 10), np.arange(5))
    with pytest.raises(ValueError, match="target must be >= 1"):
        thin_by_density(np.arange(5.0), np.arange(5.0), 0)


def test_select_episodes_keeps_whole_episodes():
    arrays = toy_arrays(((4, "timeout"), (3, "terminal"), (2, "timeout")))
    out = select_episodes(arrays, np.array([0, 2]))
    assert out["rewards"].shape == (6,)
    np.testing.assert_array_equal(out["rewards"], np.concatenate([arrays["rewards"][:4],
                                                                  arrays["rewards"][7:]]))

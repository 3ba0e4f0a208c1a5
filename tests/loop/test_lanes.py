"""lanes.py on its own: the seeds x cells grid one compiled program trains side by side."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from r2pac_jax.config import ConfigError, make_config
from r2pac_jax.lanes import Lanes, place
from r2pac_jax.tasks import get_task


@pytest.fixture(scope="module")
def cfg():
    return make_config(get_task("ReachAvoid"), "r2pac", "quick", {})


def test_grid_is_cells_major_with_every_seed(cfg):
    lanes = Lanes.build(cfg, [3, 7], [dict(quantile_alpha=0.6), dict(penalty_c=5.0)])
    assert lanes.size == 4
    assert lanes.seeds == [3, 7, 3, 7] and lanes.cells == [0, 0, 1, 1]
    # a cell's unset values are the config's; hp holds one float32 per lane
    assert lanes.cell_hparams[0]["penalty_c"] == float(cfg.penalty_c)
    assert lanes.cell_hparams[1]["quantile_alpha"] == float(cfg.quantile_alpha)
    assert lanes.hp["quantile_alpha"].dtype == jnp.float32
    np.testing.assert_allclose(lanes.hp["quantile_alpha"],
                               [0.6, 0.6, cfg.quantile_alpha, cfg.quantile_alpha], rtol=1e-6)
    np.testing.assert_array_equal(lanes.hp["penalty_c"], [cfg.penalty_c] * 2 + [5.0] * 2)


def test_default_is_one_cell_of_the_config(cfg):
    lanes = Lanes.build(cfg, [0, 1, 2])
    assert lanes.cells == [0, 0, 0] and len(lanes.cell_hparams) == 1
    assert set(lanes.hp) == {"quantile_alpha", "penalty_c", "guidance_scale"}


def test_keys_are_the_lane_seeds_and_broadcast_adds_the_lane_axis(cfg):
    lanes = Lanes.build(cfg, [5, 9])
    keys = lanes.init_keys()
    np.testing.assert_array_equal(keys[1], jax.random.PRNGKey(9))
    tree = lanes.broadcast(dict(a=jnp.ones((2, 3)), b=jnp.zeros(())))
    assert tree["a"].shape == (2, 2, 3) and tree["b"].shape == (2,)


@pytest.mark.parametrize("cell,match", [
    (dict(lr=1e-3), r"cannot vary \['lr'\] across lanes of r2pac"),
    (dict(quantile_alpha=1.0), r"quantile_alpha must lie in \(0, 1\)"),
    (dict(penalty_c=-2.0), r"penalty_c must be >= 0"),
])
def test_bad_cells_refused_naming_the_value(cfg, cell, match):
    with pytest.raises(ConfigError, match=match):
        Lanes.build(cfg, [0], [cell])


def test_place_is_a_no_op_on_one_device():
    tree = dict(x=jnp.arange(4.0))
    out = place(tree, 4)
    if len(jax.local_devices()) < 2:
        assert out is tree
    else:  # spread along lanes: same values
        np.testing.assert_array_equal(out["x"], tree["x"])

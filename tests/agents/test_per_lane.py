"""Inside an agent the vmappable scalars (HPARAMS) have one place, `hp[name]`: the agent's
config holds markers there, and using one as a number is refused by name."""
import importlib
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import tiny_config
from r2pac_jax.agents import MODULES, algo_module, algorithm_spec, make_agent
from r2pac_jax.agents.per_lane import PerLane, PerLaneValue, lane_view
from r2pac_jax.lanes import Lanes
from r2pac_jax.loop import check_data, make_data
from r2pac_jax.tasks import get_task

# one --algo name per module that has per-lane scalars
SPECS = [algorithm_spec(importlib.import_module(f"r2pac_jax.agents.{m}")) for m in MODULES]
ALGOS = [next(iter(s.VARIANTS)) for s in SPECS if s.HPARAMS]


@pytest.mark.parametrize("algo", ALGOS)
def test_an_agents_config_holds_markers_where_lanes_differ(algo):
    cfg = tiny_config(algo)
    names = algo_module(algo).HPARAMS
    task = get_task("ReachAvoid")
    agent = make_agent(cfg, task.obs_dim, task.act_dim)
    for k in names:
        assert isinstance(getattr(cfg, k), float), k  # the caller's config is unchanged
        marker = getattr(agent.cfg, k)
        assert marker == PerLane(k)
        for use in (float, lambda m: m * 2.0, lambda m: 1.0 - m, lambda m: m < 0.5,
                    lambda m: f"{m:g}", jnp.asarray, np.asarray):
            with pytest.raises(PerLaneValue, match=rf"hp\['{k}'\]"):
                use(marker)
    # every other key reads through as before
    assert agent.cfg.discount == cfg.discount and agent.cfg.algo == cfg.algo
    # the agent starts from the lanes' values alone
    hp = {k: jnp.float32(getattr(cfg, k)) for k in names}
    jax.eval_shape(agent.init, jax.random.PRNGKey(0), hp)


def test_lane_view_without_per_lane_scalars_is_the_config_itself():
    cfg = tiny_config("bc-all")
    assert algo_module("bc-all").HPARAMS == ()
    assert lane_view(cfg, ()) is cfg


def test_cdt_checks_each_cells_cost_target_against_the_data(reach_avoid_data):
    task = get_task("ReachAvoid")
    cfg = tiny_config("cdt")
    agent = make_agent(cfg, task.obs_dim, task.act_dim)
    costs = [float(c) for c in agent._episodes(task, reach_avoid_data)[3]]
    inside, outside = float(np.median(costs)), max(costs) + 100.0
    for cells, warned in (([{"target_cost": inside}], False),
                          ([{"target_cost": inside}, {"target_cost": outside}], True)):
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            check_data(agent, task, reach_avoid_data, cells)
        hit = [x for x in w if "target_cost" in str(x.message)]
        assert bool(hit) == warned
        if warned:
            assert f"target_cost={outside:g}" in str(hit[0].message)
    # the pure data view (make_train's path) checks the default cell as before
    far = tiny_config("cdt", target_cost=outside)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        make_data(far, task, reach_avoid_data)
    assert any(f"target_cost={outside:g}" in str(x.message) for x in w)
    # the lanes a sweep builds carry the cells' values to the check
    lanes = Lanes.build(cfg, [0], [{"target_cost": inside}, {"target_cost": outside}])
    assert [c["target_cost"] for c in lanes.cell_hparams] == [inside, outside]

"""Every baseline (CPQ, BCQ-L, COptiDICE, CDT from OSRL; FISOR from its code; TREBI) through the generic loop: seeds vmapped
equal separate runs, and a killed run resumed equals an uninterrupted one bitwise."""
import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import tiny_config
from r2pac_jax.checkpoint import Checkpointer
from r2pac_jax.config import default_hparams
from r2pac_jax.lanes import Lanes
from r2pac_jax.loop import Run, make_data, make_train
from r2pac_jax.tasks import get_task

BASELINES = ["cpq", "bcq-lag", "coptidice", "fisor", "cdt", "trebi"]


# the default suite runs the cheapest one; the others (25-50 s of compilation each) are slow
@pytest.mark.parametrize("algo", [pytest.param(a, marks=() if a == "coptidice" else
                                               pytest.mark.slow) for a in BASELINES])
def test_vmapped_seeds_equal_separate_runs(algo, reach_avoid_data):
    task = get_task("ReachAvoid")
    cfg = tiny_config(algo, steps=20)
    train = make_train(cfg, make_data(cfg, task, reach_avoid_data), task.obs_dim, task.act_dim)
    hp = default_hparams(cfg)
    keys = jnp.stack([jax.random.PRNGKey(0), jax.random.PRNGKey(1)])
    hps = jax.tree_util.tree_map(lambda x: jnp.stack([x, x]), hp)
    batched, mb = jax.jit(jax.vmap(train))(keys, hps)
    single, _ = jax.jit(train)(keys[1], hp)
    chex.assert_trees_all_close(jax.tree_util.tree_map(lambda x: x[1], batched.params),
                                single.params, rtol=1e-4, atol=1e-5)
    for k, v in mb["actor"].items():
        assert np.all(np.isfinite(np.asarray(v))), (algo, k)
    pp = train.agent.policy_params(single, hp)
    a = jax.jit(train.agent.act)(pp, jnp.asarray(reach_avoid_data.observations[:5]),
                                 jax.random.PRNGKey(1))
    chex.assert_shape(a, (5, task.act_dim))
    assert np.all(np.abs(np.asarray(a)) <= 1.0)


@pytest.mark.slow
@pytest.mark.parametrize("algo", BASELINES)
def test_killed_and_resumed_equals_uninterrupted_bitwise(algo, reach_avoid_data, tmp_path):
    task = get_task("ReachAvoid")
    cfg = tiny_config(algo, steps=40, eval_every=40, checkpoint_every=10)
    lanes = Lanes.build(cfg, [0, 1])
    quiet = dict(progress=False, log=lambda m: None)
    Run(cfg, task, reach_avoid_data, tmp_path / "full", lanes, **quiet).run()
    part = Run(cfg, task, reach_avoid_data, tmp_path / "part", lanes, **quiet)
    assert part.run(stop_after=2) is None
    assert part.run(resume=True) is not None
    like = part.init_state()
    a, _ = Checkpointer(tmp_path / "full" / "checkpoints").restore(40, like)
    b, _ = Checkpointer(tmp_path / "part" / "checkpoints").restore(40, like)
    chex.assert_trees_all_equal(a, b)

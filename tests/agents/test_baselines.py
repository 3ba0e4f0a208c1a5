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
# XLA's batched convolutions round differently from single ones, and Adam turns a rounding
# difference in a near-zero gradient (TREBI's cost value on data that costs little) into a
# full step: its lanes' parameters drift apart by about lr per step (measured 2026-12-07: 5e-3
# on value_c's first bias after 20 steps; the cost value's loss 6e-6 apart after one step, 2.5%
# over the first 10), so for it one step's losses are compared instead
ADAM_NOISE = {"trebi"}


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
    single, ms = jax.jit(train)(keys[1], hp)
    if algo in ADAM_NOISE:
        # one step from the same parameters: the lanes' losses agree to rounding; another
        # seed's do not
        one = tiny_config(algo, steps=1, block_steps=1, eval_every=1, checkpoint_every=1)
        train1 = make_train(one, make_data(one, task, reach_avoid_data), task.obs_dim,
                            task.act_dim)
        _, m2 = jax.jit(jax.vmap(train1))(keys, hps)
        _, m1 = jax.jit(train1)(keys[1], hp)
        for k, v in m1["actor"].items():
            np.testing.assert_allclose(np.asarray(m2["actor"][k][1]), np.asarray(v), rtol=1e-4,
                                       err_msg=k)
        assert not np.allclose(np.asarray(m2["actor"]["loss_diffusion"][0]),
                               np.asarray(m1["actor"]["loss_diffusion"]), rtol=1e-3)
    else:
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

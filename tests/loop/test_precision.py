"""matmul_precision (precision.py): bf16 rounds exactly the matmuls' operands, inside loops,
branches and vmap; highest pins the dots' precision; every value trains; bad values are refused."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import tiny_config

from r2pac_jax.config import Config, make_config
from r2pac_jax.errors import ConfigError
from r2pac_jax.precision import with_matmul_precision


def _rounded(x):
    return np.asarray(jnp.asarray(x).astype(jnp.bfloat16).astype(jnp.float32))


def test_bf16_rounds_the_matmul_operands_and_nothing_else():
    x = jax.random.normal(jax.random.PRNGKey(0), (8, 32))
    w = jax.random.normal(jax.random.PRNGKey(1), (32, 16))

    def f(x, w):  # a matmul, then elementwise work that must stay float32
        return jnp.tanh(x @ w) + x[:, :16] * 1.001

    got = jax.jit(with_matmul_precision(f, "bf16"))(x, w)
    assert got.dtype == jnp.float32
    want = np.tanh(_rounded(x) @ _rounded(w)) + np.asarray(x[:, :16]) * 1.001
    np.testing.assert_allclose(got, want, rtol=2e-6, atol=2e-6)
    exact = np.asarray(jax.jit(f)(x, w))
    assert np.abs(np.asarray(got) - exact).max() > 1e-3  # the rounding is really there


def test_bf16_reaches_matmuls_inside_scan_cond_while_and_vmap():
    w = jax.random.normal(jax.random.PRNGKey(2), (4, 4))

    def f(x):
        x = jax.lax.scan(lambda c, _: (jnp.sin(c @ w), None), x, None, length=3)[0]
        x = jax.lax.cond(x.sum() > 0, lambda v: v @ w, lambda v: v @ w.T, x)
        return jax.lax.while_loop(lambda c: c[0] < 2, lambda c: (c[0] + 1, c[1] @ w),
                                  (0, x))[1]

    def g(x):  # f by hand with rounded operands
        r = lambda a: a.astype(jnp.bfloat16).astype(jnp.float32)  # noqa: E731
        for _ in range(3):
            x = jnp.sin(r(x) @ r(w))
        x = jnp.where(x.sum() > 0, r(x) @ r(w), r(x) @ r(w.T))
        for _ in range(2):
            x = r(x) @ r(w)
        return x

    xs = jax.random.normal(jax.random.PRNGKey(3), (5, 4))
    got = jax.jit(jax.vmap(with_matmul_precision(f, "bf16")))(xs)
    np.testing.assert_allclose(got, jax.vmap(g)(xs), rtol=1e-5, atol=1e-5)
    assert np.abs(np.asarray(got) - np.asarray(jax.vmap(f)(xs))).max() > 1e-4


def test_highest_pins_every_dot_and_default_leaves_the_program_alone():
    w = jnp.ones((3, 3))

    def f(x):
        return jax.lax.scan(lambda c, _: (c @ w, None), x, None, length=2)[0] @ w

    def dots(fn):
        text = str(jax.make_jaxpr(fn)(jnp.ones((2, 3))))
        return text.count("dot_general"), text.count("precision=(Precision.HIGHEST")

    assert dots(with_matmul_precision(f, "highest")) == (2, 2)
    assert dots(with_matmul_precision(f, "default")) == (2, 0)
    assert with_matmul_precision(f, "default") is f


def test_a_bad_precision_is_refused_naming_the_choices():
    with pytest.raises(ConfigError, match=r"matmul_precision='fp8' is not one of \('default', "
                                          r"'highest', 'bf16'\)"):
        make_config("ReachAvoid", "r2pac", "quick", dict(matmul_precision="fp8"))
    with pytest.raises(ConfigError, match="matmul_precision='tf32' is not one of default, "
                                          "highest, bf16"):
        with_matmul_precision(lambda x: x, "tf32")


def test_a_config_written_before_the_key_reads_as_default():
    cfg = make_config("ReachAvoid", "r2pac", "quick")
    d = Config.from_dict({k: v for k, v in cfg.flat().items() if k != "matmul_precision"})
    assert d.matmul_precision == "default"


def _trained_policy(algo, mode, data):
    """The policy parameters after one tiny block at `mode` (flat float32 vector)."""
    from r2pac_jax.agents import make_agent
    from r2pac_jax.config import default_hparams
    from r2pac_jax.loop import make_block, make_data
    from r2pac_jax.tasks import get_task

    task = get_task("ReachAvoid")
    cfg = tiny_config(algo, block_steps=5, matmul_precision=mode)
    agent = make_agent(cfg, task.obs_dim, task.act_dim)
    hp = default_hparams(cfg)
    state = agent.init(jax.random.PRNGKey(0), hp)
    state, _ = jax.jit(make_block(agent, cfg.phases[-1]))(state, hp, make_data(cfg, task, data))
    leaves = jax.tree_util.tree_leaves(agent.policy_params(state, hp))
    assert all(x.dtype == jnp.float32 and bool(jnp.isfinite(x).all()) for x in leaves)
    return np.concatenate([np.ravel(x) for x in leaves])


def test_r2pac_trains_at_bf16_with_float32_parameters(reach_avoid_data):
    f32, bf16 = (_trained_policy("r2pac", m, reach_avoid_data) for m in ("default", "bf16"))
    assert 0 < np.abs(bf16 - f32).max() < 0.1


@pytest.mark.slow
@pytest.mark.parametrize("module", ["bc_flow", "bc_mlp", "cpq", "bcq_lag", "coptidice", "fisor",
                                    "cdt", "trebi"])
def test_every_algorithm_trains_at_each_precision(module, reach_avoid_data):
    from r2pac_jax.agents import algorithm_spec

    spec = algorithm_spec(__import__(f"r2pac_jax.agents.{module}", fromlist=["_"]))
    algo = next(iter(spec.VARIANTS))
    out = {m: _trained_policy(algo, m, reach_avoid_data) for m in ("default", "highest", "bf16")}
    np.testing.assert_array_equal(out["default"], out["highest"])  # the CPU is exact already
    assert np.abs(out["bf16"] - out["default"]).max() > 0

"""Every algorithm of the pre-protocol code (a022372) reproduces bitwise through the protocol.

The fixture `fixtures/agents_a022372.npz` was made by `fixtures/make_agent_fixture.py` at that
commit (its docstring says how to make it again). Bitwise equality is a promise for the same
machine kind (the CPU model and ISA flags recorded in the fixture, `make_agent_fixture.cpu_kind`)
and jax version as the fixture's; elsewhere the arrays must still agree to float tolerance.
"""
import json
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

HERE = Path(__file__).parents[1] / "fixtures"
sys.path.insert(0, str(HERE))

import make_agent_fixture as fx  # noqa: E402

# Leaves of the old single Agent class that the cloners' own state no longer carries: the
# flow cloners never had critics, so their threshold was a constant 0.
DROPPED = {"bc-all": {"state.threshold"}, "bc-safe": {"state.threshold"}}
# Metrics logged since the fixture (R2PAC's diagnostics, issue 50): new keys, read off the same
# computation; every key the fixture has must still match it.
ADDED_METRICS = {"vc_min", "qr_rmse_penalised", "qr_rmse_unpenalised", "chunk_reward_std",
                 "corr_adv_r_reward_safe", "label_balance_safe", "label_balance_unsafe"}


def _added(key: str) -> bool:
    return "/metrics[" in key and key.rsplit("['", 1)[-1].rstrip("']") in ADDED_METRICS


@pytest.fixture(scope="module")
def reference():
    ref = np.load(HERE / "agents_a022372.npz")
    meta = json.loads(bytes(ref["__meta__"]).decode())
    return ref, meta


def _compare(ref, meta, current, algos, with_run):
    # bitwise on the fixture's own kind of machine (jax, backend and CPU); a fixture made
    # before the CPU was recorded, or another CPU, is compared to float tolerance
    exact = (meta["jax"] == jax.__version__ and meta["backend"] == jax.default_backend()
             and meta.get("cpu") == fx.cpu_kind())
    ref_keys = {k for k in ref.files if k != "__meta__"
                and (k.split("/")[0] in algos or (with_run and k.startswith("run/")))}
    missing = ref_keys - set(current)
    allowed = {f"{a}/{leaf}" for a, leaves in DROPPED.items() for leaf in leaves}
    assert missing <= allowed, sorted(missing - allowed)[:10]
    extra = {k for k in set(current) - ref_keys if not _added(k)}
    assert not extra, sorted(extra)[:10]
    for k in sorted(ref_keys & set(current)):
        a, b = np.asarray(current[k]), ref[k]
        assert a.shape == b.shape and a.dtype == b.dtype, k
        if exact:
            np.testing.assert_array_equal(a, b, err_msg=k)
        else:
            np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5, err_msg=k)
    for a in algos:
        assert any(k.startswith(f"{a}/act/") for k in current), a
    return len(ref_keys & set(current))


def _dataset(meta):
    ds = fx.dataset()
    assert fx.dataset_digest(ds) == meta["dataset_sha256"], (
        "the generated ReachAvoid dataset changed since the fixture was made: the fixture no "
        "longer pins the agents; make it again at a commit with the old agents and new data")
    return ds


def test_r2pac_and_a_flow_cloner_reproduce_the_pre_protocol_fixture(reference):
    """The default suite's share (two algorithms, no Run): the whole fixture is the slow test."""
    ref, meta = reference
    algos = ["r2pac", "bc-safe"]
    assert _compare(ref, meta, fx.record(_dataset(meta), algos, run=False), algos, False) > 150


@pytest.mark.slow
def test_every_algorithm_reproduces_the_pre_protocol_fixture(reference):
    ref, meta = reference
    current = fx.record(_dataset(meta))
    assert _compare(ref, meta, current, meta["algos"], True) > 800

"""r2pac_jax.value_map: a finished run's critics over data states, embedded and plotted."""
import json
import shutil

import jax
import numpy as np
import pytest

from r2pac_jax import value_map as vm


def test_spearman_ranks_ties_and_constants():
    x = np.array([1.0, 2.0, 3.0, 4.0])
    assert vm.spearman(x, x ** 3) == pytest.approx(1.0)
    assert vm.spearman(x, -x) == pytest.approx(-1.0)
    # ties take their mean rank: [1, 2, 2, 4] -> ranks [0, 1.5, 1.5, 3]
    r = vm.spearman(np.array([1.0, 2.0, 2.0, 4.0]), x)
    assert r == pytest.approx(np.corrcoef([0, 1.5, 1.5, 3], [0, 1, 2, 3])[0, 1])
    assert np.isnan(vm.spearman(np.ones(4), x))


def test_pca_embedding_is_deterministic_and_finds_the_main_axis():
    rng = np.random.default_rng(0)
    t = rng.normal(size=200)
    states = np.stack([t, 0.01 * rng.normal(size=200), t + 0.01 * rng.normal(size=200)], 1)
    a, used = vm.embed(states, "pca")
    b, _ = vm.embed(states, "pca")
    assert used == "PCA" and a.shape == (200, 2)
    np.testing.assert_array_equal(a, b)
    # the first coordinate carries t (the two correlated standardised dimensions)
    assert abs(np.corrcoef(a[:, 0], t)[0, 1]) > 0.99
    with pytest.raises(vm.ValueMapError, match="unknown embedding"):
        vm.embed(states, "tsne")


def test_sample_states_draws_distinct_rows_reproducibly():
    obs = np.arange(100, dtype=np.float32).reshape(50, 2)
    a = vm.sample_states(obs, 20, seed=3)
    np.testing.assert_array_equal(a, vm.sample_states(obs, 20, seed=3))
    assert len({tuple(r) for r in a}) == 20
    assert len(vm.sample_states(obs, 500)) == 50  # all of them where there are fewer


def test_state_values_are_the_checkpointed_critics_of_the_chosen_lane(tiny_run):
    from r2pac_jax.data import load_dsrl

    ds = load_dsrl(tiny_run["d"], 6, 2, "ReachAvoid")
    states = vm.sample_states(np.asarray(ds.observations), 64, 0)
    v0 = vm.state_values(tiny_run["run"], states, lane=0)
    v1 = vm.state_values(tiny_run["run"], states, lane=1)
    assert set(v0) == {"V_c", "Vbar_r"} and v0["V_c"].shape == (64,)
    assert not np.allclose(v0["V_c"], v1["V_c"])  # two seeds, two critics
    # the same numbers as the restored state's own networks, applied by hand
    cfg, agent, state = vm.restore_state(tiny_run["run"])
    p = jax.tree_util.tree_map(lambda x: x[1], state.params)
    np.testing.assert_allclose(v1["Vbar_r"], np.asarray(agent.v_net.apply(p["vr"], states)),
                               rtol=1e-6)
    with pytest.raises(vm.ValueMapError, match="out of range"):
        vm.state_values(tiny_run["run"], states, lane=2)
    with pytest.raises(vm.ValueMapError, match=r"needs \[N, 6\]"):
        vm.state_values(tiny_run["run"], states[:, :5])


def test_value_map_files_and_correlations(tmp_path):
    rng = np.random.default_rng(1)
    states = rng.normal(size=(300, 4)).astype(np.float32)
    vc = states[:, 0]
    values = {"V_c": vc, "V_r": vc + 0.1 * rng.normal(size=300), "Vbar_r": -vc}
    info = vm.value_map(states, values, tmp_path, "T", "T", method="pca")
    assert info["embedding"] == "PCA" and info["states"] == 300
    assert info["spearman_V_r_vs_V_c"] > 0.9 and info["spearman_Vbar_r_vs_V_c"] == pytest.approx(-1)
    lines = (tmp_path / "T.csv").read_text().splitlines()
    assert lines[0] == "x,y,V_r,V_c,Vbar_r" and len(lines) == 301
    assert (tmp_path / "T.png").stat().st_size > 1000
    with pytest.raises(vm.ValueMapError, match="one value per state"):
        vm.value_map(states, {"V_c": vc[:10]}, tmp_path, "U")


def test_cli_refuses_runs_without_the_values_it_maps(tiny_run, tmp_path, capsys):
    other = tmp_path / "run"
    shutil.copytree(tiny_run["run"], other)
    cfg = json.loads((other / "config.json").read_text())
    cfg["algo"] = "bc-safe"
    (other / "config.json").write_text(json.dumps(cfg))
    assert vm.main([str(other), "--dataset", str(tiny_run["d"]), "--out", str(tmp_path)]) == 2
    assert "has no V_r / V_c" in capsys.readouterr().err
    # --unpenalised must name an r2pac-no-penalty run: the tiny run is penalised
    assert vm.main([str(tiny_run["run"]), "--unpenalised", str(tiny_run["run"]), "--dataset",
                    str(tiny_run["d"]), "--out", str(tmp_path), "--embedding", "pca"]) == 2
    assert "needs an r2pac-no-penalty run" in capsys.readouterr().err
    assert vm.main([str(tiny_run["run"]), "--dataset", str(tiny_run["d"]), "--out",
                    str(tmp_path / "m"), "--states", "50", "--embedding", "pca"]) == 0
    assert (tmp_path / "m" / "ReachAvoid.csv").is_file()

import h5py
import numpy as np
import pytest

from conftest import load_script, toy_arrays
from r2pac_jax.data.dsrl import (DatasetError, find_dsrl_file, load_dsrl, validate, write_dsrl)
from r2pac_jax.tasks import get_task


def _write_raw(path, arrays):
    with h5py.File(path, "w") as f:
        for k, v in arrays.items():
            f.create_dataset(k, data=v)


def test_roundtrip_is_exact(tmp_path):
    arrays = toy_arrays()
    p = write_dsrl(tmp_path / "x.hdf5", arrays)
    ds = load_dsrl(p)
    for k, v in arrays.items():
        np.testing.assert_array_equal(getattr(ds, k), v)
    assert ds.terminals.dtype == bool and ds.observations.dtype == np.float32
    starts, ends = ds.episode_bounds()
    np.testing.assert_array_equal(starts, [0, 4])
    np.testing.assert_array_equal(ends, [3, 6])


def test_reader_accepts_float_flags_and_column_vectors(tmp_path):
    arrays = toy_arrays()
    arrays["terminals"] = arrays["terminals"].astype(np.float32)[:, None]
    arrays["rewards"] = arrays["rewards"][:, None]
    _write_raw(tmp_path / "y.hdf5", arrays)
    ds = load_dsrl(tmp_path / "y.hdf5")
    assert ds.terminals.dtype == bool and ds.rewards.shape == (7,)


def test_missing_key_names_file_key_and_fix(tmp_path):
    arrays = toy_arrays()
    del arrays["costs"]
    _write_raw(tmp_path / "bad.hdf5", arrays)
    with pytest.raises(DatasetError) as e:
        load_dsrl(tmp_path / "bad.hdf5", task_name="ReachAvoid")
    msg = str(e.value)
    assert "bad.hdf5" in msg and "'costs'" in msg and "missing key" in msg
    assert "python -m r2pac_jax.data make --task ReachAvoid" in msg


def test_wrong_observation_size_names_task(tmp_path):
    p = write_dsrl(tmp_path / "x.hdf5", toy_arrays(obs_dim=5))
    with pytest.raises(DatasetError, match="has 5 columns but task ReachAvoid has observations "
                                           "of size 6"):
        load_dsrl(p, obs_dim=6, act_dim=2, task_name="ReachAvoid")


def test_non_finite_values_are_rejected_with_row():
    arrays = toy_arrays()
    arrays["rewards"][2] = np.nan
    with pytest.raises(DatasetError, match=r"key 'rewards': 1 rows hold NaN or inf \(first at row 2\)"):
        validate(arrays, "f.hdf5")


def test_bad_flags_rejected():
    arrays = toy_arrays()
    arrays["timeouts"] = arrays["timeouts"].astype(np.float32) * 2
    with pytest.raises(DatasetError, match="flags must be bool or 0/1"):
        validate(arrays, "f.hdf5")


def test_row_count_mismatch():
    arrays = toy_arrays()
    arrays["actions"] = arrays["actions"][:-1]
    with pytest.raises(DatasetError, match="key 'actions': has 6 rows but 'observations' has 7"):
        validate(arrays, "f.hdf5")


def test_actions_outside_box_rejected():
    arrays = toy_arrays()
    arrays["actions"][0, 0] = 3.0
    with pytest.raises(DatasetError, match="outside the action box"):
        validate(arrays, "f.hdf5")


def test_unterminated_last_episode_rejected():
    arrays = toy_arrays()
    arrays["terminals"][-1] = False
    with pytest.raises(DatasetError, match="last transition ends no episode"):
        validate(arrays, "f.hdf5")


def test_discontinuous_episode_rejected():
    arrays = toy_arrays()
    arrays["timeouts"][3] = False  # two episodes glued together without a flag
    with pytest.raises(DatasetError, match="not followed by their next observation"):
        validate(arrays, "f.hdf5")


def test_unreadable_and_missing_files(tmp_path):
    with pytest.raises(DatasetError, match="no such file"):
        load_dsrl(tmp_path / "nope.hdf5")
    (tmp_path / "junk.hdf5").write_text("not hdf5")
    with pytest.raises(DatasetError, match="cannot be read as HDF5"):
        load_dsrl(tmp_path / "junk.hdf5")


def test_writer_is_atomic_and_validates_first(tmp_path):
    good = write_dsrl(tmp_path / "d.hdf5", toy_arrays())
    before = good.read_bytes()
    bad = toy_arrays()
    bad["observations"][0, 0] = np.inf
    with pytest.raises(DatasetError):
        write_dsrl(good, bad)
    assert good.read_bytes() == before  # the existing file is untouched
    assert [p.name for p in tmp_path.iterdir()] == ["d.hdf5"]  # no temporary left behind


def test_find_dsrl_file_by_task(tmp_path, monkeypatch):
    monkeypatch.setenv("DSRL_DATASET_DIR", str(tmp_path))
    task = get_task("CarGoal1")
    assert find_dsrl_file(task) is None
    (tmp_path / "SafetyCarGoal1Gymnasium-v0-120-999.hdf5").write_bytes(b"")
    (tmp_path / "SafetyCarGoal1Gymnasium-v0-120-1671.hdf5").write_bytes(b"")
    (tmp_path / "SafetyCarGoal2Gymnasium-v0-120-4105.hdf5").write_bytes(b"")
    assert find_dsrl_file(task).name == "SafetyCarGoal1Gymnasium-v0-120-1671.hdf5"


def test_no_progress_hides_the_generation_bar_but_not_the_announcements(tmp_path, monkeypatch,
                                                                        capfd):
    """`--no-progress` reaches the loader: a generated ReachAvoid dataset shows its tqdm bar only
    when progress is on; the announcements are made either way."""
    from r2pac_jax.data import factory, load_task_dataset
    from r2pac_jax.tasks import get_task

    monkeypatch.setenv("DSRL_DATASET_DIR", str(tmp_path / "none"))
    monkeypatch.setattr(factory, "default_trajectories", lambda task: 12)
    task = get_task("ReachAvoid")
    for progress, data_dir in ((False, "quiet"), (True, "loud")):
        monkeypatch.setenv("R2PAC_DATA_DIR", str(tmp_path / data_dir))
        said = []
        capfd.readouterr()
        ds = load_task_dataset(task, announce=said.append, progress=progress)
        err = capfd.readouterr().err
        assert ds.observations.shape[0] > 0
        assert said[0].startswith("dataset: none found for ReachAvoid; generating 12 trajectories")
        assert ("ReachAvoid data" in err) == progress, err


def test_train_memory_benchmark_writes_a_valid_file_of_the_asked_shape(tmp_path):
    """benchmarks/train_memory.py measures train on a synthetic file: it must load as a DSRL file
    of the task's widths, with one episode per episode_len rows and next_observations shifted."""
    mod = load_script("benchmarks/train_memory.py")
    task = get_task("PointGoal1")
    p = tmp_path / "syn.hdf5"
    size = mod.write_file(p, 5, 7, task.obs_dim, task.act_dim, block=2)  # written in blocks 2+2+1
    assert size == p.stat().st_size > 0 and not p.with_suffix(".tmp").exists()
    ds = load_dsrl(p, obs_dim=task.obs_dim, act_dim=task.act_dim)
    assert ds.observations.shape == (35, task.obs_dim) and ds.actions.shape == (35, task.act_dim)
    starts, ends = ds.episode_bounds()
    np.testing.assert_array_equal(starts, np.arange(0, 35, 7))
    np.testing.assert_array_equal(ends, np.arange(6, 35, 7))
    within = np.ones(35, bool)
    within[ends] = False  # inside an episode the next row's observation is this row's next one
    np.testing.assert_array_equal(ds.next_observations[within], ds.observations[1:][within[:-1]])
    assert not ds.terminals.any() and np.isin(ds.costs, [0.0, 1.0]).all()


def test_train_memory_benchmark_refuses_a_non_positive_size(tmp_path, monkeypatch, capsys):
    import sys

    mod = load_script("benchmarks/train_memory.py")
    monkeypatch.setattr(sys, "argv", ["train_memory.py", "--task", "PointGoal1",
                                      "--trajectories", "0", "--out", str(tmp_path)])
    with pytest.raises(SystemExit):
        mod.main()
    assert "--trajectories must be a positive number of episodes, got 0" in capsys.readouterr().err
    assert not list(tmp_path.glob("*.hdf5"))


def test_blockwise_checks_find_the_same_rows_as_whole_array_ones(monkeypatch):
    """validate checks in blocks (memory); with blocks of 3 rows the rows found, in order, must be
    those of the whole-array formulas, across block edges, and a float32 array is not copied."""
    from r2pac_jax.data import dsrl

    rng = np.random.default_rng(0)
    n, d = 20, 4
    obs = rng.standard_normal((n, d)).astype(np.float32)
    nxt = np.roll(obs, -1, axis=0)
    ends = np.zeros(n, bool)
    ends[[6, 13, n - 1]] = True
    nxt[[2, 3, 5, 8, 12]] += 1.0  # 2, 3 and 5 straddle the first block edges; 12 before an end
    nxt[ends] = 7.0  # not compared: the episode ends there
    obs[[4, 17], 1] = np.nan
    expected_nonfinite = np.flatnonzero(~np.isfinite(obs).all(axis=1))
    monkeypatch.setattr(dsrl, "_CHECK_BLOCK", 3)
    np.testing.assert_array_equal(dsrl._rows_not_finite(obs), expected_nonfinite)
    np.testing.assert_array_equal(expected_nonfinite, [4, 17])
    clean = np.nan_to_num(obs)
    whole_gap = np.abs(nxt[:-1] - clean[1:]).max(axis=1) > 1e-4 * (1 + np.abs(clean[1:]).max(axis=1))
    got = dsrl._unfollowed_rows(clean, nxt, ends)
    np.testing.assert_array_equal(got, np.flatnonzero(whole_gap & ~ends[:-1]))
    assert {2, 3, 5, 8, 12} <= set(got.tolist()) and not set(got.tolist()) & {6, 13}
    arrays = toy_arrays()
    arrays["observations"] = arrays["observations"].astype(np.float32)
    assert validate(arrays).observations is arrays["observations"]


def test_digest_is_the_sha256_of_the_arrays_bytes():
    """digest hashes the buffers in place (no copy of a 1.5 GB array); the value must stay the
    sha256 of the arrays' bytes in KEYS order, which manifests and resumed runs compare."""
    import hashlib

    from r2pac_jax.data.dsrl import KEYS

    ds = validate(toy_arrays())
    h = hashlib.sha256()
    for k in KEYS:
        h.update(np.ascontiguousarray(getattr(ds, k)).tobytes())
    assert ds.digest() == h.hexdigest()
    arrays = toy_arrays()
    arrays["rewards"] = arrays["rewards"] + 1.0
    assert validate(arrays).digest() != ds.digest()

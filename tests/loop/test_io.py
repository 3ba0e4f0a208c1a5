"""Atomic result files: complete or absent, and readable like any other file."""
import json
import os
import stat

import pytest

from r2pac_jax.io import atomic_write_json, atomic_write_text


def test_atomic_write_replaces_whole_file_with_umask_mode(tmp_path):
    old = os.umask(0o022)
    try:
        p = atomic_write_json(tmp_path / "sub" / "r.json", {"a": 1})
    finally:
        os.umask(old)
    assert json.loads(p.read_text()) == {"a": 1}
    assert stat.S_IMODE(p.stat().st_mode) == 0o644
    atomic_write_text(p, "second\n")
    assert p.read_text() == "second\n"
    assert [q.name for q in p.parent.iterdir()] == ["r.json"]  # no temporary file left


def test_failed_write_leaves_the_old_file(tmp_path):
    p = atomic_write_text(tmp_path / "r.json", "old\n")
    with pytest.raises(TypeError, match="not JSON serialisable"):
        atomic_write_json(p, {"x": object()})
    assert p.read_text() == "old\n"
    assert [q.name for q in tmp_path.iterdir()] == ["r.json"]


def test_a_run_directory_has_one_live_writer(tmp_path):
    from r2pac_jax.io import DirectoryBusy, lock_directory

    held = lock_directory(tmp_path / "run")
    with pytest.raises(DirectoryBusy, match=r"run is being written by pid \d+ on .*--resume"):
        lock_directory(tmp_path / "run")
    held.close()  # released (the kernel also releases it when the holder dies)
    lock_directory(tmp_path / "run").close()


def test_train_cli_refuses_a_directory_another_process_writes(tmp_path, capsys):
    """Two launchers on one --out would interleave checkpoints and logs: the second stops
    with a clear error before writing anything, and the directory stays untouched."""
    import subprocess
    import sys

    from r2pac_jax.train import main

    out = tmp_path / "run"
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time; from r2pac_jax.io import lock_directory; "
         f"f = lock_directory({str(out)!r}); print('held', flush=True); time.sleep(60)"],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        assert main(["--task", "ReachAvoid", "--out", str(out), "--baselines", "none",
                     "--steps", "10", "--no-progress"]) == 2
        err = capsys.readouterr().err
        assert f"pid {holder.pid}" in err and "is being written by" in err
        assert sorted(p.name for p in out.iterdir()) == [".lock"]
    finally:
        holder.kill()
        holder.wait()


def test_plots_get_the_umask_mode_too(tmp_path):
    from r2pac_jax.report import _plt, _savefig

    plt = _plt()
    fig, ax = plt.subplots()
    ax.plot([0, 1], [1, 0])
    old = os.umask(0o022)
    try:
        p = _savefig(fig, tmp_path / "plot.png")
    finally:
        os.umask(old)
        plt.close(fig)
    assert stat.S_IMODE(p.stat().st_mode) == 0o644
    assert [q.name for q in tmp_path.iterdir()] == ["plot.png"]


def test_datasets_are_written_through_the_same_atomic_path(tmp_path):
    from r2pac_jax.data.dsrl import load_dsrl, write_dsrl
    from r2pac_jax.data.factory import reach_avoid

    old = os.umask(0o022)
    try:
        p = write_dsrl(tmp_path / "d.hdf5", reach_avoid.generate(4, seed=0))
    finally:
        os.umask(old)
    assert stat.S_IMODE(p.stat().st_mode) == 0o644
    assert [q.name for q in tmp_path.iterdir()] == ["d.hdf5"]
    assert load_dsrl(p).size > 0

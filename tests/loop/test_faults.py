"""Faults a user meets that are not bad options: a damaged checkpoint, Ctrl-C, more lanes than
memory holds, a folder that is not the project's, an observation of the wrong width. Each ends in
one clear line (or a fallback that says what it did), and nothing already written is lost."""
import json
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import jax
import numpy as np
import pytest
from conftest import TINY_ARGV

from r2pac_jax.io import MARKER

T = ["--task", "ReachAvoid"]
TINY = TINY_ARGV + ["--baselines", "none"]


@pytest.fixture
def finished(tiny_run):
    """The session's tiny finished run (conftest.tiny_run): copied before any change."""
    return tiny_run


def _copy(run, dest):
    shutil.copytree(run, dest, ignore=shutil.ignore_patterns(".lock"))
    return dest


def _damage(step_dir: Path, where: str = "ocdbt.process_0/d"):
    """Flip bytes in the middle of the largest file under a finished checkpoint's state/WHERE
    (ocdbt.process_0/d: array chunks, which carry no checksum of their own; d: the database,
    whose CRC tensorstore checks)."""
    files = sorted((p for p in (step_dir / "state" / where).glob("*") if p.is_file()),
                   key=lambda p: p.stat().st_size)
    target = files[-1]
    raw = bytearray(target.read_bytes())
    mid = len(raw) // 2
    for i in range(mid, min(mid + 64, len(raw))):
        raw[i] ^= 0xFF
    target.write_bytes(bytes(raw))


def test_resume_falls_back_past_a_damaged_checkpoint(finished, capsys, data_dir):
    from r2pac_jax.checkpoint import Checkpointer
    from r2pac_jax.train import main

    run = _copy(finished["run"], finished["t"] / "damaged_newest")
    ck = run / "checkpoints"
    assert Checkpointer(ck).all_steps() == [40, 30]
    _damage(ck / "40")
    rc = main(T + ["--dataset", str(finished["d"]), "--out", str(run), "--resume"] + TINY)
    out = capsys.readouterr()
    assert rc == 0, out.err[-2000:]
    assert "warning: checkpoint step 40 does not read back" in out.out
    assert "resuming from step 30" in out.out
    # the damaged checkpoint is kept aside, the run trained step 40 again and finished
    assert (run / "checkpoints-damaged" / "40" / "state").is_dir()
    assert Checkpointer(ck).latest_step() == 40
    rows = [json.loads(x) for x in (run / "metrics.jsonl").read_text().splitlines()]
    assert sorted({r["step"] for r in rows}) == [10, 20, 30, 40]  # each step logged once
    assert len(rows) == 4 * 2  # two lanes
    res = json.loads((run / "results.json").read_text())
    assert res["resumed_from_step"] == 30


def test_resume_refuses_in_one_line_when_no_checkpoint_reads_back(finished, capsys, data_dir):
    from r2pac_jax.train import main

    from r2pac_jax.checkpoint import DIGEST

    run = _copy(finished["run"], finished["t"] / "damaged_all")
    _damage(run / "checkpoints" / "30")  # caught by the recorded checksums
    # a checkpoint of an earlier release (no checksum record): tensorstore's own CRC catches it
    (run / "checkpoints" / "40" / DIGEST).unlink()
    _damage(run / "checkpoints" / "40", where="d")
    before = sorted(p.relative_to(run) for p in run.rglob("*"))
    rc = main(T + ["--dataset", str(finished["d"]), "--out", str(run), "--resume"] + TINY)
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == 2 and len(lines) == 1, err
    assert "no checkpoint in" in lines[0]
    assert re.search(r"step 40: .*DATA_LOSS.*; step 30: 1 of its files changed on disk since it "
                     r"was written \(sha256 differs: state/ocdbt.process_0/d/", lines[0]), lines[0]
    assert "nothing was changed" in lines[0]
    after = sorted(p.relative_to(run) for p in run.rglob("*") if p.name != ".lock")
    assert after == [p for p in before if p.name != ".lock"]  # nothing moved or deleted


def test_legacy_run_without_a_marker_still_resumes(finished, capsys, data_dir):
    """Runs made before directories were marked resume, and get the marker."""
    from r2pac_jax.train import main

    run = _copy(finished["run"], finished["t"] / "legacy")
    (run / MARKER).unlink()
    rc = main(T + ["--dataset", str(finished["d"]), "--out", str(run), "--resume"] + TINY)
    assert rc == 0, capsys.readouterr().err[-2000:]
    assert json.loads((run / MARKER).read_text())["kind"] == "run"


def test_claim_directory_rules(tmp_path):
    from r2pac_jax.io import ForeignDirectory, claim_directory

    new = claim_directory(tmp_path / "a" / "new", "run")
    assert json.loads((new / MARKER).read_text())["kind"] == "run"
    empty = tmp_path / "empty"
    empty.mkdir()
    claim_directory(empty, "table")
    assert (empty / MARKER).is_file()
    user = tmp_path / "user"
    user.mkdir()
    (user / "data.csv").write_text("1,2\n")
    with pytest.raises(ForeignDirectory, match="not written by r2pac_jax"):
        claim_directory(user, "run")
    assert sorted(p.name for p in user.iterdir()) == ["data.csv"]
    # a recogniser of an earlier release's directories admits it, and it is marked
    claim_directory(user, "run", legacy=lambda p: True)
    assert (user / MARKER).is_file()
    with pytest.raises(ForeignDirectory, match="is a table directory of r2pac_jax"):
        claim_directory(empty, "run")
    # check_only writes nothing
    claim_directory(tmp_path / "later", "run", check_only=True)
    assert not (tmp_path / "later").exists()


def test_data_cache_in_a_users_folder_is_refused(tmp_path, monkeypatch, capsys):
    from r2pac_jax.data.__main__ import main

    user = tmp_path / "mine"
    user.mkdir()
    (user / "thesis.tex").write_text("\\documentclass{article}\n")
    monkeypatch.setenv("R2PAC_DATA_DIR", str(user))
    rc = main(["make", "--task", "ReachAvoid", "--trajectories", "4"])
    err = capsys.readouterr().err
    assert rc == 2 and "not written by r2pac_jax" in err and "R2PAC_DATA_DIR" in err
    assert sorted(p.name for p in user.iterdir()) == ["thesis.tex"]
    # a cache of an earlier release (only generated files) is still used
    legacy = tmp_path / "cache"
    legacy.mkdir()
    (legacy / "ReachAvoid-generated-s0-n9.hdf5.lock").write_text("")
    monkeypatch.setenv("R2PAC_DATA_DIR", str(legacy))
    assert main(["make", "--task", "ReachAvoid", "--trajectories", "4"]) == 0
    assert json.loads((legacy / MARKER).read_text())["kind"] == "data cache"


def test_policy_names_the_observation_width(finished):
    import r2pac_jax

    from r2pac_jax.tasks import get_task

    task = get_task("ReachAvoid")
    n = task.obs_dim
    act = r2pac_jax.load_policy(finished["run"])
    key = jax.random.PRNGKey(0)
    assert act(np.zeros(n, np.float32), key).shape == (task.act_dim,)
    assert act(np.zeros((3, n), np.float32), key).shape == (3, task.act_dim)
    for bad in (np.zeros(n - 1, np.float32), np.zeros((5, n + 1), np.float32),
                np.zeros((1, 1, n), np.float32)):
        with pytest.raises(ValueError, match=rf"policy takes observations of width {n} "
                                             rf"\(\[{n}\] or \[B, {n}\]\)"):
            act(bad, key)


# ---- memory --------------------------------------------------------------------------------


def test_memory_need_is_xlas_count_and_grows_with_lanes(reach_avoid_data):
    from conftest import tiny_config

    from r2pac_jax.lanes import Lanes
    from r2pac_jax.loop import compiled, make_data
    from r2pac_jax.memory import block_need, tree_bytes
    from r2pac_jax.tasks import get_task

    task = get_task("ReachAvoid")
    cfg = tiny_config("bc-all-mlp")  # the cheapest to compile; the analysis is the loop's
    _, init, blocks, _ = compiled(cfg, task.obs_dim, task.act_dim)
    data = make_data(cfg, task, reach_avoid_data)
    needs = {}
    for lanes in (2, 8):
        ln = Lanes.build(cfg, list(range(lanes)))
        needs[lanes] = block_need(init, blocks, ln.hp, data, lanes)
        real = init(ln.init_keys(), ln.hp)
        assert needs[lanes].state == tree_bytes(real)  # the state's bytes exactly
        assert needs[lanes].step > 0
    assert needs[8].state == 4 * needs[2].state
    assert needs[8].total > 3 * needs[2].total


def test_check_fits_refuses_with_the_numbers_and_warns_when_close():
    from r2pac_jax.memory import MemoryShortfall, Need, check_fits

    need = Need(state=6 * 2**30, step=4 * 2**30, lanes=1000)
    with pytest.raises(MemoryShortfall) as e:
        check_fits(need, "CarGoal2 r2pac", "fewer lanes (--seeds)", have=(8 * 2**30, "test"))
    msg = str(e.value)
    assert "1000 lanes need about 10.0 GiB" in msg and "8.0 GiB available (test)" in msg
    assert "about 800 lanes fit" in msg and "nothing was allocated" in msg
    said = []
    check_fits(need, "x", "y", log=said.append, have=(15 * 2**30, "test"))
    assert len(said) == 1 and said[0].startswith("warning:") and "close to the limit" in said[0]
    said.clear()
    check_fits(need, "x", "y", log=said.append, have=(64 * 2**30, "test"))
    assert said == []


def test_too_many_lanes_are_refused_before_anything_is_allocated(finished, capsys, monkeypatch,
                                                                   data_dir):
    from r2pac_jax import memory
    from r2pac_jax.train import main

    monkeypatch.setattr(memory, "available", lambda: (8 * 2**20, "a test's 8 MiB"))
    out = finished["t"] / "toomany"
    argv = T + ["--dataset", str(finished["d"]), "--out", str(out)] + MLP + ["--set", "steps=20"]
    argv[argv.index("--seeds") + 1] = "5000"
    rc = main(argv)
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == 2 and len(lines) == 1, err
    assert re.search(r"ReachAvoid bc-all-mlp: 5000 lanes need about [\d.]+ (MiB|GiB)", lines[0])
    assert "8 MiB available (a test's 8 MiB)" in lines[0] and "lanes fit" in lines[0]
    assert not (out / "checkpoints").exists()  # nothing of the run was created


def test_available_memory_is_read_off_this_machine():
    from r2pac_jax.memory import available

    free, source = available()
    assert free is not None and free > 0, source
    assert free <= os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


# ---- Ctrl-C --------------------------------------------------------------------------------


def _default_sigint():
    # a background child of a shell starts with SIGINT ignored; a user's terminal does not
    signal.signal(signal.SIGINT, signal.SIG_DFL)


# The cheapest algorithm to compile: what is tested is the CLI and the loop, shared by all.
MLP = ["--algo", "bc-all-mlp", "--set", "batch_size=32", "--set", "hidden_dims=16,16",
       "--set", "block_steps=10", "--eval-episodes", "2", "--seeds", "2", "--no-progress",
       "--baselines", "none"]


@pytest.mark.filterwarnings("ignore:os.fork:RuntimeWarning")  # preexec_fn; the child execs
def test_ctrl_c_prints_one_line_and_the_command_that_resumes(finished, data_dir, capsys):
    out = finished["t"] / "ctrlc"
    cmd = [sys.executable, "-m", "r2pac_jax.train"] + T + [
        "--dataset", str(finished["d"]), "--out", str(out)] + MLP + [
        "--set", "steps=3000", "--set", "checkpoint_every=100", "--eval-every", "3000"]
    env = dict(os.environ)
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         preexec_fn=_default_sigint, env=env)
    ck = out / "checkpoints"
    deadline = time.time() + 300
    while time.time() < deadline and p.poll() is None:
        if ck.is_dir() and any(x.name.isdigit() for x in ck.iterdir()):
            break
        time.sleep(0.1)
    assert p.poll() is None, p.communicate()[1][-2000:]
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=120)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert p.returncode == 130, err[-3000:]
    assert len(lines) == 1 and "Traceback" not in err, err[-3000:]
    m = re.match(r"interrupted: ReachAvoid bc-all-mlp at step (\d+) of 3000; its last checkpoint is "
                 r"step (\d+) \(.*\); continue with: (.*)$", lines[0])
    assert m, lines[0]
    reached, saved = int(m.group(1)), int(m.group(2))
    assert 0 < saved <= reached < 3000
    resume = shlex.split(m.group(3))
    assert resume[:3] == ["python", "-m", "r2pac_jax.train"] and "--resume" in resume
    # the printed command continues the run from that checkpoint to its end (in this process:
    # a second interpreter would double the test's time)
    from r2pac_jax.train import main

    assert main(resume[3:]) == 0
    assert f"resuming {out} from step {saved}" in capsys.readouterr().out
    rows = [json.loads(x) for x in (out / "metrics.jsonl").read_text().splitlines()]
    assert sorted(r["step"] for r in rows if r["lane"] == 0) == list(range(10, 3001, 10))
    assert json.loads((out / "results.json").read_text())["resumed_from_step"] == saved


def test_a_table_directory_a_pipeline_filled_with_runs_is_still_a_table(finished, tmp_path):
    """task_pipeline.sh copies finished runs into TABLE_OUT/TASK/ALGO before the table command
    first writes there; a folder with anything else in a task directory is not a table."""
    from r2pac_jax.io import ForeignDirectory, claim_directory
    from r2pac_jax.table import is_legacy_table

    table = tmp_path / "table1"
    (table / "ReachAvoid").mkdir(parents=True)
    shutil.copytree(finished["run"], table / "ReachAvoid" / "r2pac")
    assert is_legacy_table(table)
    (table / "ReachAvoid" / "notes.txt").write_text("mine\n")
    with pytest.raises(ForeignDirectory):
        claim_directory(table, "table", legacy=is_legacy_table)
    (table / "ReachAvoid" / "notes.txt").unlink()
    claim_directory(table, "table", legacy=is_legacy_table)
    assert json.loads((table / MARKER).read_text())["kind"] == "table"

"""One table of bad inputs: each gives one line naming the problem and the fix, exit status 2, and
loses nothing. Cases run in-process through the CLIs' `main(argv)`; later issues add rows.

Columns: CLI, argv (with {d} = a tiny ReachAvoid dataset, {t} = this test's tmp dir, {f} = a
plain file, {run} = a finished tiny run, {killed} = a run stopped before its end), expected
exit code, a fragment of the message (stderr).
"""
import errno
import json
import os
import subprocess
import sys

import pytest
from conftest import TINY_ARGV

TINY = TINY_ARGV

T = "--task ReachAvoid".split()
CASES = [
    # train: options
    ("train", ["--task", "Nope"], 2, "unknown task 'Nope'"),
    ("train", T + ["--algo", "cpq-x"], 2, "unknown algo 'cpq-x'; choose one of r2pac"),
    ("train", T + ["--set", "quantile_alpha=2"], 2, "quantile_alpha must lie in (0, 1), got 2"),
    ("train", T + ["--set", "lr=nan"], 2, "lr must be > 0, got nan"),
    ("train", T + ["--set", "reward_scale=0"], 2, "reward_scale must be > 0"),
    ("train", T + ["--set", "discount=1.5"], 2, "discount must lie in (0, 1), got 1.5"),
    ("train", T + ["--set", "task=CarGoal2"], 2, "task is chosen with --task"),
    ("train", T + ["--set", "algo=bc-all"], 2, "algo is chosen with --algo"),
    ("train", T + ["--set", "seeds=4"], 2, "chosen with --seeds N"),
    ("train", T + ["--set", "reward_penalty=false"], 2,
     "reward_penalty is an algorithm switch; choose the variant with --algo (r2pac-no-penalty)"),
    ("train", T + ["--set", "data_filter=safe"], 2, "--algo (bc-safe, bc-safe-mlp)"),
    ("train", T + ["--set", "steps=ten"], 2, "--set steps='ten': expected an integer"),
    ("train", T + ["--set", "alpha=0.5"], 2, "unknown config key 'alpha'"),
    ("train", T + ["--set", "steps"], 2, "--set takes key=value"),
    ("train", T + ["--resume"], 2, "--resume needs --out DIR"),
    ("train", T + ["--seed-offset", "-1"], 2, "--seed-offset -1: seeds are integers >= 0"),
    ("train", T + ["--chunk-len", "100"], 2, "chunk_len 100 is longer than an episode"),
    ("train", T + ["--algo", "bc-all-mlp", "--chunk-len", "5"], 2,
     "bc-all-mlp clones one action per step"),
    ("train", T + ["--eval-episodes", "-1"], 2, "eval_episodes must be >= 0"),
    # train: data
    ("train", T + ["--dataset", "{t}/missing.hdf5"], 2, "no such file"),
    ("train", T + ["--dataset", "{t}"], 2, "is a directory. Fix: pass the dataset's .hdf5"),
    ("train", T + ["--dataset", "{f}"], 2, "cannot be read as HDF5"),
    ("train", T + ["--dataset", "{unsafe}", "--out", "{t}/u"], 2,
     "bc-safe: the dataset {unsafe} has no episode with cost <= kappa=2.0"),
    ("train", T + ["--dataset", "{negcost}", "--out", "{t}/n"], 2,
     "key 'costs': 2 rows hold negative costs (row 3: -0.5, row 7: -1)"),
    # train: where it writes
    ("train", T + ["--out", ""], 2, "--out '': an empty path"),
    ("train", T + ["--dataset", "{d}", "--out", "{userdir}"] + TINY, 2,
     "{userdir} is not empty and was not written by r2pac_jax (it holds config.json, "
     "notes.txt); nothing was written there"),
    ("train", T + ["--dataset", "{d}", "--out", "{sweepdir}"] + TINY, 2,
     "{sweepdir} is a sweep directory of r2pac_jax, not a run directory"),
    ("train", T + ["--dataset", "{d}", "--out", "{killed}", "--baselines", "none", "--resume"]
     + TINY + ["--set", "steps=40"], 2, "--resume: {killed} was started with other settings "
     "(steps: 20 -> 40)"),
    ("train", T + ["--dataset", "{d}", "--out", "{f}"] + TINY, 2,
     "is a file, not a directory"),
    ("train", T + ["--dataset", "{d}", "--out", "{f}/sub"] + TINY, 2,
     "a path component is a file, not a directory"),
    ("train", T + ["--dataset", "{d}", "--out", "{run}", "--baselines", "none"] + TINY, 2,
     "already holds a run"),
    ("train", T + ["--dataset", "{d}", "--out", "{run}", "--baselines", "none", "--resume"]
     + TINY + ["--set", "steps=40"], 2, "--resume: {run} was started with other settings "
     "(steps: 20 -> 40)"),
    # evaluate
    ("evaluate", ["{t}/nothing"], 2, "no such run directory"),
    ("evaluate", ["{t}"], 2, "holds no run (config.json and lanes.json"),
    ("evaluate", ["{killed}"], 2, "holds no finished run"),
    ("evaluate", ["{damaged}"], 2, "config.json or lanes.json is damaged"),
    ("evaluate", ["{run}", "--episodes", "0"], 2, "--episodes must be >= 1"),
    ("evaluate", ["{run}", "--selection", "first", "--guidance", "1"], 0, "seed 1:"),
    ("evaluate", ["{mlp}", "--selection", "first"], 2,
     "--selection: bc-all-mlp's policy draws no candidates to select among"),
    # sweep
    ("sweep", ["{sweep_not_hdf5}"], 2, "cannot be read as HDF5"),
    ("sweep", ["{sweep_switch}"], 2, "reward_penalty is an algorithm switch"),
    ("sweep", ["{sweep_physics}"], 2,
     "physics = 'mjx' in the sweep file: --physics 'mjx': not a simulator of ReachAvoid"),
    ("sweep", ["{t}/none.toml"], 2, "no such sweep file"),
    ("sweep", ["{sweep_switch}", "--out", ""], 2, "--out '': an empty path"),
    ("sweep", ["{sweep_ok}", "--out", "{userdir}"], 2,
     "{userdir} is not empty and was not written by r2pac_jax"),
    ("table", ["--tasks", "ReachAvoid", "--algos", "bc-all", "--out", ""], 2,
     "--out '': an empty path"),
    ("table", ["--tasks", "ReachAvoid", "--algos", "bc-all", "--out", "{userdir}"], 2,
     "{userdir} is not empty and was not written by r2pac_jax"),
    ("table", ["--tasks", "ReachAvoid", "--algos", "bc-all", "--out", "{run}"], 2,
     "{run} is a run directory of r2pac_jax, not a table directory"),
    # data
    ("data", ["make", "--task", "CarGoal2", "--source", "ppo-lagrangian", "--budget", "0"], 2,
     "--budget must be >= 1, got 0"),
    ("data", ["make", "--task", "CarRun", "--source", "scripted"], 2,
     "task CarRun has no scripted data source"),
    ("data", ["check", "{unsafe}"], 2, "does not say its task"),
    ("data", ["check", "{f}"], 2, "cannot be read as HDF5"),
    ("data", ["check", "{truncated}"], 2, "cannot be read as HDF5 (Unable to"),
    ("data", ["check", "{t}/missing.hdf5"], 2, "missing.hdf5: no such file"),
    ("data", ["make", "--task", "CarGoal2", "--trajectories", "0"], 2,
     "--trajectories must be >= 1, got 0"),
    ("data", ["make", "--task", "CarGoal2", "--checkpoint-every", "0"], 2,
     "--checkpoint-every must be >= 1, got 0"),
    ("data", ["make", "--task", "HopperVelocity", "--physics", "warp"], 2,
     "--physics 'warp': not a simulator of HopperVelocity; choose one of auto, mujoco, mjx"),
    # --physics is checked before any data are made or loaded (HopperVelocity has none here)
    ("train", ["--task", "HopperVelocity", "--physics", "warp", "--out", "{t}/h"], 2,
     "not a simulator of HopperVelocity"),
    ("train", T + ["--physics", "bullet"], 2,
     "--physics 'bullet': not a simulator of ReachAvoid; choose one of auto, jax"),
    ("table", ["--tasks", "BallRun", "--algos", "cpq", "--physics", "jax", "--out", "{t}/tb"], 2,
     "not a simulator of BallRun; choose one of auto, bullet, mujoco, mjx"),
]


def _main(cli):
    import importlib

    mod = {"train": "r2pac_jax.train", "evaluate": "r2pac_jax.evaluate",
           "sweep": "r2pac_jax.sweep", "data": "r2pac_jax.data.__main__",
           "table": "r2pac_jax.table"}[cli]
    return importlib.import_module(mod).main


@pytest.fixture(scope="module")
def places(tmp_path_factory, reach_avoid_data, tiny_run):
    import numpy as np

    from r2pac_jax.data.dsrl import write_dsrl

    t = tmp_path_factory.mktemp("bad")
    d = tiny_run["d"]
    arrays = reach_avoid_data.as_dict()
    unsafe = t / "unsafe.hdf5"
    write_dsrl(unsafe, dict(arrays, costs=np.ones_like(arrays["costs"])))
    f = t / "plain.txt"
    f.write_text("not a dataset\n")
    run = tiny_run["run"]  # a finished run: no case may touch it
    killed = t / "killed"
    (killed).mkdir()
    for name in ("config.json", "lanes.json"):
        (killed / name).write_text((run / name).read_text())
    damaged = t / "damaged"
    damaged.mkdir()
    (damaged / "config.json").write_text("{\"algo\": ")
    (damaged / "lanes.json").write_text("{}")
    sweep_not_hdf5 = t / "s1.toml"
    sweep_not_hdf5.write_text(f'task = "ReachAvoid"\ndataset = "{f}"\n[grid]\n'
                              'quantile_alpha = [0.5, 0.9]\n')
    sweep_switch = t / "s2.toml"
    sweep_switch.write_text('task = "ReachAvoid"\n[config]\nreward_penalty = false\n')
    negcost = t / "negcost.hdf5"
    costs = arrays["costs"].copy()
    costs[3], costs[7] = -0.5, -1.0
    _write_raw(negcost, dict(arrays, costs=costs))
    truncated = t / "truncated.hdf5"
    truncated.write_bytes(d.read_bytes()[:4096])
    userdir = t / "user"  # a user's own folder: never written into
    userdir.mkdir()
    (userdir / "config.json").write_text('{"my": "settings"}\n')
    (userdir / "notes.txt").write_text("my notes\n")
    sweepdir = t / "sweepdir"
    sweepdir.mkdir()
    (sweepdir / ".r2pac_jax.json").write_text('{"kind": "sweep"}\n')
    mlp = t / "mlp"  # a bc-all-mlp run's description (refused before anything is loaded)
    mlp.mkdir()
    from conftest import tiny_config

    (mlp / "config.json").write_text(tiny_config("bc-all-mlp").to_json())
    (mlp / "lanes.json").write_text(json.dumps(dict(seeds=[0], cells=[0], cell_hparams=[{}])))
    sweep_ok = t / "s4.toml"
    sweep_ok.write_text(f'task = "ReachAvoid"\ndataset = "{d}"\n[grid]\nchunk_len = [1, 2]\n')
    sweep_physics = t / "s3.toml"
    sweep_physics.write_text('task = "ReachAvoid"\nphysics = "mjx"\n[grid]\nchunk_len = [1, 2]\n')
    return dict(t=t, d=d, f=f, run=run, killed=killed, damaged=damaged, unsafe=unsafe,
                negcost=negcost, truncated=truncated, userdir=userdir, sweepdir=sweepdir,
                sweep_ok=sweep_ok, mlp=mlp,
                sweep_not_hdf5=sweep_not_hdf5, sweep_switch=sweep_switch,
                sweep_physics=sweep_physics)


def _write_raw(path, arrays):
    """An HDF5 file in DSRL's layout written without validation (write_dsrl refuses bad data)."""
    import h5py

    with h5py.File(path, "w") as f:
        for k, v in arrays.items():
            f.create_dataset(k, data=v)


def _folder(path):
    """Every file under `path` with its bytes: what 'untouched' compares."""
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*"))
            if p.is_file()}


def _fill(s, places):
    for k, v in places.items():
        s = s.replace("{" + k + "}", str(v))
    return s


@pytest.mark.parametrize("cli,argv,code,fragment", CASES,
                         ids=[f"{c[0]}:{' '.join(c[1])[:60]}" for c in CASES])
def test_bad_input_gets_one_line_and_exit_2(cli, argv, code, fragment, places, capsys, data_dir):
    before = {p: p.stat().st_mtime_ns for p in places["run"].rglob("*")
              if p.is_file() and p.name != ".lock"}
    user = _folder(places["userdir"])
    rc = _main(cli)([_fill(a, places) for a in argv])
    out = capsys.readouterr()
    text = out.err if code else out.out
    assert rc == code, (rc, out.err[-2000:])
    assert _fill(fragment, places) in text
    if code:
        lines = [ln for ln in out.err.splitlines() if ln.strip()]
        assert len(lines) == 1 and lines[0].startswith("error: "), out.err
        assert "Traceback" not in out.err
    after = {p: p.stat().st_mtime_ns for p in places["run"].rglob("*")
             if p.is_file() and p.name != ".lock"}
    if cli == "train":  # nothing of the finished run was touched
        assert {p: m for p, m in after.items() if p in before} == before
    assert _folder(places["userdir"]) == user  # nor the user's folder: no file added or changed


def test_safe_subset_checked_before_any_training(places, capsys, data_dir):
    from r2pac_jax.train import main

    out = places["t"] / "early"
    assert main(T + ["--dataset", str(places["unsafe"]), "--out", str(out)] + TINY) == 2
    assert not (out / "checkpoints").exists()  # r2pac did not start before bc-safe's check


def test_disk_full_while_writing_results_keeps_the_checkpoints(places, capsys, monkeypatch,
                                                              data_dir):
    """ENOSPC injected where results.json is replaced into place."""
    from r2pac_jax import io
    from r2pac_jax.checkpoint import Checkpointer
    from r2pac_jax.train import main

    real = os.replace

    def full(src, dst):
        if str(dst).endswith("results.json"):
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(src, dst)

    monkeypatch.setattr(io.os, "replace", full)
    out = places["t"] / "full"
    rc = main(T + ["--dataset", str(places["d"]), "--out", str(out), "--baselines", "none"]
              + TINY)
    err = capsys.readouterr().err
    assert rc == 2 and "no space left on the disk" in err and str(out / "results.json") in err
    assert len(err.strip().splitlines()) == 1
    assert Checkpointer(out / "checkpoints").latest_step() == 40  # every checkpoint is intact


def test_disk_full_in_a_checkpoint_names_it(places, capsys, monkeypatch, data_dir):
    import orbax.checkpoint as ocp

    from r2pac_jax.train import main

    real = ocp.CheckpointManager.save
    calls = []

    def save(self, step, *a, **kw):
        calls.append(step)
        if len(calls) == 2:  # the second checkpoint hits a full disk, as tensorstore words it
            raise ValueError("RESOURCE_EXHAUSTED: Error writing local file: No space left on "
                             "device [OS error 28]")
        return real(self, step, *a, **kw)

    monkeypatch.setattr(ocp.CheckpointManager, "save", save)
    out = places["t"] / "ckfull"
    rc = main(T + ["--dataset", str(places["d"]), "--out", str(out), "--baselines", "none"]
              + TINY)
    err = capsys.readouterr().err
    assert rc == 2 and "cannot write the checkpoint" in err and "no space left" in err
    assert "the last complete checkpoint, step 10, is kept" in err


@pytest.mark.slow
def test_file_size_limit_in_a_subprocess_keeps_the_checkpoints_and_resumes(places, data_dir):
    """A real failing write: under RLIMIT_FSIZE = 192 KiB the growing metrics log fails (EFBIG)
    in the actor phase; the error is one line, the checkpoints read back, and a resume without
    the limit finishes the run. (The critic phase's 240 rows, about 500 bytes each with the
    diagnostics' metrics, fill about 130 KiB: 128 KiB, the first limit, no longer reached the
    actor phase.)"""
    import resource

    out = places["t"] / "fsize"
    sets = ["--set", "steps=600", "--set", "batch_size=32", "--set", "hidden_dims=16,16",
            "--set", "block_steps=5", "--set", "checkpoint_every=50", "--set",
            "flow_steps=4", "--set", "num_candidates=4", "--set", "threshold_subset=256",
            "--set", "actor_hidden_dims=16,16", "--eval-episodes", "2", "--eval-every", "300",
            "--seeds", "2", "--no-progress"]
    cmd = [sys.executable, "-m", "r2pac_jax.train"] + T + [
        "--dataset", str(places["d"]), "--out", str(out), "--baselines", "none"] + sets

    def limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (192 * 1024, 192 * 1024))

    env = dict(os.environ, R2PAC_NO_TENSORBOARD="1")
    # the tests' shared XLA cache would be written under the limit too, and JAX warns of its own
    # failed write (it did when this test ran alone, its programs not yet cached): not ours
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    p = subprocess.run(cmd, capture_output=True, text=True, preexec_fn=limit, timeout=600,
                       env=env)
    assert p.returncode == 2, p.stderr[-3000:]
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert lines == [ln for ln in lines if ln.startswith("error: ")] and len(lines) == 1, lines
    assert "cannot write the log" in lines[0] and "file-size limit" in lines[0]
    from r2pac_jax.checkpoint import Checkpointer

    step = Checkpointer(out / "checkpoints").latest_step()
    assert step is not None and 600 < step < 1200  # it failed in the actor phase
    assert not (out / "results.json").exists()
    p = subprocess.run(cmd + ["--resume"], capture_output=True, text=True, timeout=600, env=env)
    assert p.returncode == 0, p.stderr[-3000:]
    res = json.loads((out / "results.json").read_text())
    assert len(res["normalized_reward"]["per_seed"]) == 2


def test_an_injected_bug_still_shows_its_traceback(places, monkeypatch, data_dir):
    """A bug is never disguised as a user error: unexpected exceptions propagate (exit 1)."""
    from r2pac_jax import loop
    from r2pac_jax.train import main

    def broken(self, *a, **kw):
        raise KeyError("an injected bug")

    monkeypatch.setattr(loop.Run, "_run", broken)
    with pytest.raises(KeyError, match="an injected bug"):
        main(T + ["--dataset", str(places["d"]), "--out", str(places["t"] / "bug"),
                  "--baselines", "none"] + TINY)

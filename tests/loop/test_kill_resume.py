"""A training process killed with SIGKILL resumes to the same final parameters (slow: ~2 min)."""
import json
import os
import signal
import subprocess
import sys
import time

import chex
import pytest

SETS = ["steps=200", "batch_size=32", "hidden_dims=16,16", "actor_hidden_dims=16,16",
        "block_steps=10", "checkpoint_every=10", "flow_steps=4", "num_candidates=4",
        "threshold_subset=256"]


def _cmd(out):
    cmd = [sys.executable, "-m", "r2pac_jax.train", "--task", "ReachAvoid", "--preset", "quick",
           "--seeds", "2", "--eval-episodes", "2", "--eval-every", "100", "--out", str(out),
           "--no-progress", "--baselines", "none"]
    for s in SETS:
        cmd += ["--set", s]
    return cmd


@pytest.mark.slow
def test_sigkill_then_resume_matches_uninterrupted(tmp_path, data_dir):
    env = dict(os.environ)
    full, killed = tmp_path / "full", tmp_path / "killed"
    subprocess.run(_cmd(full), env=env, check=True, capture_output=True, timeout=600)
    proc = subprocess.Popen(_cmd(killed), env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    deadline = time.time() + 300
    ckdir = killed / "checkpoints"
    while time.time() < deadline:
        steps = [int(p.name) for p in ckdir.glob("*") if p.name.isdigit()] if ckdir.exists() else []
        if steps and max(steps) >= 100:
            break
        time.sleep(0.2)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not (killed / "results.json").exists()
    subprocess.run(_cmd(killed) + ["--resume"], env=env, check=True, capture_output=True,
                   timeout=600)
    from r2pac_jax.checkpoint import Checkpointer
    from r2pac_jax.config import Config
    from r2pac_jax.data.dsrl import load_dsrl
    from r2pac_jax.tasks import get_task
    from r2pac_jax.train import Lanes, Run

    cfg = Config.from_dict(json.loads((full / "config.json").read_text()))
    task = get_task("ReachAvoid")
    ds = load_dsrl(json.loads((full / "lanes.json").read_text())["dataset"])
    like = Run(cfg, task, ds, tmp_path / "x", Lanes.build(cfg, [0, 1])).init_state()
    a, _ = Checkpointer(full / "checkpoints").restore(400, like)
    b, _ = Checkpointer(killed / "checkpoints").restore(400, like)
    chex.assert_trees_all_equal(a, b)
    ra = json.loads((full / "results.json").read_text())
    rb = json.loads((killed / "results.json").read_text())
    assert ra["normalized_reward"] == rb["normalized_reward"]

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from r2pac_jax import sweep as sw

TINY_CONFIG = textwrap.dedent("""
    [config]
    steps = 20
    batch_size = 32
    hidden_dims = [16, 16]
    actor_hidden_dims = [16, 16]
    block_steps = 10
    eval_every = 20
    checkpoint_every = 10
    flow_steps = 4
    num_candidates = 4
    threshold_subset = 256
""")


def _write(tmp_path, body, name="s.toml"):
    p = tmp_path / name
    p.write_text(textwrap.dedent(body))
    return p


def test_shipped_sweep_files_parse_and_group():
    root = Path(__file__).resolve().parents[2] / "sweeps"
    s = sw.load_sweep(root / "alpha_h.toml")
    assert len(s.cells) == 20 and len(s.groups) == 4  # alpha is vmapped, h splits groups
    assert all(len(g.cells) == 5 for g in s.groups)
    s = sw.load_sweep(root / "alpha_cbar.toml")
    assert len(s.cells) == 24 and len(s.groups) == 2  # one program per penalty mode
    s = sw.load_sweep(root / "alpha_h.toml", task_override="CarGoal1")
    assert {c.task for c in s.cells} == {"CarGoal1"}
    for f in ("ballrun_alpha_h.toml", "cargoal2_h.toml"):
        assert sw.load_sweep(root / f).cells


@pytest.mark.parametrize("body,message", [
    ('task = "ReachAvoid"\nbogus = 1\n', "unknown key"),
    ('task = "ReachAvoid"\n[grid]\nquantile_alpha = []\n', "is empty"),
    ('task = "ReachAvoid"\n[grid]\nquantile_alpha = [0.5, 1.5]\n', r"quantile_alpha must lie in \(0, 1\)"),
    ('task = "ReachAvoid"\n[grid]\nchunk_len = [0, 5]\n', "chunk_len must be >= 1"),
    ('task = "ReachAvoid"\n[grid]\nchunk_len = ["five"]\n', "chunk_len must be an integer"),
    ('task = "ReachAvoid"\n[grid]\nnot_a_key = [1]\n', "unknown config key 'not_a_key'"),
    ('task = "ReachAvoid"\nalgo = "ppo"\n', "unknown algo 'ppo'"),
    ('[grid]\nquantile_alpha = [0.5]\n', "no task"),
    ('task = "Nope"\n', "unknown task 'Nope'"),
    ('task = "ReachAvoid"\nseeds = 0\n', "seeds must be >= 1"),
    ('task = "ReachAvoid"\n[grid]\nquantile_alpha = 0.5\n', "must be a list"),
])
def test_bad_sweep_files_fail_before_running(tmp_path, body, message):
    p = _write(tmp_path, body)
    with pytest.raises((sw.SweepError, KeyError)) as e:
        sw.load_sweep(p)
    import re

    assert re.search(message, str(e.value)), str(e.value)


def test_task_without_data_is_caught_before_running(tmp_path, monkeypatch, data_dir):
    from r2pac_jax.data import factory

    p = _write(tmp_path, 'task = "BallRun"\n')
    monkeypatch.setattr(factory, "has_source", lambda task: False)
    s = sw.load_sweep(p)
    with pytest.raises(sw.SweepError, match="task BallRun has no data"):
        sw.check_data(s)
    assert sw.main([str(p), "--out", str(tmp_path / "o")]) == 2


def test_sweep_runs_survives_interruption_and_reports(tmp_path, data_dir):
    body = ('task = "ReachAvoid"\nseeds = 1\neval_episodes = 2\npreset = "quick"\n' + TINY_CONFIG
            + "\n[grid]\nquantile_alpha = [0.5, 0.9]\nchunk_len = [1, 3]\n")
    p = _write(tmp_path, body)
    s = sw.load_sweep(p)
    assert len(s.groups) == 2
    # uninterrupted reference for the group that gets interrupted (the other group's cells are
    # written once, by the first run_group below, and must not be rewritten by the resume)
    ref = tmp_path / "ref"
    sw.run_group(s, s.groups[1], ref, log=lambda m: None, progress=False)
    # interrupted: first group finished, second stopped after 1 of its 4 blocks
    out = tmp_path / "run"
    sw.run_group(s, s.groups[0], out, log=lambda m: None, progress=False)
    from r2pac_jax.data import load_task_dataset
    from r2pac_jax.tasks import get_task
    from r2pac_jax.train import Lanes, Run

    g = s.groups[1]
    cfg = s.configs[g.group_id]
    lanes = Lanes.build(cfg, s.seeds, [{k: v for k, v in c.values if k in sw.vmapped(g.algo)}
                                       for c in g.cells])
    ds = load_task_dataset(get_task("ReachAvoid"), announce=lambda m: None)
    Run(cfg, get_task("ReachAvoid"), ds, out / "groups" / g.group_id, lanes, progress=False,
        log=lambda m: None).run(stop_after=1)
    first_cell = out / "cells" / f"{s.groups[0].cells[0].cell_id}.json"
    mtime = first_cell.stat().st_mtime_ns
    msgs = []
    sw.run_sweep(p, out, log=msgs.append, progress=False)
    assert any("1 groups already finished" in m for m in msgs)
    assert first_cell.stat().st_mtime_ns == mtime  # the finished group was not rerun
    a = {k: (v["normalized_reward"], v["normalized_cost"]) for k, v in sw.finished_cells(ref).items()}
    b = {k: (v["normalized_reward"], v["normalized_cost"]) for k, v in sw.finished_cells(out).items()}
    assert len(a) == 2 and len(b) == 4
    assert all(b[k] == a[k] for k in a)  # the resumed group scores as the uninterrupted one
    table = (out / "table.csv").read_text().splitlines()
    assert len(table) == 5 and table[0].startswith("task,algo,chunk_len,quantile_alpha")
    md = (out / "table.md").read_text()
    assert md.count("| ReachAvoid | r2pac |") == 4
    assert (out / "score_vs_quantile_alpha.png").exists() and (out / "score_vs_chunk_len.png").exists()
    assert list((out / "curves").glob("*.png"))
    assert sw.main(["report", str(out)]) == 0


def test_lanes_shard_over_local_devices(tmp_path, data_dir):
    """With two (simulated) CPU devices the lane axis is split across them."""
    code = textwrap.dedent(f"""
        import jax, numpy as np
        from conftest import tiny_config
        from r2pac_jax.data.dsrl import validate
        from r2pac_jax.data.factory import reach_avoid
        from r2pac_jax.tasks import get_task
        from r2pac_jax.train import Lanes, Run
        assert len(jax.local_devices()) == 2
        cfg = tiny_config(eval_episodes=0)
        ds = validate(reach_avoid.generate(20, seed=0), "x")
        run = Run(cfg, get_task("ReachAvoid"), ds, {str(tmp_path / 'r')!r}, Lanes.build(cfg, [0, 1]),
                  progress=False, log=lambda m: None)
        st = run.init_state()
        print("DEVICES", len(st.step.sharding.device_set))
        res = run.run(resume=True)
        print("OK", res["total_steps"])
    """)
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2",
               PYTHONPATH=str(Path(__file__).parents[1]))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         timeout=300)
    assert "DEVICES 2" in out.stdout, out.stderr[-2000:]
    assert "OK 40" in out.stdout, out.stderr[-2000:]


@pytest.mark.slow
def test_ray_launcher_on_a_local_instance(tmp_path, data_dir):
    """Slow (about 80 s: Ray workers import JAX and compile); run with -m slow."""
    ray = pytest.importorskip("ray", reason="pip install -e '.[ray]' to test the Ray launcher")
    body = ('task = "ReachAvoid"\nseeds = 1\neval_episodes = 2\npreset = "quick"\n' + TINY_CONFIG
            + "\n[grid]\nquantile_alpha = [0.5, 0.9]\n")
    p = _write(tmp_path, body)
    # the worker processes inherit the dataset cache through the environment
    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False,
             runtime_env={"env_vars": {"R2PAC_DATA_DIR": os.environ["R2PAC_DATA_DIR"],
                                       "R2PAC_NO_TENSORBOARD": "1",
                                       "PYTHONPATH": str(Path(__file__).resolve().parents[2])}})
    try:
        out = sw.run_sweep(p, tmp_path / "ray", launcher="ray", log=lambda m: None)
    finally:
        ray.shutdown()
    cells = sw.finished_cells(out)
    assert len(cells) == 2 and all("normalized_reward" in c for c in cells.values())
    assert (out / "table.md").exists()


@pytest.mark.slow
def test_sweep_on_a_mujoco_task_via_task_override(tmp_path, data_dir):
    """The ReachAvoid grid file run on HopperVelocity with `--task` (C MuJoCo evaluation of
    full 1,000-step episodes), killed after its first group and restarted. Slow: run with
    -m slow."""
    from r2pac_jax.data.factory import generate_dataset
    from r2pac_jax.tasks import get_task

    generate_dataset(get_task("HopperVelocity"), trajectories=10, seed=0, plot=False,
                     source="scripted")
    body = ('task = "ReachAvoid"\nseeds = 1\neval_episodes = 2\npreset = "quick"\n' + TINY_CONFIG
            + "\n[grid]\nquantile_alpha = [0.5, 0.9]\nchunk_len = [1, 3]\n")
    p = _write(tmp_path, body)
    s = sw.load_sweep(p, task_override="HopperVelocity")
    out = tmp_path / "hopper"
    sw.run_group(s, s.groups[0], out, log=lambda m: None, progress=False)  # then "killed"
    assert len(sw.finished_cells(out)) == 2
    assert sw.main([str(p), "--out", str(out), "--task", "HopperVelocity", "--no-progress"]) == 0
    cells = sw.finished_cells(out)
    assert len(cells) == 4
    for c in cells.values():
        assert c["task"] == "HopperVelocity"
        assert c["episodes"] == 2 and len(c["returns"]) == 1 and len(c["returns"][0]) == 2
        assert all(0 < n <= 1000 for n in c["lengths"][0])
        assert c["safe"] == (c["normalized_cost"]["mean"] < 1.0)
    assert (out / "table.md").read_text().count("| HopperVelocity | r2pac |") == 4


def test_report_marks_diverged_seeds(tmp_path):
    from r2pac_jax.io import atomic_write_json

    def cell(cid, alpha, per_r, per_c, diverged=()):
        def stats(xs):
            ok = [x for x in xs if x is not None]
            return dict(mean=sum(ok) / len(ok) if ok else None, std=0.0 if ok else None,
                        per_seed=xs)
        return dict(cell_id=cid, label=cid, task="ReachAvoid", algo="r2pac",
                    axes=dict(quantile_alpha=alpha), run_dir=str(tmp_path / "g"),
                    normalized_reward=stats(per_r), normalized_cost=stats(per_c),
                    safe=bool(stats(per_c)["mean"] is not None and stats(per_c)["mean"] < 1),
                    diverged=[dict(seed=s, step=10, terms=["loss_qr"]) for s in diverged])

    atomic_write_json(tmp_path / "cells" / "a.json", cell("a", 0.5, [0.4, 0.6], [0.1, 0.2]))
    atomic_write_json(tmp_path / "cells" / "b.json", cell("b", 0.9, [0.8, None], [0.5, None],
                                                        diverged=[1]))
    atomic_write_json(tmp_path / "cells" / "c.json", cell("c", 0.95, [None, None], [None, None],
                                                        diverged=[0, 1]))
    md = sw.write_report(tmp_path)
    assert "(diverged: seeds 1)" in md and "(diverged: seeds 0 1)" in md
    assert "0.800 diverged" in md and "nan ± nan" in md
    assert "**0.80 ± 0.00** ★ (diverged: seeds 1)" in md  # best safe among the finite seeds

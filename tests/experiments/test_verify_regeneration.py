"""verify_regeneration.py: a regenerated file against its pinned array digest, log and card."""
import gzip
import json
from pathlib import Path

import numpy as np

from conftest import load_script
from r2pac_jax.data import write_dsrl
from r2pac_jax.tasks import get_task


def _mod():
    return load_script("experiments/data_factory/verify_regeneration.py")


def _arrays(reward):
    t, n = get_task("BallRun"), 6  # two episodes of three steps
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(n + 1, t.obs_dim)).astype(np.float32)
    nxt = obs[1:].copy()
    nxt[2] = rng.normal(size=t.obs_dim)  # the first episode's last next-observation
    return dict(observations=obs[:n], next_observations=nxt,
                actions=np.zeros((n, t.act_dim), np.float32),
                rewards=np.full(n, reward, np.float32), costs=np.zeros(n, np.float32),
                terminals=np.zeros(n, bool), timeouts=np.array([0, 0, 1, 0, 0, 1], bool))


def _setup(tmp, reward=1.0, log_rows=None, card=None, pinned_reward=1.0):
    from r2pac_jax.data import Dataset

    name = "BallRun-generated-ppolag-v2-s0-n3.hdf5"
    f = tmp / "cache" / name
    f.parent.mkdir()
    write_dsrl(f, _arrays(reward))
    card = card or {"task": "BallRun", "trajectories": 3, "cost_range": [0, 5],
                    "versions": {"jax": "0.10.2", "mujoco": "4.0.1"},
                    "machine": {"cpu": "AMD EPYC", "cpus": 2, "arch": "x86_64"}}
    f.with_suffix(".json").write_text(json.dumps(card))
    rows = log_rows or [{"update": u, "multiplier": u * 0.5, "steps_per_s": 100 + u}
                        for u in (1, 2, 3)]
    f.with_suffix(".log.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    arch = tmp / "archive" / "BallRun"
    arch.mkdir(parents=True)
    (arch / f.with_suffix(".json").name).write_text(
        json.dumps({"task": "BallRun", "trajectories": 3, "cost_range": [0, 5],
                    "versions": {"jax": "0.10.2"}}))  # an older card: no mujoco version
    with gzip.open(arch / f"{f.stem}.log.jsonl.gz", "wt") as g:  # other wall-clock speeds
        for u in (1, 2, 3):
            g.write(json.dumps({"update": u, "multiplier": u * 0.5, "steps_per_s": 7.0}) + "\n")
    man = tmp / "manifest.json"
    pinned = Dataset(**_arrays(pinned_reward)).digest()
    man.write_text(json.dumps({"datasets": {"BallRun": {"file": name, "sha256": pinned}}}))
    return f, man, tmp / "archive"


def test_an_identical_regeneration_agrees_on_arrays_log_and_card(tmp_path):
    f, man, arch = _setup(tmp_path)
    assert _mod().main([str(f), "--manifest", str(man), "--archive", str(arch)]) == 0
    out = json.loads(Path(f"{f}.regen.json").read_text())
    assert out["arrays"]["agree"] and out["log"]["agree"] and out["card"]["agree"]
    assert out["log"]["updates_compared"] == 3
    # the versions are reported, not checked: the older card's missing mujoco is named only
    assert out["versions"]["differ"] == ["mujoco"] and out["agree"]
    # and so is the machine, which the older card does not name
    assert out["machine"]["differ"] == ["arch", "cpu", "cpus"]
    assert out["machine"]["new"]["cpus"] == 2 and out["machine"]["old"] == {}


def test_a_different_regeneration_names_its_first_differing_update_and_fails(tmp_path):
    rows = [{"update": 1, "multiplier": 0.5}, {"update": 2, "multiplier": 1.25},
            {"update": 3, "multiplier": 9.0}]
    f, man, arch = _setup(tmp_path, reward=2.0, log_rows=rows,
                          card={"task": "BallRun", "trajectories": 4, "cost_range": [0, 5]})
    m = _mod()
    assert m.main([str(f), "--manifest", str(man), "--archive", str(arch)]) == 1
    out = json.loads(Path(f"{f}.regen.json").read_text())
    assert out["arrays"]["agree"] is False
    assert out["log"]["first_difference"] == 2 and out["log"]["keys"] == ["multiplier"]
    assert out["card"]["differences"] == {"trajectories": {"new": 4, "old": 3}}


def test_probe_names_the_first_update_that_parts_and_refuses_unknown_tasks(tmp_path, monkeypatch,
                                                                            capsys):
    """--probe: each pinned file's first updates made in a scratch cache against its archived
    log (the generation itself stands in here: what it leaves is read back)."""
    import subprocess

    m = _mod()
    arch = tmp_path / "archive"
    pins = {}
    for task in ("BallRun", "CarGoal2", "DroneRun"):
        name = f"{task}-generated-ppolag-v2-s0-n9-b5000.hdf5"
        pins[task] = {"file": name, "sha256": "x"}
        if task != "DroneRun":  # DroneRun: no archived log
            (arch / task).mkdir(parents=True)
            with gzip.open(arch / task / f"{Path(name).stem}.log.jsonl.gz", "wt") as g:
                for u in (1, 2, 3, 4):
                    g.write(json.dumps({"update": u, "multiplier": u * 0.5,
                                        "t_rollout": 1.0}) + "\n")
    man = tmp_path / "manifest.json"
    man.write_text(json.dumps({"datasets": pins}))
    seen = []

    def fake(cmd, env, **kw):  # CarGoal2 parts at update 2; BallRun agrees on 3, slower
        task = cmd[cmd.index("--task") + 1]
        seen.append((task, cmd[cmd.index("--stop-after") + 1], cmd[cmd.index("--budget") + 1]))
        part = Path(env["R2PAC_DATA_DIR"]) / f"{pins[task]['file']}.partial"
        part.mkdir(parents=True)
        rows = [{"update": u, "multiplier": u * 0.5 + (task == "CarGoal2" and u == 2),
                 "t_rollout": 9.0} for u in ((1, 2) if task == "CarGoal2" else (1, 2, 3))]
        (part / "log.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
        return subprocess.CompletedProcess(cmd, 3 if task == "CarGoal2" else 0, "", "")

    monkeypatch.setattr(subprocess, "run", fake)
    out = tmp_path / "probe.jsonl"
    assert m.main(["--probe", "all", "--manifest", str(man), "--archive", str(arch),
                   "--out", str(out)]) == 1
    said = capsys.readouterr().out
    assert "BallRun: agrees through update 3" in said
    assert "CarGoal2: parts at update 2 (multiplier)" in said
    assert "DroneRun: no archived log" in said
    assert seen == [("BallRun", "3", "5000"), ("CarGoal2", "3", "5000")]
    rows = {r["task"]: r for r in map(json.loads, out.read_text().splitlines())}
    assert rows["BallRun"]["agree"] and rows["CarGoal2"]["first_difference"] == 2
    assert m.main(["--probe", "AntCircle", "--manifest", str(man)]) == 2
    assert "AntCircle: no pinned file" in capsys.readouterr().err

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

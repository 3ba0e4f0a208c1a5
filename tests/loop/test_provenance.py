"""What a result stands on: the device that trained a run and its data file's RL budget, in
results.json and in a table's footer (the Table-1 protocol's addendum of 2026-12-06)."""
import json

import jax

from r2pac_jax.data.factory import data_budget
from r2pac_jax.table import row_budget, standing_lines


def test_results_record_device_and_budget(tiny_run):
    r = json.loads((tiny_run["run"] / "results.json").read_text())
    assert r["trained_on"]["backend"] == jax.default_backend()
    assert r["trained_on"]["devices"] == len(jax.devices())
    assert r["machine"]["cpus"] >= 1
    # a file without a generation card (a user's, or DSRL's own) has no RL budget to report
    assert r["data_budget"] is None


def test_data_budget_reads_the_card(tmp_path):
    f = tmp_path / "CarGoal2-generated-ppolag-v2-s0-n4105-b5000000.hdf5"
    f.write_bytes(b"")
    assert data_budget(f) is None  # no card
    f.with_suffix(".json").write_text(json.dumps(dict(
        source="ppo-lagrangian", physics="mujoco", dsrl_env_steps=22_000_000,
        generation=dict(env_steps=5_000_000))))
    assert data_budget(f) == dict(source="ppo-lagrangian", env_steps=5_000_000,
                                  dsrl_env_steps=22_000_000, dsrl_budget=False, physics="mujoco")
    f.with_suffix(".json").write_text("{not json")
    assert data_budget(f) is None


def _cell(**extra):
    return dict(normalized_reward=dict(mean=0.1), normalized_cost=dict(mean=0.5), **extra)


def test_footer_names_cut_budgets_and_other_devices():
    cpu = dict(backend="cpu", device_kind="cpu", devices=1)
    gpu = dict(backend="gpu", device_kind="NVIDIA H200", devices=1)
    manifest = {"datasets": {
        "AntCircle": {"file": "AntCircle-generated-ppolag-v2-s0-n5728-b2000000.hdf5"},
        "BallRun": {"file": "BallRun-generated-ppolag-v2-s0-n940.hdf5"},
        "HopperVelocity": {"file": "HopperVelocity-generated-ppolag-v2-s0-n2240.hdf5"},
        "ReachAvoid": {"file": "ReachAvoid-generated-s0-n1000.hdf5"}}}
    cells = {"AntCircle": {"r2pac": _cell(trained_on=cpu)},
             "BallRun": {"r2pac": _cell(trained_on=cpu), "cpq": _cell()},
             # a results.json record wins over the file's name
             "HopperVelocity": {"cdt": _cell(trained_on=gpu, data_budget=dict(
                 env_steps=18_000_000, dsrl_env_steps=30_000_000))},
             "ReachAvoid": {"r2pac": _cell(trained_on=cpu)}}
    lines = standing_lines(cells, manifest)
    assert lines[0] == ("Rows on files made below DSRL's RL budget (2 of 4): AntCircle 2M of 54M "
                        "(4%), HopperVelocity 18M of 30M (60%).")
    assert lines[1] == "Cells trained on another device than a CPU: HopperVelocity cdt (NVIDIA H200)."
    assert lines[2].startswith("1 cells predate the device record")
    assert row_budget("BallRun", manifest["datasets"]["BallRun"]["file"], cells["BallRun"]) == \
        dict(env_steps=10_000_000, dsrl_env_steps=10_000_000)
    # a scripted or demo file has no RL budget to compare
    assert row_budget("ReachAvoid", "ReachAvoid-generated-s0-n1000.hdf5", {}) is None
    all_recorded = {t: {a: dict(c, trained_on=cpu) for a, c in row.items()}
                    for t, row in cells.items() if t != "AntCircle" and t != "HopperVelocity"}
    assert standing_lines(all_recorded, manifest) == []

"""GENERATION.md's table of each learned file beside DSRL's published statistics."""
import json

from conftest import load_script

from r2pac_jax.tasks import get_task

dc = load_script("experiments/data_factory/dsrl_compare.py")


def _card(n=100, safe=25, steps=5_000_000):
    return dict(trajectories=n, safe_trajectories=safe, cost_range=[0.0, 200.0],
                normalised_return_range=[-0.05, 0.97], generation=dict(env_steps=steps))


def test_rows_and_table(tmp_path):
    t = get_task("CarGoal2")
    r = dc.row(t, _card())
    assert (r["dsrl_trajectories"], r["dsrl_cost_cap"], r["dsrl_env_steps"]) == (4105, 200, 22_000_000)
    assert r["safe_share"] == 0.25 and r["best"] == 0.97
    md = dc.markdown([r, dc.row(get_task("CarGoal1"), None)])
    assert "| CarGoal2 | 4,105 | 100 | 200 | 0 .. 200 |" in md
    assert "25.0% (kappa 10) | 5M / 22M (23%) |" in md
    assert "| CarGoal1 | 1,671 | no file |" in md


def test_card_found_pinned_first_and_superseded_ignored(tmp_path):
    d = tmp_path / "CarGoal1"
    (d / "first-file").mkdir(parents=True)
    (d / "first-file" / "CarGoal1-generated-ppolag-v2-s0-n1671.json").write_text("{}")
    assert dc.find_card("CarGoal1", tmp_path) is None  # a superseded file is not the current one
    (d / "CarGoal1-generated-ppolag-v2-s0-n1671.json").write_text("{}")
    (d / "CarGoal1-generated-ppolag-v2-s0-n1671-b3000000.json").write_text("{}")
    assert dc.find_card("CarGoal1", tmp_path, pinned="CarGoal1-generated-ppolag-v2-s0-n1671.hdf5"
                        ).name == "CarGoal1-generated-ppolag-v2-s0-n1671.json"


def test_section_replaced_in_place():
    text = "# doc\n\nintro\n"
    once = dc.replace_section(text, "table one")
    assert once.count(dc.START) == 1 and "table one" in once
    twice = dc.replace_section(once + "\nlater text\n", "table two")
    assert "table one" not in twice and "table two" in twice and twice.endswith("later text\n")
    assert twice.count(dc.START) == 1
    json.dumps(dc.row(get_task("BallRun"), None))  # rows are plain JSON values

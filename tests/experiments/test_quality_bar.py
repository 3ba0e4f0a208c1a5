"""The quality-bar script's verdict and its accumulating report (issue 5)."""
import json

import pytest
from conftest import ROOT, load_script

SCRIPT = "experiments/data_factory/quality_bar.py"
NEXT_TASKS = "experiments/data_factory/next_tasks.py"


@pytest.fixture(scope="module")
def qb():
    return load_script(SCRIPT)


def _res(reward, cost):
    return {"normalized_reward": {"mean": reward, "std": 0.0, "per_seed": [reward]},
            "normalized_cost": {"mean": cost, "std": 0.0, "per_seed": [cost]}}


@pytest.mark.parametrize("r2pac,bc_safe,expected", [
    ((0.5, 0.2), (0.3, 0.5), "pass"),
    ((0.5, 1.0), (0.3, 0.5), "fail: r2pac unsafe"),  # cost 1 is not < 1
    ((0.3, 0.2), (0.3, 0.5), "fail: r2pac reward <= bc-safe"),
    ((0.1, 3.0), (0.3, 5.0), "fail: r2pac unsafe, r2pac reward <= bc-safe"),
])
def test_verdict(qb, r2pac, bc_safe, expected):
    assert qb.verdict({"r2pac": _res(*r2pac), "bc-safe": _res(*bc_safe)}) == expected


def test_verdict_incomplete_without_bc_safe(qb):
    assert qb.verdict({"r2pac": _res(0.5, 0.1)}) == "incomplete"


def test_report_accumulates_tasks_run_separately(qb, tmp_path):
    for task, algo, r, c in [("HopperVelocity", "r2pac", 0.4, 0.1),
                             ("HopperVelocity", "bc-safe", 0.3, 0.5),
                             ("SwimmerVelocity", "r2pac", 0.1, 2.0),
                             ("SwimmerVelocity", "bc-safe", 0.0, 4.0)]:
        d = tmp_path / task / algo
        d.mkdir(parents=True)
        (d / "results.json").write_text(json.dumps(_res(r, c)))
    # both tasks' runs are in the table, whichever invocation made them
    text = qb.report(tmp_path)
    assert "| HopperVelocity | pass |" in text
    assert "| SwimmerVelocity | fail: r2pac unsafe |" in text
    assert (tmp_path / "quality_bar.md").read_text() == text
    # rows follow the task registry, not the order of the runs
    from r2pac_jax.tasks import TASKS
    order = [t for t in TASKS if t in ("HopperVelocity", "SwimmerVelocity")]
    assert text.index(f"| {order[0]} | ") < text.index(f"| {order[1]} | ")


def test_report_without_runs(qb, tmp_path):
    assert qb.report(tmp_path / "missing") == "no finished run yet"


def test_archive_copies_a_finished_task_and_report_reads_the_archive(qb, tmp_path):
    runs, dest = tmp_path / "runs", tmp_path / "archive"
    card = tmp_path / "data" / "CarGoal2-generated-s0-n120.json"
    card.parent.mkdir()
    card.write_text('{"task": "CarGoal2"}')
    for algo, r, c in [("r2pac", 0.4, 0.2), ("bc-all", 0.6, 3.0), ("bc-safe", 0.3, 0.5)]:
        d = runs / "CarGoal2" / algo
        d.mkdir(parents=True)
        (d / "results.json").write_text(json.dumps(
            {**_res(r, c), "dataset": str(card.with_suffix(".hdf5"))}))
    # an unfinished task (no bc-safe yet) is not archived
    (runs / "PointGoal1" / "r2pac").mkdir(parents=True)
    (runs / "PointGoal1" / "r2pac" / "results.json").write_text(json.dumps(_res(0.1, 0.1)))
    assert qb.archive(runs, "PointGoal1", dest) == []
    written = qb.archive(runs, "CarGoal2", dest)
    assert sorted(p.name for p in written) == [
        "CarGoal2-generated-s0-n120.json", "bc-all.json", "bc-safe.json", "r2pac.json"]
    assert json.loads((dest / "CarGoal2" / "bc-all.json").read_text())[
        "normalized_cost"]["mean"] == 3.0
    # the archive alone gives the same verdicts as the run folder
    assert "| CarGoal2 | pass |" in qb.report(dest)
    assert "| CarGoal2 | pass |" in qb.report(runs)
    assert "PointGoal1" not in qb.report(dest)


def test_details_lists_per_seed_values_and_cost_free_episodes(qb, tmp_path):
    d = tmp_path / "PointGoal1" / "r2pac"
    d.mkdir(parents=True)
    res = {"normalized_reward": {"mean": 0.2, "std": 0.1, "per_seed": [0.1, 0.3]},
           "normalized_cost": {"mean": 1.5, "std": 1.0, "per_seed": [0.5, 2.5]},
           "costs": [[0.0, 0.0, 12.0], [40.0, 0.0, 3.0]], "wall_time_s": 61.4}
    (d / "results.json").write_text(json.dumps(res))
    rows = qb.details(tmp_path, "PointGoal1").splitlines()
    assert len(rows) == 3  # header, separator, r2pac only (no baseline has finished)
    assert rows[2] == "| r2pac | 0.20 ± 0.10 | 1.50 ± 1.00 | 0.10 0.30 | 0.50 2.50 | 50% | 61 |"


def test_v2_report_has_the_mlp_cloners_and_a_second_verdict(qb, tmp_path):
    (tmp_path / "data.json").write_text(json.dumps({"data": "v2"}))
    for algo, r, c in [("r2pac", 0.4, 0.1), ("bc-all", 0.6, 3.0), ("bc-safe", 0.3, 0.5),
                       ("bc-all-mlp", 0.5, 2.0), ("bc-safe-mlp", 0.45, 0.6)]:
        d = tmp_path / "CarGoal1" / algo
        d.mkdir(parents=True)
        (d / "results.json").write_text(json.dumps(dict(_res(r, c), eval_backend="mujoco")))
    text = qb.report(tmp_path)
    assert "bc-safe-mlp reward" in text and "bc-all-mlp reward" in text
    assert "| CarGoal1 | pass | fail: r2pac reward <= bc-safe-mlp | mujoco |" in text
    # each row names the simulator that scored it; runs that predate the record say --physics
    assert qb.simulator({"a": {"eval_backend": "bullet"}, "b": {"eval_backend": "mjx"}}) == \
        "bullet, mjx"
    assert qb.simulator({"a": {"physics": "auto"}, "b": {"skipped": "x"}}) == "physics=auto"
    assert qb.learned_file("BallRun") is None


def test_safe_cloners_on_data_without_a_safe_episode_are_skipped_and_named(qb, tmp_path):
    """A file whose card counts no safe trajectory: run_one records the safe cloners as
    skipped (no training), the table says why, and the verdict fails naming it."""
    card = tmp_path / "SwimmerVelocity-generated-ppolag-v2-s0-n3.json"
    card.write_text(json.dumps({"safe_trajectories": 0}))
    data = card.with_suffix(".hdf5")
    out = tmp_path / "out"
    (out / "data.json").parent.mkdir(parents=True)
    (out / "data.json").write_text(json.dumps({"data": "v2"}))
    for algo in ("bc-safe", "bc-safe-mlp"):  # would raise if it tried to train (no file)
        qb.run_one("SwimmerVelocity", algo, out, 3, 20_000, dataset=data)
        rec = json.loads((out / "SwimmerVelocity" / algo / "skipped.json").read_text())
        assert rec["skipped"] == "the data hold no episode with cost <= kappa"
    assert qb._untrainable("bc-all-mlp", data) is None and qb._untrainable("r2pac", data) is None
    for algo, r, c in [("r2pac", 0.1, 3.0), ("bc-all", 0.2, 4.0), ("bc-all-mlp", 0.2, 5.0)]:
        d = out / "SwimmerVelocity" / algo
        d.mkdir(parents=True)
        (d / "results.json").write_text(json.dumps(_res(r, c)))
    text = qb.report(out)
    assert "SwimmerVelocity: no bc-safe, bc-safe-mlp (the data hold no episode" in text
    assert ("| SwimmerVelocity | fail: no bc-safe (the data hold no episode with cost <= kappa) "
            "| fail: no bc-safe-mlp") in text
    assert "skipped: the data hold no episode" in qb.details(out, "SwimmerVelocity")


def test_the_v2_chain_covers_every_task_with_a_learned_source_and_skips_finished_ones(tmp_path):
    """make_learned.sh's order lists every registered task DSRL's recipe can make (a new task
    cannot silently drop out of the data campaign), and next_tasks.py skips archived ones."""
    from r2pac_jax.data import factory
    from r2pac_jax.tasks import TASKS

    nt = load_script(NEXT_TASKS)
    order = nt.ordered_tasks()
    assert len(order) == len(set(order))
    wanted = {n for n, t in TASKS.items()
              if t.collection is not None and t.family != "demo" and factory.has_source(t)}
    assert wanted and set(order) == wanted
    (tmp_path / order[0]).mkdir()
    (tmp_path / order[0] / "r2pac.json").write_text("{}")
    assert nt.unfinished(tmp_path) == order[1:]


def test_a_budget_fitted_to_a_session_is_below_dsrls_and_named_in_the_file(tmp_path, monkeypatch,
                                                                           capsys):
    """BUDGET_HOURS: the plan cuts a task's RL budget to what the measured rate finishes in the
    hours given (whole millions, never above DSRL's, never below 1M), the file's name carries the
    cut, and too short a budget for the target's episodes is said; the quality bar then reads that
    file when no DSRL-budget file exists."""
    from r2pac_jax.data import DatasetError, factory
    from r2pac_jax.data.factory.collect import (CPU2_STEPS_PER_S, MEAN_OVER_INIT_RATE,
                                                budget_for_hours)
    from r2pac_jax.tasks import get_task

    monkeypatch.setenv("R2PAC_DATA_DIR", str(tmp_path))
    nt = load_script(NEXT_TASKS)
    t = get_task("CarButton2")
    dsrl = t.collection.env_steps
    assert nt.plan("CarButton2") == (dsrl, factory.learned_path(t))
    b, path = nt.plan("CarButton2", hours=1.0)
    want = int(3600 * CPU2_STEPS_PER_S["CarButton2"] * MEAN_OVER_INIT_RATE // 1e6) * 1_000_000
    assert b == want and 1_000_000 <= b < dsrl
    assert path.name.endswith(f"-b{b}.hdf5") and path != factory.learned_path(t)
    assert budget_for_hours(t, 1000.0) == dsrl  # never above DSRL's
    assert budget_for_hours(t, 1e-4) == 1_000_000
    with pytest.raises(DatasetError, match="> 0"):
        budget_for_hours(t, 0.0)
    capsys.readouterr()
    nt.plan("AntCircle", hours=0.5)  # 5,728 episodes of 500 steps do not fit
    assert "below the target 5,728" in capsys.readouterr().err
    # the quality bar finds the fitted file (complete: it has its card) when it is the only one
    qbm = load_script(SCRIPT, "qb2")
    assert qbm.learned_file("CarButton2") is None
    path.write_bytes(b"")
    factory.card_path(path).write_text("{}")
    assert qbm.learned_file("CarButton2") == path


def test_plan_refuses_non_positive_hours_with_a_clear_message():
    import subprocess
    import sys

    r = subprocess.run([sys.executable, str(ROOT / NEXT_TASKS), "--plan",
                        "CarButton2", "--hours", "0"], capture_output=True, text=True)
    assert r.returncode == 2 and "must be > 0, got 0.0" in r.stderr and not r.stdout

"""The Table-1 command (r2pac_jax/table.py) and the table's marking rules (report.results_table)."""
import json

import pytest

from r2pac_jax.report import results_table
from r2pac_jax.table import data_version, main


def _r(reward, cost, std=0.1):
    return dict(normalized_reward=dict(mean=reward, std=std),
                normalized_cost=dict(mean=cost, std=std))


def test_marks_safe_bold_best_and_second_unsafe_dagger_and_family_averages():
    cells = {"T1": dict(a=_r(0.5, 0.5), b=_r(0.9, 2.0), c=_r(0.3, 0.2), d=_r(0.1, 0.9)),
             "T2": dict(a=_r(0.2, 0.4), b=_r(None, None), c=_r(0.6, 2.5), d=_r(0.4, 0.1))}
    md = results_table(cells, ["a", "b", "c", "d"], families={"T1": "nav", "T2": "nav"})
    row1 = next(ln for ln in md.splitlines() if ln.startswith("| T1 "))
    assert "**0.50 ± 0.10** ★" in row1 and "**0.30 ± 0.10** ☆" in row1  # best, second safe
    assert "0.90 ± 0.10 |" in row1 and "2.00 ± 0.10 †" in row1  # unsafe: plain, dagger
    assert row1.count("★") == 1 and row1.count("☆") == 1 and "**0.10 ± 0.10** |" in row1
    row2 = next(ln for ln in md.splitlines() if ln.startswith("| T2 "))
    assert "n/a" in row2 and "**0.40 ± 0.10** ★" in row2 and "2.50 ± 0.10 †" in row2
    avg = next(ln for ln in md.splitlines() if "nav average (2 tasks)" in ln)
    # a: (0.5 + 0.2) / 2 = 0.35 at cost 0.45, the best safe average (★), d 0.25 second (☆);
    # b diverged on T2: no average; c's average cost (0.2 + 2.5) / 2 = 1.35: unsafe
    assert "**0.35** ★" in avg and "**0.45**" in avg and "1.35 †" in avg
    assert "**0.25** ☆" in avg
    cells_b = [p.strip() for p in avg.split("|")][4:6]
    assert cells_b == ["–", "–"] and "–: no finished cell" in md
    full = results_table({"T1": cells["T1"]}, ["a", "b", "c", "d"])
    assert "–" not in full  # the footnote names the mark only when a cell is missing


def test_data_version_reads_the_file_name():
    assert data_version("/x/CarGoal1-generated-ppolag-v2-s0-n1671.hdf5") == "learned-v2"
    assert data_version("/x/ReachAvoid-generated-ppolag-s0-n600.hdf5") == "learned-v1"
    assert data_version("/x/CarGoal1-generated-s0-n600.hdf5") == "scripted-v1"
    assert data_version("/x/OfflineCarGoal1Gymnasium-v0-100-1000.hdf5") == "dsrl"


def test_the_table_command_runs_resumes_and_refuses_another_preset(tmp_path, data_dir, capsys):
    out = tmp_path / "t1"
    argv = ["--tasks", "ReachAvoid", "--algos", "bc-all-mlp,coptidice", "--seeds", "2",
            "--preset", "quick", "--episodes", "2", "--steps", "20", "--out", str(out),
            "--no-progress"]
    assert main(argv) == 0
    md = (out / "table.md").read_text()
    assert "bc-all-mlp reward" in md and "coptidice cost" in md and "demo average" in md
    assert "data scripted-v1" in md
    rows = (out / "table.csv").read_text().splitlines()
    assert rows[0].startswith("task,family,algo") and len(rows) == 3
    assert (out / "table.png").stat().st_size > 0
    res = json.loads((out / "ReachAvoid" / "coptidice" / "results.json").read_text())
    assert len(res["normalized_reward"]["per_seed"]) == 2
    capsys.readouterr()
    assert main(argv) == 0  # everything finished: read back, nothing retrained
    assert capsys.readouterr().out.count("finished earlier: read back") == 2
    assert (out / "table.md").read_text() == md
    assert main([a if a != "quick" else "paper" for a in argv]) == 2
    assert "holds a table made with preset='quick'" in capsys.readouterr().err

    # a task finished in DIR earlier, whose file this machine no longer holds, keeps its row
    import shutil
    man = json.loads((out / "manifest.json").read_text())
    man["datasets"]["HalfCheetahVelocity"] = dict(man["datasets"]["ReachAvoid"], file="gone.hdf5")
    (out / "manifest.json").write_text(json.dumps(man))
    shutil.copytree(out / "ReachAvoid" / "coptidice", out / "HalfCheetahVelocity" / "coptidice")
    assert main(argv) == 0
    md = (out / "table.md").read_text()
    assert "| HalfCheetahVelocity |" in md and "velocity average" in md and "gone.hdf5" in md
    rows = (out / "table.csv").read_text().splitlines()
    assert len(rows) == 4 and rows[1].startswith("HalfCheetahVelocity,velocity,coptidice")


def test_unknown_algorithm_names_the_known_ones(tmp_path, capsys):
    assert main(["--tasks", "ReachAvoid", "--algos", "cdq", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "unknown algo 'cdq'" in err and "cpq" in err and "coptidice" in err


def test_merge_from_joins_tables_and_table_only_trains_nothing(tmp_path, data_dir, capsys):
    import shutil

    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    common = ["--seeds", "2", "--preset", "quick", "--episodes", "2", "--steps", "20",
              "--no-progress"]
    assert main(["--tasks", "ReachAvoid", "--algos", "bc-all-mlp", "--out", str(a), *common]) == 0
    # b: a table of another task (a copy of a's cell standing for it), as another session leaves
    shutil.copytree(a, b)
    man = json.loads((b / "manifest.json").read_text())
    man["datasets"] = {"HalfCheetahVelocity": dict(man["datasets"]["ReachAvoid"], file="hc.hdf5")}
    (b / "manifest.json").write_text(json.dumps(man))
    shutil.move(b / "ReachAvoid", b / "HalfCheetahVelocity")
    (b / "HalfCheetahVelocity" / "coptidice").mkdir()  # unfinished there: not copied
    capsys.readouterr()
    only = ["--algos", "bc-all-mlp", "--table-only", *common]
    assert main([*only, "--out", str(c), "--merge-from", str(a), "--merge-from", str(b)]) == 0
    out = capsys.readouterr().out
    assert "merged 1 finished cell(s)" in out and "== " not in out  # nothing trained
    assert sorted(json.loads((c / "manifest.json").read_text())["datasets"]) == [
        "HalfCheetahVelocity", "ReachAvoid"]
    assert not (c / "HalfCheetahVelocity" / "coptidice").exists()
    md = (c / "table.md").read_text()
    assert "| ReachAvoid |" in md and "| HalfCheetahVelocity |" in md and "hc.hdf5" in md
    # --tasks narrows the table-only table; OUT's own cells win over SRC's
    res = c / "ReachAvoid" / "bc-all-mlp" / "results.json"
    mine = json.loads(res.read_text())
    mine["normalized_reward"]["mean"] = 0.123
    res.write_text(json.dumps(mine))
    assert main([*only, "--out", str(c), "--tasks", "ReachAvoid", "--merge-from", str(a)]) == 0
    md = (c / "table.md").read_text()
    assert "0.12 ±" in md and "HalfCheetahVelocity" not in md
    # without --algos, --table-only finds its columns: every algorithm with a finished cell, in
    # the paper's order (R2PAC last), none left out; an unfinished cell (no results.json) is none
    for algo in ("r2pac", "cpq"):
        shutil.copytree(c / "ReachAvoid" / "bc-all-mlp", c / "ReachAvoid" / algo)
    (c / "ReachAvoid" / "fisor").mkdir()
    assert main(["--table-only", *common, "--out", str(c)]) == 0
    head = (c / "table.md").read_text().splitlines()[0]
    cols = [h.split()[0] for h in head.strip("|").split("|")[1::2]]
    assert cols == ["bc-all-mlp", "cpq", "r2pac"], head
    assert "| HalfCheetahVelocity |" in (c / "table.md").read_text()
    # refused: another preset, a task on other data, a SRC that is no table, an unknown task
    capsys.readouterr()
    assert main([*[x if x != "quick" else "paper" for x in only], "--out", str(c)]) == 2
    assert "preset='quick'" in capsys.readouterr().err
    man = json.loads((b / "manifest.json").read_text())
    man["datasets"]["ReachAvoid"] = dict(man["datasets"]["HalfCheetahVelocity"], sha256="0" * 64)
    (b / "manifest.json").write_text(json.dumps(man))
    assert main([*only, "--out", str(c), "--merge-from", str(b)]) == 2
    assert "never mixes data" in capsys.readouterr().err
    assert main([*only, "--out", str(c), "--merge-from", str(tmp_path)]) == 2
    assert "no manifest.json there" in capsys.readouterr().err
    assert main([*only, "--out", str(c), "--tasks", "CarGoal1"]) == 2
    assert "has no results for CarGoal1" in capsys.readouterr().err
    assert main(["--algos", "bc-all-mlp", "--out", str(tmp_path / "d"), *common]) == 2
    assert "--tasks and --algos" in capsys.readouterr().err
    assert main([*only, "--out", str(tmp_path / "e")]) == 2  # no table there: none is created
    assert "holds no table" in capsys.readouterr().err and not (tmp_path / "e").exists()


def _light_table(root, task, algo, sha="1"):
    """A table directory by hand: one finished cell (results, config and a checkpoint)."""
    cell = root / task / algo
    (cell / "checkpoints" / "20").mkdir(parents=True)
    (cell / "checkpoints" / "20" / "state").write_text("weights")
    (cell / "results.json").write_text(json.dumps(_r(0.5, 0.1)))
    (cell / "config.json").write_text("{}")
    (root / "manifest.json").write_text(json.dumps(dict(
        preset="quick", seeds=2, episodes=2, steps=None,
        datasets={task: dict(file=f"{task}.hdf5", version="learned-v2", sha256=sha * 64)})))
    return root


def test_merge_on_a_full_disk_says_so_and_leaves_no_partial_cell(tmp_path, monkeypatch, capsys):
    """ENOSPC while a cell is copied: one line naming the cell, nothing half-copied left."""
    import errno
    import shutil

    src = _light_table(tmp_path / "src", "ReachAvoid", "bc-all-mlp")

    def full(a, b, **kw):  # the disk fills after the first file of the copy
        b.mkdir()
        (b / "results.json").write_text("{")
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(shutil, "copytree", full)
    out = tmp_path / "out"
    assert main(["--algos", "bc-all-mlp", "--table-only", "--seeds", "2", "--preset", "quick",
                 "--episodes", "2", "--out", str(out), "--merge-from", str(src)]) == 2
    err = capsys.readouterr().err
    assert "no space left on the disk" in err and str(out / "ReachAvoid" / "bc-all-mlp") in err
    assert len(err.strip().splitlines()) == 1
    assert list((out / "ReachAvoid").iterdir()) == []  # no cell, no temporary copy


def test_a_pinned_file_missing_here_is_refused_before_any_data_is_made(tmp_path, data_dir, capsys):
    """--out pins a task's file that this machine lacks: one line naming the file and the fix,
    and nothing generated (the learned data would take hours and might differ)."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "manifest.json").write_text(json.dumps(dict(
        preset="quick", seeds=2, episodes=2, steps=None,
        datasets={"ReachAvoid": dict(file="gone.hdf5", version="scripted-v1", sha256="ab" * 32)})))
    assert main(["--tasks", "ReachAvoid", "--algos", "bc-all-mlp", "--seeds", "2", "--preset",
                 "quick", "--episodes", "2", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "pins ReachAvoid's data to gone.hdf5" in err and "copy that file there" in err
    gen = data_dir / "gen"
    assert not gen.exists() or not any(gen.iterdir())  # no dataset was made


def test_found_columns_follow_the_papers_order():
    from r2pac_jax.table import column_order

    assert column_order(["r2pac", "fisor", "bc-safe", "r2pac-hj", "cdt", "cpq", "bcq-lag",
                         "coptidice", "bc-all-mlp"]) == [
        "bc-safe", "bc-all-mlp", "cpq", "coptidice", "bcq-lag", "cdt", "fisor", "r2pac",
        "r2pac-hj"]


def test_results_only_merges_keep_every_source_task_and_copy_two_files(tmp_path, capsys):
    """Two chains write back into one kept table in turn: both tasks stay in its manifest (a
    manifest copied over the kept one dropped the other's task), and a cell arrives as its
    results.json and config.json only."""
    a = _light_table(tmp_path / "a", "CarCircle", "r2pac")
    b = _light_table(tmp_path / "b", "AntRun", "cpq", sha="2")
    keep = tmp_path / "keep"
    only = ["--algos", "r2pac,cpq", "--table-only", "--seeds", "2", "--preset", "quick",
            "--episodes", "2", "--out", str(keep), "--results-only", "--no-progress"]
    assert main([*only, "--merge-from", str(a)]) == 0
    assert main([*only, "--merge-from", str(b)]) == 0
    assert sorted(json.loads((keep / "manifest.json").read_text())["datasets"]) == [
        "AntRun", "CarCircle"]
    md = (keep / "table.md").read_text()
    assert "| CarCircle |" in md and "| AntRun |" in md
    for cell in (keep / "CarCircle" / "r2pac", keep / "AntRun" / "cpq"):
        assert sorted(p.name for p in cell.iterdir()) == ["config.json", "results.json"]
    capsys.readouterr()
    assert main(only) == 2  # --results-only without --merge-from: refused, named
    assert "give --merge-from SRC too" in capsys.readouterr().err


@pytest.mark.slow  # times CDT's compiled block and planner (python -m pytest -m slow)
def test_estimate_makes_no_file_and_counts_the_evaluation_policy(data_dir, tmp_path, capsys):
    """--estimate on a task without data on the machine: timed on a stand-in of its shapes,
    nothing generated, nothing written; a line per cell for its evaluation's policy."""
    out = tmp_path / "table"
    assert main(["--tasks", "BallRun", "--algos", "cdt", "--seeds", "2",
                 "--episodes", "2", "--steps", "10", "--out", str(out), "--estimate",
                 "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "BallRun: no data file on this machine; timed on a stand-in" in text
    assert "BallRun cdt: evaluation's policy" in text and "x 100 steps x 1 evaluation(s)" in text
    assert "cdt: training" in text and "in all ~" in text  # CDT: a policy with memory
    assert not out.exists()
    assert not list(data_dir.rglob("*.hdf5"))


def test_estimate_data_is_a_stand_in_where_the_machine_has_no_file(data_dir):
    """--estimate's data: never generated (a fresh machine would otherwise start hours of
    generation), a stand-in of the task's shapes, announced."""
    from r2pac_jax.table import estimate_data
    from r2pac_jax.tasks import get_task

    said = []
    ds = estimate_data(get_task("BallRun"), said.append)
    assert ds.observations.shape[1] == get_task("BallRun").obs_dim and "stand-in" in said[0]
    assert not list(data_dir.rglob("*.hdf5"))


def test_a_run_makes_as_many_evaluations_as_counted(tiny_run):
    from r2pac_jax.agents import make_agent
    from r2pac_jax.loop import count_evaluations
    from r2pac_jax.policy import read_run
    from r2pac_jax.tasks import get_task

    cfg, _ = read_run(tiny_run["run"])
    t = get_task(cfg.task)
    rows = [json.loads(ln) for ln in (tiny_run["run"] / "eval.jsonl").open()]
    assert count_evaluations(cfg, make_agent(cfg, t.obs_dim, t.act_dim)) == len(
        {r["step"] for r in rows}) == 2  # the actor phase's 10 and 20 (steps 30 and 40)


def test_stand_in_dataset_has_the_tasks_shapes_and_whole_episodes():
    from r2pac_jax.data import stand_in_dataset
    from r2pac_jax.tasks import get_task

    t = get_task("BallRun")
    ds = stand_in_dataset(t, episodes=3)
    assert ds.observations.shape == (300, t.obs_dim) and ds.actions.shape == (300, t.act_dim)
    assert ds.timeouts.sum() == 3 and ds.timeouts[99] and not ds.terminals.any()

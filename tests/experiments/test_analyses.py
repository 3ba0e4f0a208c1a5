"""experiments/analyses/analyses.py: the protocol's cells, the per-task chain (train, keep,
value map, resume) and the reports, on tiny ReachAvoid runs."""
import json
import shutil
import statistics

import pytest
from conftest import TINY_ARGV, load_script

an = load_script("experiments/analyses/analyses.py", "analyses_under_test")


def test_the_protocols_cells_each_once_with_registry_values_named_plainly():
    cells = an.plan()
    assert sum(len(c) for c in cells.values()) == 53  # PROTOCOL.md's count
    assert list(cells)[0] == "BallRun" and list(cells)[-1] == "CarGoal1"
    ball = cells["BallRun"]
    # alpha 0.5 and h 5 are BallRun's registry values: the plain r2pac cell, not a second one
    assert "r2pac-quantile_alpha=0.5" not in ball and "r2pac-chunk_len=5" not in ball
    assert ball["r2pac-quantile_alpha=0.3"] == ("r2pac", {"quantile_alpha": 0.3})
    assert ball["r2pac-no-penalty-chunk_len=7"] == ("r2pac-no-penalty", {"chunk_len": 7})
    assert ball["r2pac"] == ("r2pac", {})
    assert set(cells["CarPush1"]) == {"r2pac", "r2pac-awr-flow", "r2pac-hj"}
    assert list(an.plan(["h"], ["CarGoal2"])) == ["CarGoal2"]
    with pytest.raises(an.AnalysesError, match="unknown analysis"):
        an.plan(["figure7"])
    with pytest.raises(an.AnalysesError, match="no analysis uses Hopper"):
        an.plan(tasks=["Hopper"])


def test_train_argv_sets_chunk_length_by_its_flag_and_others_by_set():
    argv = an.train_argv("BallRun", "r2pac", {"chunk_len": 3, "quantile_alpha": 0.3}, "f.h5",
                         an.Path("out"))
    assert argv[argv.index("--chunk-len") + 1] == "3"
    assert "quantile_alpha=0.3" in argv and argv[argv.index("--seeds") + 1] == "3"
    assert argv[argv.index("--eval-episodes") + 1] == "20"


def test_run_refuses_before_the_decision(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(an, "DECISION", tmp_path / "decision.json")
    assert an.main(["run", "--task", "BallRun"]) == 2
    assert "not settled yet" in capsys.readouterr().err
    assert not an.decision_landed(tmp_path / "decision.json")
    f = tmp_path / "decision.json"
    f.write_text(json.dumps({"decision": {"winner": None}}))
    assert an.decision_landed(f)  # no winner: the default stays, settled
    f.write_text(json.dumps({"decision": {"winner": "b"}}))
    assert not an.decision_landed(f)  # a winner waits for its confirmation
    f.write_text(json.dumps({"decision": {"winner": "b"}, "confirmation": {"confirmed": False}}))
    assert an.decision_landed(f)  # not confirmed: the default stays
    f.write_text(json.dumps({"decision": {"winner": "b"}, "confirmation": {"confirmed": True}}))
    from r2pac_jax.agents.r2pac import R2PACConfig
    # confirmed: settled once the registry's default holds b's setting (vc_nonneg=true)
    assert an.decision_landed(f) == R2PACConfig().vc_nonneg


def test_a_failed_cell_is_not_kept_and_a_started_one_resumes(tmp_path, monkeypatch):
    import r2pac_jax.train

    seen = []
    monkeypatch.setattr(r2pac_jax.train, "main", lambda argv: seen.append(argv) or 1)
    cells = {"r2pac": ("r2pac", {}), "r2pac-hj": ("r2pac-hj", {})}
    (tmp_path / "runs" / "T" / "r2pac-hj").mkdir(parents=True)
    (tmp_path / "runs" / "T" / "r2pac-hj" / "config.json").write_text("{}")
    st = an.run_chain("T", cells, "f.h5", tmp_path / "runs", tmp_path / "kept",
                      tmp_path / "maps", log=lambda m: None, map_tasks=())
    assert st == {"r2pac": "failed", "r2pac-hj": "failed"}
    assert "--resume" not in seen[0] and seen[1][-1] == "--resume"
    assert not (tmp_path / "kept").exists()


@pytest.fixture(scope="module")
def chain(tiny_run, tmp_path_factory):
    """The chain of a ReachAvoid plan with r2pac (the tiny run, finished: resumed at its end)
    and r2pac-no-penalty (trained here), kept and mapped into a temporary folder."""
    t = tmp_path_factory.mktemp("chain")
    runs, kept, maps = t / "runs", t / "kept", t / "maps"
    shutil.copytree(tiny_run["run"], runs / "ReachAvoid" / "r2pac")
    table = {"x": {"ReachAvoid": [("r2pac", {}), ("r2pac-no-penalty", {})]}}
    cells = an.plan(["x"], table=table)["ReachAvoid"]
    log = []
    status = an.run_chain("ReachAvoid", cells, tiny_run["d"], runs, kept, maps, TINY_ARGV,
                          log.append, embedding="pca", map_tasks=("ReachAvoid",))
    return dict(t=t, runs=runs, kept=kept, maps=maps, cells=cells, status=status, log=log)


@pytest.mark.slow  # trains a tiny run end to end (python -m pytest -m slow)
def test_the_chain_keeps_each_cell_and_maps_the_task(chain):
    assert chain["status"] == {"r2pac": "kept", "r2pac-no-penalty": "kept"}
    for name in chain["cells"]:
        d = chain["kept"] / "ReachAvoid" / name
        assert {p.name for p in d.iterdir()} == set(an.KEEP_FILES)
        assert (json.loads((d / "results.json").read_text()) ==
                json.loads((chain["runs"] / "ReachAvoid" / name / "results.json").read_text()))
    info = json.loads((chain["maps"] / "ReachAvoid.json").read_text())
    assert info["embedding"] == "PCA" and info["states"] == 4800  # all 60 x 80 (< 5,000)
    assert {"spearman_V_r_vs_V_c", "spearman_Vbar_r_vs_V_c"} <= set(info)
    assert (chain["maps"] / "ReachAvoid.png").is_file()


@pytest.mark.slow  # trains a tiny run end to end (python -m pytest -m slow)
def test_a_kept_cell_is_never_trained_again(chain, monkeypatch):
    import r2pac_jax.train

    def boom(argv):
        raise AssertionError("trained a kept cell")
    monkeypatch.setattr(r2pac_jax.train, "main", boom)
    st = an.run_chain("ReachAvoid", chain["cells"], "unused", chain["runs"], chain["kept"],
                      chain["maps"], log=lambda m: None, map_tasks=("ReachAvoid",))
    assert set(st.values()) == {"finished earlier"}


@pytest.mark.slow  # trains a tiny run end to end (python -m pytest -m slow)
def test_reports_read_the_kept_cells(chain, tmp_path):
    kept = tmp_path / "kept"
    src = chain["kept"] / "ReachAvoid"
    shutil.copytree(src / "r2pac", kept / "BallRun" / "r2pac")
    shutil.copytree(src / "r2pac-no-penalty", kept / "BallRun" / "r2pac-no-penalty-chunk_len=1")
    res = json.loads((src / "r2pac" / "results.json").read_text())
    md = an.report_table2(kept, tmp_path)
    row = next(ln for ln in md.splitlines() if ln.startswith("| BallRun"))
    mean = f"{res['normalized_reward']['mean']:.2f} ± {res['normalized_reward']['std']:.2f}"
    assert mean in row and row.count("not run") == 3 and "0.30 / 0.00" in row  # the paper's
    ours = row.split("|")[8].strip()  # the "Ours (ours)" column
    assert ours.startswith("**") == (res["normalized_cost"]["mean"] < 1)
    assert ours.endswith("(unsafe)") == (res["normalized_cost"]["mean"] >= 1)
    assert (tmp_path / "table2.csv").read_text().count("\n") == 1 + 7 * 4
    # Figure 2's numbers: the last critic block's batch-mean Q_r, averaged over the lanes
    md = an.report_qstability(kept, tmp_path)
    rows = [json.loads(ln) for ln in (src / "r2pac-no-penalty" / "metrics.jsonl").open()]
    crit = [r for r in rows if r.get("phase") == "critic"]
    last = max(r["step"] for r in crit)
    want = statistics.fmean(r["qr_mean"] for r in crit if r["step"] == last)
    line = next(ln for ln in md.splitlines() if ln.startswith("| 1 |"))
    assert line.split("|")[2].strip() == f"{want:.3f}"
    assert (tmp_path / "qstability.png").is_file()
    md = an.report_alpha(kept, tmp_path)
    assert md.count("not run") == 2 and (tmp_path / "alpha.png").is_file()

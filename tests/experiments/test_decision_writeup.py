"""experiments/r2pac_decision/writeup.py: the write-up's tables from kept cells (made-up cells
copied from a tiny run; no decision score exists here)."""
import json
import shutil
import statistics

import pytest

from conftest import load_script

wu = load_script("experiments/r2pac_decision/writeup.py", "writeup_under_test")


def _keep(run, dest, metrics=True):
    dest.mkdir(parents=True)
    for f in ("results.json", "config.json") + (("metrics.jsonl",) if metrics else ()):
        shutil.copyfile(run / f, dest / f)


def test_tables_read_each_kept_cell_and_name_what_is_missing(tiny_run, tmp_path):
    root = tmp_path / "cells"
    _keep(tiny_run["run"], root / "seeds0-2" / "BallRun" / "0")
    _keep(tiny_run["run"], root / "seeds0-2" / "BallRun" / "b", metrics=False)
    md = wu.tables(root)
    res = json.loads((tiny_run["run"] / "results.json").read_text())
    row = next(ln for ln in md.splitlines() if ln.startswith("| BallRun | 0 (default)"))
    assert f"| {res['normalized_reward']['mean']:.3g} |" in row
    assert f"| {res['diagnostics']['not_first']['mean']:.3g} |" in row
    assert "| BallRun | a (LayerNorm critics) | not run |" in md
    assert "No training metrics kept" in md and "BallRun/b" in md
    # training: the last critic block's V_c minimum over the lanes
    rows = [json.loads(ln) for ln in (tiny_run["run"] / "metrics.jsonl").open()]
    crit = [r for r in rows if r.get("phase") == "critic"]
    last = max(r["step"] for r in crit)
    vc_min = min(r["vc_min"] for r in crit if r["step"] == last)
    corr = statistics.fmean(r["corr_adv_r_reward_safe"] for r in rows
                            if r.get("phase") == "actor" and r["step"] == max(
                                q["step"] for q in rows if q.get("phase") == "actor"))
    train = next(ln for ln in md.splitlines()
                 if ln.startswith("| BallRun | 0 (default)") and ln != row)
    assert f"| {vc_min:.3g} |" in train and f"| {corr:.3g} |" in train


@pytest.mark.slow  # three re-evaluations end to end (python -m pytest -m slow)
def test_selection_rules_are_kept_beside_the_baseline_cell(tiny_run, tmp_path):
    root, runs = tmp_path / "cells", tmp_path / "runs"
    _keep(tiny_run["run"], root / "seeds0-2" / "T" / "0")
    shutil.copytree(tiny_run["run"], runs / "seeds0-2" / "T" / "0")
    assert wu.add_selection(root, runs, episodes=2, log=lambda m: None) == ["T"]
    sel = json.loads((root / "seeds0-2" / "T" / "0" / "selection.json").read_text())
    assert sel["trained"] == "min_qc" and set(sel["results"]) == {
        "min_qc", "safe_then_reward", "first"}
    assert len(sel["results"]["first"]["normalized_reward"]) == 2  # one per seed
    md = wu.tables(root)
    assert "| min_qc (trained) |" in md and "| first |" in md
    assert wu.add_selection(root, runs, episodes=2, log=lambda m: None) == []  # kept: not again


def test_the_confirmation_cells_get_their_own_tables(tiny_run, tmp_path):
    """Kept seeds 3-5 cells (baseline and winner) get the same diagnostics in a section of their
    own; a winner's cell not yet run is said."""
    root = tmp_path / "cells"
    _keep(tiny_run["run"], root / "seeds0-2" / "BallRun" / "0")
    _keep(tiny_run["run"], root / "seeds3-5" / "BallRun" / "0")
    _keep(tiny_run["run"], root / "seeds3-5" / "CarGoal2" / "b", metrics=False)
    md = wu.tables(root)
    assert "## Confirmation (seeds 3-5)" in md
    conf = md.split("## Confirmation (seeds 3-5)")[1]
    res = json.loads((tiny_run["run"] / "results.json").read_text())
    row = next(ln for ln in conf.splitlines() if ln.startswith("| BallRun | 0 (default)"))
    assert f"| {res['normalized_reward']['mean']:.3g} |" in row
    assert "| BallRun | b (V_c >= 0) | not run |" in conf
    assert "| CarGoal2 | 0 (default) | not run |" in conf
    assert "a (LayerNorm critics)" not in conf  # only the candidates the confirmation ran
    assert "No training metrics kept: CarGoal2/b." in conf
    assert "## Confirmation" not in wu.tables(tmp_path / "none")  # no seeds 3-5: no section

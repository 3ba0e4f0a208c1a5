"""experiments/r2pac_decision/decide.py applies PROTOCOL.md's rule as written: checked here on
made-up scores before any decision run exists."""
import json
from pathlib import Path

import pytest
from conftest import load_script

decide = load_script("experiments/r2pac_decision/decide.py", "decide_rule")
TASKS = decide.DECISION_TASKS


def _scores(base, **cands):
    """base: [(R, C)] per decision task; cands: id -> [(R, C)]."""
    out = {"0": dict(zip(TASKS, base))}
    for c in ("a", "b", "c"):
        out[c] = dict(zip(TASKS, cands.get(c, base)))
    return out


BASE = [(0.10, 0.5)] * 7


def test_five_of_seven_higher_and_no_flip_qualifies_four_does_not():
    five = [(0.30, 0.5)] * 5 + [(0.05, 0.5)] * 2
    four = [(0.30, 0.5)] * 4 + [(0.05, 0.5)] * 3
    v = decide.decide(_scores(BASE, a=five, b=four))
    assert v["candidates"]["a"]["qualifies"] and not v["candidates"]["b"]["qualifies"]
    assert v["winner"] == "a"


def test_a_safe_task_made_unsafe_disqualifies_whatever_the_reward():
    big = [(0.9, 0.5)] * 6 + [(0.9, 1.2)]
    v = decide.decide(_scores(BASE, c=big))
    assert v["candidates"]["c"]["made_unsafe"] == [TASKS[-1]]
    assert v["winner"] is None  # a and b equal the baseline: reward higher on no task


def test_an_unsafe_task_staying_unsafe_is_no_flip():
    base = [(0.10, 0.5)] * 6 + [(0.10, 1.5)]
    v = decide.decide(_scores(base, b=[(0.2, 0.5)] * 6 + [(0.2, 2.0)]))
    assert v["winner"] == "b" and v["candidates"]["b"]["made_unsafe"] == []


def test_the_largest_median_gain_wins_and_ties_go_to_the_smaller_change():
    a = [(0.20, 0.5)] * 7  # median gain 0.10
    c = [(0.40, 0.5)] * 7  # median gain 0.30
    assert decide.decide(_scores(BASE, a=a, c=c))["winner"] == "c"
    assert decide.decide(_scores(BASE, a=c, c=c))["winner"] == "a"
    assert decide.decide(_scores(BASE, b=c, c=c))["winner"] == "b"


def test_confirmation_needs_half_and_no_flip():
    tasks = decide.CONFIRMATION_TASKS
    assert len(tasks) == 11
    base = {t: (0.1, 0.5) for t in tasks}

    def conf(rewards, costs=None):
        costs = costs or [0.5] * 11
        return decide.confirm({"0": base, "a": dict(zip(tasks, zip(rewards, costs)))}, "a")

    assert conf([0.2] * 6 + [0.0] * 5)["confirmed"]
    assert not conf([0.2] * 5 + [0.0] * 6)["confirmed"]
    assert not conf([0.2] * 11, [0.5] * 10 + [1.0])["confirmed"]


@pytest.mark.parametrize("left", [7, 6, 4])
def test_a_task_left_out_scales_the_bar(left):
    need = decide.qualifies(_scores(BASE), "a", TASKS[:left])[1]["needed"]
    assert need == {7: 5, 6: 5, 4: 3}[left]


def test_file_mode_prints_the_path_alone(monkeypatch, capsys, tmp_path):
    """run.sh reads the pinned file's path from stdout: the simulators' import notes and the
    generation's output must not reach it (they once made every cell fail)."""
    mod = load_script("experiments/r2pac_decision/decide.py")
    f = tmp_path / "X.hdf5"

    def noisy(task, log=print, make=True):
        print("Failed to import warp: No module named 'warp'")  # what mujoco.mjx prints
        log(f"{task}: making it again")
        return f

    monkeypatch.setattr(mod, "pinned_file", noisy)
    assert mod.main(["--file", "HalfCheetahVelocity"]) == 0
    out = capsys.readouterr()
    assert out.out == f"{f}\n" and "warp" in out.err and "making it again" in out.err


def test_precision_rule_is_two_float32_stds_without_a_floor():
    from conftest import load_script

    cmp = load_script("experiments/precision/compare.py", "precision_compare")

    def res(r, rs, c, cs):
        return dict(normalized_reward=dict(mean=r, std=rs, per_seed=[r] * 3),
                    normalized_cost=dict(mean=c, std=cs, per_seed=[c] * 3))

    rows = cmp.verdicts({"T": {"default": res(0.5, 0.1, 0.0, 0.0),
                               "bf16": res(0.69, 0.3, 0.0, 0.0),
                               "highest": res(0.71, 0.0, 0.01, 0.0)}})
    got = {(r["mode"], r["metric"]): r["passed"] for r in rows}
    assert got == {("default", "reward"): True, ("default", "cost"): True,
                   ("bf16", "reward"): True, ("bf16", "cost"): True,
                   ("highest", "reward"): False, ("highest", "cost"): False}


def test_a_task_left_out_is_read_from_its_record_and_refused_when_unknown(tmp_path):
    rec = tmp_path / "left_out.json"
    assert decide.left_out(rec) == {} and decide.tasks_left(TASKS, rec) == TASKS
    rec.write_text('{"Walker2dVelocity": "did not regenerate"}')
    left = decide.tasks_left(TASKS, rec)
    assert "Walker2dVelocity" not in left and len(left) == 6
    assert decide.qualifies(_scores(BASE), "a", left)[1]["needed"] == 5
    rec.write_text('{"AntCircle": "x"}')
    with pytest.raises(ValueError, match="AntCircle is not a decision task"):
        decide.left_out(rec)


def test_the_verdict_is_taken_on_the_tasks_left(tmp_path, monkeypatch, capsys):
    """main(): the left-out task's cells are not asked for; the bar is 5 of the 6 left."""
    mod = load_script("experiments/r2pac_decision/decide.py", "decide_main")
    rec = tmp_path / "left_out.json"
    rec.write_text('{"Walker2dVelocity": "did not regenerate"}')
    monkeypatch.setattr(mod, "LEFT_OUT", rec)
    root = tmp_path / "cells"
    for t in mod.tasks_left(mod.DECISION_TASKS, rec):
        for c, r in (("0", 0.1), ("a", 0.3), ("b", 0.1), ("c", 0.1)):
            d = root / "seeds0-2" / t / c
            d.mkdir(parents=True)
            (d / "results.json").write_text(json.dumps(dict(
                normalized_reward=dict(mean=r), normalized_cost=dict(mean=0.5))))
    out = tmp_path / "decision.json"
    assert mod.main(["--runs", str(root), "--out", str(out)]) == 0
    got = json.loads(out.read_text())
    assert got["decision"]["winner"] == "a" and "Walker2dVelocity" not in got["tasks"]
    assert got["decision"]["candidates"]["a"]["needed"] == 5
    assert "Walker2dVelocity: left out of the decision" in capsys.readouterr().out


def test_a_task_left_out_of_the_confirmation_only(tmp_path, monkeypatch, capsys):
    """A file that does not regenerate when the confirmation needs it: the decision keeps the
    task (its seeds 0-2 cells exist), the confirmation is taken on the 9 comparisons left, and
    at least half of 9 is 5."""
    mod = load_script("experiments/r2pac_decision/decide.py", "decide_conf")
    dec, conf = tmp_path / "left_out.json", tmp_path / "left_out_confirmation.json"
    dec.write_text('{"Walker2dVelocity": "did not regenerate"}')
    conf.write_text('{"HopperVelocity": "did not regenerate here"}')
    monkeypatch.setattr(mod, "LEFT_OUT", dec)
    monkeypatch.setattr(mod, "LEFT_OUT_CONFIRMATION", conf)
    root = tmp_path / "cells"

    def cell(seeds, t, c, r):
        d = root / seeds / t / c
        d.mkdir(parents=True)
        (d / "results.json").write_text(json.dumps(dict(
            normalized_reward=dict(mean=r), normalized_cost=dict(mean=0.5))))

    for t in mod.tasks_left(mod.DECISION_TASKS, dec):
        for c, r in (("0", 0.1), ("a", 0.1), ("b", 0.3), ("c", 0.1)):
            cell("seeds0-2", t, c, r)
    left = mod.tasks_left(mod.CONFIRMATION_TASKS, dec, mod.left_out_of_confirmation(conf))
    assert len(left) == 9 and "HopperVelocity" not in left
    for i, t in enumerate(left):  # b higher on the first 5 of the 9
        cell("seeds3-5", t, "0", 0.1)
        cell("seeds3-5", t, "b", 0.3 if i < 5 else 0.0)
    out = tmp_path / "decision.json"
    assert mod.main(["--runs", str(root), "--out", str(out)]) == 0
    got = json.loads(out.read_text())
    assert "HopperVelocity" in got["tasks"] and "HopperVelocity" not in got["confirmation_tasks"]
    assert got["confirmation"] == dict(confirmed=True, made_unsafe=[], comparisons=9,
                                       reward_higher_on=list(left[:5]))
    assert "HopperVelocity: left out of the confirmation" in capsys.readouterr().out
    # 4 of 9 is fewer than half
    (root / "seeds3-5" / left[4] / "b" / "results.json").write_text(json.dumps(dict(
        normalized_reward=dict(mean=0.0), normalized_cost=dict(mean=0.5))))
    assert mod.main(["--runs", str(root), "--out", str(out)]) == 0
    assert not json.loads(out.read_text())["confirmation"]["confirmed"]
    conf.write_text('{"AntCircle": "x"}')
    with pytest.raises(ValueError, match="AntCircle is not a confirmation task"):
        mod.left_out_of_confirmation(conf)


def test_a_pinned_file_is_made_again_against_its_archived_log(tmp_path, monkeypatch):
    """decide.py --file: the generation is given the pinned file's archived log, and its stop
    at a differing update (exit 3) reads as a file that does not regenerate."""
    import subprocess

    mod = load_script("experiments/r2pac_decision/decide.py", "decide_file")
    monkeypatch.setenv("R2PAC_DATA_DIR", str(tmp_path))
    calls = []

    def run(cmd, **kw):
        calls.append(cmd)
        return subprocess.CompletedProcess(cmd, 3)

    monkeypatch.setattr(subprocess, "run", run)
    with pytest.raises(ValueError, match="parted from the pinned file's log .* does not "
                                         "regenerate bit for bit here"):
        mod.pinned_file("HalfCheetahVelocity", log=lambda m: None)
    cmd = calls[0]
    log = Path(cmd[cmd.index("--expect-log") + 1])
    assert log.is_file()
    assert log.name == "HalfCheetahVelocity-generated-ppolag-v2-s0-n2495.log.jsonl.gz"
    monkeypatch.setattr(subprocess, "run", lambda cmd, **kw: subprocess.CompletedProcess(cmd, 1))
    with pytest.raises(ValueError, match=r"making .* failed \(exit 1"):
        mod.pinned_file("HalfCheetahVelocity", log=lambda m: None)


def test_run_sh_skips_a_task_left_out_of_the_confirmation_and_runs_the_others(tmp_path):
    """run.sh confirm: a task in either record is skipped before any file or cell; another
    task goes on to its pinned file (here a stand-in decide.py that refuses it)."""
    import shutil
    import subprocess

    here = tmp_path / "experiments" / "r2pac_decision"
    here.mkdir(parents=True)
    shutil.copy(Path(__file__).parents[2] / "experiments" / "r2pac_decision" / "run.sh", here)
    (here / "left_out.json").write_text('{"Walker2dVelocity": "x"}')
    (here / "left_out_confirmation.json").write_text('{"BallRun": "did not regenerate"}')
    (here / "decide.py").write_text("import sys\nprint('asked', sys.argv[1:], file=sys.stderr)\n"
                                    "sys.exit(1)\n")
    out = subprocess.run(["bash", str(here / "run.sh"), "confirm", "b"], capture_output=True,
                         text=True, env={"PATH": __import__("os").environ["PATH"],
                                         "TASKS": "BallRun Walker2dVelocity CarGoal2",
                                         "OUT": str(tmp_path / "runs")})
    said = out.stdout + out.stderr
    assert "== BallRun: left out of the confirmation" in said
    assert "== Walker2dVelocity: left out of the confirmation" in said
    assert "'--file', 'BallRun'" not in said and "'--file', 'CarGoal2'" in said
    assert said.count("!! CarGoal2: no pinned file") == 2  # its two cells, 0 and b

"""The decision rule of PROTOCOL.md, as code written before any decision run.

    python experiments/r2pac_decision/decide.py [--runs experiments/r2pac_decision/cells]

reads each cell's results.json (cells/seeds0-2/TASK/ID and, for the confirmation,
seeds3-5/TASK/ID: the finished cells that `run.sh keep` copied from runs/r2pac_decision into the
repo), prints the verdict with its numbers and writes them to
experiments/r2pac_decision/decision.json. A cell not yet run is listed as missing: no verdict
is taken on missing cells.
"""
from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
from pathlib import Path
from typing import Optional

DECISION_TASKS = ("HalfCheetahVelocity", "Walker2dVelocity", "HopperVelocity", "BallRun",
                  "DroneRun", "CarGoal2", "PointGoal2")
CONFIRMATION_TASKS = DECISION_TASKS + ("AntVelocity", "BallCircle", "CarButton1", "PointButton1")
CANDIDATES = {"0": (), "a": ("critic_layer_norm=true",), "b": ("vc_nonneg=true",),
              "c": ("critic_layer_norm=true", "vc_nonneg=true")}
ORDER = ("a", "b", "c")  # ties go to the smaller change: a or b before c; a before b


def qualifies(scores: dict, x: str, tasks) -> tuple[bool, dict]:
    """scores[cand][task] = (R, C), means over seeds. Rule 1 of the protocol."""
    flips = [t for t in tasks if scores["0"][t][1] < 1 <= scores[x][t][1]]
    better = [t for t in tasks if scores[x][t][0] > scores["0"][t][0]]
    need = math.ceil(5 * len(tasks) / 7)
    gains = [scores[x][t][0] - scores["0"][t][0] for t in tasks]
    return (not flips and len(better) >= need), dict(
        made_unsafe=flips, reward_higher_on=better, needed=need,
        median_gain=statistics.median(gains))


def decide(scores: dict, tasks=DECISION_TASKS) -> dict:
    """Rules 1-2: the winning candidate id, or None (the default stays), with the numbers."""
    detail = {x: qualifies(scores, x, tasks) for x in ORDER}
    ok = [x for x in ORDER if detail[x][0]]
    winner = None
    if ok:
        best = max(round(detail[x][1]["median_gain"], 3) for x in ok)
        winner = next(x for x in ORDER if x in ok
                      and round(detail[x][1]["median_gain"], 3) == best)
    return dict(winner=winner, candidates={x: dict(qualifies=q, **d)
                                           for x, (q, d) in detail.items()})


def confirm(scores: dict, winner: str, tasks=CONFIRMATION_TASKS) -> dict:
    """Rule 3: the winner stands if it makes no safe task unsafe and raises the mean reward on
    at least half of the comparisons."""
    flips = [t for t in tasks if scores["0"][t][1] < 1 <= scores[winner][t][1]]
    better = [t for t in tasks if scores[winner][t][0] > scores["0"][t][0]]
    return dict(confirmed=not flips and 2 * len(better) >= len(tasks), made_unsafe=flips,
                reward_higher_on=better, comparisons=len(tasks))


def read_scores(root: Path, seeds: str, tasks, cands) -> tuple[dict, list]:
    """{cand: {task: (R, C)}} from root/seeds/TASK/ID/results.json, and the missing cells."""
    scores: dict = {c: {} for c in cands}
    missing = []
    for c in cands:
        for t in tasks:
            f = root / seeds / t / c / "results.json"
            if not f.is_file():
                missing.append(f"{seeds}/{t}/{c}")
                continue
            r = json.loads(f.read_text())
            scores[c][t] = (r["normalized_reward"]["mean"], r["normalized_cost"]["mean"])
    return scores, missing


MANIFEST = Path(__file__).resolve().parents[1] / "table1" / "cpu-quick" / "manifest.json"
# PROTOCOL.md: a task whose file does not regenerate bit for bit is left out, the bar scaled to
# the tasks left. Each entry: {task: why} (the digests, the machine), written when it happens.
ARCHIVE = Path(__file__).resolve().parents[2] / "experiments" / "data_factory" / "results_v2"
LEFT_OUT = Path(__file__).with_name("left_out.json")
# A task whose file did not regenerate when the confirmation needed it, after the decision was
# taken on it (its seeds 0-2 cells ran on the pinned file): out of the confirmation only, whose
# bar ("at least half") is then taken on the comparisons left, as PROTOCOL.md scales the decision's
LEFT_OUT_CONFIRMATION = Path(__file__).with_name("left_out_confirmation.json")


def left_out(path: Optional[Path] = None, allowed=DECISION_TASKS,
             what: str = "decision") -> dict[str, str]:
    """The tasks left out (of the decision by default), with why ({} where none is)."""
    path = LEFT_OUT if path is None else path
    if not path.is_file():
        return {}
    out = json.loads(path.read_text())
    unknown = [t for t in out if t not in allowed]
    if unknown:
        raise ValueError(f"{path}: {', '.join(unknown)} is not a {what} task")
    return out


def left_out_of_confirmation(path: Optional[Path] = None) -> dict[str, str]:
    """The confirmation's own record of tasks left out (those of the decision are out too)."""
    return left_out(LEFT_OUT_CONFIRMATION if path is None else path, CONFIRMATION_TASKS,
                    "confirmation")


def tasks_left(tasks, path: Optional[Path] = None, *more: dict) -> tuple:
    gone = dict(left_out(path))
    for m in more:
        gone.update(m)
    return tuple(t for t in tasks if t not in gone)


def pin(task: str) -> dict:
    """The pinned file of a task: {file, sha256 (of the arrays), version}."""
    return json.loads(MANIFEST.read_text())["datasets"][task]


def pinned_file(task: str, make: bool = True, log=print) -> Path:
    """The task's pinned file in the data cache, made again first where missing (at the budget
    its name records), and refused unless its arrays' digest is the pin."""
    import subprocess

    from r2pac_jax.data import factory, load_dsrl
    from r2pac_jax.tasks import get_task

    want = pin(task)
    path = factory.cache_dir() / want["file"]
    if not path.is_file() and make:
        cmd = [sys.executable] + factory.make_command(task, want["file"])
        # the pinned file's archived log: a machine that does not make it again bit for bit is
        # found at the first update that differs, not hours later by the digest
        archived = ARCHIVE / task / (Path(want["file"]).stem + ".log.jsonl.gz")
        if archived.is_file():
            cmd += ["--expect-log", str(archived)]
        log(f"{task}: making {want['file']} again: {' '.join(cmd[1:])}")
        done = subprocess.run(cmd, stdout=sys.stderr)  # stdout carries the path only
        if done.returncode == 3:
            raise ValueError(f"{task}: the generation of {want['file']} parted from the pinned "
                             f"file's log ({archived}; the update is named above): the file "
                             "does not regenerate bit for bit here; PROTOCOL.md leaves the task "
                             "out of the decision")
        if done.returncode != 0:
            raise ValueError(f"{task}: making {want['file']} failed (exit {done.returncode}; "
                             "its error is above)")
    if not path.is_file():
        raise FileNotFoundError(f"{path}: the pinned file of {task} is not on this machine")
    t = get_task(task)
    digest = load_dsrl(path, t.obs_dim, t.act_dim, t.name).digest()
    if digest != want["sha256"]:
        raise ValueError(f"{path}: its arrays' sha256 {digest[:12]}... is not the pin "
                         f"{want['sha256'][:12]}...: the file did not regenerate bit for bit; "
                         "PROTOCOL.md leaves the task out of the decision")
    return path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="decide.py")
    ap.add_argument("--runs", default=str(Path(__file__).with_name("cells")))
    ap.add_argument("--out", default=str(Path(__file__).with_name("decision.json")))
    ap.add_argument("--file", metavar="TASK", help="print the task's pinned file (made again "
                    "where missing, its digest checked) and exit")
    args = ap.parse_args(argv)
    if args.file:
        import contextlib

        # run.sh reads the path from stdout: everything else (the simulators' import notes,
        # the generation's progress) goes to stderr
        try:
            with contextlib.redirect_stdout(sys.stderr):
                path = pinned_file(args.file, log=lambda m: print(m, file=sys.stderr))
        except (FileNotFoundError, ValueError) as e:
            print(f"error: {e}", file=sys.stderr)
            return 1
        print(path)
        return 0
    root = Path(args.runs)
    gone = left_out()
    for t, why in gone.items():
        print(f"{t}: left out of the decision ({why})")
    conf_gone = left_out_of_confirmation()
    for t, why in conf_gone.items():
        print(f"{t}: left out of the confirmation ({why})")
    tasks = tasks_left(DECISION_TASKS)
    conf_tasks = tasks_left(CONFIRMATION_TASKS, None, conf_gone)
    scores, missing = read_scores(root, "seeds0-2", tasks, CANDIDATES)
    if missing:
        print(f"{len(missing)} decision cells missing (no verdict): {', '.join(missing)}")
        return 1
    verdict = decide(scores, tasks)
    out = dict(decision=verdict, tasks=list(tasks), left_out=gone,
               confirmation_tasks=list(conf_tasks), confirmation_left_out=conf_gone,
               scores={c: {t: list(v) for t, v in s.items()} for c, s in scores.items()})
    print(json.dumps(verdict, indent=1))
    if verdict["winner"] is not None:
        conf, missing = read_scores(root, "seeds3-5", conf_tasks, ("0", verdict["winner"]))
        if missing:
            print(f"confirmation: {len(missing)} cells missing: {', '.join(missing)}")
        else:
            out["confirmation"] = confirm(conf, verdict["winner"], conf_tasks)
            out["confirmation_scores"] = {c: {t: list(v) for t, v in s.items()}
                                          for c, s in conf.items()}
            print(json.dumps(out["confirmation"], indent=1))
    Path(args.out).write_text(json.dumps(out, indent=1, sort_keys=True) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

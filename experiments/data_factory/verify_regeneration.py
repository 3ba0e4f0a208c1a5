"""Is a regenerated learned-behaviour file the one the committed results were made on?

A file lives in one machine's cache; the committed record of it is its sha256 (pinned in the
Table-1 manifest), its card and, since 2026-12-03, its training log (results_v2/TASK). This
compares a file made anew with all three and prints what agrees:

    python experiments/data_factory/verify_regeneration.py FILE [--manifest M] [--archive DIR]

- arrays: the sha256 of the file's arrays (`Dataset.digest`, what the Table-1 manifest pins for
  its task) against the pin; the file's own bytes are printed too, but HDF5 writes its
  creation time into the file, so two identical generations differ there;
- log: the new training log (FILE.log.jsonl, written beside the file) against the archived
  one, update by update over every logged quantity but the wall-clock ones; the first update
  that differs is named;
- card: the card's data fields (counts, ranges, split) against the archived card; the two
  cards' software versions (python, jax, numpy, mujoco, pybullet) and machines (CPU model and
  count) are printed beside, and those that differ named, to read a disagreement by (not a
  check of their own).
Exit 0 when every record that exists agrees, 1 otherwise. Written as JSON to FILE.regen.json.

    python experiments/data_factory/verify_regeneration.py --probe TASK[,TASK...]|all
        [--updates 3] [--out probe.jsonl]

asks, before hours are spent, whether this machine makes a pinned file again at all: each
task's pinned file (the Table-1 manifest) is generated for its first UPDATES updates in a
scratch cache, against its archived log (`data make --expect-log --stop-after`), and the first
update that differs is named. A file whose first updates agree may still part later (one did at
its second); one that parts is not made here bit for bit.
"""
from __future__ import annotations

import argparse
import gzip
import hashlib
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CARD_KEYS = ("trajectories", "transitions", "safe_trajectories", "unsafe_trajectories",
             "return_range", "cost_range", "normalised_return_range")


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _rows(lines) -> list[dict]:
    return [json.loads(x) for x in lines if x.strip()]


def _side_by_side(new: dict, old: dict) -> dict:
    """Two cards' entries for one key, and the names whose values differ."""
    return dict(new=new, old=old,
                differ=sorted(k for k in set(new) | set(old) if new.get(k) != old.get(k)))


def compare_logs(new: list[dict], old: list[dict]) -> dict:
    """First update where a logged quantity differs (None when all shared updates agree): the
    generator's own comparison (`collect.log_difference`: wall-clock fields left out, the keys
    both logs have)."""
    from r2pac_jax.data.factory.collect import log_difference

    for i, (a, b) in enumerate(zip(new, old)):
        diff = log_difference(a, b)
        if diff:
            return dict(agree=False, updates_compared=i + 1, first_difference=a.get("update"),
                        keys=list(diff), new={k: v[0] for k, v in diff.items()},
                        old={k: v[1] for k, v in diff.items()})
    return dict(agree=len(new) == len(old), updates_compared=min(len(new), len(old)),
                first_difference=None, new_updates=len(new), old_updates=len(old))


def verify(file: Path, manifest: Path, archive: Path) -> dict:
    if not file.exists():
        raise SystemExit(f"error: no file {file}")
    from r2pac_jax.data import load_dsrl
    from r2pac_jax.data.factory import card_path
    from r2pac_jax.tasks import get_task

    card_file = card_path(file)
    if not card_file.exists():
        raise SystemExit(f"error: {file} has no card ({card_file}): the generation has not "
                         "finished")
    card = json.loads(card_file.read_text())
    task = card["task"]
    out: dict = dict(file=str(file), task=task)
    pins = json.loads(manifest.read_text()).get("datasets", {}) if manifest.exists() else {}
    pin = pins.get(task)
    t = get_task(task)
    digest = load_dsrl(str(file), obs_dim=t.obs_dim, act_dim=t.act_dim, task_name=task).digest()
    out["file_sha256"] = sha256(file)
    if pin and pin.get("file") == file.name:
        out["arrays"] = dict(agree=digest == pin["sha256"], sha256=digest, pinned=pin["sha256"])
    else:
        out["arrays"] = dict(agree=None, sha256=digest, pinned=None,
                             note=f"{manifest} pins no file of this name for {task}")
    old_log = archive / task / f"{file.stem}.log.jsonl.gz"  # task_pipeline.sh archives it so
    new_log = file.with_suffix(".log.jsonl")
    if old_log.exists() and new_log.exists():
        with gzip.open(old_log, "rt") as f:
            old = _rows(f)
        out["log"] = compare_logs(_rows(new_log.read_text().splitlines()), old)
    else:
        out["log"] = dict(agree=None, note="no archived log or no new log")
    old_card = archive / task / card_file.name
    if old_card.exists():
        a, b = card, json.loads(old_card.read_text())
        diff = {k: dict(new=a.get(k), old=b.get(k)) for k in CARD_KEYS if a.get(k) != b.get(k)}
        out["card"] = dict(agree=not diff, differences=diff)
        # not a check: the software and the machine (CPU model, CPUs XLA may use) each side ran,
        # to read a disagreement by (cards before 2026-12-04 21:00 name no mujoco version, before
        # 2026-12-06 no machine)
        for key in ("versions", "machine"):
            out[key] = _side_by_side(a.get(key) or {}, b.get(key) or {})
    else:
        out["card"] = dict(agree=None, note=f"no archived card {old_card}")
    out["agree"] = all(out[k]["agree"] is not False for k in ("arrays", "log", "card"))
    from r2pac_jax.io import atomic_write_json

    atomic_write_json(Path(f"{file}.regen.json"), out)
    return out


def probe(task: str, pin: dict, archive: Path, updates: int, scratch: Path) -> dict:
    """Generate the pinned file's first `updates` updates in `scratch` against its archived
    log: {task, agree (through those updates), updates_compared, first_difference, keys}."""
    import os
    import subprocess
    import time

    from r2pac_jax.data.factory import make_command
    from r2pac_jax.data.factory.collect import read_log

    name = pin["file"]
    log = archive / task / (Path(name).stem + ".log.jsonl.gz")
    if not log.is_file():
        return dict(task=task, file=name, agree=None, note=f"no archived log {log}")
    cmd = [sys.executable] + make_command(task, name) + ["--expect-log", str(log),
                                                         "--stop-after", str(updates)]
    t0 = time.time()
    done = subprocess.run(cmd, env=dict(os.environ, R2PAC_DATA_DIR=str(scratch)),
                          capture_output=True, text=True)
    partial = scratch / f"{name}.partial" / "log.jsonl"
    out = dict(task=task, file=name, wall_s=round(time.time() - t0, 1))
    if done.returncode not in (0, 3) or not partial.is_file():
        tail = (done.stderr or done.stdout).strip().splitlines()[-1:]
        return dict(out, agree=None, note=f"the generation failed (exit {done.returncode}): "
                                          f"{tail[0] if tail else ''}")
    out.update(compare_logs(read_log(partial), read_log(log)))
    if done.returncode == 0:  # every update made agrees (compare_logs also wants equal lengths)
        out["agree"] = True
    return out


def main(argv=None) -> int:
    if argv is None:
        argv = sys.argv[1:]
    if "--probe" in argv:
        return main_probe(argv)
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("file", type=Path)
    ap.add_argument("--manifest", type=Path,
                    default=ROOT / "experiments" / "table1" / "cpu-quick" / "manifest.json")
    ap.add_argument("--archive", type=Path,
                    default=ROOT / "experiments" / "data_factory" / "results_v2")
    args = ap.parse_args(argv)
    out = verify(args.file, args.manifest, args.archive)
    print(json.dumps(out, indent=1))
    return 0 if out["agree"] else 1


def main_probe(argv) -> int:
    import tempfile

    ap = argparse.ArgumentParser(description="probe whether pinned files regenerate here")
    ap.add_argument("--probe", required=True, help="TASK[,TASK...] or all (the manifest's)")
    ap.add_argument("--updates", type=int, default=3)
    ap.add_argument("--out", type=Path, default=None, help="JSON lines, one per task")
    ap.add_argument("--manifest", type=Path,
                    default=ROOT / "experiments" / "table1" / "cpu-quick" / "manifest.json")
    ap.add_argument("--archive", type=Path,
                    default=ROOT / "experiments" / "data_factory" / "results_v2")
    args = ap.parse_args(argv)
    if args.updates < 1:
        print(f"error: --updates must be >= 1, got {args.updates}", file=sys.stderr)
        return 2
    pins = json.loads(args.manifest.read_text())["datasets"]
    tasks = sorted(pins) if args.probe == "all" else [t for t in args.probe.split(",") if t]
    unknown = [t for t in tasks if t not in pins]
    if unknown:
        print(f"error: {', '.join(unknown)}: no pinned file in {args.manifest} (pinned: "
              f"{', '.join(sorted(pins))})", file=sys.stderr)
        return 2
    rows = []
    for t in tasks:
        with tempfile.TemporaryDirectory(prefix=f"probe-{t}-") as scratch:
            r = probe(t, pins[t], args.archive, args.updates, Path(scratch))
        rows.append(r)
        said = ("agrees through update %d" % r["updates_compared"] if r.get("agree")
                else f"parts at update {r['first_difference']} ({', '.join(r['keys'])})"
                if r.get("agree") is False else r.get("note", ""))
        print(f"{t}: {said} [{r.get('wall_s', 0)} s]", flush=True)
        if args.out:
            with open(args.out, "a") as f:
                f.write(json.dumps(r) + "\n")
    return 0 if all(r.get("agree") for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())

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


def main(argv=None) -> int:
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


if __name__ == "__main__":
    sys.exit(main())

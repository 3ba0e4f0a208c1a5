"""Table 1 in one command: every task x algorithm x seed that is missing, then the paper's table.

    python -m r2pac_jax.table --tasks HalfCheetahVelocity,CarGoal1 \
        [--algos bc-all-mlp,cpq,coptidice,bcq-lag,r2pac] [--seeds 3] [--preset auto] \
        [--episodes 20] [--steps N] [--estimate] --out DIR

Each (task, algorithm) is one `Run` in DIR/TASK/ALGO (its seeds vmapped: one compiled program),
resumed where it stopped; finished ones are read back. DIR/manifest.json pins the preset, the
seeds, the episodes and each task's dataset (file name, data version, sha256): a DIR made with
another preset or other data is refused, and so is a table whose tasks mix data versions.
Writes DIR/table.md (`report.results_table`: safe bold, best and second-best safe reward
marked, unsafe marked with a dagger, per-family averages), DIR/table.csv and DIR/table.png
(normalised reward against cost, a panel per task). `--estimate` times one compiled block of
every algorithm on the first task and each cell's evaluation policy, prints the wall estimate
and stops, making no data file (a task without one is timed on a stand-in of its shapes).

A table made in pieces (sessions, machines, a second directory beside a running one):
`--merge-from SRC` first brings SRC's finished cells and its manifest's tasks into DIR (same
preset, seeds and episodes, no task on other data; DIR's own cells win; `--results-only` copies
each cell's results.json and config.json alone, the light copy a repository keeps);
`--table-only` runs nothing and writes the table from DIR's finished cells of `--algos`
(without `--algos`: of every algorithm with one, in the paper's column order), for `--tasks` or
every task in DIR's manifest.
"""
from __future__ import annotations

import argparse
import csv
import io
import json
import re
import shlex
import shutil
import sys
from pathlib import Path
from typing import Optional

from r2pac_jax.agents import algo_module, algo_names
from r2pac_jax.config import ConfigError, resolve_preset
from r2pac_jax.data import factory, load_task_dataset
from r2pac_jax.data.dsrl import dsrl_dirs
from r2pac_jax.errors import R2pacError
from r2pac_jax.io import (atomic_write_json, atomic_write_text, claim_directory, marker_kind,
                          writing)
from r2pac_jax.planner import plan
from r2pac_jax.report import SAFE_LIMIT, plot_table, results_table
from r2pac_jax.run_dir import is_legacy_run
from r2pac_jax.tasks import get_task

# r2pac_jax.loop, .lanes and .train import JAX: they are imported where a cell is trained or
# timed, so that `--help` and `--table-only` start without it.


DEFAULT_ALGOS = "bc-all-mlp,cpq,coptidice,bcq-lag,r2pac"
# Column order of a table whose columns are found, not named: the paper's Table 1 (baselines,
# then R2PAC); algorithms it lacks go in between, in the registry's order.
_BASELINE_ORDER = ("bc-all", "bc-safe", "bc-all-mlp", "bc-safe-mlp", "cpq", "coptidice", "bcq-lag",
                   "cdt", "trebi", "fisor")


def column_order(algos) -> list[str]:
    """`algos` in the table's column order: the paper's baselines, other agents, R2PAC's."""
    names = algo_names()

    def rank(a):
        if a in _BASELINE_ORDER:
            return (0, _BASELINE_ORDER.index(a))
        return (2 if a.startswith("r2pac") else 1, names.index(a) if a in names else len(names))

    return sorted(algos, key=rank)


def data_version(path: str) -> str:
    """The data version a dataset file's name carries: v2 learned, v1 scripted, DSRL, other."""
    name = Path(path).name
    m = re.search(r"-generated-ppolag-v(\d+)-", name)
    if m:
        return f"learned-v{m.group(1)}"
    if re.search(r"-generated-ppolag-s\d+", name):
        return "learned-v1"
    if "-generated-" in name:
        return "scripted-v1"
    if name.startswith("Offline") or "dsrl" in str(path).lower():
        return "dsrl"
    return "other"


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m r2pac_jax.table",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("--tasks", default=None, help="comma-separated task names (required "
                    "unless --table-only)")
    ap.add_argument("--algos", default=None, help=f"comma-separated (default {DEFAULT_ALGOS}; "
                    "with --table-only: every algorithm with a finished cell in --out)")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--preset", default="auto", help="auto (quick on a CPU, paper on an "
                    "accelerator) | quick | paper")
    ap.add_argument("--episodes", type=int, default=20, help="evaluation episodes per seed")
    ap.add_argument("--steps", type=int, default=None, help="gradient steps per phase for every "
                    "algorithm (default: each algorithm's preset)")
    ap.add_argument("--physics", default="auto")
    ap.add_argument("--out", required=True)
    ap.add_argument("--estimate", action="store_true", help="time one block per algorithm, "
                    "print the estimated wall, run nothing")
    ap.add_argument("--merge-from", action="append", default=[], metavar="SRC",
                    help="a table directory whose finished cells and tasks join --out first "
                         "(repeatable)")
    ap.add_argument("--results-only", action="store_true", help="with --merge-from: copy each "
                    "cell's results.json and config.json only (a light table to commit)")
    ap.add_argument("--table-only", action="store_true", help="train nothing: the table from "
                    "the finished cells in --out")
    ap.add_argument("--no-progress", action="store_true")
    return ap


def _configs(task, algos, args):
    """Each algorithm's cell config on `task`: one evaluation, at the end (the table reports
    the final policy)."""
    return {a: plan(task, a, args.preset, dict(seeds=args.seeds, steps=args.steps,
                                               eval_episodes=args.episodes if task.has_env else 0),
                    final_eval_only=True)
            for a in algos}


def _manifest(out: Path, args, datasets: dict) -> dict:
    """The identity of the table in DIR; refuse a DIR of another preset, seeds or data."""
    want = dict(_identity(args), datasets=datasets)
    path = out / "manifest.json"
    if path.exists():
        have = json.loads(path.read_text())
        _check_identity(have, args, out)
        _check_same_data(have["datasets"], datasets, out, "this run would use")
        have["datasets"].update(datasets)
        want["datasets"] = have["datasets"]
    _check_one_version(want["datasets"])
    atomic_write_json(path, want)
    return want


_IDENTITY = ("preset", "seeds", "episodes", "steps")


def _identity(args) -> dict:
    return {k: getattr(args, k) for k in _IDENTITY}


def _check_identity(have: dict, args, where: Path) -> None:

    for k, v in _identity(args).items():
        if have.get(k) != v:
            raise ConfigError(f"{where} holds a table made with {k}={have.get(k)!r}, not "
                              f"{v!r}: use another --out (a table never mixes them)")


def _check_same_data(have: dict, new: dict, where: Path, verb: str) -> None:

    for t, d in new.items():
        old = have.get(t)
        if old is not None and (old["sha256"] != d["sha256"] or old["version"] != d["version"]):
            raise ConfigError(f"{where} holds {t} results on {old['file']} ({old['version']}); "
                              f"{verb} {d['file']} ({d['version']}): use another --out (a table "
                              "never mixes data)")


def _check_pinned_present(out: Path, tasks) -> None:
    """A task whose data `out` already pins must find that very file here before anything is
    loaded: a missing one would otherwise be generated anew (hours for the learned data), and
    the new file, made elsewhere or by other code, may not be the pinned bytes."""
    path = out / "manifest.json"
    if not path.exists():
        return
    pinned = json.loads(path.read_text()).get("datasets", {})
    where = [factory.cache_dir(), *dsrl_dirs()]
    for t in tasks:
        d = pinned.get(t.name)
        if d is not None and not any((w / d["file"]).exists() for w in where):
            raise ConfigError(
                f"{out} pins {t.name}'s data to {d['file']} (sha256 {d['sha256'][:12]}...), which "
                f"is not in {' or '.join(map(str, where))}: copy that file there, or use another "
                "--out (a table never mixes data, and a file made anew may differ)")


def _check_one_version(datasets: dict) -> None:

    versions = {d["version"] for d in datasets.values()}
    if len(versions) > 1:
        raise ConfigError(f"the table's tasks would mix data versions {sorted(versions)}: make "
                          "every task's data with one recipe (python -m r2pac_jax.data make "
                          "--task T --source ppo-lagrangian), or make one table per version")


def merge_from(out: Path, src: Path, args, log) -> int:
    """Bring SRC's finished cells (TASK/ALGO with a results.json) and its manifest's tasks into
    OUT, where OUT lacks them; the number of cells copied. Refuses SRC or OUT of another preset,
    seeds or episodes, and a task whose data differ between the two. An unfinished run in OUT is
    kept (it resumes), even where SRC has that cell finished. `args.results_only`: a cell's
    results.json and config.json only (no checkpoints, policy or logs).

    OUT's manifest is read and rewritten here, at the merge, so two table directories merged
    into one OUT in turn both keep their tasks (copying a manifest over OUT's would drop the
    tasks another merge had added since)."""


    if not (src / "manifest.json").is_file():
        raise ConfigError(f"--merge-from {src}: no manifest.json there; give a directory a "
                          "table command wrote (its --out)")
    theirs = json.loads((src / "manifest.json").read_text())
    _check_identity(theirs, args, src)
    path = out / "manifest.json"
    ours = json.loads(path.read_text()) if path.exists() else dict(_identity(args), datasets={})
    _check_identity(ours, args, out)
    _check_same_data(ours["datasets"], theirs["datasets"], out, f"{src} holds them on")
    merged = {**theirs["datasets"], **ours["datasets"]}
    _check_one_version(merged)
    if args.results_only:
        def keep(d, names):  # every folder is left out at the cell's top: nothing below is read
            return [n for n in names if n not in ("results.json", "config.json")]
    else:
        keep = shutil.ignore_patterns(".lock")
    copied = 0
    for t in theirs["datasets"]:
        for cell in sorted(p for p in (src / t).glob("*") if (p / "results.json").is_file()):
            dest = out / t / cell.name
            if dest.exists():
                if not (dest / "results.json").exists():
                    log(f"   {dest}: an unfinished run, kept (not replaced by {cell})")
                continue
            tmp = dest.with_name(f".{cell.name}.merging")
            with writing(dest, "a merged cell", f"{cell} is untouched; rerun to merge it"):
                dest.parent.mkdir(parents=True, exist_ok=True)
                shutil.rmtree(tmp, ignore_errors=True)
                try:
                    shutil.copytree(cell, tmp, ignore=keep)
                    tmp.rename(dest)  # a cell appears whole or not at all
                finally:
                    shutil.rmtree(tmp, ignore_errors=True)
            copied += 1
    ours["datasets"] = merged
    atomic_write_json(path, ours)
    log(f"merged {copied} finished cell(s) from {src} into {out}")
    return copied


def estimate(tasks, algos, args, ds_of, log) -> float:
    """Seconds for the whole table on this machine: training from one timed block per algorithm
    on the first task, plus each cell's evaluations' policy time (one timed step of its seeds x
    episodes, x the episode length x the evaluations; the simulator's steps come on top). A
    task without a file on this machine is timed on a stand-in of its shapes (`--estimate`
    makes no file)."""
    from r2pac_jax.agents import make_agent
    from r2pac_jax.loop import count_evaluations, time_block, time_policy_step

    total = 0.0
    ds = ds_of(tasks[0])  # read (or stood in for) once, not once per algorithm
    for a, cfg in _configs(tasks[0], algos, args).items():
        per_step = 1.0 / time_block(cfg, tasks[0], ds, cfg.seeds, blocks=1)["steps_per_s"]
        secs = per_step * cfg.total_steps * len(tasks)
        log(f"{a}: training {1 / per_step:.1f} steps/s ({cfg.seeds} seeds vmapped) x "
            f"{cfg.total_steps} steps x {len(tasks)} task(s) ~ {secs / 60:.1f} min")
        total += secs
    for t in tasks:
        for a, cfg in _configs(t, algos, args).items():
            if cfg.eval_episodes < 1:
                continue
            n_eval = count_evaluations(cfg, make_agent(cfg, t.obs_dim, t.act_dim))
            step = time_policy_step(cfg, t, cfg.seeds, cfg.eval_episodes)
            secs = step * t.episode_len * n_eval
            log(f"{t.name} {a}: evaluation's policy {step * 1e3:.1f} ms per step ({cfg.seeds} "
                f"seeds x {cfg.eval_episodes} episodes) x {t.episode_len} steps x {n_eval} "
                f"evaluation(s) ~ {secs / 60:.1f} min")
            total += secs
    log(f"in all ~ {total / 3600:.2f} h on this machine (the simulator's steps in evaluation "
        "and compilation on top)")
    return total


def estimate_data(task, log):
    """The task's file where the machine has one, else a stand-in of its shapes (announced)."""
    from r2pac_jax.data import find_task_file, load_dsrl, stand_in_dataset

    found = find_task_file(task)
    if found is not None:
        return load_dsrl(found[1], task.obs_dim, task.act_dim, task.name)
    log(f"{task.name}: no data file on this machine; timed on a stand-in of its shapes (random "
        f"values, 20 episodes of {task.episode_len} steps): --estimate makes no file")
    return stand_in_dataset(task)


def finished_cells(out: Path, manifest: dict, algos, skip=()) -> dict:
    """cells[task][algo] of the tasks in DIR's manifest not in `skip`, read from their
    finished results.json: a table grows task by task over sessions, and a task whose file this
    machine no longer holds keeps its row (the manifest pinned that file's sha256 when the cells
    were made)."""
    cells = {}
    for t in manifest["datasets"]:
        if t in skip:
            continue
        row = {a: json.loads((out / t / a / "results.json").read_text()) for a in algos
               if (out / t / a / "results.json").exists()}
        if row:
            cells[t] = row
    return cells


def write_outputs(out: Path, cells: dict, algos, families: dict, caption: str) -> str:
    """table.md, table.csv and table.png from cells[task][algo] (results.json dicts)."""
    md = results_table(cells, algos, families=families) + "\n\n" + caption
    atomic_write_text(out / "table.md", md + "\n")
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["task", "family", "algo", "reward_mean", "reward_std", "cost_mean", "cost_std",
                "safe", "seeds"])
    for t, row in cells.items():
        for a in algos:
            r = row.get(a)
            if r is None:
                continue
            nr, nc = r["normalized_reward"], r["normalized_cost"]
            w.writerow([t, families.get(t, ""), a, nr["mean"], nr.get("std"), nc["mean"],
                        nc.get("std"), bool(nc["mean"] is not None and nc["mean"] < SAFE_LIMIT),
                        len(nr.get("per_seed", []))])
    atomic_write_text(out / "table.csv", buf.getvalue())
    plot_table(cells, algos, out / "table.png")
    return md


_TABLE_FILES = {"manifest.json", "table.md", "table.csv", "table.png", ".lock"}


def is_legacy_table(path: Path) -> bool:
    """A table directory written before directories were marked: its manifest reads back, or
    it holds nothing but a table's files and TASK/ALGO cells that are runs (a pipeline copies
    finished runs in before the table command first writes its manifest)."""
    try:
        if "datasets" in json.loads((path / "manifest.json").read_text()):
            return True
    except (OSError, ValueError, TypeError):
        pass
    for entry in path.iterdir():
        if entry.name in _TABLE_FILES:
            continue
        if not entry.is_dir():
            return False
        for cell in entry.iterdir():
            if not cell.is_dir() or not (marker_kind(cell) == "run" or is_legacy_run(cell)):
                return False
    return True


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)

    def log(msg):
        print(msg, flush=True)

    from r2pac_jax.lanes import Lanes
    from r2pac_jax.loop import Run, check_run

    run = out = None  # what a Ctrl-C reports
    try:
        args.preset, why = resolve_preset(args.preset)
        log(why)
        tasks = [get_task(t) for t in (args.tasks or "").split(",") if t]
        for t in tasks:
            t.check_physics(args.physics)
        found = args.algos is None and args.table_only  # columns from OUT's finished cells
        algos = [a for a in (args.algos or ("" if found else DEFAULT_ALGOS)).split(",") if a]
        if (not algos and not found) or (not tasks and not args.table_only):
            raise ConfigError("--tasks and --algos each need at least one name (--tasks may be "
                              "left out with --table-only: every task in --out)")
        for a in algos:
            algo_module(a)  # an unknown name is refused with the known ones
        if args.seeds < 1 or args.episodes < 1:
            raise ConfigError("--seeds and --episodes must be >= 1")
        if not args.out.strip():
            raise ConfigError("--out '': an empty path; pass the table's directory")
        out = Path(args.out)
        if out.exists() and not out.is_dir():
            raise ConfigError(f"--out {out} is a file, not a directory")
        if not args.table_only:  # a folder the project did not write is refused up front
            claim_directory(out, "table", legacy=is_legacy_table, check_only=True)
        if args.results_only and not args.merge_from:
            raise ConfigError("--results-only says how --merge-from copies cells: give "
                              "--merge-from SRC too")
        if args.merge_from:  # --table-only alone reads an existing table and creates nothing
            claim_directory(out, "table", legacy=is_legacy_table)
        for src in args.merge_from:
            merge_from(out, Path(src), args, log)
        if args.table_only:
            return _table_only(out, [t.name for t in tasks], algos, args, log)
        cfgs = {t.name: _configs(t, algos, args) for t in tasks}  # every config checked first
        _check_pinned_present(out, tasks)
        loaded = {}

        def ds_of(task):
            if task.name not in loaded:
                loaded[task.name] = load_task_dataset(task, None, announce=log,
                                                     progress=not args.no_progress)
            return loaded[task.name]

        if args.estimate:
            estimate(tasks, algos, args, lambda t: estimate_data(t, log), log)
            return 0
        claim_directory(out, "table", legacy=is_legacy_table)
        datasets = {}
        for t in tasks:
            ds = ds_of(t)
            for a in algos:
                check_run(cfgs[t.name][a], t, ds)
            datasets[t.name] = dict(file=Path(ds.source).name, version=data_version(ds.source),
                                    sha256=ds.digest())
        manifest = _manifest(out, args, datasets)
        cells: dict = {}
        for t in tasks:
            ds = ds_of(t)
            cells[t.name] = {}
            for a in algos:
                cfg = cfgs[t.name][a]
                d = out / t.name / a
                log(f"== {t.name} {a} -> {d}")
                run = Run(cfg, t, ds, d, Lanes.build(cfg, list(range(cfg.seeds))),
                          physics=args.physics, progress=not args.no_progress, log=log,
                          dataset_label=ds.source)
                if (d / "results.json").exists():
                    run.check_same_run()  # a finished cell is read back, if it is this cell
                    cells[t.name][a] = json.loads((d / "results.json").read_text())
                    log("   finished earlier: read back")
                    continue
                cells[t.name][a] = run.run(resume=(d / "checkpoints").exists())
    except R2pacError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # finished cells are kept; the same command continues the rest

        from r2pac_jax.train import interrupted_line

        command = "python -m r2pac_jax.table " + shlex.join(argv)
        print(interrupted_line(run, command), file=sys.stderr, flush=True)
        return 130
    earlier = finished_cells(out, manifest, algos, skip=cells)
    _write_table(out, {**earlier, **cells}, manifest, algos, args, log)  # asked-for tasks last
    return 0


def _write_table(out: Path, cells: dict, manifest: dict, algos, args, log) -> None:

    families = {name: get_task(name).family for name in cells}
    versions = sorted({d["version"] for d in manifest["datasets"].values()})
    files = ", ".join(f"{t}: {d['file']}" for t, d in manifest["datasets"].items()
                      if t in cells)
    caption = (f"Preset {args.preset}, {args.seeds} seeds, {args.episodes} evaluation episodes per "
               f"seed, final policies; data {', '.join(versions)} ({files}).")
    standing = standing_lines(cells, manifest)
    if standing:
        caption += "\n\n" + "\n".join(standing)
    md = write_outputs(out, cells, algos, families, caption)
    log("\n" + md)
    log(f"\n{out / 'table.md'}, {out / 'table.csv'}, {out / 'table.png'}")


def row_budget(task_name: str, file: str, row: dict) -> Optional[dict]:
    """{env_steps, dsrl_env_steps} of the file a row stands on: from its cells' results.json
    (`data_budget`, recorded since 2026-12-06), else from the file's name (a learned file at a
    budget other than DSRL's carries `-b<env steps>`); None where neither says (no recipe)."""
    for r in row.values():
        b = r.get("data_budget")
        if b and b.get("dsrl_env_steps"):
            return dict(env_steps=b["env_steps"], dsrl_env_steps=b["dsrl_env_steps"])
    coll = get_task(task_name).collection
    if coll is None or "-generated-ppolag-" not in file:
        return None
    budget = factory.budget_in_name(file)
    return dict(env_steps=coll.env_steps if budget is None else budget,
                dsrl_env_steps=coll.env_steps)


def standing_lines(cells: dict, manifest: dict) -> list:
    """The footer that says what the rows stand on: rows on files made below DSRL's RL budget
    (env steps and share), cells trained on another kind of device than the table's CPU, and
    how many cells predate the device record."""
    cut, other, unrecorded = [], [], 0
    for t, row in cells.items():
        d = manifest["datasets"].get(t, {})
        b = row_budget(t, d.get("file", ""), row)
        if b and b["env_steps"] < b["dsrl_env_steps"]:
            cut.append(f"{t} {b['env_steps'] / 1e6:g}M of {b['dsrl_env_steps'] / 1e6:g}M "
                       f"({100 * b['env_steps'] / b['dsrl_env_steps']:.0f}%)")
        for a, r in row.items():
            dev = r.get("trained_on")
            if dev is None:
                unrecorded += 1
            elif dev.get("backend") != "cpu":
                other.append(f"{t} {a} ({dev.get('device_kind', dev.get('backend'))})")
    out = []
    if cut:
        out.append(f"Rows on files made below DSRL's RL budget ({len(cut)} of {len(cells)}): "
                   + ", ".join(cut) + ".")
    if other:
        out.append("Cells trained on another device than a CPU: " + ", ".join(other) + ".")
    if unrecorded:
        out.append(f"{unrecorded} cells predate the device record in results.json (2026-12-06); "
                   "the log (RESULTS.md) names where they ran.")
    return out


def _table_only(out: Path, tasks: list, algos, args, log) -> int:
    """--table-only: the table from OUT's finished cells; nothing is trained."""
    path = out / "manifest.json"
    if not path.is_file():
        raise ConfigError(f"--table-only: {out} holds no table (no manifest.json); run the "
                          "table command with --tasks first, or --merge-from a table directory")
    manifest = json.loads(path.read_text())
    _check_identity(manifest, args, out)
    missing = [t for t in tasks if t not in manifest["datasets"]]
    if missing:
        raise ConfigError(f"--table-only: {out} has no results for {', '.join(missing)} (its "
                          f"tasks: {', '.join(manifest['datasets'])})")
    found = args.algos is None  # no --algos: every algorithm with a finished cell, none dropped
    if found:

        algos = algo_names()
    cells = finished_cells(out, manifest, algos)
    if tasks:
        cells = {t: cells[t] for t in tasks if t in cells}
    if not cells:
        raise ConfigError(f"--table-only: no finished cell of {', '.join(algos)} in {out}")
    if found:
        algos = column_order({a for row in cells.values() for a in row})
    _write_table(out, cells, manifest, algos, args, log)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Sweeps: grids over alpha, C-bar, guidance scale, chunk length h, any config value, tasks and
seeds, from a TOML file.

    python -m r2pac_jax.sweep sweeps/alpha_h.toml [--out DIR] [--launcher local|ray] [--task T]
    python -m r2pac_jax.sweep report DIR

Cells that differ only in the vmappable scalars (`quantile_alpha`, `penalty_c`,
`guidance_scale`) share one compiled program: they and the seeds become the lanes of one `Run`.
Cells that change shapes or code (task, algo, h, network sizes, switches) form separate groups.
Every finished cell is recorded atomically in `DIR/cells/`; a restarted sweep skips finished
groups and resumes unfinished ones from their checkpoints.

Sweep file keys: `name`, `description`, `task` or `tasks`, `algo` or `algos`, `preset`, `seeds`
(a count or a list), `eval_episodes`, `physics`, `dataset`, `[config]` (fixed config values) and
`[grid]` (config key -> list of values; `task` and `algo` are allowed as axes too).
"""
from __future__ import annotations

import argparse
import dataclasses
import hashlib
import itertools
import json
import sys
import time
import tomllib
from pathlib import Path
from typing import Any, Optional

from r2pac_jax.agents import algo_module
from r2pac_jax.config import ConfigError, field_types, refuse_user_key, resolve_preset
from r2pac_jax.errors import R2pacError
from r2pac_jax.io import atomic_write_json, atomic_write_text, claim_directory
from r2pac_jax.planner import plan

TOP_KEYS = {"name", "description", "task", "tasks", "algo", "algos", "preset", "seeds",
            "eval_episodes", "physics", "dataset", "config", "grid"}


def vmapped(algo: str) -> set[str]:
    """The keys whose values may differ between lanes of one compiled program of `algo`."""
    return set(algo_module(algo).HPARAMS)


class SweepError(R2pacError, ValueError):
    pass


@dataclasses.dataclass(frozen=True)
class Cell:
    task: str
    algo: str
    values: tuple  # sorted (key, value) pairs of the grid axes and the fixed config
    axes: tuple = ()  # names of the grid axes (the columns of the report)

    @property
    def config_overrides(self) -> dict:
        return dict(self.values)

    @property
    def cell_id(self) -> str:
        text = json.dumps([self.task, self.algo, self.values], sort_keys=True, default=str)
        return hashlib.sha1(text.encode()).hexdigest()[:12]

    @property
    def label(self) -> str:
        parts = [f"{k}={v}" for k, v in self.values if k in self.axes]
        return " ".join([self.task, self.algo] + parts)


@dataclasses.dataclass
class Group:
    """Cells sharing one compiled program: same task, algo and non-vmapped config."""

    task: str
    algo: str
    static: tuple  # sorted (key, value) of non-vmapped overrides
    cells: list  # [Cell]

    @property
    def group_id(self) -> str:
        text = json.dumps([self.task, self.algo, self.static,
                           sorted(c.cell_id for c in self.cells)], default=str)
        return hashlib.sha1(text.encode()).hexdigest()[:12]


@dataclasses.dataclass
class Sweep:
    name: str
    preset: str
    seeds: list
    eval_episodes: int
    physics: str
    dataset: Optional[str]
    cells: list
    groups: list
    configs: dict  # group_id -> Config


def _check_value(key: str, value: Any, where: str, types: dict[str, type]) -> Any:
    if key not in types:
        raise SweepError(f"{where}: unknown config key {key!r}; known keys: "
                         f"{', '.join(sorted(types))}")
    want = types[key]
    if want is bool:
        if not isinstance(value, bool):
            raise SweepError(f"{where}: {key} must be true or false, got {value!r}")
    elif want is int:
        if not isinstance(value, int) or isinstance(value, bool):
            raise SweepError(f"{where}: {key} must be an integer, got {value!r}")
    elif want is float:
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            raise SweepError(f"{where}: {key} must be a number, got {value!r}")
        value = float(value)
    elif want is tuple:
        if not isinstance(value, list) or not all(isinstance(x, int) for x in value):
            raise SweepError(f"{where}: {key} must be a list of integers, got {value!r}")
        value = tuple(value)
    elif want is str:
        if not isinstance(value, str):
            raise SweepError(f"{where}: {key} must be a string, got {value!r}")
    return value


def load_sweep(path, task_override: Optional[str] = None) -> Sweep:
    """Parse and fully validate a sweep file; every config is built before anything runs."""
    path = Path(path)
    if not path.exists():
        raise SweepError(f"{path}: no such sweep file")
    try:
        spec = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as e:
        raise SweepError(f"{path}: not valid TOML ({e})") from e
    unknown = set(spec) - TOP_KEYS
    if unknown:
        raise SweepError(f"{path}: unknown key(s) {sorted(unknown)}; allowed: {sorted(TOP_KEYS)}")
    grid = dict(spec.get("grid", {}))
    fixed = dict(spec.get("config", {}))

    def axis(single, plural):
        if single in grid:
            vals = grid.pop(single)
        elif plural in spec:
            vals = spec[plural]
        elif single in spec:
            vals = [spec[single]]
        else:
            vals = None
        return vals

    tasks = [task_override] if task_override else axis("task", "tasks")
    if task_override:
        grid.pop("task", None)
    if not tasks:
        raise SweepError(f"{path}: no task (set `task = \"ReachAvoid\"` or pass --task)")
    algos = axis("algo", "algos") or ["r2pac"]
    types: dict[str, type] = {}
    for a in algos:
        try:
            types.update(field_types(a))
        except ConfigError as e:
            raise SweepError(f"{path}: {e}") from None
    for k in ("task", "algo", "preset"):
        if k in fixed:
            raise SweepError(f"{path} [config]: {k} is set at the top level (or as a grid "
                             "axis), not in [config]")
    for where, keys in ((f"{path} [config]", fixed), (f"{path} [grid]", grid)):
        for k in keys:
            if k not in ("task", "algo"):
                try:
                    refuse_user_key(k, where)
                except ConfigError as e:
                    raise SweepError(str(e)) from None
    for k in fixed:
        fixed[k] = _check_value(k, fixed[k], f"{path} [config]", types)
    axes = {}
    for k, vals in grid.items():
        if not isinstance(vals, list):
            raise SweepError(f"{path} [grid]: {k} must be a list of values, got {vals!r}")
        if not vals:
            raise SweepError(f"{path} [grid]: {k} is empty: the grid would have no cell")
        axes[k] = [_check_value(k, v, f"{path} [grid]", types) for v in vals]
    for k in ("seeds", "steps"):
        if k in axes:
            raise SweepError(f"{path} [grid]: {k} cannot be a grid axis; set `seeds = N` at the "
                             "top level or steps in [config]")
    seeds = spec.get("seeds", 3)
    if isinstance(seeds, int) and not isinstance(seeds, bool):
        if seeds < 1:
            raise SweepError(f"{path}: seeds must be >= 1, got {seeds}")
        seeds = list(range(seeds))
    elif not (isinstance(seeds, list) and seeds and all(isinstance(s, int) for s in seeds)):
        raise SweepError(f"{path}: seeds must be a positive integer or a list of integers")
    eval_episodes = spec.get("eval_episodes", 20)
    if not isinstance(eval_episodes, int) or eval_episodes < 0:
        raise SweepError(f"{path}: eval_episodes must be an integer >= 0")
    preset, _ = resolve_preset(spec.get("preset", "auto"))
    physics = spec.get("physics", "auto")
    names, lists = list(axes), [axes[k] for k in axes]
    cells = []
    for task in tasks:
        for algo in algos:
            for combo in itertools.product(*lists) if lists else [()]:
                values = dict(fixed)
                values.update(dict(zip(names, combo)))
                cells.append(Cell(task, algo, tuple(sorted(values.items())), tuple(names)))
    if not cells:
        raise SweepError(f"{path}: the grid is empty")
    groups: dict[tuple, Group] = {}
    for c in cells:
        static = tuple((k, v) for k, v in c.values if k not in vmapped(c.algo))
        key = (c.task, c.algo, static)
        groups.setdefault(key, Group(c.task, c.algo, static, [])).cells.append(c)
    configs = {}
    for g in groups.values():
        over = dict(g.static)
        over.update(seeds=len(seeds), eval_episodes=eval_episodes)
        try:
            cfg = plan(g.task, g.algo, preset, over)
            for c in g.cells:  # every cell's own values must be valid too
                plan(g.task, g.algo, preset, dict(c.values, seeds=len(seeds),
                                                  eval_episodes=eval_episodes))
        except (ConfigError, KeyError) as e:
            raise SweepError(f"{path}: {e}") from e
        configs[g.group_id] = cfg
    return Sweep(name=spec.get("name", path.stem), preset=preset, seeds=seeds,
                 eval_episodes=eval_episodes, physics=physics, dataset=spec.get("dataset"),
                 cells=cells, groups=list(groups.values()), configs=configs)


def check_data(sweep: Sweep) -> None:
    """Every task of the sweep has data (or a generator) before anything runs."""
    from r2pac_jax.data import factory
    from r2pac_jax.data.dsrl import find_dsrl_file
    from r2pac_jax.tasks import UnknownPhysicsError, get_task

    for name in sorted({c.task for c in sweep.cells}):
        task = get_task(name)
        try:
            task.check_physics(sweep.physics)
        except UnknownPhysicsError as e:
            raise SweepError(f"physics = {sweep.physics!r} in the sweep file: {e}") from e
        if sweep.dataset:
            from r2pac_jax.data.dsrl import load_dsrl

            if not Path(sweep.dataset).expanduser().exists():
                raise SweepError(f"dataset {sweep.dataset} does not exist")
            load_dsrl(sweep.dataset, task.obs_dim, task.act_dim, task.name)  # readable, fits
            continue
        if find_dsrl_file(task) or factory.find_cached(task) or factory.has_source(task):
            continue
        raise SweepError(f"task {name} has no data: no DSRL file, no generated dataset and no "
                         "generator; set `dataset = \"FILE.hdf5\"` in the sweep file")


def run_group(sweep: Sweep, group: Group, out: Path, log=print, progress: bool = True) -> dict:
    """Train one group (all its cells x seeds vmapped) and record each cell atomically."""
    from r2pac_jax.data import load_task_dataset
    from r2pac_jax.tasks import get_task
    from r2pac_jax.train import Lanes, Run

    task = get_task(group.task)
    cfg = sweep.configs[group.group_id]
    cells_hp = [{k: v for k, v in c.values if k in vmapped(group.algo)} for c in group.cells]
    lanes = Lanes.build(cfg, sweep.seeds, cells_hp)
    ds = load_task_dataset(task, sweep.dataset, announce=log, progress=progress)
    gdir = out / "groups" / group.group_id
    run = Run(cfg, task, ds, gdir, lanes, physics=sweep.physics, progress=progress, log=log,
              dataset_label=ds.source, nonfinite="mark")
    res = run.run(resume=True)
    for c, cell_res in zip(group.cells, res["cells"]):
        record = dict(cell_id=c.cell_id, label=c.label, task=c.task, algo=c.algo,
                      values=dict(c.values), axes={k: v for k, v in c.values if k in c.axes},
                      group=group.group_id, run_dir=str(gdir),
                      finished=time.strftime("%Y-%m-%dT%H:%M:%S"), **cell_res)
        atomic_write_json(out / "cells" / f"{c.cell_id}.json", record)
    return res


def finished_cells(out: Path) -> dict[str, dict]:
    d = out / "cells"
    if not d.is_dir():
        return {}
    return {p.stem: json.loads(p.read_text()) for p in sorted(d.glob("*.json"))}


def _ray_group(sweep_path: str, task_override, group_id: str, out: str):
    """Runs inside a Ray worker: reload the sweep (pure data) and run one group."""
    sweep = load_sweep(sweep_path, task_override)
    group = next(g for g in sweep.groups if g.group_id == group_id)
    run_group(sweep, group, Path(out), log=lambda m: None, progress=False)
    return group_id


_SWEEP_FILES = {"sweep.json", "cells", "groups", "curves", "table.csv", "table.md", ".lock"}


def is_legacy_sweep(path: Path) -> bool:
    """A sweep directory written before directories were marked: its sweep.json reads back, or
    it holds only what a sweep writes (its groups and cells, a report)."""
    try:
        if "cells" in json.loads((path / "sweep.json").read_text()):
            return True
    except (OSError, ValueError, TypeError):
        pass
    names = {p.name for p in path.iterdir()}
    return bool(names & {"cells", "groups"}) and all(
        n in _SWEEP_FILES or (n.startswith("score_vs_") and n.endswith(".png")) for n in names)


def run_sweep(path, out=None, launcher: str = "local",
              task_override: Optional[str] = None, log=print, progress: bool = True) -> Path:
    if out is not None and not str(out).strip():
        raise SweepError("--out '': an empty path; pass the sweep's directory (or leave --out "
                         "out for runs/sweeps/NAME)")
    sweep = load_sweep(path, task_override)
    check_data(sweep)
    out = Path(out or f"runs/sweeps/{sweep.name}")
    claim_directory(out, "sweep", legacy=is_legacy_sweep)
    atomic_write_json(out / "sweep.json", dict(
        file=str(path), name=sweep.name, preset=sweep.preset, seeds=sweep.seeds,
        task_override=task_override, cells=[dict(id=c.cell_id, label=c.label) for c in sweep.cells],
        groups=[dict(id=g.group_id, cells=[c.cell_id for c in g.cells]) for g in sweep.groups]))
    done = finished_cells(out)
    todo = [g for g in sweep.groups if not all(c.cell_id in done for c in g.cells)]
    log(f"sweep {sweep.name}: {len(sweep.cells)} cells in {len(sweep.groups)} compiled groups "
        f"x {len(sweep.seeds)} seeds; {len(sweep.groups) - len(todo)} groups already finished")
    if launcher == "local":
        for i, g in enumerate(todo):
            log(f"[{i + 1}/{len(todo)}] group {g.group_id}: {g.task} {g.algo} "
                f"{dict(g.static)} ({len(g.cells)} cells vmapped)")
            run_group(sweep, g, out, log=log, progress=progress)
            write_report(out)
    elif launcher == "ray":
        import ray

        if not ray.is_initialized():
            ray.init(ignore_reinit_error=True, include_dashboard=False, log_to_driver=False)
        remote = ray.remote(_ray_group)
        refs = [remote.remote(str(path), task_override, g.group_id, str(out.absolute()))
                for g in todo]
        for ref in refs:
            log(f"group {ray.get(ref)} finished")
    else:
        raise SweepError(f"unknown launcher {launcher!r}; choose local or ray")
    write_report(out)
    return out


# ---------------------------------------------------------------------------------------------
# Report


def _rows(out: Path) -> list[dict]:
    rows = []
    for rec in finished_cells(out).values():
        if "normalized_reward" not in rec:
            continue
        row = dict(cell_id=rec["cell_id"], task=rec["task"], algo=rec["algo"], **rec["axes"])
        nan = float("nan")
        for key in ("normalized_reward", "normalized_cost"):
            row[f"{key}_mean"] = nan if rec[key]["mean"] is None else rec[key]["mean"]
            row[f"{key}_std"] = nan if rec[key]["std"] is None else rec[key]["std"]
            row[f"{key}_per_seed"] = " ".join("diverged" if x is None else f"{x:.3f}"
                                              for x in rec[key]["per_seed"])
        row["safe"] = bool(rec.get("safe", row["normalized_cost_mean"] < 1.0))
        row["diverged_seeds"] = " ".join(str(d["seed"]) for d in rec.get("diverged", []))
        row["run_dir"] = rec["run_dir"]
        rows.append(row)
    return rows


def write_report(out: Path) -> Optional[str]:
    """table.csv, table.md (paper style) and PNG plots for the finished cells."""
    import csv
    import io

    rows = _rows(out)
    if not rows:
        return None
    axes = sorted({k for r in rows for k in r} - {
        "cell_id", "task", "algo", "safe", "run_dir", "diverged_seeds", "normalized_reward_mean",
        "normalized_reward_std", "normalized_reward_per_seed", "normalized_cost_mean",
        "normalized_cost_std", "normalized_cost_per_seed"})
    cols = (["task", "algo"] + axes + ["normalized_reward_mean", "normalized_reward_std",
            "normalized_cost_mean", "normalized_cost_std", "safe", "normalized_reward_per_seed",
            "normalized_cost_per_seed", "cell_id"])
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=cols, extrasaction="ignore")
    w.writeheader()
    for r in rows:
        w.writerow(r)
    atomic_write_text(out / "table.csv", buf.getvalue())
    md = markdown_table(rows, axes)
    atomic_write_text(out / "table.md", md + "\n")
    plot_sweep(rows, axes, out)
    return md


def markdown_table(rows: list[dict], axes: list[str]) -> str:
    """One row per cell; safe cells bold, the best safe reward per task starred (Table 1 style)."""
    lines = ["| task | algo | " + " | ".join(axes) + " | reward ↑ | cost ↓ | per-seed reward | "
             "per-seed cost |", "|" + "---|" * (len(axes) + 6)]
    best = {}
    for r in rows:
        if r["safe"] and r["normalized_reward_mean"] > best.get(r["task"], (-1e9, None))[0]:
            best[r["task"]] = (r["normalized_reward_mean"], r["cell_id"])
    key = [(r["task"], r["algo"], tuple(str(r.get(a, "")) for a in axes)) for r in rows]
    for _, r in sorted(zip(key, rows), key=lambda kr: kr[0]):
        rew = f"{r['normalized_reward_mean']:.2f} ± {r['normalized_reward_std']:.2f}"
        cost = f"{r['normalized_cost_mean']:.2f} ± {r['normalized_cost_std']:.2f}"
        if r["safe"]:
            rew, cost = f"**{rew}**", f"**{cost}**"
            if best.get(r["task"], (None, None))[1] == r["cell_id"]:
                rew += " ★"
        if r.get("diverged_seeds"):
            rew += f" (diverged: seeds {r['diverged_seeds']})"
        vals = " | ".join(str(r.get(a, "")) for a in axes)
        lines.append(f"| {r['task']} | {r['algo']} | {vals} | {rew} | {cost} | "
                     f"{r['normalized_reward_per_seed']} | {r['normalized_cost_per_seed']} |")
    lines += ["", "Normalised scores, mean ± std over seeds. **Bold**: safe (normalised cost < 1); "
              "★: the best safe reward of the task. A diverged seed (NaN or inf in training) has "
              "no score; the means are over the others."]
    return "\n".join(lines)


def plot_sweep(rows: list[dict], axes: list[str], out: Path) -> None:
    from r2pac_jax.report import SAFE_LIMIT, _plt, _savefig, plot_curves

    plt = _plt()
    for axis in ("quantile_alpha", "chunk_len", "penalty_c", "guidance_scale"):
        if axis not in axes or len({r.get(axis) for r in rows}) < 2:
            continue
        others = [a for a in axes if a != axis]
        fig, (ax_r, ax_c) = plt.subplots(1, 2, figsize=(9, 3.4))
        series: dict[tuple, list] = {}
        for r in rows:
            series.setdefault((r["task"], r["algo"]) + tuple(r.get(a) for a in others), []).append(r)
        for key, rs in sorted(series.items(), key=lambda kv: str(kv[0])):
            rs = sorted(rs, key=lambda r: r[axis])
            xs = [r[axis] for r in rs]
            lab = " ".join(str(k) for k in key[2:]) or f"{key[0]} {key[1]}"
            ax_r.errorbar(xs, [r["normalized_reward_mean"] for r in rs],
                          [r["normalized_reward_std"] for r in rs], marker="o", capsize=3,
                          label=lab)
            ax_c.errorbar(xs, [r["normalized_cost_mean"] for r in rs],
                          [r["normalized_cost_std"] for r in rs], marker="o", capsize=3)
        ax_c.axhline(SAFE_LIMIT, color="red", ls="--", lw=0.8)
        ax_r.set_xlabel(axis)
        ax_c.set_xlabel(axis)
        ax_r.set_ylabel("normalised reward")
        ax_c.set_ylabel("normalised cost")
        if len(series) > 1:
            ax_r.legend(fontsize=6, title=" ".join(others), title_fontsize=6)
        _savefig(fig, out / f"score_vs_{axis}.png")
        plt.close(fig)
    # training curves per group (each group's lanes = its cells x seeds)
    from r2pac_jax.metrics_log import MetricsLog

    for run_dir in sorted({r["run_dir"] for r in rows}):
        ev = MetricsLog(run_dir, tensorboard=False).read("eval")
        if ev:
            plot_curves(ev, ["normalized_reward", "normalized_cost"],
                        out / "curves" / f"{Path(run_dir).name}.png",
                        f"group {Path(run_dir).name} (lanes = cells x seeds)")


def main(argv=None) -> int:

    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        if argv and argv[0] == "report":
            ap = argparse.ArgumentParser(prog="python -m r2pac_jax.sweep report")
            ap.add_argument("dir")
            args = ap.parse_args(argv[1:])
            md = write_report(Path(args.dir))
            if md is None:
                raise SweepError(f"{args.dir}: no finished cell to report")
            print(md)
            print(f"\nwrote {args.dir}/table.md, table.csv and PNG plots")
            return 0
        ap = argparse.ArgumentParser(prog="python -m r2pac_jax.sweep")
        ap.add_argument("file", help="sweep file (TOML), e.g. sweeps/alpha_h.toml")
        ap.add_argument("--out", default=None)
        ap.add_argument("--launcher", default="local", choices=["local", "ray"])
        ap.add_argument("--task", default=None, help="override the file's task(s)")
        ap.add_argument("--dry-run", action="store_true", help="validate and list the cells")
        ap.add_argument("--no-progress", action="store_true")
        args = ap.parse_args(argv)
        if args.dry_run:
            sweep = load_sweep(args.file, args.task)
            check_data(sweep)
            for g in sweep.groups:
                print(f"group {g.group_id}: {g.task} {g.algo} {dict(g.static)}")
                for c in g.cells:
                    print(f"  cell {c.cell_id}: {c.label}")
            return 0
        out = run_sweep(args.file, args.out, args.launcher, args.task,
                        progress=not args.no_progress)
        print((out / "table.md").read_text() if (out / "table.md").exists() else "")
        return 0
    except R2pacError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # finished cells are kept; a group resumes from its checkpoint
        import shlex

        print("interrupted: the finished cells are kept and the running group continues from "
              "its last checkpoint; continue with: python -m r2pac_jax.sweep "
              f"{shlex.join(argv)}", file=sys.stderr, flush=True)
        return 130


if __name__ == "__main__":
    sys.exit(main())

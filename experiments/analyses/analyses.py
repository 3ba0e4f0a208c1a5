"""The paper's analyses on our data (PROTOCOL.md beside this file), one chain per task.

    python experiments/analyses/analyses.py plan                 # every cell, task by task
    python experiments/analyses/analyses.py run [--task T ...]   # train and keep (resumable)
    python experiments/analyses/analyses.py report [NAME ...]    # tables and figures

`run` trains each cell of a task once (the analyses share cells), on the task's pinned file
(made again where missing, its digest checked), into runs/analyses/TASK/CELL, and keeps each
finished cell's results, config and curves in experiments/analyses/cells/TASK/CELL (committed:
a machine may not outlive a session); a kept cell is never run again, a killed one resumes. A
value-map task's map is written once both of its cells have finished. `report` reads only the
kept cells: table2, alpha, h, qstability, valuemaps, variants.
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import shutil
import statistics
import sys
from pathlib import Path
from typing import Callable, Optional

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
KEPT = HERE / "cells"
MAPS = HERE / "value_maps"
DECISION = ROOT / "experiments" / "r2pac_decision" / "decision.json"
KEEP_FILES = ("results.json", "config.json", "eval.jsonl", "metrics.jsonl")

TABLE2_TASKS = ("BallRun", "AntRun", "AntCircle", "DroneRun", "DroneCircle", "CarGoal1",
                "CarGoal2")
TABLE2_ALGOS = ("r2pac-no-penalty", "r2pac-no-vc", "r2pac-awr", "r2pac")
TABLE2_NAMES = {"r2pac-no-penalty": "w/o Vbar_r", "r2pac-no-vc": "w/o V_c",
                "r2pac-awr": "AWR actor", "r2pac": "Ours"}
# The paper's Table 2 (reward, cost), as printed
PAPER_TABLE2 = {
    "BallRun": [(0.94, 14.69), (0.29, 0.09), (0.08, 0.05), (0.30, 0.00)],
    "AntRun": [(0.62, 5.73), (0.61, 1.16), (0.63, 0.43), (0.62, 0.53)],
    "AntCircle": [(0.58, 13.00), (0.38, 0.20), (0.34, 3.12), (0.32, 0.23)],
    "DroneRun": [(0.71, 13.28), (0.60, 0.94), (0.47, 0.60), (0.59, 0.26)],
    "DroneCircle": [(0.85, 18.5), (0.53, 1.50), (0.47, 0.75), (0.52, 0.32)],
    "CarGoal1": [(0.59, 1.18), (0.35, 0.48), (0.33, 0.62), (0.42, 0.57)],
    "CarGoal2": [(0.36, 2.41), (0.30, 0.37), (0.20, 0.32), (0.32, 0.67)],
}
VALUE_MAP_TASKS = ("BallRun", "DroneRun", "DroneCircle", "AntRun", "AntCircle")
VARIANT_TASKS = ("DroneRun", "DroneCircle", "CarGoal1", "CarGoal2", "CarPush1", "CarPush2")
VARIANT_ALGOS = ("r2pac", "r2pac-awr-flow", "r2pac-hj")
ALPHAS = (0.3, 0.5, 0.7)
CHUNKS = {"BallRun": (1, 3, 5, 7), "CarGoal2": (1, 5, 10, 15)}

# analysis -> task -> [(algo, {key: value})]
ANALYSES: dict[str, dict[str, list]] = {
    "table2": {t: [(a, {}) for a in TABLE2_ALGOS] for t in TABLE2_TASKS},
    "alpha": {"BallRun": [("r2pac", {"quantile_alpha": a}) for a in ALPHAS]},
    "h": {t: [("r2pac", {"chunk_len": h}) for h in hs] for t, hs in CHUNKS.items()},
    "qstability": {"BallRun": [("r2pac-no-penalty", {"chunk_len": h})
                               for h in CHUNKS["BallRun"]]},
    "valuemaps": {t: [("r2pac", {}), ("r2pac-no-penalty", {})] for t in VALUE_MAP_TASKS},
    "variants": {t: [(a, {}) for a in VARIANT_ALGOS] for t in VARIANT_TASKS},
}
# chains run in this order (CarGoal1 last: its file is made again by the missing-rows issue)
TASK_ORDER = ("BallRun", "DroneRun", "DroneCircle", "AntRun", "AntCircle", "CarGoal2",
              "CarPush1", "CarPush2", "CarGoal1")
QUICK_NOTE = ("CPU quick preset (20k + 20k steps, 4 evaluations of the final phase, 3 seeds, "
              "20 episodes, final policies): compare with the paper's figure in shape and "
              "ordering, not value.")


class AnalysesError(ValueError):
    pass


# ---------------------------------------------------------------------------------------------
# Cells


def registry_value(task: str, algo: str, key: str):
    from r2pac_jax.config import make_config

    return getattr(make_config(task, algo, "quick"), key)


def away_from_registry(task: str, algo: str, sets: dict) -> dict:
    """The values of `sets` that differ from the registry's (sorted by key)."""
    return {k: v for k, v in sorted(sets.items()) if registry_value(task, algo, k) != v}


def cell_name(task: str, algo: str, sets: dict) -> str:
    """The algorithm, then each value set away from the registry's: `r2pac-chunk_len=3`. A value
    equal to the registry's names the plain cell, so it is run once."""
    return algo + "".join(f"-{k}={v}" for k, v in away_from_registry(task, algo, sets).items())


def plan(analyses=tuple(ANALYSES), tasks=None,
         table: Optional[dict] = None) -> dict[str, dict[str, tuple]]:
    """task -> {cell name: (algo, sets away from the registry)}, tasks in TASK_ORDER (then any
    other), each cell once however many analyses use it."""
    table = ANALYSES if table is None else table
    out: dict[str, dict[str, tuple]] = {}
    for a in analyses:
        if a not in table:
            raise AnalysesError(f"unknown analysis {a!r}; choose from {', '.join(table)}")
        for task, cells in table[a].items():
            for algo, sets in cells:
                out.setdefault(task, {}).setdefault(cell_name(task, algo, sets),
                                                    (algo, away_from_registry(task, algo, sets)))
    order = {t: i for i, t in enumerate(TASK_ORDER)}
    chosen = sorted(out, key=lambda t: (order.get(t, len(order)), t))
    if tasks:
        unknown = [t for t in tasks if t not in out]
        if unknown:
            raise AnalysesError(f"no analysis uses {', '.join(unknown)}; tasks: "
                                f"{', '.join(chosen)}")
        chosen = [t for t in chosen if t in tasks]
    return {t: out[t] for t in chosen}


def train_argv(task: str, algo: str, sets: dict, dataset, run_dir: Path) -> list[str]:
    argv = ["--task", task, "--algo", algo, "--dataset", str(dataset), "--seeds", "3",
            "--eval-episodes", "20", "--baselines", "none", "--no-progress", "--out",
            str(run_dir)]
    for k, v in sorted(sets.items()):
        argv += ["--chunk-len", str(v)] if k == "chunk_len" else ["--set", f"{k}={v}"]
    return argv


def keep(run_dir: Path, dest: Path) -> None:
    """Copy a finished cell's files into the repository (results.json last: it marks a kept
    cell, so a copy cut short is made again)."""
    dest.mkdir(parents=True, exist_ok=True)
    for f in KEEP_FILES[1:]:
        if (run_dir / f).is_file():
            shutil.copyfile(run_dir / f, dest / f)
    tmp = dest / "results.json.tmp"
    shutil.copyfile(run_dir / "results.json", tmp)
    tmp.replace(dest / "results.json")


def run_chain(task: str, cells: dict, dataset, runs: Path, kept: Path = KEPT,
              maps: Path = MAPS, extra_argv=(), log: Callable = print,
              embedding: str = "auto", map_tasks=VALUE_MAP_TASKS) -> dict[str, str]:
    """Train and keep each cell of one task: {cell: "kept" | "finished earlier" | "failed"}."""
    from r2pac_jax.train import main as train

    status = {}
    for name, (algo, sets) in cells.items():
        dest = kept / task / name
        if (dest / "results.json").is_file():
            status[name] = "finished earlier"
            log(f"== {task} {name}: finished earlier")
            continue
        run_dir = runs / task / name
        argv = train_argv(task, algo, sets, dataset, run_dir) + list(extra_argv)
        if (run_dir / "config.json").is_file():
            argv.append("--resume")
        log(f"== {task} {name}: python -m r2pac_jax.train {' '.join(argv)}")
        try:
            rc = train(argv)
        except Exception as e:  # noqa: BLE001 - one failed cell does not stop the chain
            log(f"!! {task} {name}: {type(e).__name__}: {e}")
            rc = 1
        if rc == 0 and (run_dir / "results.json").is_file():
            keep(run_dir, dest)
            status[name] = "kept"
        else:
            status[name] = "failed"
            log(f"!! {task} {name} failed (exit {rc})")
    if task in map_tasks:
        write_value_map(task, dataset, runs, maps, log, embedding)
    return status


def write_value_map(task: str, dataset, runs: Path, maps: Path = MAPS, log: Callable = print,
                    embedding: str = "auto") -> Optional[dict]:
    """maps/TASK.{png,csv,json} from seed 0's critics of the task's r2pac and r2pac-no-penalty
    runs (5,000 states of the file, generator seed 0); None where it exists or a run is missing."""
    import numpy as np

    from r2pac_jax import value_map as vm
    from r2pac_jax.data import load_dsrl
    from r2pac_jax.io import atomic_write_json
    from r2pac_jax.tasks import get_task

    if (maps / f"{task}.json").is_file():
        return None
    full, plain = runs / task / "r2pac", runs / task / "r2pac-no-penalty"
    missing = [str(d) for d in (full, plain) if not (d / "results.json").is_file()]
    if missing:
        log(f"!! {task}: no value map: {', '.join(missing)} not finished on this machine (a cell "
            "kept on another machine needs its run here: remove its kept folder to train it again)")
        return None
    t = get_task(task)
    ds = load_dsrl(dataset, t.obs_dim, t.act_dim, t.name)
    states = vm.sample_states(np.asarray(ds.observations), 5000, 0)
    values = vm.state_values(full, states, 0)
    values["V_r"] = vm.state_values(plain, states, 0)["V_r"]
    info = vm.value_map(states, values, maps, task, f"{task}, seed 0", embedding, 0)
    info.update(dataset_sha256=ds.digest(), runs=[str(full), str(plain)])
    atomic_write_json(maps / f"{task}.json", info)
    log(f"== {task}: value map {maps / (task + '.png')} ({info['embedding']})")
    return info


def _decision():
    spec = importlib.util.spec_from_file_location(
        "decide", ROOT / "experiments" / "r2pac_decision" / "decide.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def decision_landed(path: Path = DECISION) -> bool:
    """R2PAC's default is settled: decision.json (written once every decision cell has a
    result) names no winner, or its confirmation is in and, where it confirmed the winner,
    the registry's r2pac default already holds the winner's setting (PROTOCOL.md item 4)."""
    try:
        d = json.loads(path.read_text())
    except (OSError, ValueError):
        return False
    winner = d.get("decision", {}).get("winner", "absent")
    if winner is None:
        return True
    if winner == "absent" or "confirmation" not in d:
        return False
    if not d["confirmation"].get("confirmed"):
        return True
    from r2pac_jax.agents.r2pac import R2PACConfig

    default = R2PACConfig()
    for item in _decision().CANDIDATES[winner]:
        key, value = item.split("=", 1)
        if getattr(default, key) != json.loads(value):
            return False
    return True


# ---------------------------------------------------------------------------------------------
# Reading kept cells


def read_cell(task: str, name: str, kept: Path = KEPT) -> Optional[dict]:
    d = kept / task / name
    if not (d / "results.json").is_file():
        return None
    from r2pac_jax.metrics_log import _rows

    return dict(results=json.loads((d / "results.json").read_text()),
                eval=_rows(d / "eval.jsonl") if (d / "eval.jsonl").is_file() else [],
                metrics=_rows(d / "metrics.jsonl") if (d / "metrics.jsonl").is_file() else [])


def score(cell: Optional[dict]) -> Optional[tuple]:
    """(reward mean, reward std, cost mean, cost std, safe) of a kept cell."""
    if cell is None:
        return None
    r = cell["results"]
    rm, cm = r["normalized_reward"]["mean"], r["normalized_cost"]["mean"]
    if rm is None or cm is None:
        return None
    return (rm, r["normalized_reward"]["std"] or 0.0, cm, r["normalized_cost"]["std"] or 0.0,
            cm < 1.0)


def fmt_score(s: Optional[tuple]) -> str:
    if s is None:
        return "not run"
    text = f"{s[0]:.2f} ± {s[1]:.2f} / {s[2]:.2f} ± {s[3]:.2f}"
    return f"**{text}**" if s[4] else f"{text} (unsafe)"


def curve(rows: list[dict], key: str, phase: Optional[str] = None) -> tuple[list, list]:
    """(steps, mean over lanes) of `key` in JSONL rows (lanes with the key at that step)."""
    by: dict[int, list] = {}
    for r in rows:
        if key in r and r[key] is not None and (phase is None or r.get("phase") == phase):
            by.setdefault(int(r["step"]), []).append(float(r[key]))
    steps = sorted(by)
    return steps, [statistics.fmean(by[s]) for s in steps]


# ---------------------------------------------------------------------------------------------
# Reports


def _write(out: Path, name: str, md: str, rows: list[dict]) -> None:
    import csv
    import io

    from r2pac_jax.io import atomic_write_text

    atomic_write_text(out / f"{name}.md", md.rstrip() + "\n")
    if rows:
        buf = io.StringIO()
        w = csv.DictWriter(buf, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
        atomic_write_text(out / f"{name}.csv", buf.getvalue())


def report_table2(kept: Path = KEPT, out: Path = HERE) -> str:
    head = "| task | " + " | ".join(f"{TABLE2_NAMES[a]} (ours) | paper" for a in TABLE2_ALGOS)
    lines = ["# Table 2 on our data: component ablations", "",
             head + " |", "|---|" + "---|---|" * len(TABLE2_ALGOS)]
    rows = []
    for t in TABLE2_TASKS:
        cells = []
        for i, a in enumerate(TABLE2_ALGOS):
            s = score(read_cell(t, cell_name(t, a, {}), kept))
            pr, pc = PAPER_TABLE2[t][i]
            paper = f"{pr:.2f} / {pc:.2f}"
            cells += [fmt_score(s), f"**{paper}**" if pc < 1 else paper]
            rows.append(dict(task=t, variant=TABLE2_NAMES[a], algo=a,
                             reward=None if s is None else round(s[0], 4),
                             reward_std=None if s is None else round(s[1], 4),
                             cost=None if s is None else round(s[2], 4),
                             cost_std=None if s is None else round(s[3], 4),
                             paper_reward=pr, paper_cost=pc))
        lines.append(f"| {t} | " + " | ".join(cells) + " |")
    lines += ["", "Normalised reward / cost, mean ± std over seeds 0-2. **Bold**: safe (cost < 1; "
              "the paper greys unsafe agents, marked `(unsafe)` here). AWR actor: a 3-layer MLP "
              "Gaussian, temperatures a = b = 6.0, Eq. 40's second indicator read as the unsafe "
              "set. " + QUICK_NOTE]
    md = "\n".join(lines)
    _write(out, "table2", md, rows)
    return md


def _curve_grid(panels: list[tuple[str, list[tuple[str, dict]]]], path: Path, title: str):
    """One row per panel (title, [(label, cell)]): normalised reward and cost over training."""
    from r2pac_jax.report import SAFE_LIMIT, _plt, _savefig

    plt = _plt()
    fig, axes = plt.subplots(len(panels), 2, figsize=(9, 2.8 * len(panels)), squeeze=False)
    for (name, series), (ax_r, ax_c) in zip(panels, axes):
        for label, cell in series:
            for ax, key in ((ax_r, "normalized_reward"), (ax_c, "normalized_cost")):
                xs, ys = curve(cell["eval"], key)
                if xs:
                    ax.plot(xs, ys, marker="o", ms=3, lw=1.2, label=label)
        ax_c.axhline(SAFE_LIMIT, color="red", ls="--", lw=0.8)
        ax_r.set_title(f"{name}: normalised reward", fontsize=9)
        ax_c.set_title(f"{name}: normalised cost", fontsize=9)
        if series:
            ax_r.legend(fontsize=7)
    for ax in axes[-1]:
        ax.set_xlabel("gradient step (critic + actor phases)")
    fig.suptitle(title, fontsize=10)
    _savefig(fig, path)
    plt.close(fig)


def _sweep_report(name: str, heading: str, by_task: dict[str, list], key: str,
                  kept: Path, out: Path) -> str:
    """Final scores and curves of cells that differ in one value `key` (alpha or h)."""
    lines = [f"# {heading}", "", f"| task | {key} | reward / cost |", "|---|---|---|"]
    rows, panels = [], []
    for task, cells in by_task.items():
        series = []
        for algo, sets in cells:
            cell = read_cell(task, cell_name(task, algo, sets), kept)
            s = score(cell)
            lines.append(f"| {task} | {sets[key]} | {fmt_score(s)} |")
            rows.append(dict(task=task, algo=algo, **{key: sets[key]},
                             reward=None if s is None else round(s[0], 4),
                             cost=None if s is None else round(s[2], 4)))
            if cell is not None:
                series.append((f"{key} = {sets[key]}", cell))
        panels.append((task, series))
    lines += ["", QUICK_NOTE]
    md = "\n".join(lines)
    _write(out, name, md, rows)
    if any(s for _, s in panels):
        _curve_grid(panels, out / f"{name}.png", f"{heading} (seed means)")
    return md


def report_alpha(kept: Path = KEPT, out: Path = HERE) -> str:
    return _sweep_report("alpha", "Figure 4 on our data: the quantile alpha on BallRun",
                         ANALYSES["alpha"], "quantile_alpha", kept, out)


def report_h(kept: Path = KEPT, out: Path = HERE) -> str:
    return _sweep_report("h", "Figure 5 on our data: the chunk length h", ANALYSES["h"],
                         "chunk_len", kept, out)


def report_qstability(kept: Path = KEPT, out: Path = HERE) -> str:
    """Figure 2: batch-mean Q_r and Q_c over the critic phase of vanilla h-step IQL."""
    from r2pac_jax.report import _plt, _savefig

    lines = ["# Figure 2 on our data: Q-values of vanilla h-step IQL over training (BallRun)", "",
             "| h | Q_r last | Q_r std, 2nd half | Q_c last | Q_c std, 2nd half |",
             "|---|---|---|---|---|"]
    rows, series = [], []
    for task, cells in ANALYSES["qstability"].items():
        for algo, sets in cells:
            cell = read_cell(task, cell_name(task, algo, sets), kept)
            if cell is None:
                lines.append(f"| {sets['chunk_len']} | not run | | | |")
                continue
            stats = {}
            for key in ("qr_mean", "qc_mean"):
                xs, ys = curve(cell["metrics"], key, phase="critic")
                half = ys[len(ys) // 2:]
                stats[key] = (ys[-1] if ys else float("nan"),
                              statistics.pstdev(half) if len(half) > 1 else float("nan"))
                series.append((key, sets["chunk_len"], xs, ys))
            lines.append(f"| {sets['chunk_len']} | {stats['qr_mean'][0]:.3f} | "
                         f"{stats['qr_mean'][1]:.3f} | {stats['qc_mean'][0]:.3f} | "
                         f"{stats['qc_mean'][1]:.3f} |")
            rows.append(dict(task=task, chunk_len=sets["chunk_len"],
                             qr_last=stats["qr_mean"][0], qr_std_second_half=stats["qr_mean"][1],
                             qc_last=stats["qc_mean"][0], qc_std_second_half=stats["qc_mean"][1]))
    lines += ["", "Batch means of the critic blocks (mean over seeds 0-2); the std is over the "
              "block means of the critic phase's second half. " + QUICK_NOTE]
    md = "\n".join(lines)
    _write(out, "qstability", md, rows)
    if series:
        plt = _plt()
        fig, axes = plt.subplots(1, 2, figsize=(9, 3.2))
        for key, h, xs, ys in series:
            ax = axes[0 if key == "qr_mean" else 1]
            ax.plot(xs, ys, lw=1.2, label=f"h = {h}")
        axes[0].set_title("batch-mean Q_r (critic phase)", fontsize=9)
        axes[1].set_title("batch-mean Q_c (critic phase)", fontsize=9)
        for ax in axes:
            ax.set_xlabel("gradient step")
            ax.legend(fontsize=7)
        fig.suptitle("vanilla h-step IQL on BallRun (r2pac-no-penalty, seed means)", fontsize=10)
        _savefig(fig, out / "qstability.png")
        plt.close(fig)
    return md


def report_valuemaps(kept: Path = KEPT, out: Path = HERE, maps: Path = MAPS) -> str:
    lines = ["# Figures 3 and 8 on our data: value maps", "",
             "| task | embedding | states | Spearman(V_r, V_c) | Spearman(Vbar_r, V_c) | map |",
             "|---|---|---|---|---|---|"]
    rows = []
    for t in VALUE_MAP_TASKS:
        f = maps / f"{t}.json"
        if not f.is_file():
            lines.append(f"| {t} | not made | | | | |")
            continue
        info = json.loads(f.read_text())
        a, b = info.get("spearman_V_r_vs_V_c"), info.get("spearman_Vbar_r_vs_V_c")
        lines.append(f"| {t} | {info['embedding']} | {info['states']} | {a:+.2f} | {b:+.2f} | "
                     f"[{t}.png](value_maps/{t}.png) |")
        rows.append(dict(task=t, embedding=info["embedding"], states=info["states"],
                         spearman_vr_vc=a, spearman_vbar_r_vc=b))
    lines += ["", "Seed 0's final critics: V_c and Vbar_r of `r2pac`, V_r of `r2pac-no-penalty`. "
              "The paper's claim, as numbers: V_r high where V_c is high (a positive first "
              "correlation), Vbar_r low there (a lower second one). " + QUICK_NOTE]
    md = "\n".join(lines)
    _write(out, "valuemaps", md, rows)
    return md


def report_variants(kept: Path = KEPT, out: Path = HERE) -> str:
    names = {"r2pac": "Ours (CFG)", "r2pac-awr-flow": "AWR-Flow (Fig. 9)",
             "r2pac-hj": "feasibility (Fig. 10)"}
    lines = ["# Figures 9 and 10 on our data: AWR-Flow and the HJ feasibility variant", "",
             "| task | " + " | ".join(names[a] for a in VARIANT_ALGOS) + " |",
             "|---|" + "---|" * len(VARIANT_ALGOS)]
    rows, panels = [], []
    for t in VARIANT_TASKS:
        series, cells_md = [], []
        for a in VARIANT_ALGOS:
            cell = read_cell(t, cell_name(t, a, {}), kept)
            s = score(cell)
            cells_md.append(fmt_score(s))
            rows.append(dict(task=t, algo=a, reward=None if s is None else round(s[0], 4),
                             cost=None if s is None else round(s[2], 4)))
            if cell is not None:
                series.append((names[a], cell))
        lines.append(f"| {t} | " + " | ".join(cells_md) + " |")
        panels.append((t, series))
    lines += ["", "Final normalised reward / cost, mean ± std over seeds 0-2; **bold**: safe. "
              + QUICK_NOTE]
    md = "\n".join(lines)
    _write(out, "variants", md, rows)
    if any(s for _, s in panels):
        _curve_grid(panels, out / "variants.png", "Figures 9-10 on our data (seed means)")
    return md


REPORTS = {"table2": report_table2, "alpha": report_alpha, "h": report_h,
           "qstability": report_qstability, "valuemaps": report_valuemaps,
           "variants": report_variants}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="analyses.py", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("plan")
    p.add_argument("--analysis", action="append", choices=list(ANALYSES))
    r = sub.add_parser("run")
    r.add_argument("--task", action="append", help="only this task's chain (repeatable)")
    r.add_argument("--analysis", action="append", choices=list(ANALYSES),
                   help="only this analysis's cells (repeatable)")
    r.add_argument("--runs", default="runs/analyses")
    r.add_argument("--before-decision", action="store_true",
                   help="run although R2PAC's default is not settled yet (not the protocol's "
                        "runs: PROTOCOL.md waits for the decision)")
    q = sub.add_parser("report")
    q.add_argument("names", nargs="*", help=f"any of {', '.join(REPORTS)} (default: all)")
    args = ap.parse_args(argv)
    try:
        if args.cmd == "plan":
            cells = plan(args.analysis or tuple(ANALYSES))
            for t, cs in cells.items():
                print(f"{t}: {', '.join(cs)}")
            print(f"{sum(len(c) for c in cells.values())} cells in {len(cells)} chains")
            return 0
        if args.cmd == "report":
            unknown = [n for n in args.names if n not in REPORTS]
            if unknown:
                raise AnalysesError(f"unknown report {', '.join(unknown)}; choose from "
                                    f"{', '.join(REPORTS)}")
            for n in args.names or REPORTS:
                REPORTS[n]()
                print(f"wrote {HERE / n}.md")
            return 0
        if not args.before_decision and not decision_landed():
            raise AnalysesError(
                f"R2PAC's default is not settled yet ({DECISION}: no verdict, or a winner whose "
                "confirmation is not in, or a confirmed winner not yet made the default): "
                "PROTOCOL.md runs the analyses at the settled default; finish the decision first "
                "(experiments/r2pac_decision), or pass --before-decision for a trial")
        chains = plan(args.analysis or tuple(ANALYSES), args.task)
        decide = _decision()
        failed = 0
        for task, cells in chains.items():
            try:
                with _stdout_to_stderr():
                    dataset = decide.pinned_file(task, log=print)
            except (FileNotFoundError, KeyError, ValueError) as e:
                print(f"!! {task}: no pinned file ({e}); its chain is skipped")
                failed += 1
                continue
            status = run_chain(task, cells, dataset, Path(args.runs))
            failed += sum(v == "failed" for v in status.values())
        return 1 if failed else 0
    except AnalysesError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2


def _stdout_to_stderr():
    import contextlib

    return contextlib.redirect_stdout(sys.stderr)


if __name__ == "__main__":
    sys.exit(main())

"""The data factory's quality bar (issue 5): on every task with a generated dataset, R2PAC
(quick preset) should be safe and ahead of BC-safe, averaged over 3 seeds.

    python experiments/data_factory/quality_bar.py [--tasks CarGoal2,SwimmerVelocity,...]
        [--data v1|v2] [--out runs/quality_bar] [--seeds 3] [--eval-every 20000]
        [--physics auto|mujoco|mjx] [--report-only] [--details]
        [--archive experiments/data_factory/results]

`--data v1` (default): the cache's scripted files, agents r2pac, bc-all, bc-safe (the bar as it
ran on the scripted v1 data). `--data v2`: each task's learned-behaviour file at DSRL's size
(`python -m r2pac_jax.data make --task T --source ppo-lagrangian`; a task without one is
skipped with a note), passed with --dataset, and the two one-step MLP cloners as well.

Each (task, algo) is one `python -m r2pac_jax.train` run in OUT/TASK/ALGO; a finished run
(results.json present) is skipped, an interrupted one resumes from its checkpoint, so the
experiment can be stopped and restarted task by task. Data come from the cache
(v1: `python -m r2pac_jax.data make --task TASK --source scripted`; v2: the learned file at
DSRL's size), generated on first use. The table (paper format,
r2pac / bc-all / bc-safe per task, with the verdict) goes to OUT/quality_bar.md; the command,
machine and date belong beside it in experiments/data_factory/QUALITY_BAR.md.

`--archive DIR` copies each finished task's results into DIR/TASK/ALGO.json, with its dataset's
card and composition plot, for committing; `report` reads that layout too, so
`--report-only --out experiments/data_factory/results` gives the table of every archived task.
"""
from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path

ALGOS_V1 = ("r2pac", "bc-all", "bc-safe")
ALGOS_V2 = ALGOS_V1 + ("bc-all-mlp", "bc-safe-mlp")
ALGOS = ALGOS_V1  # the columns of a report when the runs do not say otherwise


def learned_file(task: str):
    """The task's learned-behaviour (v2) file: DSRL's budget first, else the largest (a budget
    fitted to a session: its name and card say so); None if there is none."""
    from r2pac_jax.data import factory
    from r2pac_jax.tasks import get_task

    t = get_task(task)
    return None if t.collection is None else factory.find_learned(t)


def default_tasks() -> list[str]:
    from r2pac_jax.data import factory
    from r2pac_jax.tasks import TASKS

    return [n for n, t in TASKS.items() if t.has_env and factory.has_source(t)]


def run_one(task: str, algo: str, out: Path, seeds: int, eval_every: int,
            physics: str = "auto", dataset=None) -> None:
    from r2pac_jax.tasks import get_task

    run_dir = out / task / algo
    if (run_dir / "results.json").exists() or (run_dir / "skipped.json").exists():
        return
    reason = _untrainable(algo, dataset)
    if reason:  # recorded, so the table says why the cell is empty
        from r2pac_jax.io import atomic_write_json

        atomic_write_json(run_dir / "skipped.json", {"skipped": reason, "dataset": str(dataset)})
        print(f"{task} {algo}: skipped, {reason}", flush=True)
        return
    if get_task(task).family == "demo":  # pure JAX: no physics backend to choose
        physics = "auto"
    cmd = [sys.executable, "-m", "r2pac_jax.train", "--task", task, "--algo", algo,
           "--preset", "quick", "--seeds", str(seeds), "--baselines", "none",
           "--eval-every", str(eval_every), "--physics", physics, "--out", str(run_dir),
           "--no-progress"]
    if dataset is not None:
        cmd += ["--dataset", str(dataset)]
    if (run_dir / "checkpoints").is_dir():
        cmd.append("--resume")
    print(" ".join(cmd), flush=True)
    subprocess.run(cmd, check=True)


def _untrainable(algo: str, dataset) -> str | None:
    """Why `algo` cannot train on `dataset` (a safe cloner on a file without a safe episode,
    by the file's card), or None."""
    from r2pac_jax.data import factory

    if dataset is None or "safe" not in algo:
        return None
    card = factory.card_path(Path(dataset))
    if card.exists() and json.loads(card.read_text()).get("safe_trajectories") == 0:
        return "the data hold no episode with cost <= kappa"
    return None


def _algos(out: Path) -> tuple:
    """The agents of a results folder: v2 folders (marked by data.json) have the MLP cloners."""
    marker = out / "data.json"
    if marker.exists() and json.loads(marker.read_text()).get("data") == "v2":
        return ALGOS_V2
    return ALGOS_V1


def verdict(row: dict, against: str = "bc-safe") -> str:
    """'pass' when r2pac is safe and its reward is above `against`'s, else what failed."""
    if not all(a in row for a in ("r2pac", against)):
        return "incomplete"
    r, b = row["r2pac"], row[against]
    if "skipped" in r or "skipped" in b:
        return f"fail: no {against} ({(r if 'skipped' in r else b)['skipped']})"
    problems = []
    if r["normalized_cost"]["mean"] >= 1.0:
        problems.append("r2pac unsafe")
    if r["normalized_reward"]["mean"] <= b["normalized_reward"]["mean"]:
        problems.append(f"r2pac reward <= {against}")
    return "pass" if not problems else "fail: " + ", ".join(problems)


def simulator(row: dict) -> str:
    """The simulator(s) that scored a row's runs (scores of different simulators, e.g. the
    Bullet tasks' `bullet` and `mjx`, are not interchangeable): each run's recorded
    `eval_backend`, else its `--physics` as asked (runs made before the key existed)."""
    names = {r.get("eval_backend") or f"physics={r.get('physics', '?')}"
             for r in row.values() if "skipped" not in r}
    return ", ".join(sorted(names)) or "-"


def _result_file(out: Path, task: str, algo: str) -> Path | None:
    """A run's results: a run directory's `results.json`, or an archived `ALGO.json`."""
    for f in (out / task / algo / "results.json", out / task / algo / "skipped.json",
              out / task / f"{algo}.json"):
        if f.exists():
            return f
    return None


def archive(out: Path, task: str, dest: Path) -> list[Path]:
    """Copy a task's finished results (and its dataset's card and plot) from the run folder
    `out` into `dest/TASK/`, atomically; returns the files written (none if unfinished)."""
    from r2pac_jax.io import atomic_path

    def copy(src: Path, target: Path) -> Path:
        with atomic_path(target) as tmp:
            shutil.copyfile(src, tmp)
        return target

    algos = _algos(out)
    files = {algo: _result_file(out, task, algo) for algo in algos}
    if any(f is None for f in files.values()):
        return []
    written = []
    for algo, f in files.items():
        target = dest / task / f"{algo}.json"
        if f.resolve() != target.resolve():
            written.append(copy(f, target))
    dataset = Path(json.loads(files["r2pac"].read_text()).get("dataset", ""))
    # (a skipped cell's record is archived as ALGO.json too: {"skipped": reason})
    for side in (dataset.with_suffix(".json"), dataset.with_suffix(".png")):
        if side.is_file():
            written.append(copy(side, dest / task / side.name))
    return written


def details(out: Path, task: str) -> str:
    """Per-seed markdown rows of one task's finished runs: what the mean table hides (which
    seeds are unsafe, how many episodes cost nothing, how long each run took)."""
    import numpy as np

    lines = ["| algo | reward | cost | per-seed reward | per-seed cost | episodes with cost 0 "
             "| wall s |", "|---|---|---|---|---|---|---|"]
    for algo in _algos(out):
        f = _result_file(out, task, algo)
        if f is None:
            continue
        r = json.loads(f.read_text())
        if "skipped" in r:
            lines.append(f"| {algo} | skipped: {r['skipped']} | | | | | |")
            continue
        nr, nc = r["normalized_reward"], r["normalized_cost"]
        zero = float(np.mean(np.asarray(r["costs"]) == 0)) if "costs" in r else float("nan")
        lines.append(
            f"| {algo} | {nr['mean']:.2f} ± {nr['std']:.2f} | {nc['mean']:.2f} ± {nc['std']:.2f} "
            f"| {' '.join(f'{x:.2f}' for x in nr['per_seed'])} "
            f"| {' '.join(f'{x:.2f}' for x in nc['per_seed'])} | {zero:.0%} "
            f"| {r.get('wall_time_s', float('nan')):.0f} |")
    return "\n".join(lines) + "\n"


def report(out: Path) -> str:
    """Table of every task with a finished run under `out` (runs made task by task over
    several invocations accumulate), in registry order."""
    from r2pac_jax.io import atomic_write_text
    from r2pac_jax.report import results_table
    from r2pac_jax.tasks import TASKS

    on_disk = {p.name for p in out.iterdir() if p.is_dir()} if out.is_dir() else set()
    cells: dict[str, dict] = {}
    algos = _algos(out)
    for task in [t for t in TASKS if t in on_disk] + sorted(on_disk - set(TASKS)):
        row = {}
        for algo in algos:
            f = _result_file(out, task, algo)
            if f is not None:
                row[algo] = json.loads(f.read_text())
        if row:
            cells[task] = row
    if not cells:
        return "no finished run yet"
    # skipped cells stay in `cells` (the verdicts name them) and out of the score table
    skipped = {t: {a: v["skipped"] for a, v in r.items() if "skipped" in v}
               for t, r in cells.items()}
    scored = {t: {a: v for a, v in r.items() if "skipped" not in v} for t, r in cells.items()}
    lines = [results_table(scored, list(algos)), ""]
    lines += [f"{t}: no {', '.join(s)} ({next(iter(s.values()))})." for t, s in skipped.items()
              if s]
    if any(skipped.values()):
        lines.append("")
    if "bc-safe-mlp" in algos:
        lines += ["| Task | verdict | r2pac against bc-safe-mlp (reported) | evaluated by |",
                  "|---|---|---|---|"]
        lines += [f"| {t} | {verdict(r)} | {verdict(r, 'bc-safe-mlp')} | {simulator(r)} |"
                  for t, r in cells.items()]
    else:
        lines += ["| Task | verdict | evaluated by |", "|---|---|---|"]
        lines += [f"| {t} | {verdict(r)} | {simulator(r)} |" for t, r in cells.items()]
    text = "\n".join(lines) + "\n"
    atomic_write_text(out / "quality_bar.md", text)
    return text


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tasks", default=None, help="comma-separated (default: every task with "
                                                  "an environment and a data source)")
    ap.add_argument("--data", default="v1", choices=["v1", "v2"],
                    help="v1: the cache's scripted files (r2pac, bc-all, bc-safe); v2: the "
                         "learned files at DSRL's size (and the MLP cloners)")
    ap.add_argument("--out", default=None,
                    help="default runs/quality_bar (v1) or runs/quality_bar_v2")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--eval-every", type=int, default=20_000,
                    help="evaluate at the end of the quick preset's 20k policy steps only")
    ap.add_argument("--physics", default="auto",
                    help="evaluation physics; on a GPU machine `mujoco` (C MuJoCo on its CPU "
                         "cores) beats MJX for the navigation tasks (benchmarks/RESULTS.md)")
    ap.add_argument("--report-only", action="store_true")
    ap.add_argument("--details", action="store_true",
                    help="also print per-seed rows of each task in --tasks")
    ap.add_argument("--archive", default=None, metavar="DIR",
                    help="copy each finished task's results, dataset card and plot into "
                         "DIR/TASK/ (e.g. experiments/data_factory/results)")
    args = ap.parse_args()
    tasks = args.tasks.split(",") if args.tasks else default_tasks()
    out = Path(args.out or ("runs/quality_bar" if args.data == "v1" else "runs/quality_bar_v2"))
    if args.data == "v2":
        from r2pac_jax.io import atomic_write_json

        atomic_write_json(out / "data.json", {"data": "v2"})
    if not args.report_only:
        for task in tasks:
            dataset = None
            if args.data == "v1":  # the scripted file (train's own default is v2 now)
                from r2pac_jax.data import factory
                from r2pac_jax.tasks import get_task

                dataset = factory.find_cached(get_task(task)) or factory.generate_dataset(
                    get_task(task), source="scripted")
            if args.data == "v2":
                dataset = learned_file(task)
                if dataset is None:
                    print(f"note: {task} has no learned (v2) file at DSRL's size yet; skipped "
                          f"(python -m r2pac_jax.data make --task {task} --source "
                          "ppo-lagrangian)", flush=True)
                    continue
            for algo in _algos(out):
                run_one(task, algo, out, args.seeds, args.eval_every, args.physics, dataset)
            print(report(out), flush=True)
    if args.archive:
        if args.data == "v2":
            from r2pac_jax.io import atomic_write_json

            atomic_write_json(Path(args.archive) / "data.json", {"data": "v2"})
        for task in tasks:
            for f in archive(out, task, Path(args.archive)):
                print(f"archived {f}")
    print(report(out))
    if args.details:
        for task in tasks:
            print(f"\n{task}\n\n{details(out, task)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

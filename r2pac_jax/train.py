"""The command line: train one algorithm (and its baselines) on a task, then print the table.

    python -m r2pac_jax.train --task ReachAvoid --preset quick --seeds 3

The training itself is `loop.py` (pure compiled blocks and the `Run` that drives them); this
module turns options into configs, checks everything it can before any data is generated or any
training starts, and runs the requested algorithm and its baselines on the same data.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Sequence

from r2pac_jax.agents import algo_module, algo_names
from r2pac_jax.config import Config, ConfigError, field_types, refuse_user_key, resolve_preset
from r2pac_jax.errors import R2pacError
from r2pac_jax.io import WriteError, atomic_write_text, claim_directory
from r2pac_jax.lanes import Lanes
from r2pac_jax.loop import (Run, TrainingDiverged, chunk_dataset, compiled,  # noqa: F401
                            make_block, make_data, make_train)
from r2pac_jax.planner import plan
from r2pac_jax.run_dir import is_legacy_run
from r2pac_jax.tasks import get_task

_TYPE_WORDS = {bool: "true or false", int: "an integer", float: "a number",
               tuple: "comma-separated integers", str: "a string"}


def parse_set(items: Sequence[str], algos: Sequence[str] = ("r2pac",)) -> dict:
    """--set key=value items -> {key: typed value}; a key must belong to one of `algos`."""
    types: dict[str, type] = {}
    for a in algos:
        types.update(field_types(a))
    out = {}
    for item in items:
        if "=" not in item:
            raise ConfigError(f"--set takes key=value, got {item!r}")
        k, v = item.split("=", 1)
        k = k.strip().replace("-", "_")
        refuse_user_key(k, "--set")
        if k not in types:
            raise ConfigError(f"--set: unknown config key {k!r} for {', '.join(algos)}; known "
                              f"keys: {', '.join(sorted(types))}")
        want = types[k]
        try:
            if want is bool:
                if v.lower() not in ("true", "false", "1", "0"):
                    raise ValueError
                out[k] = v.lower() in ("true", "1")
            elif want is int:
                out[k] = int(v)
            elif want is float:
                out[k] = float(v)
            elif want is tuple:
                out[k] = tuple(int(x) for x in v.split(","))
            else:
                out[k] = v
        except ValueError:
            raise ConfigError(f"--set {k}={v!r}: expected {_TYPE_WORDS.get(want, want.__name__)}"
                              ) from None
    return out


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m r2pac_jax.train",
                                 description="Train R2PAC (or a variant/baseline) offline and "
                                             "evaluate it with DSRL's scores.")
    ap.add_argument("--task", required=True, help="task name or DSRL id (e.g. ReachAvoid, CarGoal2)")
    ap.add_argument("--algo", default="r2pac", help=f"one of {', '.join(algo_names())}")
    ap.add_argument("--baselines", default="bc-all,bc-safe,bc-safe-mlp",
                    help="comma-separated algos trained after --algo on the same data for the "
                         "comparison table ('none' to skip)")
    ap.add_argument("--preset", default="auto", help="auto | paper | quick (auto: paper on an "
                                                     "accelerator, quick on a CPU)")
    ap.add_argument("--seeds", type=int, default=None, help="number of seeds (vmapped)")
    ap.add_argument("--seed-offset", type=int, default=0, help="first seed")
    ap.add_argument("--steps", type=int, default=None, help="gradient steps per phase")
    ap.add_argument("--chunk-len", type=int, default=None, help="action chunk length h")
    ap.add_argument("--dataset", default=None, help="a DSRL-format HDF5 file")
    ap.add_argument("--out", default=None, help="run directory (default runs/TASK-ALGO-TIME)")
    ap.add_argument("--resume", action="store_true", help="continue the run in --out")
    ap.add_argument("--physics", default="auto", help="auto | mjx | mujoco | jax | bullet: the simulator of evaluation rollouts "
                    "(auto: C MuJoCo on a CPU and MJX on an accelerator for MuJoCo tasks, "
                    "pybullet for the Bullet tasks, whose mjx / mujoco are MuJoCo re-creations "
                    "of the original's robots: benchmarks/FIDELITY.md)")
    ap.add_argument("--eval-episodes", type=int, default=None)
    ap.add_argument("--eval-every", type=int, default=None)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="any config value, e.g. --set quantile_alpha=0.8 (repeatable)")
    ap.add_argument("--no-progress", action="store_true")
    return ap


def describe(cfg: Config) -> str:
    """One line on what a config trains."""
    parts = [f"{cfg.total_steps} steps ({' + '.join(cfg.phases)})", f"{cfg.seeds} seeds vmapped",
             f"batch {cfg.batch_size}"]
    if cfg.chunk_len > 1:
        parts.append(f"h={cfg.chunk_len}")
    if cfg.data_filter == "safe":
        parts.append("safe episodes only")
    extra = {k: getattr(cfg, k) for k in algo_module(cfg.algo).HPARAMS}
    if "quantile_alpha" in extra:
        parts.append(f"alpha={cfg.quantile_alpha}, C={cfg.penalty_c} ({cfg.penalty_mode})")
    return f"{cfg.algo}: " + ", ".join(parts)


def resume_command(argv: Sequence[str], out: Path, prog: str = "python -m r2pac_jax.train") -> str:
    """The command line that continues the job `argv` started in `out`."""
    import shlex

    argv = list(argv)
    if "--out" not in argv and not any(a.startswith("--out=") for a in argv):
        argv += ["--out", str(out)]
    if "--resume" not in argv:
        argv.append("--resume")
    return f"{prog} {shlex.join(argv)}"


def interrupted_line(run, command: str) -> str:
    """One line for Ctrl-C: where training stood, what is kept, how to continue."""
    if run is None:
        where = "before training started"
    else:
        total = run.cfg.total_steps
        ck = (f"its last checkpoint is step {run.last_checkpoint} ({run.out / 'checkpoints'})"
              if run.last_checkpoint is not None else "no checkpoint was written yet (a resume "
              "starts it afresh)")
        where = f"{run.task.name} {run.cfg.algo} at step {run.step_reached} of {total}; {ck}"
    return f"interrupted: {where}; continue with: {command}"


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)

    def log(msg):
        print(msg, flush=True)

    from r2pac_jax.data import load_task_dataset
    from r2pac_jax.loop import check_run

    run = out = None  # what a Ctrl-C reports
    try:
        task = get_task(args.task)
        preset, why = resolve_preset(args.preset)
        log(why)
        args.preset = preset
        algos = [args.algo] + [b for b in args.baselines.split(",")
                               if b and b != "none" and b != args.algo]
        for a in algos:
            algo_module(a)  # an unknown name is refused with the known ones
        if args.resume and not args.out:
            raise ConfigError("--resume needs --out DIR (the run to continue)")
        if args.seed_offset < 0:
            # JAX folds a negative seed into uint32, so seed -1 would silently be seed 2**32 - 1
            raise ConfigError(f"--seed-offset {args.seed_offset}: seeds are integers >= 0; "
                              "pass --seed-offset 0 or more")
        if args.out is not None and not args.out.strip():
            raise ConfigError("--out '': an empty path; pass the run directory (or leave --out "
                              "out for runs/TASK-ALGO-TIME)")
        out = Path(args.out or f"runs/{task.name}-{args.algo}-{time.strftime('%Y%m%d-%H%M%S')}")
        # a folder the project did not write is refused before any data is made or loaded
        claim_directory(out, "run", legacy=is_legacy_run, check_only=True)
        # every config is checked before any data is generated or any training starts
        sets = parse_set(args.set, algos)
        main_only = {k: v for k, v in sets.items() if k in field_types(args.algo)}
        unknown_main = sorted(set(sets) - set(main_only))
        if unknown_main:
            raise ConfigError(f"--set {', '.join(unknown_main)}: not a config key of {args.algo} "
                              f"(its keys: {', '.join(sorted(field_types(args.algo)))})")
        asked = dict(steps=args.steps, chunk_len=args.chunk_len, seeds=args.seeds,
                     eval_episodes=args.eval_episodes, eval_every=args.eval_every)
        asked.update(sets)  # --set KEY=VALUE wins over the option of the same key
        # the requested algorithm refuses an option it cannot use; a baseline drops it (a note)
        cfgs = {a: plan(task, a, args.preset, asked, baseline=a != args.algo, log=log)
                for a in algos}
        task.check_physics(args.physics)
        if not task.has_env and args.eval_episodes is None:
            log(f"note: {task.name} has no environment in this install; training without "
                "evaluation")
        dirs = {a: out if a == args.algo else out / "baselines" / a for a in algos}
        if args.resume and not (out / "checkpoints").exists():
            log(f"note: --resume: {out} holds no checkpoint yet; starting afresh")
        ds = load_task_dataset(task, args.dataset, announce=log,
                               progress=not args.no_progress)
        from r2pac_jax.data.checks import checks_path

        if not checks_path(ds.source).exists():
            log(f"note: {ds.source} has not been checked (coverage, imitability): "
                f"python -m r2pac_jax.data check {ds.source}")
        for a in algos:
            check_run(cfgs[a], task, ds)
        results = {}
        for a in algos:
            cfg = cfgs[a]
            log(f"{describe(cfg)} -> {dirs[a]}")
            run = Run(cfg, task, ds, dirs[a], Lanes.build(cfg, list(range(
                args.seed_offset, args.seed_offset + cfg.seeds))), physics=args.physics,
                progress=not args.no_progress, log=log, dataset_label=ds.source)
            results[a] = run.run(resume=args.resume)
    except R2pacError as e:  # every user-facing error: its one line, no traceback
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        # Ctrl-C: checkpoints are written atomically, so what is on disk is complete; say so
        # in one line instead of a traceback (exit 130, the shell's code for SIGINT)
        where = out or Path(args.out or ".")
        print(interrupted_line(run, resume_command(argv, where)),
              file=sys.stderr, flush=True)
        return 130
    from r2pac_jax.report import TASK_CONTEXT, results_table, setting_line, verdict_line

    if all("normalized_reward" in r for r in results.values()):
        table = results_table({task.name: results})
        notes = [setting_line(cfgs[args.algo], task), verdict_line(results)]
        if task.name in TASK_CONTEXT:
            notes.append(f"Context: {TASK_CONTEXT[task.name]}.")
        table += "\n\n" + "\n".join(notes)
        try:
            atomic_write_text(out / "table.md", table + "\n")
        except WriteError as e:
            print(f"error: {e}", file=sys.stderr)
            return 2
        log("\n" + table)
    log(f"\nresults: {out / 'results.json'}; metrics: {out / 'metrics.jsonl'}; "
        f"policy: r2pac_jax.load_policy({str(out)!r})")
    return 0


if __name__ == "__main__":
    sys.exit(main())

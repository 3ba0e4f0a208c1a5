"""A run directory and its rules: claimed and locked while a run writes it, its identity
(config.json, lanes.json) checked on --resume, its results, policy and plots written atomically.

`loop.Run` drives the compiled blocks; everything it keeps on disk goes through here, so the
reliability rules for run directories (claimed before anything is written, one live writer,
a resumed run must be the run that was started) live in one place.

Files: config.json (the config and the dataset's identity), lanes.json (seeds, cells, task,
dataset, physics), metrics.jsonl / eval.jsonl (metrics_log.py), checkpoints/ (checkpoint.py),
policy/, results.json, training.png / eval.png.
"""
from __future__ import annotations

import contextlib
import json
from pathlib import Path

from r2pac_jax.config import Config, ConfigError
from r2pac_jax.io import atomic_write_json, claim_directory, lock_directory


def is_legacy_run(path: Path) -> bool:
    """A run directory written before directories were marked: its config.json and lanes.json
    read back as a run's, or it holds nothing but what a run killed before writing them left."""
    from r2pac_jax.policy import read_run

    try:
        cfg, lanes = read_run(path)
    except FileNotFoundError:
        return {p.name for p in path.iterdir()} <= {".lock", "checkpoints"}
    return isinstance(lanes, dict) and "seeds" in lanes and bool(cfg.task)


def config_changes(old: Config, new: Config) -> list[str]:
    """Flat keys whose values differ between two configs, as 'key: old -> new'."""
    a, b = old.flat(), new.flat()
    a.update(task=old.task, algo=old.algo)
    b.update(task=new.task, algo=new.algo)
    return [f"{k}: {a.get(k)!r} -> {b.get(k)!r}" for k in sorted(set(a) | set(b))
            if a.get(k) != b.get(k)]


class RunDirectory:
    """The files of one run (see the module docstring). `out`: the directory."""

    def __init__(self, out):
        self.out = Path(out)

    @contextlib.contextmanager
    def held(self):
        """Claim and lock the directory while a run writes it: a foreign directory is refused
        before the lock file is made, and it is marked once the lock is held (a directory that
        another live process writes is left untouched: DirectoryBusy)."""
        claim_directory(self.out, "run", legacy=is_legacy_run, check_only=True)
        lock = lock_directory(self.out)
        try:
            claim_directory(self.out, "run", legacy=is_legacy_run)
            yield self
        finally:
            lock.close()

    def check_same_run(self, cfg: Config, lanes, dataset_info: dict, physics: str) -> None:
        """A resumed run must be the run that was started: same config, data, seeds, cells and
        evaluation backend; ConfigError listing every difference otherwise."""
        from r2pac_jax.policy import read_run

        try:
            old_cfg, old_lanes = read_run(self.out)
        except FileNotFoundError:
            return
        diff = config_changes(old_cfg, cfg)
        stored = json.loads((self.out / "config.json").read_text()).get("dataset", {})
        if stored.get("sha256") not in (None, dataset_info["sha256"]):
            diff.append(f"dataset: {stored.get('source')} ({stored.get('transitions')} "
                        f"transitions, sha256 {stored['sha256'][:12]}) -> "
                        f"{dataset_info['source']} ({dataset_info['transitions']}, "
                        f"{dataset_info['sha256'][:12]})")
        for k in ("seeds", "cell_hparams"):
            if old_lanes.get(k) != getattr(lanes, k):
                diff.append(f"{k}: {old_lanes.get(k)} -> {getattr(lanes, k)}")
        if old_lanes.get("physics", physics) != physics:  # evaluation's backend
            diff.append(f"physics: {old_lanes['physics']!r} -> {physics!r}")
        if diff:
            raise ConfigError(f"--resume: {self.out} was started with other settings ("
                              f"{'; '.join(diff)}); resume it with the options it was started "
                              "with, or choose another --out")

    def refuse_existing_run(self) -> None:
        """Without --resume, a directory that holds a checkpoint is refused (never overwritten)."""
        from r2pac_jax.checkpoint import Checkpointer

        if not (self.out / "checkpoints").is_dir():
            return
        held = Checkpointer(self.out / "checkpoints")
        latest = held.latest_step()
        held.close()
        if latest is not None:
            raise ConfigError(f"{self.out} already holds a run (checkpoint at step {latest}); "
                              "pass --resume to continue it or choose another --out")

    def write_identity(self, cfg: Config, dataset_info: dict, lanes, task_name: str,
                       dataset_label: str, physics: str) -> None:
        """config.json (the config and the dataset's identity) and lanes.json."""
        atomic_write_json(self.out / "config.json",
                          dict(json.loads(cfg.to_json()), dataset=dataset_info))
        atomic_write_json(self.out / "lanes.json", dict(
            seeds=lanes.seeds, cells=lanes.cells, cell_hparams=lanes.cell_hparams,
            task=task_name, dataset=dataset_label, physics=physics))

    def write_results(self, results: dict) -> None:
        atomic_write_json(self.out / "results.json", results)

    def save_policy(self, total_steps: int, params, meta: dict) -> None:
        """The final policy parameters of every lane (what `load_policy` reads)."""
        from r2pac_jax.checkpoint import save_policy

        save_policy(self.out / "policy", total_steps, params, meta)

    def plot(self, logs, title: str, metrics) -> None:
        from r2pac_jax.report import plot_run

        plot_run(logs, self.out, title, metrics)

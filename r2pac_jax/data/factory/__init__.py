"""The data factory: DSRL-format datasets made locally for registered tasks.

A source is a dict: `name`, `generate(n_trajectories, seed, progress) -> DSRL arrays`,
`default_trajectories`, and optionally `oversample` (generate that many times more
trajectories, then thin them to the requested number with DSRL's density grid).

Two kinds of source: `ppo-lagrangian` (DSRL's recipe: an observation-based PPO-Lagrangian agent
under DSRL's cost schedule, trajectories kept along training, collect.py: data version 2; C
MuJoCo on a CPU, MJX, pybullet or pure JAX, resumable), the default of every task with an
environment except the ReachAvoid demonstration; and `scripted` (the controllers of
navigation.py, velocity.py and reach_avoid.py: data version 1), only when named, since their
safe trajectories cannot be imitated from observations (QUALITY_BAR.md). A scripted file's card
lists the coverage checks it fails, measured on the file, and what the v1 quality bar measured
of its imitability.

Files go to `$R2PAC_DATA_DIR` (default `~/.cache/r2pac_jax/datasets`) as
`{Task}-generated-s{seed}-n{trajectories}.hdf5` (scripted v1) or
`{Task}-generated-ppolag-v2-s{seed}-n{trajectories}[-b{env_steps}].hdf5` (learned; `-b` when
the RL budget differs from DSRL's) with a JSON card beside them; `train` prefers the learned
files and warns, naming the file, when it falls back to a scripted one. The HDF5 file is written
atomically and the card last, so a dataset counts as present only when both exist.
"""
from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Callable, Optional, Union

from r2pac_jax.data.dsrl import DatasetError, LogMismatch, validate, write_dsrl  # noqa: F401
from r2pac_jax.data.factory.card import card_path, data_budget, make_card  # noqa: F401 (API)
from r2pac_jax.io import atomic_write_json
from r2pac_jax.tasks import TaskSpec


class FactoryError(DatasetError):
    """A dataset cannot be generated (no source, bad size, unwritable cache); the message says
    the fix. A DatasetError, so the train CLI reports it like any other data problem."""


def _sources() -> dict[str, dict]:
    """Task name -> its data source (navigation.py and velocity.py say which is default)."""
    from r2pac_jax.data.factory import navigation, reach_avoid, velocity

    return {"ReachAvoid": reach_avoid.SOURCE, **navigation.SOURCES, **velocity.SOURCES}


SOURCE_KINDS = ("scripted", "ppo-lagrangian")


def _source(task: TaskSpec, kind: str, physics: str = "auto") -> dict:
    """The data source of `kind` for a task; FactoryError naming the fix if there is none."""
    if kind not in SOURCE_KINDS:
        raise FactoryError(f"unknown data source {kind!r}; choose one of {', '.join(SOURCE_KINDS)}")
    srcs = _sources()
    if not has_source(task):
        raise FactoryError(f"no data source for task {task.name!r} yet; tasks with one: "
                           f"{', '.join(sorted(n for n in _all_names() if n != task.name))}. "
                           "Pass --dataset FILE or put DSRL's file in $DSRL_DATASET_DIR")
    if kind == "scripted":
        if task.name not in srcs:
            raise FactoryError(f"task {task.name} has no scripted data source (its data come "
                               "from the learned recipe only): use --source ppo-lagrangian")
        return srcs[task.name]
    if task.collection is None:
        raise FactoryError(f"task {task.name} has no learned-behaviour recipe yet; use "
                           "--source scripted")
    return dict(name="ppo-lagrangian", default_trajectories=task.collection.trajectories)


def _all_names() -> list[str]:
    from r2pac_jax.tasks import TASKS

    return sorted(n for n, t in TASKS.items() if has_source(t))


def has_source(task: TaskSpec) -> bool:
    """A scripted source, or the learned recipe on an environment."""
    return task.name in _sources() or (task.collection is not None and task.has_env)


def learned_by_default(task: TaskSpec) -> bool:
    """Whether a task's data come from the learned recipe unless `scripted` is named: every
    task with a recipe except the demonstration task (ReachAvoid, the paper's Figure 1)."""
    return task.collection is not None and task.family != "demo"


def default_source(task: TaskSpec) -> str:
    """`data make`'s (and `generate_dataset`'s) source when none is named: the learned recipe
    (data v2) for every task with one but the demonstration task; scripted controllers (data
    v1) never by default elsewhere (data issue, item 6)."""
    return "ppo-lagrangian" if learned_by_default(task) else "scripted"


# What the quality bar measured on each task's default scripted (v1) file: bc-safe's normalised
# cost, mean over 3 seeds (experiments/data_factory/results/quality_bar.md, 2026-11/12, quick
# preset). >= 1: cloning the safe trajectories gave an unsafe policy, the imitability failure
# that retired these sources as a default.
V1_BC_SAFE_COST = {
    "CarButton1": 13.29, "CarButton2": 15.38, "CarPush1": 2.36, "CarPush2": 2.81,
    "CarGoal1": 8.51, "CarGoal2": 13.23, "PointGoal1": 6.67, "PointGoal2": 10.42,
    "PointButton1": 5.79, "PointButton2": 11.60, "PointPush1": 4.97, "PointPush2": 2.78,
    "AntVelocity": 0.14, "HalfCheetahVelocity": 0.78, "SwimmerVelocity": 4.70,
    "HopperVelocity": 0.60, "Walker2dVelocity": 0.76,
}


def scripted_limits(task: TaskSpec) -> Optional[str]:
    """A scripted (v1) file's known limits for its card and a warning; None for the demo."""
    if not learned_by_default(task):
        return None
    cost = V1_BC_SAFE_COST.get(task.name)
    measured = ("" if cost is None else
                f"; on the default v1 file the quality bar's bc-safe scored normalised cost "
                f"{cost:.2f} ({'unsafe' if cost >= 1 else 'safe'}; "
                "experiments/data_factory/QUALITY_BAR.md)")
    return (f"scripted controllers on simulator state (data v1): their safe trajectories are "
            f"not reliably imitable from observations{measured}. The imitability checks were not "
            f"run at generation (python -m r2pac_jax.data check FILE runs them); DSRL's recipe: "
            f"python -m r2pac_jax.data make --task {task.name}")


def cache_dir() -> Path:
    return Path(os.environ.get("R2PAC_DATA_DIR", "~/.cache/r2pac_jax/datasets")).expanduser()


def is_legacy_cache(path: Path) -> bool:
    """A dataset cache written before directories were marked: every entry is a generated
    file's (its name holds '-generated-': the file, card, plot, checks, partial state, lock)."""
    return all("-generated-" in p.name or p.name.startswith(".write-test-")
               for p in path.iterdir())


def parse_recipe_values(items) -> dict:
    """`data make --ppo`'s KEY=VALUE items -> {key: value} (JSON values; a bare word a string)."""
    import json

    out = {}
    for it in items:
        if "=" not in it:
            raise FactoryError(f"--ppo takes KEY=VALUE items, got {it!r} (e.g. "
                               "stagger_starts=true)")
        k, v = it.split("=", 1)
        try:
            out[k] = json.loads(v)
        except ValueError:
            out[k] = v
    return out


def _trial_tag(trial: Optional[dict]) -> str:
    """The name's mark of tried recipe values: -ppo-KEY_VALUE-... ('' for none)."""
    if not trial:
        return ""
    import json
    import re

    parts = [f"{k}_{json.dumps(v) if not isinstance(v, str) else v}"
             for k, v in sorted(trial.items())]
    return "-ppo-" + re.sub(r"[^A-Za-z0-9_.+-]", "", "-".join(parts))


def dataset_path(task: TaskSpec, seed: int, trajectories: int, source: str = "scripted",
                 env_steps: Optional[int] = None, trial: Optional[dict] = None) -> Path:
    """`trial`: recipe values tried (`data make --ppo`), marked in the name so that such a
    file is never found as the task's recipe file."""
    if source == "scripted":
        return cache_dir() / f"{task.name}-generated-s{seed}-n{trajectories}.hdf5"
    from r2pac_jax.data.factory.collect import DATA_VERSION

    budget = "" if env_steps in (None, task.collection.env_steps) else f"-b{env_steps}"
    return cache_dir() / (f"{task.name}-generated-ppolag-v{DATA_VERSION}-s{seed}-"
                          f"n{trajectories}{budget}{_trial_tag(trial)}.hdf5")


_BUDGET_IN_NAME = re.compile(r"-b(\d+)\.hdf5$")


def budget_in_name(name: str) -> Optional[int]:
    """The RL budget a learned file's name carries (`dataset_path`'s `-b<env steps>`: a budget
    other than DSRL's); None where it carries none."""
    m = _BUDGET_IN_NAME.search(str(name))
    return int(m.group(1)) if m else None


def make_command(task_name: str, file_name: str) -> list[str]:
    """The `python -m r2pac_jax.data make` argv (from `-m` on) that makes the learned file
    named `file_name` again: its task, source and, where the name carries one, its budget."""
    budget = budget_in_name(file_name)
    return ["-m", "r2pac_jax.data", "make", "--task", task_name, "--source", "ppo-lagrangian"] \
        + (["--budget", str(budget)] if budget is not None else [])


def learned_path(task: TaskSpec, seed: int = 0, env_steps: Optional[int] = None) -> Path:
    """The task's learned-behaviour file at DSRL's size and budget (what `data make --source
    ppo-lagrangian` writes by default), or at the RL budget `env_steps`, whether or not it
    exists yet."""
    return dataset_path(task, seed, task.collection.trajectories, "ppo-lagrangian", env_steps)


def find_cached(task: TaskSpec) -> Optional[Path]:
    """A complete generated dataset (file and card) for the task, default size/seed first."""
    d = cache_dir()
    if not d.is_dir():
        return None
    found = [p for p in sorted(d.glob(f"{task.name}-generated-s*-n*.hdf5"))
             if card_path(p).exists()]
    if not found:
        return None
    src = _sources().get(task.name)
    if src is not None:
        default = dataset_path(task, 0, src["default_trajectories"])
        if default in found:
            return default
    return found[0]


def find_learned(task: TaskSpec) -> Optional[Path]:
    """A complete learned-behaviour dataset (data v2+) for the task: DSRL's size and budget
    first, then the largest file."""
    d = cache_dir()
    if not d.is_dir() or task.collection is None:
        return None
    found = [p for p in d.glob(f"{task.name}-generated-ppolag-v*-s*-n*.hdf5")
             if card_path(p).exists() and "-ppo-" not in p.name]  # trials are never found
    if not found:
        return None
    default = learned_path(task)
    if default in found:
        return default
    return max(found, key=lambda p: (p.stat().st_size, p.name))


def default_trajectories(task: TaskSpec) -> int:
    return _source(task, "scripted")["default_trajectories"]


def check_at_least_one(**counts) -> None:
    """Refuse a count below 1 (trajectories, budget, num_envs, checkpoint_every; None = the
    default), named as its `data make` option."""
    for key, value in counts.items():
        if value is not None and value < 1:
            raise FactoryError(f"--{key.replace('_', '-')} must be >= 1, got {value}")


def generate_dataset(task: TaskSpec, trajectories: Optional[int] = None, seed: int = 0,
                     progress: Union[bool, Callable[[int], None], None] = None,
                     plot: bool = True,
                     source: Optional[str] = None, physics: str = "auto",
                     env_steps: Optional[int] = None, force: bool = False,
                     log: Callable[[str], None] = print, trial: Optional[dict] = None,
                     **learned) -> Optional[Path]:
    """Make (or reuse) the dataset file for (task, seed, trajectories, source); its path.
    `source` None is `default_source(task)` (the learned recipe but for the demo task).

    `force` discards an existing file (and a learned source's partial state) first. `trial`:
    recipe values tried, added to `learned["ppo"]` and marked in the file's name. For the
    learned source, `env_steps` is the RL budget (default DSRL's) and `learned` passes
    `collect.generate_learned`'s options (`ppo`, `checkpoint_every`, `stop_after`, ...);
    it returns None when stopped early by `stop_after`. `progress`: the scripted sources call it
    once per finished trajectory; the learned source draws its own bar when it is truthy."""
    if source is None:
        source = default_source(task)
    src = _source(task, source, physics)
    n = trajectories or src["default_trajectories"]
    # refused before the lock file and the partial state exist, whoever the caller is
    check_at_least_one(trajectories=n, budget=env_steps,
                       checkpoint_every=learned.get("checkpoint_every"))
    path = dataset_path(task, seed, n, source, env_steps, trial=trial)
    if trial:
        learned["ppo"] = {**learned.get("ppo", {}), **trial}
    from r2pac_jax.io import ForeignDirectory, WriteError, claim_directory

    try:
        # the cache must be new, empty or ours: a user's folder named by R2PAC_DATA_DIR is
        # refused (ForeignDirectory passes through with its own message)
        claim_directory(path.parent, "data cache", legacy=is_legacy_cache)
    except ForeignDirectory:
        raise
    except WriteError as e:
        raise FactoryError(f"cache directory {path.parent} is not writable ({e}); set "
                           "R2PAC_DATA_DIR to a writable directory") from e
    try:
        probe = path.parent / f".write-test-{os.getpid()}"
        probe.write_text("")
        probe.unlink()
    except OSError as e:
        raise FactoryError(f"cache directory {path.parent} is not writable ({e}); set "
                           "R2PAC_DATA_DIR to a writable directory") from e
    from r2pac_jax.io import lock_file, remove_orphaned_temporaries

    lock = lock_file(path, "dataset")  # a second writer of this file is refused
    try:
        for p in (path, card_path(path), path.with_suffix(".png")):
            remove_orphaned_temporaries(p)  # a killed writer's leftovers: none is alive now
        return _generate_locked(task, src, n, seed, path, progress, plot, source, physics,
                                env_steps, force, log, learned)
    finally:
        lock.close()


def _generate_locked(task, src, n, seed, path, progress, plot, source, physics, env_steps, force,
                     log, learned):
    if force:
        import shutil

        for p in (path, card_path(path), path.with_suffix(".png")):
            p.unlink(missing_ok=True)
        shutil.rmtree(f"{path}.partial", ignore_errors=True)
    if path.exists() and card_path(path).exists():
        return path
    if source == "ppo-lagrangian":
        from r2pac_jax.data.factory.collect import generate_learned

        return generate_learned(task, path, n, env_steps, seed, physics, log=log,
                                progress=bool(progress), **learned)
    oversample = int(src.get("oversample", 1))
    arrays = src["generate"](n * oversample, seed,
                             progress=progress if callable(progress) else None)
    thinning = None
    if oversample > 1:  # DSRL's density grid over (cost, return), see thinning.py
        from r2pac_jax.data.factory.thinning import select_episodes, thin_by_density

        raw = validate(arrays, str(path), task.obs_dim, task.act_dim, task.name)
        rets, costs = raw.episode_sums()
        keep = thin_by_density(rets, costs, n, seed=seed)
        arrays = select_episodes(arrays, keep)
        thinning = dict(generated=int(len(rets)), kept=int(keep.size), grid="20x20 (cost, return)")
    ds = validate(arrays, str(path), task.obs_dim, task.act_dim, task.name)
    card = make_card(task, ds, seed, n, src["name"])
    card["thinning"] = thinning
    write_dsrl(path, ds, attrs={"task": task.name, "generated": True, "seed": seed,
                                "source": source})
    limits = scripted_limits(task)
    if limits is not None:  # the card lists the checks the file fails (coverage, measured here)
        from r2pac_jax.data.checks import check_coverage

        res = check_coverage(path, task.name)
        card.update(data_version=1, known_limits=limits,
                    checks=dict(fast=True, failed=res["failed"], file=f"{path}.checks.json"))
    if plot:
        from r2pac_jax.report import plot_composition

        rets, costs = ds.episode_sums()
        plot_composition(rets, costs, task.kappa, path.with_suffix(".png"),
                         f"{task.name} generated ({source}, seed {seed}, {n} trajectories)")
    atomic_write_json(card_path(path), card)  # last: marks the dataset complete
    return path

"""Data: DSRL files, generated datasets and h-step chunks."""
from __future__ import annotations

from typing import Callable, Optional

from r2pac_jax.data.dsrl import (Dataset, DatasetError, dsrl_dirs, find_dsrl_file, load_dsrl,
                                 write_dsrl)
from r2pac_jax.tasks import TaskSpec

__all__ = ["Dataset", "DatasetError", "find_dsrl_file", "load_dsrl", "write_dsrl",
           "load_task_dataset", "find_task_file", "stand_in_dataset"]


def find_task_file(task: TaskSpec):
    """The file `load_task_dataset` reads where it makes none: (kind, path) of a DSRL file
    ("dsrl"), else a learned file made earlier ("learned"), else a scripted one ("scripted");
    None where the machine has none."""
    from r2pac_jax.data import factory

    for kind, find in (("dsrl", find_dsrl_file), ("learned", factory.find_learned),
                       ("scripted", factory.find_cached)):
        path = find(task)
        if path is not None:
            return kind, path
    return None


def stand_in_dataset(task: TaskSpec, episodes: int = 20, seed: int = 0) -> Dataset:
    """Random values in the task's shapes, whole episodes of its length ending at the time limit:
    a stand-in for timing (a compiled step's speed does not depend on the values), never for
    training. Costs are 0/1 with probability 0.1."""
    import numpy as np

    from r2pac_jax.data.dsrl import validate

    rng = np.random.default_rng(seed)
    n, T = episodes, task.episode_len
    obs = rng.normal(size=(n, T + 1, task.obs_dim)).astype(np.float32)
    timeouts = np.zeros((n, T), bool)
    timeouts[:, -1] = True
    arrays = dict(observations=obs[:, :-1].reshape(n * T, -1),
                  next_observations=obs[:, 1:].reshape(n * T, -1),
                  actions=rng.uniform(-1, 1, (n * T, task.act_dim)).astype(np.float32),
                  rewards=rng.normal(size=n * T).astype(np.float32),
                  costs=(rng.uniform(size=n * T) < 0.1).astype(np.float32),
                  terminals=np.zeros(n * T, bool), timeouts=timeouts.reshape(-1))
    return validate(arrays, f"stand-in for {task.name}", task.obs_dim, task.act_dim, task.name)


def _generate_learned(task: TaskSpec, announce: Callable[[str], None],
                      progress: bool = True) -> Dataset:
    """No data for a MuJoCo task: make DSRL's learned-behaviour data at DSRL's size (hours on a
    CPU, resumable: the same command continues it), then its fast checks."""
    from r2pac_jax.data import factory
    from r2pac_jax.data.checks import check_coverage
    from r2pac_jax.data.factory.collect import estimate_hours

    c = task.collection
    hours = estimate_hours(task)
    eta = f"about {hours:.1f} h on a 2-core CPU" if hours else "hours on a CPU"
    announce(f"dataset: none found for {task.name}; generating DSRL's learned-behaviour data "
             f"({c.trajectories} trajectories from {c.env_steps:,} env steps of an "
             f"observation-based PPO-Lagrangian agent; {eta}) into {factory.cache_dir()}. It is "
             "checkpointed: interrupt it and rerun the same command to continue. The same "
             f"separately: python -m r2pac_jax.data make --task {task.name} --source "
             "ppo-lagrangian (--budget N for a smaller, recorded budget)")
    path = factory.generate_dataset(task, c.trajectories, seed=0, source="ppo-lagrangian",
                                    progress=progress, log=announce)
    res = check_coverage(path, task.name)
    announce(f"dataset: {path} (generated); coverage checks "
             f"{'passed' if res['passed'] else 'failed: ' + ', '.join(res['failed'])} "
             f"({path}.checks.json); the imitability checks: python -m r2pac_jax.data check "
             f"{path}")
    kw = dict(obs_dim=task.obs_dim, act_dim=task.act_dim, task_name=task.name)
    return load_dsrl(path, **kw)


def load_task_dataset(task: TaskSpec, dataset: Optional[str] = None,
                      announce: Callable[[str], None] = print,
                      progress: bool = True) -> Dataset:
    """The training data, in order: `dataset`; a DSRL file on disk; a cached learned-behaviour
    dataset (data v2); a cached scripted one (with a warning on the MuJoCo tasks); else a
    freshly generated one (announced): learned behaviour at DSRL's size for the MuJoCo tasks
    (hours, resumable), the scripted demonstration data for ReachAvoid (seconds). `progress`
    False hides the generation's progress bar (the announcements stay)."""
    from r2pac_jax.data import factory

    kw = dict(obs_dim=task.obs_dim, act_dim=task.act_dim, task_name=task.name)
    if dataset:
        announce(f"dataset: {dataset} (--dataset)")
        return load_dsrl(dataset, **kw)
    found = find_task_file(task)
    if found is not None:
        kind, path = found
        announce(f"dataset: {path} " + {
            "dsrl": "(DSRL file)",
            "learned": "(learned behaviour, generated earlier; see its .json card)",
            "scripted": "(generated earlier, see its .json card)"}[kind])
        if kind == "scripted" and factory.learned_by_default(task):
            announce(f"warning: {path.name} is scripted (data v1) data, whose safe trajectories "
                     "an observation-based learner cannot imitate (experiments/data_factory/"
                     "QUALITY_BAR.md); the learned data: python -m r2pac_jax.data make --task "
                     f"{task.name} --source ppo-lagrangian")
        return load_dsrl(path, **kw)
    if factory.learned_by_default(task):
        return _generate_learned(task, announce, progress)
    if not factory.has_source(task):
        raise DatasetError(
            f"no dataset for task {task.name}: no --dataset given, no DSRL file "
            f"{task.gym_id}-*.hdf5 in {', '.join(map(str, dsrl_dirs()))}, "
            "and no data generator for this task. Fix: pass --dataset FILE, or set "
            "DSRL_DATASET_DIR to the folder holding DSRL's files")
    n = factory.default_trajectories(task)
    announce(f"dataset: none found for {task.name}; generating {n} trajectories into "
             f"{factory.cache_dir()} (python -m r2pac_jax.data make --task {task.name})")
    from tqdm import tqdm

    with tqdm(total=n, unit="traj", desc=f"{task.name} data", dynamic_ncols=True,
              disable=not progress) as bar:
        path = factory.generate_dataset(task, n, seed=0, progress=bar.update,
                                        source="scripted")
    announce(f"dataset: {path} (generated)")
    return load_dsrl(path, **kw)

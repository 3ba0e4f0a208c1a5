"""A generated file's card: the JSON beside it that says what made it (task, counts, ranges,
versions, machine, the RL budget) and what it stands on. Below the factory and its collector,
which both write and read it."""
from __future__ import annotations

import platform
from pathlib import Path
from typing import Optional

import numpy as np

from r2pac_jax.data.dsrl import Dataset
from r2pac_jax.machine import describe as describe_machine
from r2pac_jax.tasks import TaskSpec


def card_path(path: Path) -> Path:
    return path.with_suffix(".json")


def data_budget(path) -> Optional[dict]:
    """What a generated file stands on, read from its card: {source, env_steps (the RL budget
    that made it), dsrl_env_steps, dsrl_budget (True when at DSRL's), physics}; None for a file
    without a card (a user's or DSRL's own file) or a source with no RL budget."""
    import json

    try:
        card = json.loads(card_path(Path(path)).read_text())
    except (OSError, ValueError):
        return None
    gen = card.get("generation") or {}
    if "env_steps" not in gen:
        return None
    dsrl = card.get("dsrl_env_steps")
    return dict(source=card.get("source"), env_steps=int(gen["env_steps"]),
                dsrl_env_steps=None if dsrl is None else int(dsrl),
                dsrl_budget=None if dsrl is None else int(gen["env_steps"]) >= int(dsrl),
                physics=card.get("physics"))


def make_card(task: TaskSpec, ds: Dataset, seed: int, trajectories: int, source: str) -> dict:
    import jax

    import r2pac_jax

    rets, costs = ds.episode_sums()
    safe = costs <= task.kappa
    span = task.r_max - task.r_min
    return dict(
        task=task.name, dsrl_id=task.dsrl_id, generated=True, seed=seed,
        trajectories=int(len(rets)), transitions=ds.size, sources=[source],
        kappa=task.kappa, safe_trajectories=int(safe.sum()), unsafe_trajectories=int((~safe).sum()),
        return_range=[float(rets.min()), float(rets.max())],
        cost_range=[float(costs.min()), float(costs.max())],
        normalised_return_range=[float((rets.min() - task.r_min) / span),
                                 float((rets.max() - task.r_min) / span)],
        r_min=task.r_min, r_max=task.r_max,
        # the physics library too: a file regenerated under another MuJoCo need not match
        versions=dict(r2pac_jax=r2pac_jax.__version__, jax=jax.__version__,
                      numpy=np.__version__, python=platform.python_version(),
                      mujoco=_installed_version("mujoco"),
                      pybullet=_installed_version("pybullet")),
        # XLA's CPU numerics depend on the threads it may use (a single-threaded run of
        # CarButton1 departs at update 1), so a file need not regenerate on another machine
        machine=describe_machine(),
    )


def _installed_version(package: str) -> Optional[str]:
    """The installed distribution's version, or None where it is not installed."""
    from importlib import metadata
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return None

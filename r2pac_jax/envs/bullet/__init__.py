"""Bullet-Safety-Gym 1.4.0's Run and Circle tasks (DSRL's Bullet tasks).

`make_env(task_spec, physics="auto"|"bullet")` is the registry's factory. `bullet` runs the
original's engine, pybullet 3.2.7 (an optional dependency: `pip install -e '.[bullet]'`), one
client per episode on the CPU (`engine.py`); `auto` picks it (there is no MJX model of these
robots yet). The tasks' rules are pure JAX over a view of the robot's state (`tasks.py`,
`robots.py`). Fidelity against the original: benchmarks/FIDELITY.md ("Bullet tasks").
"""
from __future__ import annotations

from r2pac_jax.envs.base import BackendUnavailableError

PHYSICS = ("auto", "bullet")


def resolve_physics(physics: str) -> str:
    if physics in ("auto", "bullet"):
        return "bullet"
    if physics == "mjx":
        raise BackendUnavailableError(
            "the Bullet tasks have no MJX model in this version of r2pac_jax: use --physics "
            "bullet (pybullet on the CPU)")
    raise BackendUnavailableError(
        f"physics must be auto or bullet for the Bullet tasks, got {physics!r}")


def make_env(task_spec, physics: str = "auto", **_):
    from r2pac_jax.envs.bullet.engine import BulletEnv
    from r2pac_jax.envs.bullet.tasks import make_task

    resolve_physics(physics)
    return BulletEnv(make_task(task_spec))

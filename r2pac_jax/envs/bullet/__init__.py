"""Bullet-Safety-Gym 1.4.0's Run and Circle tasks (DSRL's Bullet tasks).

`make_env(task_spec, physics="auto"|"bullet"|"mjx"|"mujoco")` is the registry's factory.
`bullet` runs the original's engine, pybullet 3.2.7 (an optional dependency: `pip install -e
'.[bullet]'`), one client per episode on the CPU (`engine.py`); `auto` picks it everywhere, as
the faithful path. `mjx` (JAX, for accelerators) and `mujoco` (C MuJoCo on the CPU) run MuJoCo
re-creations of the four robots (`mjcf.py`, `mujoco_env.py`), whose scores are not
interchangeable with the original's. The tasks' rules are pure JAX over a view of
the robot's state (`tasks.py`, `robots.py`), shared by all backends. Fidelity against the
original: benchmarks/FIDELITY.md ("Bullet tasks", "Bullet tasks in MuJoCo").
"""
from __future__ import annotations

from r2pac_jax.envs.base import BackendUnavailableError

PHYSICS = ("auto", "bullet", "mjx", "mujoco")


def resolve_physics(physics: str) -> str:
    if physics in ("auto", "bullet"):
        return "bullet"
    if physics in ("mjx", "mujoco"):
        return physics
    raise BackendUnavailableError(
        f"physics must be auto, bullet, mjx or mujoco for the Bullet tasks, got {physics!r}")


def make_env(task_spec, physics: str = "auto", **_):
    from r2pac_jax.envs.bullet.tasks import make_task

    physics = resolve_physics(physics)
    task = make_task(task_spec)
    if physics == "bullet":
        from r2pac_jax.envs.bullet.engine import BulletEnv

        return BulletEnv(task)
    from r2pac_jax.envs.bullet import mujoco_env

    return mujoco_env.make(task, physics)

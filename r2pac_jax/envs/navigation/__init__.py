"""Safety-Gymnasium's navigation tasks (Car / Point x Goal / Button / Push, levels 1-2).

`make_env(task_spec, physics="auto"|"mujoco"|"mjx")` is the registry's factory
(`r2pac_jax.tasks`): "auto" picks C MuJoCo on a CPU and MJX on an accelerator.
Modules: objects (levels as data), agents (car, point), world (the MJCF model), layout (keepout
sampling), lidar (pseudo-lidar), task (observation, reward, cost, reset), backends (MJX and
C MuJoCo).
"""
from __future__ import annotations

from r2pac_jax.envs.navigation.objects import LEVELS, level_spec


def make_task(name: str):
    from r2pac_jax.envs.navigation.task import NavTask

    return NavTask(level_spec(name))


def make_env(task_spec, physics: str = "auto", **kw):
    """The environment of a registered navigation task (see the module docstring)."""
    import jax

    from r2pac_jax.envs.navigation.backends import NavMjxEnv, NavMujocoEnv

    name = getattr(task_spec, "name", task_spec)
    task = make_task(name)
    if physics == "auto":
        physics = "mujoco" if jax.default_backend() == "cpu" else "mjx"
    if physics == "mjx":
        return NavMjxEnv(task, **kw)
    if physics == "mujoco":
        return NavMujocoEnv(task, **kw)
    raise ValueError(f"physics for navigation tasks must be auto, mujoco or mjx, got {physics!r}")


__all__ = ["LEVELS", "level_spec", "make_task", "make_env"]

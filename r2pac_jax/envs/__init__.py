"""Environments: the protocol (base.py), ReachAvoid (pure JAX), the MuJoCo physics backends
(physics.py), the velocity and navigation tasks, and the gymnasium wrapper (`gym_env`).

Submodules are imported lazily, so `import r2pac_jax.envs` stays light (no gymnasium, MuJoCo or
MJX until they are used).
"""
from __future__ import annotations


def gym_env(task, physics: str = "auto", seed=None):
    """A `gymnasium.Env` for a registered task (see `r2pac_jax.envs.gym.gym_env`)."""
    from r2pac_jax.envs.gym import gym_env as _gym_env

    return _gym_env(task, physics=physics, seed=seed)


__all__ = ["gym_env"]

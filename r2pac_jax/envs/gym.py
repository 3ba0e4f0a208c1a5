"""The gymnasium API over any registered task's environment, for users' own code.

    env = gym_env("CarGoal2", physics="mujoco", seed=0)
    obs, info = env.reset(seed=0)                         # obs [obs_dim] float32
    obs, reward, terminated, truncated, info = env.step(a)  # a [act_dim] in [-1, 1]
    info["cost"]                                          # the step's cost (float)

One episode at a time, over the task's own `reset` / `step` (JAX envs: jitted single-episode
functions; C MuJoCo: its batched step with a batch of one), so a gym episode is the same episode
as the env's own rollout: `reset(seed=s)` starts from `jax.random.PRNGKey(s)`, exactly as
`env.reset(PRNGKey(s))` (or `env.reset_batch(PRNGKey(s)[None])`). Later resets without a seed
continue a key chain drawn from that seed. The episode's time limit is the task's
(`truncated` after `episode_len` steps); stepping an ended episode is an error (call reset).
"""
from __future__ import annotations

from typing import Any, Optional

import gymnasium
import jax
import numpy as np
from gymnasium import spaces

from r2pac_jax.envs.base import check_action
from r2pac_jax.errors import R2pacError
from r2pac_jax.tasks import TaskSpec, get_task


class ResetNeeded(R2pacError, RuntimeError):
    pass


class TaskGymEnv(gymnasium.Env):
    """gymnasium.Env over one registered task (see the module docstring)."""

    metadata = {"render_modes": []}

    def __init__(self, task: str | TaskSpec, physics: str = "auto", seed: Optional[int] = None,
                 env=None):
        self.task = task if isinstance(task, TaskSpec) else get_task(task)
        self.env = env if env is not None else self.task.make_env(physics=physics)
        self.physics = getattr(self.env, "backend", "jax")
        obs_dim, act_dim = self.env.obs_dim, self.env.act_dim
        self.observation_space = spaces.Box(-np.inf, np.inf, (obs_dim,), np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, (act_dim,), np.float32)
        self._default_seed = seed
        self._key = None  # key chain for resets without a seed
        self._state = None
        self._ended = False
        if self.env.is_jax:
            self._reset_fn = jax.jit(self.env.reset)
            self._step_fn = jax.jit(self.env.step)

    # -- gymnasium API ---------------------------------------------------------------------
    def reset(self, *, seed: Optional[int] = None, options: Optional[dict] = None):
        super().reset(seed=seed)
        if seed is None and self._key is None and self._default_seed is not None:
            seed = self._default_seed
        if seed is not None:
            key = jax.random.PRNGKey(int(seed))
            self._key = jax.random.fold_in(key, 1)  # chain for the resets that follow
        else:
            if self._key is None:  # unseeded: draw from gymnasium's own (random) generator
                self._key = jax.random.PRNGKey(int(self.np_random.integers(2**31)))
            self._key, key = jax.random.split(self._key)
        if self.env.is_jax:
            self._state = self._reset_fn(key)
        else:
            if self._state is not None and hasattr(self.env, "release"):
                self.env.release(self._state)  # a client-holding backend (bullet) recycles it
            self._state = self.env.reset_batch(key[None])
        self._ended = False
        return self._obs(), {}

    def step(self, action):
        if self._state is None:
            raise ResetNeeded("step() before reset(): call env.reset() first")
        if self._ended:
            raise ResetNeeded("the episode has ended (terminated or truncated); call "
                              "env.reset() before stepping again")
        a = check_action(action, self.env.act_dim)
        if self.env.is_jax:
            self._state = self._step_fn(self._state, a)
        else:
            self._state = self.env.step_batch(self._state, a[None])
        s = self._state
        terminated, truncated = self._scalar(s.terminated, bool), self._scalar(s.truncated, bool)
        self._ended = terminated or truncated
        info = {"cost": self._scalar(s.cost, float)}
        return self._obs(), self._scalar(s.reward, float), terminated, truncated, info

    def close(self):
        self._state = None

    # -- helpers ---------------------------------------------------------------------------
    @property
    def state(self) -> Any:
        """The underlying env's state (batch of one for C-MuJoCo envs)."""
        return self._state

    def _scalar(self, x, kind):
        x = np.asarray(x)
        return kind(x.reshape(-1)[0])

    def _obs(self) -> np.ndarray:
        obs = np.asarray(self._state.obs, np.float32)
        return obs.reshape(self.env.obs_dim).copy()


def gym_env(task: str | TaskSpec, physics: str = "auto", seed: Optional[int] = None
            ) -> TaskGymEnv:
    """A `gymnasium.Env` for a registered task: Box observation [obs_dim] float32, Box action
    [-1, 1]^act_dim, cost in `info["cost"]`.

    task: short name, DSRL id or Safety-Gymnasium id (`r2pac_jax.tasks.get_task`).
    physics: "auto" | "mujoco" | "mjx" for MuJoCo tasks, "auto" | "bullet" for the Bullet ones,
    "auto" | "jax" for pure-JAX ones.
    seed: the first reset's seed when `reset()` is called without one.
    Raises UnknownTaskError (listing the known tasks) or EnvUnavailableError (task without an
    environment port).
    """
    return TaskGymEnv(task, physics=physics, seed=seed)

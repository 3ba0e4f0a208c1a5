"""The task registry: what a task is (`TaskSpec`: its constants, the paper's Table 4 values, its
environment; `CollectionSpec`: DSRL's data recipe for it) and the table of registered tasks.

Each environment family registers its own tasks, one record per task (`tasks/demo.py`,
`navigation.py`, `velocity.py`, `bullet.py`). `get_task(name)` accepts the short name
(`CarGoal2`), DSRL's id (`OfflineCarGoal2Gymnasium-v0`) or the reference simulator's id
(`SafetyCarGoal2Gymnasium-v0`). Per-task hyperparameters of the paper's Table 4 (quantile alpha,
penalty C, chunk length h, reward scale) live in those records and nowhere else; `config.py`
reads them from the `TaskSpec`.
"""
from __future__ import annotations

import dataclasses
from typing import Any, Callable, Optional

from r2pac_jax.errors import R2pacError


class UnknownTaskError(R2pacError, KeyError):
    def __str__(self) -> str:  # KeyError quotes its message; we want it plain
        return str(self.args[0])


class EnvUnavailableError(R2pacError, RuntimeError):
    """The task is registered (constants, data) but has no environment on this install."""


class UnknownPhysicsError(EnvUnavailableError):
    """`--physics` names no simulator of the task (checked before any data or training)."""


# the simulators (`--physics` values) each family's environments accept
PHYSICS = {"demo": ("auto", "jax"), "navigation": ("auto", "mujoco", "mjx"),
           "velocity": ("auto", "mujoco", "mjx"), "bullet": ("auto", "bullet", "mujoco", "mjx")}


@dataclasses.dataclass(frozen=True)
class CollectionSpec:
    """How DSRL collected a task's data (scripts/train_trpol_v0.py, dsrl/infos.py): a Lagrangian
    agent trained `epochs` x `steps_per_epoch` env steps while its cost limit moved from
    `cost_start` (until epoch `epoch_start`) linearly to `cost_end` (from epoch `epoch_end`);
    trajectories kept along training with cost <= `cost_cap` and return >= `reward_min`, thinned
    to `trajectories` (DSRL's file size). `ppo` overrides PPOLagConfig values for the task."""

    cost_start: float
    cost_end: float
    epoch_start: int
    epoch_end: int
    epochs: int
    cost_cap: float
    trajectories: int
    reward_min: float = -float("inf")
    steps_per_epoch: int = 10_000
    ppo: tuple = ()  # (key, value) pairs

    @property
    def env_steps(self) -> int:
        """DSRL's RL budget in env steps."""
        return self.epochs * self.steps_per_epoch


@dataclasses.dataclass(frozen=True)
class TaskSpec:
    """Constants of one task. Scores use DSRL's R_min/R_max and kappa (see evaluate.py)."""

    name: str
    family: str  # "demo" | "velocity" | "navigation" | "bullet"
    dsrl_id: Optional[str]
    gym_id: Optional[str]  # id in the reference simulator (Safety-Gymnasium / Bullet-Safety-Gym)
    episode_len: int
    obs_dim: int
    act_dim: int
    r_min: float
    r_max: float
    kappa: float
    reward_scale: float
    cost_scale: float
    quantile_alpha: float
    penalty_c: float
    chunk_len: int
    # (spec, physics=..., **kw) -> Env: the family's function, which imports the simulator on
    # first use (a task's constants never need MuJoCo or pybullet)
    env_factory: Optional[Callable] = None
    dsrl_trajectories: Optional[int] = None
    extras: tuple = ()  # family-specific constants as (key, value) pairs
    collection: Optional[CollectionSpec] = None  # the learned-behaviour data recipe

    def extra(self, key: str, default: Any = None) -> Any:
        return dict(self.extras).get(key, default)

    @property
    def has_env(self) -> bool:
        return self.env_factory is not None

    def check_physics(self, physics: str) -> None:
        """Refuse a `--physics` value the task's environments do not accept, naming those that
        they do, before anything is generated or trained."""
        choices = PHYSICS.get(self.family, ("auto",))
        if physics not in choices:
            raise UnknownPhysicsError(
                f"--physics {physics!r}: not a simulator of {self.name}; choose one of "
                f"{', '.join(choices)}")

    def make_env(self, physics: str = "auto", **kwargs):
        """Build the task's environment (`reset(key)` / `step(state, action)`, see envs/base.py)."""
        if self.env_factory is None:
            raise EnvUnavailableError(
                f"task {self.name!r} has no environment port in this version of r2pac_jax; "
                f"tasks with environments: {', '.join(t.name for t in TASKS.values() if t.has_env)}. "
                "Train without evaluation (--eval-episodes 0) or pick one of those."
            )
        return self.env_factory(self, physics=physics, **kwargs)


TASKS: dict[str, TaskSpec] = {}
_ALIASES: dict[str, str] = {}


def register(spec: TaskSpec, replace: bool = False) -> TaskSpec:
    """Add a task (other modules and users may register their own). A task with a collection
    recipe keeps DSRL's trajectory count from it."""
    if spec.name in TASKS and not replace:
        raise ValueError(f"task {spec.name!r} is already registered (pass replace=True)")
    if spec.collection is not None:
        spec = dataclasses.replace(spec, dsrl_trajectories=spec.collection.trajectories)
    TASKS[spec.name] = spec
    for alias in (spec.name, spec.dsrl_id, spec.gym_id):
        if alias:
            _ALIASES[alias.lower()] = spec.name
    return spec


def list_tasks() -> list[str]:
    return sorted(TASKS)


def get_task(name: str) -> TaskSpec:
    key = _ALIASES.get(str(name).lower())
    if key is None:
        raise UnknownTaskError(
            f"unknown task {name!r}; known tasks: {', '.join(list_tasks())} "
            "(DSRL ids such as OfflineCarGoal2Gymnasium-v0 are accepted too)"
        )
    return TASKS[key]


def lazy_env(module: str, function: str = "make_env") -> Callable:
    """An environment factory that imports `module` (MuJoCo, pybullet, ...) on its first call."""
    def make(spec: TaskSpec, physics: str = "auto", **kwargs):
        import importlib

        return getattr(importlib.import_module(module), function)(spec, physics=physics, **kwargs)

    make.__qualname__ = make.__name__ = f"lazy_env({module}:{function})"
    make.target = f"{module}:{function}"
    return make


def set_env_factory(name: str, factory) -> None:
    """Attach an environment factory to a registered task: a callable (spec, physics=...) ->
    Env, or "module:function", imported on first use."""
    if isinstance(factory, str):
        factory = lazy_env(*factory.split(":"))
    spec = get_task(name)
    TASKS[spec.name] = dataclasses.replace(spec, env_factory=factory)


def set_collection(name: str, collection: CollectionSpec) -> None:
    """Attach the learned-behaviour data recipe to a registered task."""
    spec = get_task(name)
    TASKS[spec.name] = dataclasses.replace(spec, collection=collection,
                                           dsrl_trajectories=collection.trajectories)

"""The task registry: one table of every task's constants and its environment factory.

`get_task(name)` accepts the short name (`CarGoal2`), DSRL's id (`OfflineCarGoal2Gymnasium-v0`)
or the reference simulator's id (`SafetyCarGoal2Gymnasium-v0`). Per-task hyperparameters of the
paper's Table 4 (quantile alpha, penalty C, chunk length h, reward scale) live here and nowhere
else; `config.py` reads them from the `TaskSpec`.
"""
from __future__ import annotations

import dataclasses
import importlib
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
    env_factory: Optional[str] = None  # "module:function(physics=...) -> Env", imported lazily
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
        module, fn = self.env_factory.split(":")
        factory: Callable = getattr(importlib.import_module(module), fn)
        return factory(self, physics=physics, **kwargs)


TASKS: dict[str, TaskSpec] = {}
_ALIASES: dict[str, str] = {}


def register(spec: TaskSpec, replace: bool = False) -> TaskSpec:
    """Add a task (other modules and users may register their own)."""
    if spec.name in TASKS and not replace:
        raise ValueError(f"task {spec.name!r} is already registered (pass replace=True)")
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


def set_env_factory(name: str, factory: str) -> None:
    """Attach an environment factory ("module:function") to a registered task."""
    spec = get_task(name)
    TASKS[spec.name] = dataclasses.replace(spec, env_factory=factory)


def set_collection(name: str, collection: CollectionSpec) -> None:
    """Attach the learned-behaviour data recipe to a registered task."""
    spec = get_task(name)
    TASKS[spec.name] = dataclasses.replace(spec, collection=collection,
                                           dsrl_trajectories=collection.trajectories)


# --------------------------------------------------------------------------------------------
# The demonstration task (pure JAX, envs/reach_avoid.py). Its constants are part of the task's
# design, fixed before any training: R_max is the return of the noiseless straight-line
# full-speed scripted controller (unsafe: it crosses the hazard), R_min is standing still;
# tests/data/test_reach_avoid.py recomputes both from the environment.
register(TaskSpec(
    name="ReachAvoid", family="demo", dsrl_id=None, gym_id=None,
    episode_len=80, obs_dim=6, act_dim=2, r_min=0.0, r_max=40.0,
    kappa=2.0, reward_scale=1.0, cost_scale=1.0,
    quantile_alpha=0.9, penalty_c=1.0, chunk_len=5,
    env_factory="r2pac_jax.envs.reach_avoid:make_env",
))

# --------------------------------------------------------------------------------------------
# DSRL tasks (../shared/BENCHMARK.md). Table 4 gives alpha and C for the paper's 17 tasks;
# the further tasks use alpha 0.9 with C 1 (velocity) or C 10 (navigation).
_SG = "Safety-Gymnasium"


def _sg(name, T, obs, act, rmax, rmin, trajs, alpha, c, family, h=5, version="v0", **extras):
    return register(TaskSpec(
        name=name, family=family,
        dsrl_id=f"Offline{name}Gymnasium-{version}", gym_id=f"Safety{name}Gymnasium-{version}",
        episode_len=T, obs_dim=obs, act_dim=act, r_min=rmin, r_max=rmax, kappa=10.0,
        reward_scale=200.0 if family == "navigation" else 1.0,
        cost_scale=1.0, quantile_alpha=alpha, penalty_c=c, chunk_len=h,
        dsrl_trajectories=trajs, extras=tuple(sorted(extras.items())),
    ))


def _bullet(name, T, obs, act, rmax, rmin, trajs, alpha, c):
    return register(TaskSpec(
        name=name, family="bullet", dsrl_id=f"Offline{name}-v0", gym_id=f"Safety{name}-v0",
        episode_len=T, obs_dim=obs, act_dim=act, r_min=rmin, r_max=rmax, kappa=5.0,
        reward_scale=1.0, cost_scale=1.0, quantile_alpha=alpha, penalty_c=c, chunk_len=5,
        dsrl_trajectories=trajs,
    ))


# Navigation (Safety-Gymnasium Car / Point). Reward scale 200 for Car (Table 3); the Point
# tasks are outside the paper's table and take their family's scale, 200, too.
_sg("CarButton1", 1000, 88, 2, 44.420003345738984, 0.0028926206826067613, 2656, 0.8, 10.0, "navigation")
_sg("CarButton2", 1000, 88, 2, 41.99513815522894, 0.001767391717990563, 3755, 0.5, 10.0, "navigation")
_sg("CarPush1", 1000, 88, 2, 16.304467598905237, 0.013700173533941762, 2871, 0.9, 10.0, "navigation")
_sg("CarPush2", 1000, 88, 2, 15.141648491514314, 0.00029391133526335267, 4407, 0.9, 10.0, "navigation")
_sg("CarGoal1", 1000, 72, 2, 39.907809198384705, 0.012232819540852091, 1671, 0.9, 10.0, "navigation")
_sg("CarGoal2", 1000, 72, 2, 28.902897990056502, 0.001032874531954775, 4105, 0.9, 10.0, "navigation")
for _n, _rmax, _rmin in [
    ("PointGoal1", 30.071114857340543, 0.01196012764197707),
    ("PointGoal2", 27.717709787852737, 0.002616959830266108),
    ("PointButton1", 41.19301568767707, 0.008822109034937853),
    ("PointButton2", 42.8985953616709, 0.014114166087574098),
    ("PointPush1", 16.518654299293367, 0.0014001545292344209),
    ("PointPush2", 14.691039145644403, 0.0012438183001730607),
]:
    # Point observation: accelerometer, velocimeter, gyro, magnetometer (12), then the lidars
    # (Goal 3, Button/Push 4 groups of 16).
    _sg(_n, 1000, 12 + 16 * (3 if "Goal" in _n else 4), 2, _rmax, _rmin, None, 0.9, 10.0, "navigation")

# Navigation environments (r2pac_jax/envs/navigation, C MuJoCo or MJX). The Point observation
# sizes above (60 / 76) were checked against Safety-Gymnasium 0.4.0's environments.
for _n in ("CarGoal1", "CarGoal2", "CarButton1", "CarButton2", "CarPush1", "CarPush2",
           "PointGoal1", "PointGoal2", "PointButton1", "PointButton2", "PointPush1", "PointPush2"):
    set_env_factory(_n, "r2pac_jax.envs.navigation:make_env")

# Velocity (Safety-Gymnasium v1 on gymnasium's v4 MuJoCo envs).
_sg("AntVelocity", 1000, 27, 8, 2976.276611328125, 6.1519012451171875, 2249, 0.95, 1.0, "velocity",
    version="v1", velocity_limit=2.6222)
_sg("HalfCheetahVelocity", 1000, 17, 6, 2806.93310546875, 5.7509765625, 2495, 0.99, 1.0, "velocity",
    h=1, version="v1", velocity_limit=3.2096)
_sg("SwimmerVelocity", 1000, 8, 2, 238.95831298828125, 0.07114458084106445, 1686, 0.7, 1.0, "velocity",
    version="v1", velocity_limit=0.2282)
_sg("HopperVelocity", 1000, 11, 3, 1911.396728515625, 37.05154800415039, None, 0.9, 1.0, "velocity",
    version="v1", velocity_limit=0.7402)
_sg("Walker2dVelocity", 1000, 17, 6, 3418.223876953125, 18.668498992919922, None, 0.9, 1.0, "velocity",
    version="v1", velocity_limit=2.3415)
# Their environments: r2pac_jax/envs/velocity.py (MJX or C MuJoCo, see envs/physics.py).
for _n in ("AntVelocity", "HalfCheetahVelocity", "SwimmerVelocity", "HopperVelocity",
           "Walker2dVelocity"):
    set_env_factory(_n, "r2pac_jax.envs.velocity:make_env")

# Bullet-Safety-Gym (kappa 5).
_bullet("AntRun", 200, 33, 8, 955.4818725585938, 0.001767391717990563, 1816, 0.7, 1.0)
_bullet("BallRun", 100, 7, 2, 1327.445556640625, 26.339754104614258, 940, 0.5, 1.0)
_bullet("CarRun", 200, 7, 2, 574.6533203125, 204.28726196289062, 651, 0.95, 1.0)
_bullet("DroneRun", 200, 17, 4, 682.8330078125, 10.557029724121094, 1990, 0.7, 1.0)
_bullet("AntCircle", 500, 34, 8, 460.7091979980469, 0.0177031010389328, 5728, 0.7, 1.0)
_bullet("BallCircle", 200, 8, 2, 881.46337890625, 0.38312244415283203, 886, 0.85, 1.0)
_bullet("CarCircle", 300, 8, 2, 534.3060913085938, 3.484419822692871, 1450, 0.9, 1.0)
_bullet("DroneCircle", 300, 18, 4, 996.38916015625, 207.794189453125, 1923, 0.7, 1.0)
# Their environments: r2pac_jax/envs/bullet (pybullet, `--physics bullet`), robot by robot.
for _n in ("BallRun", "BallCircle", "CarRun", "CarCircle", "DroneRun", "DroneCircle", "AntRun",
           "AntCircle"):
    set_env_factory(_n, "r2pac_jax.envs.bullet:make_env")

# --------------------------------------------------------------------------------------------
# DSRL's collection recipe per task (scripts/train_trpol_v0.py: cost_start, cost_end,
# epoch_start, epoch_end, epoch; 10k env steps per epoch; dsrl/infos.py's file names: the cost
# cap and the trajectory count; rmin 0 for the navigation tasks). ReachAvoid's is this
# project's own (4 kappa -> kappa / 2 over 1.5M steps, 64 episodes of 80 steps per update).
for _n, _cs, _ce, _es, _ee, _ep, _cap, _traj in [
    ("CarButton1", 200, 10, 400, 2000, 2200, 250, 2656),
    ("CarButton2", 300, 10, 400, 3000, 3500, 300, 3755),
    ("CarPush1", 150, 10, 500, 3500, 4000, 200, 2871),
    ("CarPush2", 200, 10, 500, 3500, 4000, 250, 4407),
    ("CarGoal1", 80, 5, 200, 1000, 1200, 120, 1671),
    ("CarGoal2", 180, 5, 400, 2000, 2200, 200, 4105),
    ("PointGoal1", 80, 5, 200, 1500, 1800, 100, 2022),
    ("PointGoal2", 180, 5, 400, 2000, 2200, 200, 3442),
    ("PointButton1", 150, 5, 200, 1800, 2000, 200, 2268),
    ("PointButton2", 200, 5, 800, 3000, 3200, 250, 3288),
    ("PointPush1", 100, 5, 400, 2500, 2800, 150, 2379),
    ("PointPush2", 150, 5, 500, 2500, 2800, 200, 3242),
]:
    set_collection(_n, CollectionSpec(_cs, _ce, _es, _ee, _ep, _cap, _traj, reward_min=0.0))
for _n, _es, _ee, _ep, _cap, _traj in [
    ("AntVelocity", 700, 3000, 3500, 250, 2249),
    ("HalfCheetahVelocity", 300, 2500, 3000, 250, 2495),
    ("HopperVelocity", 400, 2500, 3000, 250, 2240),
    ("SwimmerVelocity", 500, 2500, 3000, 200, 1686),
    ("Walker2dVelocity", 600, 3000, 3500, 300, 2729),
]:
    set_collection(_n, CollectionSpec(300, 10, _es, _ee, _ep, _cap, _traj))
# Bullet-Safety-Gym (the same script's Bullet configs; cost caps and counts from DSRL's file
# names, e.g. SafetyBallRun-v0-80-940.hdf5). The limits *rise*; reward_min is DSRL's -9999.
# Rollouts of whole episodes (10k steps per update as DSRL's epoch).
set_collection("BallRun", CollectionSpec(5, 100, 100, 900, 1000, 80, 940))
set_collection("BallCircle", CollectionSpec(5, 200, 100, 900, 1000, 80, 886,
                                            ppo=(("num_envs", 50), ("rollout_len", 200))))
set_collection("CarRun", CollectionSpec(5, 100, 100, 900, 1000, 40, 651,
                                        ppo=(("num_envs", 50), ("rollout_len", 200))))
set_collection("CarCircle", CollectionSpec(5, 100, 100, 900, 1000, 100, 1450,
                                           ppo=(("num_envs", 33), ("rollout_len", 300))))
# The Ants (BulletAntRunCfg, BulletAntCircleCfg: AntCircle's networks are 256 x 256); their
# episodes end early when the torso drops, so rollouts do not align with episodes.
set_collection("AntRun", CollectionSpec(5, 200, 400, 2500, 2600, 150, 1816,
                                        ppo=(("num_envs", 50), ("rollout_len", 200))))
set_collection("AntCircle", CollectionSpec(5, 200, 2000, 5000, 5400, 200, 5728,
                                           ppo=(("num_envs", 20), ("rollout_len", 500),
                                                ("hidden", (256, 256)))))
# The Drones (BulletDroneRunCfg: the limit *falls* 100 -> 5; BulletDroneCircleCfg).
set_collection("DroneRun", CollectionSpec(100, 5, 50, 800, 1000, 140, 1990,
                                          ppo=(("num_envs", 50), ("rollout_len", 200))))
set_collection("DroneCircle", CollectionSpec(5, 150, 500, 2500, 2600, 100, 1923,
                                             ppo=(("num_envs", 33), ("rollout_len", 300))))
set_collection("ReachAvoid", CollectionSpec(
    8.0, 1.0, 30, 270, 300, cost_cap=80.0, trajectories=1000, steps_per_epoch=64 * 80,
    ppo=(("num_envs", 64), ("rollout_len", 80))))

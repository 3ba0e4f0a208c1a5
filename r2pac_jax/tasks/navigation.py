"""Safety-Gymnasium's navigation tasks (Car and Point: Goal, Button, Push), on our MuJoCo ports
(`envs/navigation`, C MuJoCo or MJX). One record per task: DSRL's constants (R_max, R_min, kappa
10), the paper's Table 4 values, DSRL's collection recipe (scripts/train_trpol_v0.py:
cost_start, cost_end, epoch_start, epoch_end, epochs; 10k env steps per epoch; dsrl/infos.py's
file names: the cost cap and the trajectory count; rmin 0)."""
from __future__ import annotations

from r2pac_jax.tasks.registry import CollectionSpec, TaskSpec, register


def make_env(spec: TaskSpec, physics: str = "auto", **kwargs):
    from r2pac_jax.envs import navigation  # MuJoCo on first use

    return navigation.make_env(spec, physics=physics, **kwargs)


def task(name, obs, r_max, r_min, alpha, recipe) -> TaskSpec:
    """A navigation task: 1,000 steps, 2 actions, reward scale 200 (Table 3 for Car; the Point
    tasks, outside the paper's table, take their family's scale too), C 10, h 5.
    recipe: (cost_start, cost_end, epoch_start, epoch_end, epochs, cost cap, trajectories)."""
    return register(TaskSpec(
        name=name, family="navigation", dsrl_id=f"Offline{name}Gymnasium-v0",
        gym_id=f"Safety{name}Gymnasium-v0", episode_len=1000, obs_dim=obs, act_dim=2,
        r_min=r_min, r_max=r_max, kappa=10.0, reward_scale=200.0, cost_scale=1.0,
        quantile_alpha=alpha, penalty_c=10.0, chunk_len=5, env_factory=make_env,
        collection=CollectionSpec(*recipe, reward_min=0.0)))


# Point observation: accelerometer, velocimeter, gyro, magnetometer (12), then the lidars (Goal 3,
# Button/Push 4 groups of 16): 60 / 76, checked against Safety-Gymnasium 0.4.0's environments.
_POINT_GOAL, _POINT_OTHER = 12 + 16 * 3, 12 + 16 * 4

task("CarButton1", 88, 44.420003345738984, 0.0028926206826067613, 0.8,
     (200, 10, 400, 2000, 2200, 250, 2656))
task("CarButton2", 88, 41.99513815522894, 0.001767391717990563, 0.5,
     (300, 10, 400, 3000, 3500, 300, 3755))
task("CarPush1", 88, 16.304467598905237, 0.013700173533941762, 0.9,
     (150, 10, 500, 3500, 4000, 200, 2871))
task("CarPush2", 88, 15.141648491514314, 0.00029391133526335267, 0.9,
     (200, 10, 500, 3500, 4000, 250, 4407))
task("CarGoal1", 72, 39.907809198384705, 0.012232819540852091, 0.9,
     (80, 5, 200, 1000, 1200, 120, 1671))
task("CarGoal2", 72, 28.902897990056502, 0.001032874531954775, 0.9,
     (180, 5, 400, 2000, 2200, 200, 4105))
task("PointGoal1", _POINT_GOAL, 30.071114857340543, 0.01196012764197707, 0.9,
     (80, 5, 200, 1500, 1800, 100, 2022))
task("PointGoal2", _POINT_GOAL, 27.717709787852737, 0.002616959830266108, 0.9,
     (180, 5, 400, 2000, 2200, 200, 3442))
task("PointButton1", _POINT_OTHER, 41.19301568767707, 0.008822109034937853, 0.9,
     (150, 5, 200, 1800, 2000, 200, 2268))
task("PointButton2", _POINT_OTHER, 42.8985953616709, 0.014114166087574098, 0.9,
     (200, 5, 800, 3000, 3200, 250, 3288))
task("PointPush1", _POINT_OTHER, 16.518654299293367, 0.0014001545292344209, 0.9,
     (100, 5, 400, 2500, 2800, 150, 2379))
task("PointPush2", _POINT_OTHER, 14.691039145644403, 0.0012438183001730607, 0.9,
     (150, 5, 500, 2500, 2800, 200, 3242))

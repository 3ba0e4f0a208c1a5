"""Bullet-Safety-Gym's Run and Circle tasks (Ball, Car, Drone, Ant), on the original's engine
(`envs/bullet`, pybullet, `--physics bullet`) or our MuJoCo re-creations. One record per task:
DSRL's constants (kappa 5), the paper's Table 4 values and the collection recipe of DSRL's
script's Bullet configs (cost caps and counts from DSRL's file names, e.g.
SafetyBallRun-v0-80-940.hdf5; reward_min is DSRL's -9999, i.e. none)."""
from __future__ import annotations

from r2pac_jax.tasks.registry import CollectionSpec, TaskSpec, register


def make_env(spec: TaskSpec, physics: str = "auto", **kwargs):
    from r2pac_jax.envs import bullet  # pybullet or MuJoCo on first use

    return bullet.make_env(spec, physics=physics, **kwargs)


def task(name, episode_len, obs, act, r_max, r_min, alpha, collection) -> TaskSpec:
    return register(TaskSpec(
        name=name, family="bullet", dsrl_id=f"Offline{name}-v0", gym_id=f"Safety{name}-v0",
        episode_len=episode_len, obs_dim=obs, act_dim=act, r_min=r_min, r_max=r_max, kappa=5.0,
        reward_scale=1.0, cost_scale=1.0, quantile_alpha=alpha, penalty_c=1.0, chunk_len=5,
        env_factory=make_env, collection=collection))


def _rollouts(num_envs, rollout_len, **more) -> tuple:
    return (("num_envs", num_envs), ("rollout_len", rollout_len)) + tuple(more.items())


# The limits *rise*, except the Drone Run's (BulletDroneRunCfg: 100 -> 5). Rollouts of whole
# episodes (10k steps per update, as DSRL's epoch). The Ants' episodes end early when the torso
# drops, so their rollouts do not align with episodes; AntCircle's networks are 256 x 256.
task("AntRun", 200, 33, 8, 955.4818725585938, 0.001767391717990563, 0.7,
     CollectionSpec(5, 200, 400, 2500, 2600, 150, 1816, ppo=_rollouts(50, 200)))
task("BallRun", 100, 7, 2, 1327.445556640625, 26.339754104614258, 0.5,
     CollectionSpec(5, 100, 100, 900, 1000, 80, 940))
task("CarRun", 200, 7, 2, 574.6533203125, 204.28726196289062, 0.95,
     CollectionSpec(5, 100, 100, 900, 1000, 40, 651, ppo=_rollouts(50, 200)))
task("DroneRun", 200, 17, 4, 682.8330078125, 10.557029724121094, 0.7,
     CollectionSpec(100, 5, 50, 800, 1000, 140, 1990, ppo=_rollouts(50, 200)))
task("AntCircle", 500, 34, 8, 460.7091979980469, 0.0177031010389328, 0.7,
     CollectionSpec(5, 200, 2000, 5000, 5400, 200, 5728,
                    ppo=_rollouts(20, 500, hidden=(256, 256))))
task("BallCircle", 200, 8, 2, 881.46337890625, 0.38312244415283203, 0.85,
     CollectionSpec(5, 200, 100, 900, 1000, 80, 886, ppo=_rollouts(50, 200)))
task("CarCircle", 300, 8, 2, 534.3060913085938, 3.484419822692871, 0.9,
     CollectionSpec(5, 100, 100, 900, 1000, 100, 1450, ppo=_rollouts(33, 300)))
task("DroneCircle", 300, 18, 4, 996.38916015625, 207.794189453125, 0.7,
     CollectionSpec(5, 150, 500, 2500, 2600, 100, 1923, ppo=_rollouts(33, 300)))

"""Safety-Gymnasium's velocity tasks (v1, on gymnasium's v4 MuJoCo robots), on our ports
(`envs/velocity.py`, MJX or C MuJoCo, `envs/physics.py`). One record per task: DSRL's constants
(kappa 10), the velocity limit, the paper's Table 4 values and DSRL's collection recipe (cost
limit 300 -> 10 from epoch_start to epoch_end, 10k env steps per epoch)."""
from __future__ import annotations

from r2pac_jax.tasks.registry import CollectionSpec, TaskSpec, register


def make_env(spec: TaskSpec, physics: str = "auto", **kwargs):
    from r2pac_jax.envs import velocity  # MuJoCo on first use

    return velocity.make_env(spec, physics=physics, **kwargs)


def task(name, obs, act, r_max, r_min, alpha, velocity_limit, recipe, h=5) -> TaskSpec:
    """recipe: (epoch_start, epoch_end, epochs, cost cap, trajectories)."""
    return register(TaskSpec(
        name=name, family="velocity", dsrl_id=f"Offline{name}Gymnasium-v1",
        gym_id=f"Safety{name}Gymnasium-v1", episode_len=1000, obs_dim=obs, act_dim=act,
        r_min=r_min, r_max=r_max, kappa=10.0, reward_scale=1.0, cost_scale=1.0,
        quantile_alpha=alpha, penalty_c=1.0, chunk_len=h,
        extras=(("velocity_limit", velocity_limit),), env_factory=make_env,
        collection=CollectionSpec(300, 10, *recipe)))


task("AntVelocity", 27, 8, 2976.276611328125, 6.1519012451171875, 0.95, 2.6222,
     (700, 3000, 3500, 250, 2249))
task("HalfCheetahVelocity", 17, 6, 2806.93310546875, 5.7509765625, 0.99, 3.2096,
     (300, 2500, 3000, 250, 2495), h=1)
task("SwimmerVelocity", 8, 2, 238.95831298828125, 0.07114458084106445, 0.7, 0.2282,
     (500, 2500, 3000, 200, 1686))
task("HopperVelocity", 11, 3, 1911.396728515625, 37.05154800415039, 0.9, 0.7402,
     (400, 2500, 3000, 250, 2240))
task("Walker2dVelocity", 17, 6, 3418.223876953125, 18.668498992919922, 0.9, 2.3415,
     (600, 3000, 3500, 300, 2729))

"""The demonstration task, ReachAvoid (pure JAX, `envs/reach_avoid.py`): the paper's Figure 1,
reach a goal past a hazard."""
from __future__ import annotations

from r2pac_jax.tasks.registry import CollectionSpec, TaskSpec, register


def make_env(spec: TaskSpec, physics: str = "auto", **kwargs):
    from r2pac_jax.envs import reach_avoid

    return reach_avoid.make_env(spec, physics=physics, **kwargs)


# Its constants are part of the task's design, fixed before any training: R_max is the return of
# the noiseless straight-line full-speed scripted controller (unsafe: it crosses the hazard),
# R_min is standing still; tests/data/test_reach_avoid.py recomputes both from the environment.
# Its collection recipe is this project's own (4 kappa -> kappa / 2 over 1.5M steps, 64 episodes
# of 80 steps per update).
register(TaskSpec(
    name="ReachAvoid", family="demo", dsrl_id=None, gym_id=None,
    episode_len=80, obs_dim=6, act_dim=2, r_min=0.0, r_max=40.0,
    kappa=2.0, reward_scale=1.0, cost_scale=1.0,
    quantile_alpha=0.9, penalty_c=1.0, chunk_len=5, env_factory=make_env,
    collection=CollectionSpec(8.0, 1.0, 30, 270, 300, cost_cap=80.0, trajectories=1000,
                              steps_per_epoch=64 * 80,
                              ppo=(("num_envs", 64), ("rollout_len", 80))),
))

"""Bullet-Safety-Gym 1.4.0's Run and Circle tasks as pure JAX rules over a *view* of the robot's
state, shared by every backend (read off `bullet_safety_gym/envs/tasks.py`, `builder.py`,
`worlds.py`).

A view is a dict of arrays for one episode: `pos` [3], `quat` [4] (x, y, z, w), `vel` [3],
`angvel` [3] (world frame, as `getBaseVelocity` gives them) and `dpos` [3], the base's
displacement over the last simulation step, taken by the backend in its own precision (the Run
reward is a difference of two potentials near -60,000: in float32 it would lose ~4e-3, so it is
computed from the displacement instead, see `progress`).

| task | world | physics | reward | cost (<= 1) | reset (before one simulation step) |
|---|---|---|---|---|---|
| Run | plane 500 m | 1/120 s x 4 (Drone x 2), 5 solver iterations | 60 (|xy - g| before - after), g = (1000, 0), plus the robot's term | |y| > 2 or |v_xy| > limit | xy ~ U(-0.01, 0.01)^2, the robot's height and yaw |
| Circle | plane 30 m, 8 walls at 12 m | 1/60 s x 6, 5 solver iterations | 0.1 xy . (-v_y, v_x) / (1 + ||xy| - 7|) + 0.01 x the robot's term | |x| > 6 | xy uniform on the annulus 2 <= |xy| <= 4 (the original's rejection sampler), yaw atan2(-y, -x) + pi/2 + the robot's |

The Circle observation appends (|xy| - 7) / 10. Both reset the base's velocity to zero (the
original restores a state saved at its first reset) and then take one simulation step without an
action, whose observation the episode starts from; the Run potential is first taken before that
step, so the first reward includes the reset step's progress (`pending`).
"""
from __future__ import annotations

import math
from typing import Optional

import jax
import jax.numpy as jnp
import numpy as np

from r2pac_jax.envs.bullet.robots import ROBOTS, Robot

GOAL_X = 1e3  # the Run task's fictitious target (1000, 0)
POTENTIAL_SCALE = 60.0
RUN_Y_LIMIT = 2.0
CIRCLE_RADIUS = 7.0
CIRCLE_X_LIMIT = 6.0
CIRCLE_ENV_DIM = 10.0  # the Octagon world's env_dim, which scales the Circle observation


def progress(xy_before: jax.Array, dxy: jax.Array) -> jax.Array:
    """60 (|xy_before - g| - |xy_before + dxy - g|), g = (1000, 0), without cancellation:
    d0^2 - d1^2 = -dxy . (2 (xy_before - g) + dxy)."""
    rel = xy_before - jnp.array([GOAL_X, 0.0])
    d0 = jnp.linalg.norm(rel)
    d1 = jnp.linalg.norm(rel + dxy)
    return POTENTIAL_SCALE * (-jnp.dot(dxy, 2.0 * rel + dxy)) / (d0 + d1)


class BulletTask:
    """One Run or Circle task for one robot (see the module docstring)."""

    def __init__(self, spec, kind: str, robot: Robot):
        if kind not in ("run", "circle"):
            raise ValueError(f"Bullet task kind must be run or circle, got {kind!r}")
        self.spec, self.kind, self.robot = spec, kind, robot
        self.name, self.episode_len = spec.name, spec.episode_len
        self.act_dim = robot.act_dim
        self.obs_dim = robot.obs_dim + (1 if kind == "circle" else 0)
        if (self.obs_dim, self.act_dim) != (spec.obs_dim, spec.act_dim):
            raise ValueError(f"{spec.name}: the registry says obs {spec.obs_dim} / act "
                             f"{spec.act_dim}, the robot gives {self.obs_dim} / {self.act_dim}")
        # builder.get_physics_parameters
        if kind == "run":
            self.time_step = 1 / 120.0
            self.frame_skip = 2 if robot.name == "Drone" else 4
            self.world = "plane250"
        else:
            self.time_step, self.frame_skip, self.world = 1 / 60.0, 6, "octagon"
        self.solver_iterations = 5

    # -- reset ------------------------------------------------------------------------------
    def init(self, key: jax.Array):
        """The reset's sample: (pose {pos [3], joints [n_joints]}, extras). The orientation
        follows from the position as the original sets it (`yaw`; the bullet backend repeats
        the original's calls)."""
        z = self.robot.init_xyz[2]
        key, kj = jax.random.split(key)
        if self.kind == "run":
            xy = jax.random.uniform(key, (2,), minval=-0.01, maxval=0.01)
        else:
            # uniform on the annulus 2 <= r <= 4: the law of the original's rejection sampler
            kr, ka = jax.random.split(key)
            r = jnp.sqrt(jax.random.uniform(kr, (), minval=4.0, maxval=16.0))
            a = jax.random.uniform(ka, (), minval=0.0, maxval=2 * jnp.pi)
            xy = r * jnp.array([jnp.cos(a), jnp.sin(a)])
        pos = jnp.concatenate([xy, jnp.array([z])])
        return dict(pos=pos, joints=self.robot.sample_joints(kj)), self.empty_extras()

    def yaw(self, pos: np.ndarray) -> Optional[float]:
        """The reset's heading for a sampled position (float64, the original's arithmetic):
        Circle faces the clockwise tangent; Run keeps the robot's loaded heading (None)."""
        if self.kind == "run":
            return None
        d = -np.asarray(pos, np.float64)
        d = d / np.linalg.norm(d)
        # math.atan2 (the C library's), not np.arctan2: numpy's AVX-512 build of arctan2
        # differs from it in the last bit for 7.2% of random arguments on an AVX-512 EPYC
        # (benchmarks/fidelity_bullet/diagnostics.py),
        # and the original's recordings were made where numpy used the C library; a last-bit
        # change of the heading grows to visible differences within an episode
        return float(math.atan2(d[1], d[0]) + np.pi / 2 + self.robot.init_yaw)

    def empty_extras(self) -> dict:
        return dict(pending=jnp.zeros((), jnp.float32))

    def after_reset(self, view: dict, extras: dict) -> dict:
        """Extras once the reset's own simulation step is done (Run: its progress is pending)."""
        if self.kind != "run":
            return extras
        before = view["pos"][:2] - view["dpos"][:2]
        return dict(extras, pending=progress(before, view["dpos"][:2]).astype(jnp.float32))

    # -- rules ------------------------------------------------------------------------------
    def observe(self, view: dict, extras: dict) -> jax.Array:
        obs = self.robot.observe(view)
        if self.kind == "circle":
            dist = jnp.linalg.norm(view["pos"][:2])
            obs = jnp.concatenate([obs, ((dist - CIRCLE_RADIUS) / CIRCLE_ENV_DIM)[None]])
        return obs

    def transition(self, before: dict, after: dict, action: jax.Array, extras: dict):
        """(reward, cost, terminated, extras) of one control step."""
        pos, vel = after["pos"], after["vel"]
        if self.kind == "run":
            reward = (progress(before["pos"][:2], after["dpos"][:2]) + extras["pending"]
                      + self.robot.specific_reward(after, action))
            outside = jnp.abs(pos[1]) > RUN_Y_LIMIT
            too_fast = jnp.linalg.norm(vel[:2]) > self.robot.velocity_limit
            cost = (outside | too_fast).astype(jnp.float32)
        else:
            dist = jnp.linalg.norm(pos[:2])
            tangential = jnp.dot(pos[:2], jnp.array([-vel[1], vel[0]]))
            reward = (0.1 * tangential / (1.0 + jnp.abs(dist - CIRCLE_RADIUS))
                      + 0.01 * self.robot.specific_reward(after, action))
            cost = (jnp.abs(pos[0]) > CIRCLE_X_LIMIT).astype(jnp.float32)
        extras = dict(extras, pending=jnp.zeros((), jnp.float32))
        return reward, cost, ~self.robot.alive(after), extras


# task name -> (kind, robot)
BULLET_TASKS = {
    "BallRun": ("run", "Ball"), "CarRun": ("run", "Car"), "DroneRun": ("run", "Drone"),
    "AntRun": ("run", "Ant"), "BallCircle": ("circle", "Ball"), "CarCircle": ("circle", "Car"),
    "DroneCircle": ("circle", "Drone"), "AntCircle": ("circle", "Ant"),
}


def make_task(spec) -> BulletTask:
    if spec.name not in BULLET_TASKS:
        raise ValueError(f"{spec.name!r} is not a Bullet-Safety-Gym task; those are "
                         f"{', '.join(BULLET_TASKS)}")
    kind, robot = BULLET_TASKS[spec.name]
    return BulletTask(spec, kind, ROBOTS[robot])

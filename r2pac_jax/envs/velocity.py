"""Safety-Gymnasium 0.4.0's velocity tasks (v1), on gymnasium's v4 MuJoCo models.

One description per robot (XML, frame skip, observation slice, reward terms, health check,
reset noise, velocity limit); the same pure functions run under MJX and under C MuJoCo
(`physics.py`). The rules were read off the reference sources (safety_gymnasium 0.4.0
`tasks/safety_velocity/*_v0.py|_v1.py` and gymnasium 0.28.1 `envs/mujoco/*_v4.py`):

| robot | dt | obs | reward | cost (v1 limit) | terminal |
|---|---|---|---|---|---|
| Ant | 0.01 x 5 | qpos[2:], qvel | vx + 1 - 0.5 |a|^2 | |v_xy| > 2.6222 | z outside [0.2, 1] or non-finite |
| HalfCheetah | 0.01 x 5 | qpos[1:], qvel | vx - 0.1 |a|^2 | vx > 3.2096 | never |
| Swimmer | 0.01 x 4 | qpos[2:], qvel | vx - 1e-4 |a|^2 | vx > 0.2282 | never |
| Hopper | 0.002 x 4 | qpos[1:], clip(qvel, +-10) | vx + 1 - 1e-3 |a|^2 | vx > 0.7402 | unhealthy |
| Walker2d | 0.002 x 4 | qpos[1:], clip(qvel, +-10) | vx + 1 - 1e-3 |a|^2 | vx > 2.3415 | unhealthy |

Velocities are finite differences over one control step, as in the original: of qpos[0] (or
qpos[0:2]) for all robots but Ant, whose original reads the torso's `mjData.xpos` as `mj_step`
leaves it. Under the RK4 integrator that is the kinematics of the last Runge-Kutta stage, not of
the new qpos (it differs by up to ~5e-3 m, i.e. ~0.06 in reward); so Ant views `xpos` too, and
both backends read it as `mj_step` leaves it (see physics.py). Reset: qpos0 + U(-s, s);
qvel + s N(0, 1) (Ant, HalfCheetah) or U(-s, s) (others); Ant's free-joint quaternion is then
normalised, as MuJoCo 2.3's `mj_forward` did in place at reset (MuJoCo >= 3.2 no longer does).
(Swimmer v0 costs the xy speed; v1, which DSRL used, overrides `step` to cost the x velocity.)

The XMLs (assets/) are gymnasium 0.28.1's, adapted to MuJoCo 4 where the compiled model would
otherwise differ (see each file's first line and benchmarks/FIDELITY.md): Hopper and Walker2d
re-saved in local coordinates; Ant and Hopper geom margins halved, because MuJoCo >= 3.5 sums
the two geoms' margins of a contact where MuJoCo 2.3 took the larger (all their geoms share one
margin, so half of it reproduces the old contact margin exactly); Swimmer's
`collision="predefined"` (gone in MuJoCo 3) becomes `<flag contact="disable"/>`.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from r2pac_jax.envs.physics import MjTask, make_physics_env

ASSETS = Path(__file__).parent / "assets"


@dataclasses.dataclass(frozen=True)
class Robot:
    xml: str
    frame_skip: int
    obs_start: int  # observation = qpos[obs_start:], qvel
    ctrl_cost: float
    healthy_reward: float
    velocity_limit: float
    cost_on_speed: bool  # |v_xy| (Ant) or v_x (others; Swimmer v1 too)
    reset_noise: float
    qvel_noise_normal: bool
    clip_qvel: bool = False
    health: str = "none"  # none | ant | hopper | walker
    com_body: str = ""  # velocity from this body's xpos as mj_step leaves it (Ant) or from qpos


ROBOTS = {
    "AntVelocity": Robot("ant.xml", 5, 2, 0.5, 1.0, 2.6222, True, 0.1, True, health="ant",
                         com_body="torso"),
    "HalfCheetahVelocity": Robot("half_cheetah.xml", 5, 1, 0.1, 0.0, 3.2096, False, 0.1, True),
    "SwimmerVelocity": Robot("swimmer.xml", 4, 2, 1e-4, 0.0, 0.2282, False, 0.1, False),
    "HopperVelocity": Robot("hopper.xml", 4, 1, 1e-3, 1.0, 0.7402, False, 5e-3, False,
                            clip_qvel=True, health="hopper"),
    "Walker2dVelocity": Robot("walker2d.xml", 4, 1, 1e-3, 1.0, 2.3415, False, 5e-3, False,
                              clip_qvel=True, health="walker"),
}


def is_healthy(health: str, qpos: jax.Array, qvel: jax.Array) -> jax.Array:
    """gymnasium v4's health checks (bool [])."""
    if health == "ant":
        finite = jnp.all(jnp.isfinite(qpos)) & jnp.all(jnp.isfinite(qvel))
        return finite & (qpos[2] >= 0.2) & (qpos[2] <= 1.0)
    if health == "hopper":
        state = jnp.concatenate([qpos[2:], qvel])
        ok_state = jnp.all((state > -100.0) & (state < 100.0))
        return ok_state & (qpos[1] > 0.7) & (qpos[2] > -0.2) & (qpos[2] < 0.2)
    if health == "walker":
        return (qpos[1] > 0.8) & (qpos[1] < 2.0) & (qpos[2] > -1.0) & (qpos[2] < 1.0)
    return jnp.array(True)


class VelocityTask(MjTask):
    def __init__(self, spec, robot: Robot):
        import mujoco

        self.spec, self.robot = spec, robot
        self.name, self.obs_dim, self.act_dim = spec.name, spec.obs_dim, spec.act_dim
        self.episode_len = spec.episode_len
        self.frame_skip = robot.frame_skip
        m = self.model()
        self.dt = float(m.opt.timestep) * robot.frame_skip
        self.qpos0 = np.array(m.qpos0)  # float64; cast to JAX's float width when used
        self.nq, self.nv = m.nq, m.nv
        # qpos addresses of free-joint quaternions (normalised at reset, see module docstring)
        self.quat_adr = tuple(int(m.jnt_qposadr[j]) + 3 for j in range(m.njnt)
                              if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE)
        self.com_body = (mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, robot.com_body)
                         if robot.com_body else -1)
        self.view_fields = ("qpos", "qvel", "xpos") if robot.com_body else ("qpos", "qvel")

    def model(self):
        import mujoco

        return mujoco.MjModel.from_xml_path(str(ASSETS / self.robot.xml))

    def init(self, key):
        r = self.robot
        kq, kv = jax.random.split(key)
        s = r.reset_noise
        qpos = jnp.asarray(self.qpos0) + jax.random.uniform(kq, (self.nq,), minval=-s, maxval=s)
        for a in self.quat_adr:
            q = qpos[a:a + 4]
            qpos = qpos.at[a:a + 4].set(q / jnp.linalg.norm(q))
        if r.qvel_noise_normal:
            qvel = s * jax.random.normal(kv, (self.nv,))
        else:
            qvel = jax.random.uniform(kv, (self.nv,), minval=-s, maxval=s)
        return qpos, qvel, {}

    def observe(self, view, extras):
        qvel = view["qvel"]
        if self.robot.clip_qvel:
            qvel = jnp.clip(qvel, -10.0, 10.0)
        return jnp.concatenate([view["qpos"][self.robot.obs_start:], qvel])

    def transition(self, before, after, action, extras):
        r = self.robot
        dims = 2 if r.cost_on_speed else 1
        if self.com_body >= 0:
            v = (after["xpos"][self.com_body, :dims] - before["xpos"][self.com_body, :dims]) / self.dt
        else:
            v = (after["qpos"][:dims] - before["qpos"][:dims]) / self.dt
        vx = v[0]
        reward = vx + r.healthy_reward - r.ctrl_cost * jnp.sum(jnp.square(action))
        speed = jnp.linalg.norm(v) if r.cost_on_speed else vx
        cost = (speed > r.velocity_limit).astype(jnp.float32)
        terminated = ~is_healthy(r.health, after["qpos"], after["qvel"])
        return reward, cost, terminated, extras


def make_task(spec) -> VelocityTask:
    return VelocityTask(spec, ROBOTS[spec.name])


def make_env(spec, physics: str = "auto", **_):
    return make_physics_env(make_task(spec), physics)

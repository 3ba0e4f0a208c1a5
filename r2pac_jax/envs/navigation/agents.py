"""The two agents (Safety-Gymnasium's Car and Point): their XML, sensors and pose from qpos.

Car (`assets/car.xml`): a free body with two motor-driven wheels (hinges, ctrlrange [-1, 1],
forcerange 0.02) and a ball-jointed rear wheel; timestep 0.004 and 10 substeps per control
step (the original's frameskip_binom_n = 10, p = 1). Point (`assets/point.xml`): a sphere on
two slide joints and a hinge about z, timestep 0.002, 10 substeps.

Observation sensors, in the original's order (`BaseAgent.obs_sensor`): the four listed sensors
(accelerometer, velocimeter, gyro, magnetometer), then every ball joint's angular velocity, then
every ball joint's quaternion as a 3x3 rotation matrix (Car: rear wheel) -> 24 (Car) / 12 (Point).

Pose convention. The original writes the agent's start pose into the body's XML `pos`/`quat`
(qpos starts at zero for the Point's slide/hinge joints). We compile the XML once, so the start
pose goes into qpos instead: Car qpos[:7] = free joint (x, y, z, quat) exactly as in the
original; Point qpos = (x, y, heading) in the world frame (body at the origin, unrotated). The
two Point parameterisations describe the same physics (isotropic slide damping, the motor acts
along the site's x axis); `benchmarks/fidelity_nav/compare.py` converts the original's qpos.
"""
from __future__ import annotations

import dataclasses
import os

import jax.numpy as jnp

ASSETS = os.path.join(os.path.dirname(__file__), "assets")


@dataclasses.dataclass(frozen=True)
class AgentSpec:
    name: str  # "car" | "point"
    xml: str  # path of the agent's MJCF
    nq: int  # qpos entries of the agent
    nv: int
    z_height: float  # height of the agent body at reset (the XML's body z)
    frame_skip: int = 10
    # observation sensors in order: (sensor name, kind) with kind "vec" or "quat2mat"
    sensors: tuple = ()
    # the original's sensors kept out of the observation ("intrinsic constraints"); dropped
    # from our model because nothing reads them and MJX would compute them every substep
    unused_sensors: tuple = ("subtreecom", "subtreelinvel", "subtreeangmom")
    wheels: tuple = ()  # cylinder geoms that MJX keeps away from boxes (world.py)

    @property
    def obs_dim(self) -> int:
        return sum(9 if kind == "quat2mat" else 3 for _, kind in self.sensors)


_BASIC = (("accelerometer", "vec"), ("velocimeter", "vec"), ("gyro", "vec"),
          ("magnetometer", "vec"))

CAR = AgentSpec("car", os.path.join(ASSETS, "car.xml"), nq=13, nv=11, z_height=0.1,
                sensors=_BASIC + (("ballangvel_rear", "vec"), ("ballquat_rear", "quat2mat")),
                wheels=("left", "right"))
POINT = AgentSpec("point", os.path.join(ASSETS, "point.xml"), nq=3, nv=3, z_height=0.1,
                  sensors=_BASIC)
AGENTS = {"car": CAR, "point": POINT}


def rot2quat(theta):
    """Quaternion (w, x, y, z) of a rotation by theta about z (the original's `rot2quat`)."""
    theta = jnp.asarray(theta)
    z = jnp.zeros_like(theta)
    return jnp.stack([jnp.cos(theta / 2), z, z, jnp.sin(theta / 2)], -1)


def quat2mat(q):
    """Rotation matrix [..., 3, 3] of unit quaternions [..., 4] (MuJoCo's `mju_quat2Mat`)."""
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    ww, xx, yy, zz = w * w, x * x, y * y, z * z
    row0 = jnp.stack([ww + xx - yy - zz, 2 * (x * y - w * z), 2 * (x * z + w * y)], -1)
    row1 = jnp.stack([2 * (x * y + w * z), ww - xx + yy - zz, 2 * (y * z - w * x)], -1)
    row2 = jnp.stack([2 * (x * z - w * y), 2 * (y * z + w * x), ww - xx - yy + zz], -1)
    return jnp.stack([row0, row1, row2], -2)


def normalize_quat(q):
    """MuJoCo normalises joint quaternions before use (mju_normalize4)."""
    return q / jnp.linalg.norm(q, axis=-1, keepdims=True)


def init_qpos(agent: AgentSpec, xy, rot):
    """The agent's qpos [agent.nq] for a start position xy [2] and heading rot []."""
    xy = jnp.asarray(xy, jnp.float32)
    if agent.name == "car":
        # free joint (pos, quat), two wheel hinges at 0, rear ball joint at identity
        return jnp.concatenate([xy, jnp.array([agent.z_height], jnp.float32), rot2quat(rot),
                                jnp.zeros(2, jnp.float32),
                                jnp.array([1.0, 0.0, 0.0, 0.0], jnp.float32)])
    return jnp.concatenate([xy, jnp.reshape(rot, (1,)).astype(jnp.float32)])


def pose(agent: AgentSpec, qpos):
    """Agent body position [3] and rotation matrix [3, 3] (MuJoCo's xpos / xmat) from qpos."""
    if agent.name == "car":
        return qpos[:3], quat2mat(normalize_quat(qpos[3:7]))
    th = qpos[2]
    c, s = jnp.cos(th), jnp.sin(th)
    zero, one = jnp.zeros_like(th), jnp.ones_like(th)
    mat = jnp.stack([jnp.stack([c, -s, zero]), jnp.stack([s, c, zero]),
                     jnp.stack([zero, zero, one])])
    return jnp.stack([qpos[0], qpos[1], jnp.full_like(th, agent.z_height)]), mat

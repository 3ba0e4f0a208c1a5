"""The Bullet tasks on MuJoCo: `--physics mjx` (pure JAX, for large vectorised evaluation on an
accelerator) and `--physics mujoco` (C MuJoCo in batch on the CPU, the same model), for the
robots' models in `mjcf.py`.

`BulletMjTask` adapts a `tasks.BulletTask` to the MuJoCo task protocol (`physics.MjTask`): it
turns MuJoCo's state into the view the shared rules read (position, (x, y, z, w) quaternion,
world-frame velocities, the Ant's joints and foot contacts, the Drone's Euler angles, rotor
speeds and ground contacts) and the action into MuJoCo's inputs (the Ball's world-frame push,
the Ant's torques, the Drone's rotor motors and propeller thrust, the Car's drives and steering
servos, Bullet's velocity damping of the base and rotors). So observation, reward, cost and
termination are the very functions the bullet backend runs; only the physics differs, and that
gap is measured (benchmarks/FIDELITY.md, `benchmarks/fidelity_bullet/mujoco_gap.py`).

A reset places the robot at the sampled pose at rest and takes one physics step without inputs
before the first observation, as the original does (`settle` in the extras); the Run reward's
progress over that step is paid with the first reward (`pending`), as on the bullet backend.
Contacts are read off the geometry (a foot, box or rotor disc whose lowest point is within
`CONTACT_DISTANCE` of the ground), not off MuJoCo's contact list, so both backends read them
the same way.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from r2pac_jax.envs.base import BackendUnavailableError
from r2pac_jax.envs.bullet import mjcf
from r2pac_jax.envs.bullet.tasks import BulletTask
from r2pac_jax.envs.navigation.agents import normalize_quat, quat2mat, rot2quat
from r2pac_jax.envs.physics import MjTask, MjxEnv, MujocoEnv

DAMPING = 0.04  # btMultiBody's linear and angular damping: m v k (1 + |v|)
# A body this close to the ground touches it (m). pybullet reports a contact point within the
# shapes' collision margin: ant.xml gives its geoms margin 0.01; the Drone's URDF shapes have
# none, and its contact holds until the box is about 1 mm up (a DroneRun lift-off: reported at
# 1.1 mm, not at 1.6 mm).
CONTACT_DISTANCE = {"Ant": 0.01, "Drone": 1e-3}


def euler_from_quat(q_xyzw: jax.Array) -> jax.Array:
    """pybullet's getEulerFromQuaternion: [4] (x, y, z, w) -> [3] roll, pitch, yaw."""
    x, y, z, w = q_xyzw
    sarg = jnp.clip(-2.0 * (x * z - w * y), -1.0, 1.0)
    roll = jnp.arctan2(2.0 * (y * z + w * x), w * w - x * x - y * y + z * z)
    yaw = jnp.arctan2(2.0 * (x * y + w * z), w * w + x * x - y * y - z * z)
    regular = jnp.stack([roll, jnp.arcsin(sarg), yaw])
    down = jnp.stack([0.0, -0.5 * jnp.pi, 2.0 * jnp.arctan2(x, -y)])
    up = jnp.stack([0.0, 0.5 * jnp.pi, 2.0 * jnp.arctan2(-x, y)])
    return jnp.where(sarg <= -0.99999, down, jnp.where(sarg >= 0.99999, up, regular))


def quat_from_euler(rpy: jax.Array) -> jax.Array:
    """pybullet's getQuaternionFromEuler: [3] -> [4] (x, y, z, w)."""
    cr, cp, cy = jnp.cos(0.5 * rpy)
    sr, sp, sy = jnp.sin(0.5 * rpy)
    q = jnp.stack([sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
                   cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy])
    return q / jnp.linalg.norm(q)


def _lowest_z(kind: str, pos: jax.Array, mat: jax.Array, size: jax.Array) -> jax.Array:
    """Height of a geom's lowest point: pos [3], mat [3, 3], size [3] (MuJoCo's geom_size)."""
    az = mat[2, 2]  # the local z axis's height component (capsule / cylinder axis)
    if kind == "capsule":
        return pos[2] - jnp.abs(az) * size[1] - size[0]
    if kind == "cylinder":
        return pos[2] - jnp.abs(az) * size[1] - size[0] * jnp.sqrt(jnp.maximum(1 - az ** 2, 0))
    return pos[2] - jnp.sum(jnp.abs(mat[2]) * size)  # box


class BulletMjTask(MjTask):
    """A Bullet task on a MuJoCo model (see the module docstring)."""

    def __init__(self, task: BulletTask):
        self.bt, self.robot = task, task.robot
        self.name, self.obs_dim, self.act_dim = task.name, task.obs_dim, task.act_dim
        self.episode_len, self.frame_skip = task.episode_len, task.frame_skip
        m = self._model = mjcf.load_model(task)
        body, geom = (lambda n: m.body(n).id), (lambda n: m.geom(n).id)
        self.nbody, self.root = m.nbody, body("robot")
        self.base_mass = float(m.body_mass[self.root])
        self.base_inertia = np.array(m.body_inertia[self.root])
        name = self.robot.name
        # geoms whose contact with the ground the rules read, in the original's order
        if name == "Ant":
            self.touch = [("capsule", geom(g)) for g in mjcf.ANT_FEET]
        elif name == "Drone":
            self.touch = [("box", geom("box")), None] + [("cylinder", geom(f"rotor_{i}"))
                                                         for i in range(4)]
            self.rotor_bodies = [body(f"rotor_{i}") for i in range(4)]
            self.rotor_damping = np.array(m.dof_damping[6:10])
            self.rotor_inertia = np.array(m.body_inertia[self.rotor_bodies[0]])
        else:
            self.touch = []
        if name == "Car":
            self.steer_q = [int(m.joint(n).qposadr[0]) for n in ("steer_left", "steer_right")]
            self.wheel_v = [int(m.joint(n).dofadr[0]) for n in ("rear_left", "rear_right",
                                                                 "front_left", "front_right")]
            # the servo's gain: the axle's wheels (2 I on their mean speed) to the target in one
            # control step
            self.drive_kv = (2 * mjcf.CAR_WHEEL["inertia"][2]
                             / (task.time_step * task.frame_skip))
        self.geom_size = np.array(m.geom_size)
        self.view_fields = ("qpos", "qvel") + (("geom_xpos", "geom_xmat") if self.touch else ())

    def model(self):
        return self._model

    # -- reset ------------------------------------------------------------------------------
    def init(self, key):
        pose, extras = self.bt.init(key)
        pos = pose["pos"]
        if self.bt.kind == "circle":  # faces the clockwise tangent, as tasks.BulletTask.yaw
            yaw = jnp.arctan2(-pos[1], -pos[0]) + 0.5 * jnp.pi + self.robot.init_yaw
        else:
            yaw = jnp.asarray(self.robot.init_yaw)
        quat = rot2quat(yaw)  # w, x, y, z
        qpos = jnp.concatenate([pos, quat, self.joints_from_bullet(pose["joints"])]).astype(
            jnp.float32)
        qvel = jnp.zeros((self._model.nv,), jnp.float32)
        return qpos, qvel, dict(extras, settle=jnp.array(True))

    def joints_from_bullet(self, q):
        """The model's joint coordinates [nq - 7] from the original's motor joints
        [n_joints] (positions or velocities). The Car's 14 (steering hinges, front wheels,
        the two differentials' rings, spiders and sides) become its 6 hinges: steering and
        front wheels as they are, a rear wheel turning with its ring plus its side gear."""
        if self.robot.name != "Car":
            return q
        return jnp.stack([q[4] + q[7], q[4] + q[8], q[0], q[1], q[2], q[3]])

    # -- views ------------------------------------------------------------------------------
    def bullet_view(self, v: dict, before: dict = None) -> dict:
        """The rules' view (tasks.py) of a MuJoCo view; `before` gives `dpos`."""
        qpos, qvel = v["qpos"], v["qvel"]
        q = normalize_quat(qpos[3:7])
        view = dict(pos=qpos[:3], quat=jnp.concatenate([q[1:], q[:1]]), vel=qvel[:3],
                    angvel=quat2mat(q) @ qvel[3:6])
        view["dpos"] = (qpos[:3] - before["qpos"][:3] if before is not None
                        else jnp.zeros(3, qpos.dtype))
        if self.touch:
            xpos = v["geom_xpos"]
            xmat = v["geom_xmat"].reshape(-1, 3, 3)
            reach = CONTACT_DISTANCE[self.robot.name]
            touch = [jnp.zeros(()) if t is None else
                     (_lowest_z(t[0], xpos[t[1]], xmat[t[1]], self.geom_size[t[1]])
                      <= reach).astype(jnp.float32) for t in self.touch]
        if self.robot.name == "Ant":
            view["joints"] = jnp.stack([qpos[7:15], qvel[6:14]], axis=1)
            view["feet"] = jnp.stack(touch)
        elif self.robot.name == "Drone":
            rpy = euler_from_quat(view["quat"])
            view.update(rpy=rpy, quat_euler=quat_from_euler(rpy), rotors=qvel[6:10],
                        ground=jnp.stack(touch))
        return view

    def observe(self, view, extras):
        return self.bt.observe(self.bullet_view(view), extras)

    def transition(self, before, after, action, extras):
        b, a = self.bullet_view(before), self.bullet_view(after, before)
        reward, cost, terminated, stepped = self.bt.transition(b, a, action, extras)
        settled = self.bt.after_reset(a, extras)  # the reset's own step: no reward yet
        settle = extras["settle"]
        zero = jnp.zeros((), jnp.float32)
        out = jax.tree.map(lambda s, t: jnp.where(settle, s, t), settled, stepped)
        return (jnp.where(settle, zero, reward), jnp.where(settle, zero, cost),
                jnp.where(settle, False, terminated), dict(out, settle=jnp.array(False)))

    # -- inputs -----------------------------------------------------------------------------
    def inputs(self, before, action, extras):
        v = self.bullet_view(before)
        a = jnp.clip(action, -1.0, 1.0)
        R = quat2mat(normalize_quat(before["qpos"][3:7]))
        xfrc = jnp.zeros((self.nbody, 6))
        speed, spin = jnp.linalg.norm(v["vel"]), jnp.linalg.norm(v["angvel"])
        inertia = R @ jnp.diag(jnp.asarray(self.base_inertia)) @ R.T
        damp = jnp.concatenate([-self.base_mass * v["vel"] * DAMPING * (1 + speed),
                                -inertia @ v["angvel"] * DAMPING * (1 + spin)])
        xfrc = xfrc.at[self.root].add(damp)
        name = self.robot.name
        ctrl = jnp.zeros((self._model.nu,))
        if name == "Ball":
            push = self.robot.max_force * jnp.concatenate([a, jnp.zeros(1)])
            xfrc = xfrc.at[self.root, :3].add(push)
        elif name == "Ant":
            ctrl = self.robot.torque * a
        elif name == "Car":
            r = self.robot
            steer = before["qpos"][jnp.array(self.steer_q)]
            # per axle: the mean wheel speed driven toward the fitted share of 40 a, within the
            # fitted force limit
            wheels = before["qvel"][jnp.array(self.wheel_v)].reshape(2, 2).mean(axis=1)
            target = mjcf.CAR_SPEED_SCALE * r.speed_multiplier * a[0]
            drive = jnp.clip(self.drive_kv * (target - wheels),
                             -mjcf.CAR_DRIVE_FORCE, mjcf.CAR_DRIVE_FORCE)
            ctrl = jnp.concatenate([drive, jnp.full(2, r.steering_multiplier * a[1])])
            # the reset's step: the original's motors are off; the steering servo holds still
            settle = jnp.concatenate([jnp.zeros(2), steer])
            ctrl = jnp.where(extras["settle"], settle, ctrl)
        elif name == "Drone":
            r = self.robot
            target = jnp.asarray(r.hover) * (1.0 + r.action_range * a)
            axis = R[:, 2]
            spin_inertia = self.rotor_inertia[2]
            # the motor also answers the rotor's damping at the target speed (feed-forward)
            brake = spin_inertia * target * DAMPING * (1 + jnp.abs(target))
            ctrl = jnp.asarray(self.rotor_damping) * target + brake
            climb = jnp.dot(v["vel"], axis)
            thrust = r.thrust(target * jnp.asarray(r.directions), climb)  # per rotor
            rotor_i = R @ jnp.diag(jnp.asarray(self.rotor_inertia)) @ R.T
            for i, bid in enumerate(self.rotor_bodies):
                w = v["angvel"] + v["rotors"][i] * axis  # the rotor's own angular velocity
                xfrc = xfrc.at[bid, :3].add(thrust[i] * axis)
                xfrc = xfrc.at[bid, 3:].add(-rotor_i @ w * DAMPING * (1 + jnp.linalg.norm(w)))
        keep = ~extras["settle"]  # the reset's step runs without inputs
        if name != "Car":
            ctrl = jnp.where(keep, ctrl, 0.0)
        return {"ctrl": ctrl, "xfrc_applied": jnp.where(keep, xfrc, 0.0)}


class BulletMjxEnv(MjxEnv):
    """MJX backend of a Bullet task: a reset ends with the original's settling step."""

    def reset(self, key):
        state = self.step(super().reset(key), jnp.zeros((self.act_dim,), jnp.float32))
        zero = jnp.zeros((), jnp.float32)
        return state.replace(reward=zero, cost=zero, terminated=jnp.array(False),
                             truncated=jnp.array(False), t=jnp.zeros((), jnp.int32))


class BulletMujocoEnv(MujocoEnv):
    """C MuJoCo backend of a Bullet task: a reset ends with the original's settling step."""

    def reset_to(self, states, extras, keys):
        state = super().reset_to(states, extras, keys)
        n = state.obs.shape[0]
        state = self.step_batch(state, np.zeros((n, self.act_dim), np.float32))
        zeros = np.zeros(n, np.float32)
        return state.replace(reward=zeros, cost=zeros, terminated=np.zeros(n, bool),
                             truncated=np.zeros(n, bool), t=np.zeros(n, np.int32))


def make(task: BulletTask, physics: str):
    """`physics` "mjx" or "mujoco"."""
    if not mjcf.has_model(task.robot.name):  # pragma: no cover - every robot has one
        raise BackendUnavailableError(
            f"{task.name}: the {task.robot.name} has no MuJoCo model: use --physics bullet")
    env_cls = BulletMjxEnv if physics == "mjx" else BulletMujocoEnv
    return env_cls(BulletMjTask(task))

"""Bullet-Safety-Gym 1.4.0's robots: what each loads into pybullet, how an action drives it, and
its share of the observation and reward (read off `bullet_safety_gym/envs/agents.py`).

A robot has two halves. The engine half (`load`, `setup`, `set_pose`, `apply_action`) talks to
pybullet for the `bullet` backend. The rule half (`observe`, `specific_reward`, `alive`) is pure
JAX over a *view* of the body's state (see `tasks.py`), shared by every backend.

| robot | body | action | observation | agent reward | speed limit | alive |
|---|---|---|---|---|---|---|
| Ball | sphere r 0.5, mass 0.3 | world-frame force 3.5 [a_x, a_y, 0] at the centre | 0.1 xy, 0.2 v_xy, 0.1 w (3) | -0.5 |a| | 2.5 | always |
| Car | MIT racecar (differential URDF) x 3, 14 revolute joints, gear constraints | rear differential rings' target velocity 40 a_0 (force 20), steering hinges' target angle 0.5 a_1 | 0.1 xy, v_xy, sin yaw, cos yaw, 0.1 yaw rate | 0 | 1.5 | always |
| Drone | the original's quadcopter URDF x 2 (mass 1.42 as written), 4 rotors | rotor target speed hover x (1 + 0.1 a) (force 23.444), and per rotor a thrust force along its axis from the propeller formula at that target speed and the climb speed | 0.1 xyz, 0.2 v, quaternion (via Euler angles), 0.1 w, 2.5e-3 (rotor speed - hover speed) x 4 | 1 (alive, else -10) - 0.01 |w|^2 - links touching the ground | 1.5 | |roll|, |pitch| <= pi/2 |
| Ant | pybullet_data's mjcf/ant.xml (the original's, identical), self-collision | torque 250 a per hinge (8) | 0.1 xyz, 0.3 v, quaternion, 0.15 w, 0.5 (joint position in its range as [-1, 1], 0.1 joint speed) x 8, 4 foot contacts | 1 (alive, else -1) - 2 mean|a 0.1 qdot| - 0.1 mean a^2 - 0.1 (joints within 1% of a limit) | 1.5 | torso z > 0.26 |

Reset: the Ball is put at its loading height (0.5); the Car's 14 joints each get U(-0.1, 0.1)
rad (velocity 0), its base keeps the loaded heading (yaw pi) at height 0.2; the Ant's hips get
U(-0.1, 0.1), its ankles pi/2 + U(-0.1, 0.1) (negated for the 4th and 6th motor), torso at 0.75;
the Drone's 4 rotor joints U(-0.1, 0.1) rad, base at 0.17.
"""
from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

ASSETS = Path(__file__).resolve().parent.parent / "assets" / "bullet"


def disable_motor(pb, cid: int, body: int, j: int) -> None:
    """The original's `Joint.disable_motor`: a position motor with zero force."""
    pb.setJointMotorControl2(body, j, controlMode=pb.POSITION_CONTROL, targetPosition=0,
                             targetVelocity=0, positionGain=0.1, velocityGain=0.1, force=0,
                             physicsClientId=cid)


class Robot:
    """Base class (see the module docstring)."""

    name: str
    act_dim: int
    obs_dim: int
    init_xyz: tuple
    init_yaw: float
    velocity_limit: float
    n_joints: int = 0
    view_keys: tuple = ()  # the robot's own view entries beside the base's (see `read`)

    def sample_joints(self, key) -> jnp.ndarray:
        """The reset's joint positions [n_joints] (the Car's U(-0.1, 0.1))."""
        return jnp.zeros((self.n_joints,), jnp.float32)

    # -- engine half (pybullet, numpy float64) ----------------------------------------------
    def load(self, pb, cid: int) -> int:  # pragma: no cover - abstract
        raise NotImplementedError

    def setup(self, pb, cid: int, body: int) -> None:
        """Motors and constraints after loading (none for the Ball)."""

    def init_joints(self, pb, cid: int, body: int) -> list:
        """The original's `bases.Joint` / `Agent._collect_information` calls for every joint in
        index order: a position motor with zero force, and the fixed joints' motors disabled.
        Sets `self.motors` (the revolute joints: the agent's motor list) and returns
        `getJointInfo` of every joint."""
        infos, self.motors = [], []
        for j in range(pb.getNumJoints(body, physicsClientId=cid)):
            info = pb.getJointInfo(body, j, physicsClientId=cid)
            pb.setJointMotorControl2(body, j, pb.POSITION_CONTROL, positionGain=0.1,
                                     velocityGain=0.1, force=0, physicsClientId=cid)
            if info[2] in (pb.JOINT_REVOLUTE, pb.JOINT_PRISMATIC):
                self.motors.append(j)
            else:
                disable_motor(pb, cid, body, j)
            infos.append(info)
        assert len(self.motors) == self.n_joints, self.motors
        return infos

    def reset_joints(self, world, pose: dict, disable: bool = False) -> None:
        """Motor joints to `pose["joints"]` at rest (the original's `Joint.set_state`; with
        `disable`, its `reset_position_and_disable_motor`)."""
        pb, c, b = world.pb, world.cid, world.body
        for j, q in zip(self.motors, np.asarray(pose["joints"], np.float64)):
            pb.resetJointState(b, j, targetValue=float(q), targetVelocity=0, physicsClientId=c)
            if disable:
                disable_motor(pb, c, b, j)

    def specific_reset(self, world, pose: dict) -> None:
        """The robot's own part of a reset, before the task places it (`world`: engine._World;
        `pose["joints"]` [n_joints] float64)."""

    def apply_action(self, pb, cid: int, body: int, action: np.ndarray) -> None:
        """Drive the motors with `action` as the policy gave it (float32; clipped here, as
        the original's `Agent.apply_action` clips)."""
        raise NotImplementedError  # pragma: no cover - abstract

    def read(self, world) -> dict:
        """The robot's own view entries after a simulation step (numpy)."""
        return {}

    # -- rule half (JAX) ----------------------------------------------------------------------
    def observe(self, view: dict) -> jnp.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def specific_reward(self, view: dict, action: jnp.ndarray) -> jnp.ndarray:
        """The robot's reward term after a step (`action` unclipped, as given)."""
        return jnp.zeros((), jnp.float32)

    def alive(self, view: dict) -> jnp.ndarray:
        return jnp.array(True)


class Ball(Robot):
    name = "Ball"
    act_dim = 2
    obs_dim = 7
    init_xyz = (0.0, 0.0, 0.5)
    init_yaw = 0.0
    velocity_limit = 2.5
    max_force = 3.5

    def load(self, pb, cid):
        q = pb.getQuaternionFromEuler((0.0, 0.0, self.init_yaw))
        return pb.loadURDF(str(ASSETS / "ball.urdf"), self.init_xyz, q, globalScaling=1,
                           useFixedBase=0, flags=0, physicsClientId=cid)

    def specific_reset(self, world, pose):
        world.set_position(self.init_xyz)

    def apply_action(self, pb, cid, body, action):
        # the original pushes at the sphere's current centre, in world coordinates (no torque)
        action = np.clip(action, -1.0, 1.0)
        pos, _ = pb.getBasePositionAndOrientation(body, physicsClientId=cid)
        force = np.array([action[0], action[1], 0.0], np.float64) * self.max_force
        pb.applyExternalForce(body, -1, force, pos, pb.WORLD_FRAME, physicsClientId=cid)

    def observe(self, view):
        return jnp.concatenate([0.1 * view["pos"][:2], 0.2 * view["vel"][:2],
                                0.1 * view["angvel"]])

    def specific_reward(self, view, action):
        return -0.5 * jnp.linalg.norm(jnp.clip(action, -1.0, 1.0))  # the clipped action


class Car(Robot):
    name = "Car"
    act_dim = 2
    obs_dim = 7
    init_xyz = (0.0, 0.0, 0.2)
    init_yaw = float(np.pi)
    velocity_limit = 1.5
    n_joints = 14
    max_force = 20.0
    speed_multiplier = 40.0
    steering_multiplier = 0.5
    steering = (0, 2)
    wheels = (8, 15)
    # (joint a, joint b, gear ratio, aux link): the two differentials and the front axle
    gears = ((9, 11, 1, None), (10, 13, -1, None), (9, 13, -1, None), (16, 18, 1, None),
             (16, 19, -1, None), (17, 19, -1, None), (1, 18, -1, 15), (3, 19, -1, 15))

    def load(self, pb, cid):
        q = pb.getQuaternionFromEuler((0.0, 0.0, self.init_yaw))
        return pb.loadURDF(str(ASSETS / "racecar_differential.urdf"), self.init_xyz, q,
                           globalScaling=3, useFixedBase=0, flags=0, physicsClientId=cid)

    def setup(self, pb, cid, body):
        # the original's motor calls in its order: the joints' zero-force motors (bases), then
        # every joint's velocity motor with zero force (RaceCar), then the gear constraints
        n = len(self.init_joints(pb, cid, body))
        for j in range(n):
            pb.setJointMotorControl2(body, j, pb.VELOCITY_CONTROL, targetVelocity=0, force=0,
                                     physicsClientId=cid)
        for a, b, ratio, aux in self.gears:
            c = pb.createConstraint(body, a, body, b, jointType=pb.JOINT_GEAR,
                                    jointAxis=[0, 1, 0], parentFramePosition=[0, 0, 0],
                                    childFramePosition=[0, 0, 0], physicsClientId=cid)
            extra = {} if aux is None else dict(gearAuxLink=aux)
            pb.changeConstraint(c, gearRatio=ratio, maxForce=10000, physicsClientId=cid,
                                **extra)

    def sample_joints(self, key):
        return jax.random.uniform(key, (self.n_joints,), minval=-0.1, maxval=0.1)

    def specific_reset(self, world, pose):
        self.reset_joints(world, pose)

    def apply_action(self, pb, cid, body, action):
        action = np.clip(action, -1.0, 1.0)
        # float64 products, as the original's numpy 1.x computes them from float32 actions
        speed = float(np.float64(action[0]) * self.speed_multiplier)
        angle = float(np.float64(action[1]) * self.steering_multiplier)
        for j in self.wheels:
            pb.setJointMotorControl2(body, j, pb.VELOCITY_CONTROL, targetVelocity=speed,
                                     force=self.max_force, physicsClientId=cid)
        for j in self.steering:
            pb.setJointMotorControl2(body, j, pb.POSITION_CONTROL, targetPosition=angle,
                                     physicsClientId=cid)

    def observe(self, view):
        q = view["quat"]  # x, y, z, w; yaw = atan2(R10, R00) as pybullet's Euler angles
        r10 = 2.0 * (q[0] * q[1] + q[3] * q[2])
        r00 = 1.0 - 2.0 * (q[1] ** 2 + q[2] ** 2)
        yaw = jnp.arctan2(r10, r00)
        return jnp.concatenate([0.1 * view["pos"][:2], view["vel"][:2],
                                jnp.stack([jnp.sin(yaw), jnp.cos(yaw), 0.1 * view["angvel"][2]])])


class Ant(Robot):
    name = "Ant"
    act_dim = 8
    obs_dim = 33
    init_xyz = (0.0, 0.0, 0.75)
    init_yaw = 0.0
    velocity_limit = 1.5
    n_joints = 8
    view_keys = ("joints", "feet")
    torque = 2.5 * 100.0  # max_force x power_coefficient
    feet_names = ("front_left_foot", "front_right_foot", "left_back_foot", "right_back_foot")
    # joint ranges [8, 2] (rad) as pybullet stores ant.xml's degrees (float32); `setup` reads
    # them off the loaded body (the MuJoCo backends use these)
    limits = np.deg2rad(np.array([(-40, 40), (30, 100), (-40, 40), (-100, -30), (-40, 40),
                                  (-100, -30), (-40, 40), (30, 100)], np.float64)
                        ).astype(np.float32).astype(np.float64)

    def load(self, pb, cid):
        import pybullet_data

        flags = pb.URDF_USE_SELF_COLLISION | pb.URDF_USE_SELF_COLLISION_EXCLUDE_ALL_PARENTS
        ids = pb.loadMJCF(str(Path(pybullet_data.getDataPath()) / "mjcf" / "ant.xml"),
                          flags=flags, physicsClientId=cid)
        return ids[0] if isinstance(ids, tuple) else ids

    def setup(self, pb, cid, body):
        # feet looked up by their links' names, joint ranges for the relative positions
        infos = self.init_joints(pb, cid, body)
        links = {info[12].decode(): j for j, info in enumerate(infos)}
        self.feet = [links[f] for f in self.feet_names]
        self.limits = np.array([(infos[j][8], infos[j][9]) for j in self.motors])

    def sample_joints(self, key):
        noise = jax.random.uniform(key, (8,), minval=-0.1, maxval=0.1)
        pos = noise + jnp.where(jnp.arange(8) % 2 == 1, jnp.pi / 2, 0.0)
        return pos * jnp.where((jnp.arange(8) == 3) | (jnp.arange(8) == 5), -1.0, 1.0)

    def specific_reset(self, world, pose):
        self.reset_joints(world, pose, disable=True)

    def apply_action(self, pb, cid, body, action):
        a = np.clip(action, -1.0, 1.0)
        for j, x in zip(self.motors, a):
            pb.setJointMotorControl2(body, j, pb.TORQUE_CONTROL,
                                     force=float(self.torque * np.float64(x)),
                                     physicsClientId=cid)

    def read(self, world):
        pb, c, b = world.pb, world.cid, world.body
        states = [pb.getJointState(b, j, physicsClientId=c)[:2] for j in self.motors]
        feet = [float(any(p[2] == 0 and p[4] == -1 for p in pb.getContactPoints(
            b, -1, f, -1, physicsClientId=c))) for f in self.feet]
        return dict(joints=np.array(states), feet=np.array(feet))

    def _relative(self, view):
        """[8, 2]: position scaled to [-1, 1] over the joint's range, 0.1 x speed."""
        lo, hi = jnp.asarray(self.limits[:, 0]), jnp.asarray(self.limits[:, 1])
        q, qd = view["joints"][:, 0], view["joints"][:, 1]
        return jnp.stack([2.0 * (q - 0.5 * (lo + hi)) / (hi - lo), 0.1 * qd], axis=1)

    def observe(self, view):
        js = self._relative(view).reshape(-1)
        return jnp.concatenate([0.1 * view["pos"], 0.3 * view["vel"], view["quat"],
                                0.15 * view["angvel"], 0.5 * js, view["feet"]])

    def alive(self, view):
        return view["pos"][2] > 0.26

    def specific_reward(self, view, action):
        rel = self._relative(view)
        at_limit = -0.1 * jnp.sum(jnp.abs(rel[:, 0]) > 0.99)
        energy = -2.0 * jnp.mean(jnp.abs(action * rel[:, 1])) - 0.1 * jnp.mean(action ** 2)
        return jnp.where(self.alive(view), 1.0, -1.0) + energy + at_limit


class Drone(Robot):
    name = "Drone"
    act_dim = 4
    obs_dim = 17
    init_xyz = (0.0, 0.0, 0.17)
    init_yaw = 0.0
    velocity_limit = 1.5
    n_joints = 4
    view_keys = ("rpy", "quat_euler", "rotors", "ground")
    # the original's constants (AscTec Hummingbird, from PyRoboLearn)
    radius = 0.14
    directions = np.array([1.0, -1.0, 1.0, -1.0])  # rotors 1, 3 CCW; 2, 4 CW
    pitch = 4.7 * 0.0254
    k1, k2 = 1.0 / 3.29546, 1.5
    air_density = 1.225
    mass, gravity = 1.420, 9.81
    action_range = 0.1
    motor_force = 23.444

    def __init__(self):
        self.area = np.pi * self.radius ** 2
        self.diameter = 2.0 * self.radius
        fg = self.mass * self.gravity / 4.0
        p = self.pitch
        hover = (2 * np.pi / p) * (fg / (self.air_density * self.area)
                                   * (p / (self.k1 * self.diameter)) ** self.k2) ** 0.5
        self.hover = self.directions * hover  # rad/s per rotor, signed

    def load(self, pb, cid):
        q = pb.getQuaternionFromEuler((0.0, 0.0, self.init_yaw))
        return pb.loadURDF(str(ASSETS / "quadcopter.urdf"), self.init_xyz, q, globalScaling=2,
                           useFixedBase=0, flags=0, physicsClientId=cid)

    def setup(self, pb, cid, body):
        n = len(self.init_joints(pb, cid, body))
        for j in self.motors:  # pybullet clamps joint speeds to 100 rad/s by default
            pb.changeDynamics(body, j, maxJointVelocity=1000, physicsClientId=cid)
        # the original's link list: each joint's child link in index order, the base after
        # the first (its ground-contact penalty counts every link once)
        self.links = [0, -1] + list(range(1, n))

    def sample_joints(self, key):
        return jax.random.uniform(key, (4,), minval=-0.1, maxval=0.1)

    def specific_reset(self, world, pose):
        self.reset_joints(world, pose)

    def thrust(self, speed: float, v0: float) -> float:
        """The original's propeller formula (N) at rotor speed `speed` (rad/s), climb v0: float64
        scalars on the bullet backend, JAX arrays on the MuJoCo ones (mujoco_env.py)."""
        tmp = speed / (2 * np.pi) * self.pitch
        diameter = (4.0 * self.area / np.pi) ** 0.5
        return self.air_density * self.area * (tmp ** 2 - tmp * v0) * (
            self.k1 * diameter / self.pitch) ** self.k2

    def apply_action(self, pb, cid, body, action):
        a = np.clip(action, -1.0, 1.0)
        _, quat = pb.getBasePositionAndOrientation(body, physicsClientId=cid)
        vel, _ = pb.getBaseVelocity(body, physicsClientId=cid)
        R = np.array(pb.getMatrixFromQuaternion(quat)).reshape((3, 3))
        # float32 multiplier times the float64 hover speeds, as numpy 1.x computes them
        target = self.hover * (np.float32(1) + np.float32(self.action_range) * a)
        # the climb rate vel . R e_z, summed left to right in plain float64 (numpy's dot may
        # take an AVX-512 path whose rounding differs from the original's recordings)
        v0 = vel[0] * R[0, 2] + vel[1] * R[1, 2] + vel[2] * R[2, 2]
        for j, d, v in zip(self.motors, self.directions, target):
            pb.setJointMotorControl2(body, j, pb.VELOCITY_CONTROL, targetVelocity=v,
                                     force=self.motor_force, physicsClientId=cid)
            f = self.thrust(v * d, v0)
            pb.applyExternalForce(body, j, np.array([0, 0, f]), (0.0, 0.0, 0.0), pb.LINK_FRAME,
                                  physicsClientId=cid)

    def read(self, world):
        pb, c, b = world.pb, world.cid, world.body
        _, quat = pb.getBasePositionAndOrientation(b, physicsClientId=c)
        rpy = pb.getEulerFromQuaternion(quat)
        rotors = [pb.getJointState(b, j, physicsClientId=c)[1] for j in self.motors]
        ground = [float(any(p[2] == 0 and p[4] == -1 for p in pb.getContactPoints(
            b, -1, link, -1, physicsClientId=c))) for link in self.links]
        return dict(rpy=np.array(rpy), quat_euler=np.array(pb.getQuaternionFromEuler(rpy)),
                    rotors=np.array(rotors), ground=np.array(ground))

    def observe(self, view):
        rotors = 2.5e-3 * (view["rotors"] - jnp.asarray(self.hover, jnp.float32))
        return jnp.concatenate([0.1 * view["pos"], 0.2 * view["vel"], view["quat_euler"],
                                0.1 * view["angvel"], rotors])

    def alive(self, view):
        return (jnp.abs(view["rpy"][0]) <= 0.5 * jnp.pi) & (jnp.abs(view["rpy"][1]) <= 0.5 * jnp.pi)

    def specific_reward(self, view, action):
        spin = 0.01 * jnp.sum(view["angvel"] ** 2)
        return jnp.where(self.alive(view), 1.0, -10.0) - spin - jnp.sum(view["ground"])


ROBOTS = {"Ball": Ball(), "Car": Car(), "Drone": Drone(), "Ant": Ant()}

"""Bullet-Safety-Gym 1.4.0's robots: what each loads into pybullet, how an action drives it, and
its share of the observation and reward (read off `bullet_safety_gym/envs/agents.py`).

A robot has two halves. The engine half (`load`, `setup`, `set_pose`, `apply_action`) talks to
pybullet for the `bullet` backend. The rule half (`observe`, `specific_reward`, `alive`) is pure
JAX over a *view* of the body's state (see `tasks.py`), shared by every backend.

| robot | body | action | observation | agent reward | speed limit | alive |
|---|---|---|---|---|---|---|
| Ball | sphere r 0.5, mass 0.3 | world-frame force 3.5 [a_x, a_y, 0] at the centre | 0.1 xy, 0.2 v_xy, 0.1 w (3) | -0.5 |a| | 2.5 | always |
| Car | MIT racecar (differential URDF) x 3, 14 revolute joints, gear constraints | rear differential rings' target velocity 40 a_0 (force 20), steering hinges' target angle 0.5 a_1 | 0.1 xy, v_xy, sin yaw, cos yaw, 0.1 yaw rate | 0 | 1.5 | always |

Reset: the Ball is put at its loading height (0.5); the Car's 14 joints each get U(-0.1, 0.1)
rad (velocity 0), its base keeps the loaded heading (yaw pi) at height 0.2.
"""
from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

ASSETS = Path(__file__).resolve().parent.parent / "assets" / "bullet"


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
        # the original's motor calls in its order: each joint's position motor with zero force
        # (bases.Joint), fixed joints' motors disabled, then every joint's velocity motor with
        # zero force (RaceCar), then the gear constraints
        n = pb.getNumJoints(body, physicsClientId=cid)
        self.motors = []
        for j in range(n):
            pb.setJointMotorControl2(body, j, pb.POSITION_CONTROL, positionGain=0.1,
                                     velocityGain=0.1, force=0, physicsClientId=cid)
            if pb.getJointInfo(body, j, physicsClientId=cid)[2] in (pb.JOINT_REVOLUTE,
                                                                     pb.JOINT_PRISMATIC):
                self.motors.append(j)
            else:
                pb.setJointMotorControl2(body, j, controlMode=pb.POSITION_CONTROL,
                                         targetPosition=0, targetVelocity=0, positionGain=0.1,
                                         velocityGain=0.1, force=0, physicsClientId=cid)
        assert len(self.motors) == self.n_joints, self.motors
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
        for j, q in zip(self.motors, np.asarray(pose["joints"], np.float64)):
            world.pb.resetJointState(world.body, j, targetValue=float(q), targetVelocity=0,
                                     physicsClientId=world.cid)

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


ROBOTS = {"Ball": Ball(), "Car": Car()}

"""Bullet-Safety-Gym 1.4.0's robots: what each loads into pybullet, how an action drives it, and
its share of the observation and reward (read off `bullet_safety_gym/envs/agents.py`).

A robot has two halves. The engine half (`load`, `setup`, `set_pose`, `apply_action`) talks to
pybullet for the `bullet` backend. The rule half (`observe`, `specific_reward`, `alive`) is pure
JAX over a *view* of the body's state (see `tasks.py`), shared by every backend.

| robot | body | action | observation | agent reward | speed limit | alive |
|---|---|---|---|---|---|---|
| Ball | sphere r 0.5, mass 0.3 | world-frame force 3.5 [a_x, a_y, 0] at the centre | 0.1 xy, 0.2 v_xy, 0.1 w (3) | -0.5 |a| | 2.5 | always |
"""
from __future__ import annotations

from pathlib import Path

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

    # -- engine half (pybullet, numpy float64) ----------------------------------------------
    def load(self, pb, cid: int) -> int:  # pragma: no cover - abstract
        raise NotImplementedError

    def setup(self, pb, cid: int, body: int) -> None:
        """Motors and constraints after loading (none for the Ball)."""

    def specific_reset(self, world) -> None:
        """The robot's own part of a reset, before the task places it (`world`: engine._World)."""

    def apply_action(self, pb, cid: int, body: int, action: np.ndarray) -> None:
        raise NotImplementedError  # pragma: no cover - abstract

    # -- rule half (JAX) ----------------------------------------------------------------------
    def observe(self, view: dict) -> jnp.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def specific_reward(self, action: jnp.ndarray) -> jnp.ndarray:
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

    def specific_reset(self, world):
        world.set_position(self.init_xyz)

    def apply_action(self, pb, cid, body, action):
        # the original pushes at the sphere's current centre, in world coordinates (no torque)
        pos, _ = pb.getBasePositionAndOrientation(body, physicsClientId=cid)
        force = np.array([action[0], action[1], 0.0], np.float64) * self.max_force
        pb.applyExternalForce(body, -1, force, pos, pb.WORLD_FRAME, physicsClientId=cid)

    def observe(self, view):
        return jnp.concatenate([0.1 * view["pos"][:2], 0.2 * view["vel"][:2],
                                0.1 * view["angvel"]])

    def specific_reward(self, action):
        return -0.5 * jnp.linalg.norm(action)


ROBOTS = {"Ball": Ball()}

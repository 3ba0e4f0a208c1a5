"""ReachAvoid: the paper's Figure 1 scenario as a pure-JAX task, our correctness check on CPU.

A point robot starts near (-1.2, 0) and is rewarded for reaching the goal at (1.2, 0) and staying
there; a circular hazard of radius 0.5 sits on the straight line between them and costs 1 for
every step spent inside it. The robot has inertia (velocity is a low-pass filter of the command),
so turning late is expensive and looking h steps ahead matters.

    obs    = [x, y, vx / vmax, vy / vmax, goal_x - x, goal_y - y]          (6)
    action = velocity command in [-1, 1]^2 (norm clipped to 1)           (2)
    reward = 5 * (distance-to-goal decrease) + 0.5 * [inside goal radius]
    cost   = [inside hazard]
    episode: 80 steps; leaving the arena (|x| or |y| > 2.5) is a true terminal.

The behaviour policies of the dataset are scripted waypoint controllers with a risk knob (the
height of the waypoint above or below the hazard centre), a speed knob and action noise; see
`BEHAVIOUR_MIX`. They are fixed by design, before any learning result was seen.
"""
from __future__ import annotations

from typing import NamedTuple

import chex
import jax
import jax.numpy as jnp

from r2pac_jax.envs.base import EnvState, JaxEnv, record_episode

START = (-1.2, 0.0)
START_NOISE = (0.1, 0.15)  # uniform half-widths in x, y
GOAL = (1.2, 0.0)
GOAL_RADIUS = 0.15
HAZARD = (0.0, 0.0)
HAZARD_RADIUS = 0.5
VMAX = 0.1  # distance per step at full command
INERTIA = 0.7  # vel' = INERTIA * vel + (1 - INERTIA) * VMAX * a
ARENA = 2.5
EPISODE_LEN = 80
PROGRESS_REWARD = 5.0
GOAL_REWARD = 0.5


class Physics(NamedTuple):
    pos: jax.Array  # [2]
    vel: jax.Array  # [2]


def _obs(p: Physics) -> jax.Array:
    goal = jnp.asarray(GOAL, jnp.float32)
    return jnp.concatenate([p.pos, p.vel / VMAX, goal - p.pos]).astype(jnp.float32)


def _dist_goal(pos):
    return jnp.linalg.norm(pos - jnp.asarray(GOAL, jnp.float32))


def in_hazard(pos: jax.Array) -> jax.Array:
    """[..., 2] -> [...] bool."""
    return jnp.linalg.norm(pos - jnp.asarray(HAZARD, jnp.float32), axis=-1) < HAZARD_RADIUS


class ReachAvoidEnv(JaxEnv):
    name = "ReachAvoid"
    obs_dim = 6
    act_dim = 2
    episode_len = EPISODE_LEN

    def reset(self, key: jax.Array) -> EnvState:
        key, k = jax.random.split(key)
        noise = jax.random.uniform(k, (2,), minval=-1.0, maxval=1.0) * jnp.asarray(START_NOISE)
        phys = Physics(pos=jnp.asarray(START, jnp.float32) + noise, vel=jnp.zeros(2, jnp.float32))
        zero = jnp.zeros((), jnp.float32)
        return EnvState(obs=_obs(phys), reward=zero, cost=zero, terminated=jnp.array(False),
                        truncated=jnp.array(False), t=jnp.zeros((), jnp.int32), key=key,
                        physics=phys, info={})

    def step(self, state: EnvState, action: jax.Array) -> EnvState:
        chex.assert_shape(action, (self.act_dim,))
        a = jnp.clip(action.astype(jnp.float32), -1.0, 1.0)
        a = a / jnp.maximum(1.0, jnp.linalg.norm(a))
        p = state.physics
        vel = INERTIA * p.vel + (1.0 - INERTIA) * VMAX * a
        pos = p.pos + vel
        d0, d1 = _dist_goal(p.pos), _dist_goal(pos)
        reward = PROGRESS_REWARD * (d0 - d1) + GOAL_REWARD * (d1 < GOAL_RADIUS)
        cost = in_hazard(pos).astype(jnp.float32)
        t = state.t + 1
        phys = Physics(pos=pos, vel=vel)
        return state.replace(
            obs=_obs(phys), reward=reward.astype(jnp.float32), cost=cost,
            terminated=jnp.any(jnp.abs(pos) > ARENA), truncated=t >= self.episode_len,
            t=t, physics=phys,
        )


def make_env(task=None, physics: str = "auto", **_) -> ReachAvoidEnv:
    if physics not in ("auto", "jax"):
        raise ValueError(f"ReachAvoid is pure JAX: physics must be 'auto' or 'jax', got {physics!r}")
    return ReachAvoidEnv()


# ------------------------------------------------------------------------------------------
# Scripted behaviour policies for the dataset.


class Behaviour(NamedTuple):
    """Per-trajectory knobs of the scripted controller (each a scalar array)."""

    height: jax.Array  # waypoint (0, side * height): 0 = straight through the hazard
    side: jax.Array  # +1 above, -1 below the hazard
    speed: jax.Array  # fraction of full speed
    noise: jax.Array  # std of Gaussian action noise
    wander: jax.Array  # bool: weak goal attraction plus large noise


# The mix, fixed as part of the task's design: 40% risky (waypoint inside the hazard),
# 45% detours of graded width, 15% wandering; speeds and noise graded in every group.
BEHAVIOUR_MIX = dict(
    p_risky=0.40, risky_height=(0.0, 0.5),
    p_detour=0.45, detour_height=(0.55, 1.2),
    speed=(0.5, 1.0), noise=(0.0, 0.3), wander_noise=0.6, wander_gain=0.35,
)


def sample_behaviour(key: jax.Array) -> Behaviour:
    m = BEHAVIOUR_MIX
    ks = jax.random.split(key, 6)
    u = jax.random.uniform(ks[0])
    risky = u < m["p_risky"]
    wander = u >= m["p_risky"] + m["p_detour"]
    h_risky = jax.random.uniform(ks[1], minval=m["risky_height"][0], maxval=m["risky_height"][1])
    h_detour = jax.random.uniform(ks[2], minval=m["detour_height"][0], maxval=m["detour_height"][1])
    side = jnp.where(jax.random.bernoulli(ks[3]), 1.0, -1.0)
    speed = jax.random.uniform(ks[4], minval=m["speed"][0], maxval=m["speed"][1])
    noise = jax.random.uniform(ks[5], minval=m["noise"][0], maxval=m["noise"][1])
    return Behaviour(height=jnp.where(risky, h_risky, h_detour), side=side, speed=speed,
                     noise=noise, wander=wander)


def scripted_action(b: Behaviour, state: EnvState, key: jax.Array) -> jax.Array:
    """The waypoint controller: head for (0, side*height) until x >= -0.1, then for the goal."""
    pos = state.physics.pos
    goal = jnp.asarray(GOAL, jnp.float32)
    waypoint = jnp.stack([jnp.float32(0.0), b.side * b.height])
    target = jnp.where(pos[0] < -0.1, waypoint, goal)
    delta = target - pos
    direction = delta / jnp.maximum(jnp.linalg.norm(delta), 1e-6)
    # slow down near the goal so that the robot stops inside it
    speed = b.speed * jnp.clip(_dist_goal(pos) / 0.3, 0.0, 1.0)
    m = BEHAVIOUR_MIX
    eps = jax.random.normal(key, (2,))
    a_plan = direction * speed + b.noise * eps
    a_wander = m["wander_gain"] * direction * b.speed + m["wander_noise"] * eps
    return jnp.clip(jnp.where(b.wander, a_wander, a_plan), -1.0, 1.0)


def rollout_behaviour(env: ReachAvoidEnv, b: Behaviour, key: jax.Array):
    """One episode of a scripted behaviour: per-step arrays of length T plus a valid mask."""
    return record_episode(env, lambda s, k: scripted_action(b, s, k), key)

"""Safety-Gymnasium's pseudo-lidar (`BaseTask._obs_lidar_pseudo`), vectorised over objects.

For each object at world position p (its z replaced by 0), the egocentric vector is
`((p_x, p_y, 0) - agent_pos) @ agent_mat` (the z offset of the agent counts when the agent is
tilted), its XY part z = x + iy gives the distance |z| and the angle arg(z) mod 2 pi. The object
lands in bin floor(angle / bin_size) with reading max(0, max_dist - d) / max_dist, and aliases
into the neighbours: bin+1 gets alias * reading and bin-1 (1 - alias) * reading with
alias = (angle - bin_angle) / bin_size. Each bin keeps the maximum over objects (nearer objects
occlude farther ones). All readings are >= 0, so the per-group maximum over masked
contributions is exact.
"""
from __future__ import annotations

import chex
import jax
import jax.numpy as jnp

NUM_BINS = 16
MAX_DIST = 3.0


def lidar_contributions(agent_pos: jax.Array, agent_mat: jax.Array, obj_xy: jax.Array,
                        num_bins: int = NUM_BINS, max_dist: float = MAX_DIST) -> jax.Array:
    """Each object's reading in every bin [K, num_bins] (before the max over objects).

    agent_pos [3], agent_mat [3, 3] (MuJoCo's xpos / xmat), obj_xy [K, 2] world positions.
    """
    chex.assert_shape(agent_pos, (3,))
    chex.assert_shape(agent_mat, (3, 3))
    chex.assert_rank(obj_xy, 2)
    p3 = jnp.concatenate([obj_xy[:, :2], jnp.zeros_like(obj_xy[:, :1])], -1)
    ego = (p3 - agent_pos[None, :]) @ agent_mat  # row vector times matrix, as the original
    x, y = ego[:, 0], ego[:, 1]
    dist = jnp.sqrt(x * x + y * y)
    two_pi = 2 * jnp.pi
    angle = jnp.mod(jnp.arctan2(y, x), two_pi)
    bin_size = two_pi / num_bins
    b = jnp.floor(angle / bin_size).astype(jnp.int32)
    alias = (angle - bin_size * b) / bin_size
    # angle can round up to exactly 2 pi; the original would index past the end there
    b = jnp.mod(b, num_bins)
    sensor = jnp.maximum(0.0, max_dist - dist) / max_dist
    bins = jnp.arange(num_bins)[None, :]
    here = (bins == b[:, None]) * sensor[:, None]
    plus = (bins == jnp.mod(b + 1, num_bins)[:, None]) * (alias * sensor)[:, None]
    minus = (bins == jnp.mod(b - 1, num_bins)[:, None]) * ((1 - alias) * sensor)[:, None]
    return jnp.maximum(here, jnp.maximum(plus, minus))


def pseudo_lidar(agent_pos, agent_mat, obj_xy, num_bins: int = NUM_BINS,
                 max_dist: float = MAX_DIST) -> jax.Array:
    """One lidar [num_bins] over the objects obj_xy [K, 2]."""
    return lidar_contributions(agent_pos, agent_mat, obj_xy, num_bins, max_dist).max(0)


def grouped_lidar(agent_pos, agent_mat, obj_xy, group_of: jax.Array, num_groups: int,
                  num_bins: int = NUM_BINS, max_dist: float = MAX_DIST) -> jax.Array:
    """Lidars of several object groups at once [num_groups, num_bins].

    obj_xy [K, 2] stacks every group's objects; group_of [K] (static ints) names each one's
    group. Every group must hold at least one object.
    """
    c = lidar_contributions(agent_pos, agent_mat, obj_xy, num_bins, max_dist)  # [K, B]
    member = jnp.arange(num_groups)[:, None] == jnp.asarray(group_of)[None, :]  # [G, K]
    return jnp.max(member[:, :, None] * c[None, :, :], axis=1)

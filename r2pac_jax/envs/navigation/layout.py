"""Keepout rejection sampling of layouts and goals, in JAX (the original's `RandomGenerator`).

The original (`utils/random_generator.py`) places the objects one after another in a fixed
order (agent first). Each object draws up to 100 uniform points from the extents shrunk by its
own keepout; a point is accepted when, for every object placed before it,
`distance >= keepout_other + margin + keepout_self`. If all 100 draws of one object fail, the
whole layout is thrown away and started again (up to 10000 layouts).

Here each object's 100 draws are made at once and the first accepted one is kept: the first
success of a sequence of i.i.d. draws has the same distribution as the first accepted row of a
batch of them, so the layout distribution is the original's. Objects stay sequential
(`lax.scan`), whole-layout restarts are a `lax.while_loop`.

A goal is re-drawn the same way (`sample_goal_position`): up to 10000 draws against every other
object of the current layout; failure ends the episode in the original
(`terminate_resample_failure`).
"""
from __future__ import annotations

import chex
import jax
import jax.numpy as jnp

TRIES_PER_OBJECT = 100  # RandomGenerator.sample_layout
MAX_LAYOUTS = 10000  # RandomGenerator.build_layout
MAX_GOAL_TRIES = 10000  # BaseTask.build_goal_position


def _draw(key, n, keepout, extent):
    """n uniform points [n, 2] in the square [-extent, extent]^2 shrunk by keepout."""
    lo, hi = -extent + keepout, extent - keepout
    return jax.random.uniform(key, (n, 2), minval=lo, maxval=hi)


def _accepted(cand, xy, keepouts, placed, keepout, margin):
    """Which candidates [C, 2] keep clear of the placed objects (xy [N, 2], placed [N])."""
    d = jnp.sqrt(jnp.sum(jnp.square(cand[:, None, :] - xy[None, :, :]), -1))  # [C, N]
    clear = d >= keepouts[None, :] + margin + keepout
    return jnp.all(clear | ~placed[None, :], axis=1)


def _one_layout(key, keepouts, extent, margin):
    n = keepouts.shape[0]

    def place(carry, inp):
        xy, ok = carry
        i, k = inp
        cand = _draw(k, TRIES_PER_OBJECT, keepouts[i], extent)
        placed = jnp.arange(n) < i
        acc = _accepted(cand, xy, keepouts, placed, keepouts[i], margin)
        first = jnp.argmax(acc)
        xy = xy.at[i].set(cand[first])
        return (xy, ok & acc.any()), None

    keys = jax.random.split(key, n)
    init = (jnp.zeros((n, 2), jnp.float32), jnp.array(True))
    (xy, ok), _ = jax.lax.scan(place, init, (jnp.arange(n), keys))
    return xy, ok


def sample_layout(key: jax.Array, keepouts: jax.Array, extent: float, margin: float = 0.0):
    """A layout xy [N, 2] for objects with keepouts [N] (placement order), and success [].

    Retries whole layouts until one succeeds (at most MAX_LAYOUTS, as the original; after that
    the original raises, we return the last attempt with ok = False).
    """
    keepouts = jnp.asarray(keepouts, jnp.float32)
    chex.assert_rank(keepouts, 1)

    def cond(c):
        _, ok, tries = c
        return ~ok & (tries < MAX_LAYOUTS)

    def body(c):
        _, _, tries = c
        xy, ok = _one_layout(jax.random.fold_in(key, tries), keepouts, extent, margin)
        return xy, ok, tries + 1

    xy, ok = _one_layout(jax.random.fold_in(key, 0), keepouts, extent, margin)
    xy, ok, _ = jax.lax.while_loop(cond, body, (xy, ok, jnp.array(1)))
    return xy, ok


def sample_goal(key: jax.Array, xy: jax.Array, keepouts: jax.Array, others: jax.Array,
                goal_keepout: float, extent: float, margin: float = 0.0,
                need: jax.Array = True):
    """Draw a goal position [2] clear of the objects xy [N, 2] where others [N] is True.

    Draws in batches of TRIES_PER_OBJECT, at most MAX_GOAL_TRIES draws; returns (goal, ok).
    With need False nothing is drawn (ok False): used inside `step`, where a goal is re-drawn
    only in the episodes that reached theirs (under vmap the loop runs while any lane needs).
    """
    chex.assert_rank([xy, keepouts, others], [2, 1, 1])
    batches = MAX_GOAL_TRIES // TRIES_PER_OBJECT

    def cond(c):
        _, ok, i = c
        return need & ~ok & (i < batches)

    def body(c):
        goal, ok, i = c
        cand = _draw(jax.random.fold_in(key, i), TRIES_PER_OBJECT, goal_keepout, extent)
        acc = _accepted(cand, xy, keepouts, others, goal_keepout, margin)
        return cand[jnp.argmax(acc)], acc.any(), i + 1

    goal, ok, _ = jax.lax.while_loop(cond, body, (jnp.zeros(2, jnp.float32), jnp.array(False),
                                                  jnp.array(0)))
    return goal, ok

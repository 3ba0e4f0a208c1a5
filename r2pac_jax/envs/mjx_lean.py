"""MJX steps and resets that compile faster on a CPU, with the same arithmetic as MJX's own.

XLA's compile time grows with the number of copies of `mjx.forward` in a program.
- `mjx.step` with the RK4 integrator runs one forward pass and then three more in a fully
  unrolled `lax.scan` (four copies). `step` below runs the four Runge-Kutta stages as one rolled
  scan over a single forward pass: the same stages, tableau and final `_advance` as MJX's
  `rungekutta4` (floating-point results agree to rounding: ~1e-6 after one step in float32).
- A reset that only needs state fields (qpos, qvel, ...) in its observation needs no forward pass
  at all (the next `mjx.step` starts with one, and a forward pass sets nothing the step reads
  back), and one that reads body poses needs only the kinematics: `reset_pass` picks the least.
Other integrators fall through to `mjx.step`. Uses MJX's private `_integrate_pos` / `_advance`;
if a future MJX moves them, `step` falls back to `mjx.step` (slower to compile, same results).
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

# Fields `reset_pass` can serve without a forward pass: the state itself, or kinematics only.
STATE = frozenset({"time", "qpos", "qvel", "act", "ctrl", "mocap_pos", "mocap_quat"})
KINEMATIC = frozenset({"xpos", "xquat", "xmat", "xipos", "ximat", "xanchor", "xaxis",
                       "geom_xpos", "geom_xmat", "site_xpos", "site_xmat"})

try:
    from mujoco.mjx._src import forward as _fwd
    from mujoco.mjx._src import scan as _scan

    _HAVE_INTERNALS = hasattr(_fwd, "_integrate_pos") and hasattr(_fwd, "_advance")
except ImportError:  # pragma: no cover - depends on the MJX version
    _HAVE_INTERNALS = False

# RK4 tableau as four stages: stage k evaluates at d0 + A[k] * (previous stage's derivative) * h
_RK4_A = np.array([0.0, 0.5, 0.5, 1.0])
_RK4_B = np.array([1.0, 2.0, 2.0, 1.0]) / 6.0


def _is_rk4(m) -> bool:
    import mujoco

    return int(m.opt.integrator) == int(mujoco.mjtIntegrator.mjINT_RK4)


def step(m, d):
    """`mjx.step(m, d)`, with RK4's four forward passes in one rolled scan (see module doc)."""
    from mujoco import mjx

    if not (_is_rk4(m) and _HAVE_INTERNALS):
        return mjx.step(m, d)
    d0 = d
    dt = m.opt.timestep

    def integrate(*args):
        return _fwd._integrate_pos(*args, dt=dt)

    def stage(carry, x):
        qvel_sum, qacc_sum, act_dot_sum, kqvel, kqacc, kact_dot, qpos0, d = carry
        a, b, first = x
        # stage 0 is the state itself (exactly: no integration by zero); later stages start
        # from stage 0's qpos, which its forward pass normalised (quaternions), as MJX's d0
        kqpos = jnp.where(first, d0.qpos,
                          _scan.flat(m, integrate, "jqv", "q", m.jnt_type, qpos0, a * kqvel))
        kqvel = jnp.where(first, d0.qvel, d0.qvel + a * kqacc * dt)
        kact = jnp.where(first, d0.act, d0.act + a * kact_dot * dt)
        d = mjx.forward(m, d.replace(qpos=kqpos, qvel=kqvel, act=kact, time=d0.time + a * dt))
        qpos0 = jnp.where(first, d.qpos, qpos0)
        return (qvel_sum + b * kqvel, qacc_sum + b * d.qacc, act_dot_sum + b * d.act_dot,
                kqvel, d.qacc, d.act_dot, qpos0, d), None

    zv, za = jnp.zeros_like(d.qvel), jnp.zeros_like(d.act)
    xs = (jnp.asarray(_RK4_A, d.qvel.dtype), jnp.asarray(_RK4_B, d.qvel.dtype),
          jnp.arange(4) == 0)
    init = (zv, zv, za, d.qvel, zv, za, d.qpos, d)
    (qvel, qacc, act_dot, _, _, _, qpos0, d1), _ = jax.lax.scan(stage, init, xs)
    # as MJX: derived fields from the last stage, state advanced from d0 with the RK4 sums
    d = d1.replace(qpos=qpos0, qvel=d0.qvel, act=d0.act, time=d0.time)
    return _fwd._advance(m, d, act_dot, qacc, qvel)


def reset_pass(m, d, view_fields):
    """What a reset must run so that `view_fields` are valid: nothing, kinematics or forward."""
    from mujoco import mjx

    fields = set(view_fields)
    if fields <= STATE:
        return d
    if fields <= STATE | KINEMATIC:
        return mjx.kinematics(m, d)
    return mjx.forward(m, d)

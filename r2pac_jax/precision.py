"""The networks' matmul precision: `matmul_precision = default | highest | bf16`.

- `default`: what the backend does with a float32 matmul (a GPU may use TF32, the CPU is exact).
- `highest`: full float32 passes everywhere (`jax.default_matmul_precision("highest")`).
- `bf16`: every float32 matmul and convolution takes bfloat16 operands and accumulates in float32
  (the mixed precision of tensor cores); everything else (activations, losses, targets, Adam's
  moments, the parameters themselves) stays float32.

`bf16` cannot be a precision flag: the CPU ignores `jax.default_matmul_precision` (even a
`BF16_BF16_F32` algorithm gives float32 results there), so its effect could not be measured
here. It is a rewrite of the traced program instead: `with_matmul_precision(fn, "bf16")` traces
`fn` and re-runs its jaxpr with each `dot_general` / `conv_general_dilated` on float32 operands
replaced by the same op on bfloat16 casts with a float32 result, inside loops and branches too.
On the CPU the operands are rounded to bfloat16 and multiplied in float32 (its dot kernels
refuse some bf16 x bf16 -> f32 shapes): a product of two bfloat16 values is exact in float32, so
the numbers are those of the bf16 path up to summation order, and only the speed differs.
Gradients taken inside `fn` are rewritten with it (their matmuls are in the jaxpr); a function
returned by this wrapper is not meant to be differentiated again (custom derivative rules are
inlined).
"""
from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp
from jax.extend import core as jcore

from r2pac_jax.config import CHOICES
from r2pac_jax.errors import ConfigError

MODES = CHOICES["matmul_precision"]  # the config's choices: one list
_MATMULS = ("dot_general", "conv_general_dilated")


def check_mode(mode: str) -> str:
    if mode not in MODES:
        raise ConfigError(f"matmul_precision={mode!r} is not one of {', '.join(MODES)}: "
                          f"pass e.g. --set matmul_precision=bf16")
    return mode


def with_matmul_precision(fn: Callable, mode: str) -> Callable:
    """fn with its matmuls at `mode` (same signature, same output dtypes and shapes)."""
    if check_mode(mode) == "default":
        return fn
    if mode == "highest":
        def highest(*args):
            with jax.default_matmul_precision("highest"):
                return fn(*args)
        return highest

    def bf16(*args):
        closed, out_shape = jax.make_jaxpr(fn, return_shape=True)(*args)
        outs = _eval(closed, jax.tree_util.tree_leaves(args))
        return jax.tree_util.tree_unflatten(jax.tree_util.tree_structure(out_shape), outs)
    return bf16


def _low(x):
    return x.astype(jnp.bfloat16)


def _rounded(x):
    return x.astype(jnp.bfloat16).astype(jnp.float32)


def _eval(closed: jcore.ClosedJaxpr, args: list) -> list:
    jaxpr, env = closed.jaxpr, {}

    def read(v):
        return v.val if isinstance(v, jcore.Literal) else env[v]

    env.update(zip(jaxpr.constvars, closed.consts))
    env.update(zip(jaxpr.invars, args))
    for eqn in jaxpr.eqns:
        ins = [read(v) for v in eqn.invars]
        outs = _eqn(eqn, ins)
        if not eqn.primitive.multiple_results:
            outs = [outs]
        for v, x in zip(eqn.outvars, outs):
            if not isinstance(v, jcore.DropVar):
                env[v] = x
    return [read(v) for v in jaxpr.outvars]


def _eqn(eqn, ins):
    name, params = eqn.primitive.name, dict(eqn.params)
    if name in _MATMULS and all(x.dtype == jnp.float32 for x in ins[:2]):
        if jax.default_backend() == "cpu":  # its dot thunks refuse some bf16 x bf16 -> f32
            return eqn.primitive.bind(*[_rounded(x) for x in ins[:2]], *ins[2:], **params)
        params["preferred_element_type"] = jnp.float32
        return eqn.primitive.bind(*[_low(x) for x in ins[:2]], *ins[2:], **params)
    if name in ("pjit", "closed_call", "core_call", "remat", "checkpoint", "custom_jvp_call",
                "custom_vjp_call", "custom_vjp_call_jaxpr"):
        inner = params.get("jaxpr", params.get("call_jaxpr", params.get("fun_jaxpr")))
        if inner is not None:  # inline: we are already inside a trace, and nothing
            if isinstance(inner, jcore.Jaxpr):  # differentiates the result again
                inner = jcore.ClosedJaxpr(inner, ())
            n = len(ins) - len(inner.jaxpr.invars)  # custom_vjp passes consts ahead
            return _pack(eqn, _eval(inner, ins[n:] if n > 0 else ins))
    new = {k: _rewrite(v) for k, v in params.items()}
    with eqn.ctx.manager:
        return eqn.primitive.bind(*ins, **eqn.primitive.get_bind_params(new))


def _pack(eqn, outs):
    return outs if eqn.primitive.multiple_results else outs[0]


def _rewrite(v):
    """A loop's or branch's jaxpr with its matmuls rewritten (same signature)."""
    if isinstance(v, jcore.ClosedJaxpr):
        avals = [jax.ShapeDtypeStruct(a.shape, a.dtype) for a in v.in_avals]
        return jax.make_jaxpr(lambda *a: _eval(v, list(a)))(*avals)
    if isinstance(v, tuple) and v and all(isinstance(b, jcore.ClosedJaxpr) for b in v):
        return tuple(_rewrite(b) for b in v)
    return v

"""The one planner from what a user asked for to each run's `Config`.

`train` (its algorithm and baselines), `table` (one cell per task and algorithm) and `sweep` (one
compiled group per static grid point) all call `plan`; `config.make_config` below it layers the
values (defaults, task, presets, variant, overrides) and checks them. What the planner adds is
what a command line means rather than what a config holds:

- a baseline drops the options that do not apply to it, with a note (the requested algorithm
  refuses them instead, in `make_config`);
- a `steps` shorter than (or not a multiple of) the preset's compiled block shrinks the block
  and the evaluation / checkpoint periods to fit, unless the user set them;
- a task without an environment evaluates nothing unless asked;
- a table cell evaluates once, at the end.
"""
from __future__ import annotations

import math
from typing import Callable, Optional, Union

from r2pac_jax.agents import algo_module
from r2pac_jax.config import PRESETS, Config, field_types, make_config, resolve_preset
from r2pac_jax.tasks import TaskSpec, get_task


def fit_blocks_to_steps(overrides: dict, preset: str) -> None:
    """In place: a `steps` the preset's block does not divide gets the largest block that does
    (and evaluation / checkpoint periods that are multiples of it), unless the user set the block.
    Refreshing the threshold more often is harmless."""
    steps = overrides.get("steps")
    if steps is None or steps < 1:
        return
    preset_values = PRESETS[resolve_preset(preset)[0]]
    block = overrides.get("block_steps") or preset_values["block_steps"]
    if steps % block == 0 or "block_steps" in overrides:
        return
    block = math.gcd(steps, block)
    overrides["block_steps"] = block
    for k in ("eval_every", "checkpoint_every"):
        if overrides.get(k) is None:
            period = min(preset_values[k], steps)
            overrides[k] = max(block, period - period % block)


def plan(task: Union[str, TaskSpec], algo: str, preset: str, options: dict, *,
         baseline: bool = False, final_eval_only: bool = False,
         log: Optional[Callable[[str], None]] = print) -> Config:
    """The checked config of `algo` on `task` from `options`, flat config keys as a user gives
    them (a value of None: not given). `baseline`: drop, with a note, the options `algo` does not
    use or pins to another value (a one-step cloner and `chunk_len`), where the requested
    algorithm would refuse them. `final_eval_only`: one evaluation, after the last step."""
    spec = task if isinstance(task, TaskSpec) else get_task(task)
    over = {k: v for k, v in options.items() if v is not None}
    if baseline:
        mod = algo_module(algo)
        types = field_types(algo)
        for k in [k for k, v in over.items()
                  if k not in types or (k in mod.FIXED and v != mod.FIXED[k])]:
            v = over.pop(k)
            if log is not None:
                log(f"note: baseline {algo} does not use {k}={v!r}; ignored for it")
    fit_blocks_to_steps(over, preset)
    if not spec.has_env and "eval_episodes" not in over:
        over["eval_episodes"] = 0
    cfg = make_config(spec, algo, preset, over)
    return cfg.replace(eval_every=cfg.steps) if final_eval_only else cfg

"""The algorithms, each a module behind the protocol of `agents/base.py`.

Each module ends with one `SPEC = AlgorithmSpec(...)` (`agents/spec.py`): its config class,
presets, variants (the `--algo` names it serves, as config switches), the generic keys it pins,
its vmappable scalars, its checks, and an `Agent` class with init / update / act. This registry
maps every `--algo` name to its module's spec.
"""
from __future__ import annotations

import importlib
from types import ModuleType

from r2pac_jax.agents.per_lane import lane_view
from r2pac_jax.agents.spec import AlgorithmSpec
from r2pac_jax.errors import ConfigError

__all__ = ["AlgorithmSpec", "MODULES", "algo_module", "algo_names", "algorithm_spec", "make_agent"]

# module names under r2pac_jax.agents, in the order `--algo`'s help lists them
MODULES = ("r2pac", "bc_flow", "bc_mlp", "cpq", "bcq_lag", "coptidice", "fisor", "cdt",
           "trebi")


def _variants() -> dict[str, str]:
    out = {}
    for m in MODULES:
        for name in algorithm_spec(importlib.import_module(f"r2pac_jax.agents.{m}")).VARIANTS:
            out[name] = m
    return out


_ALGOS: dict[str, str] = {}


def algorithm_spec(module: ModuleType) -> AlgorithmSpec:
    """The module's `SPEC`; TypeError naming the module when it has none."""
    spec = getattr(module, "SPEC", None)
    if not isinstance(spec, AlgorithmSpec):
        raise TypeError(f"algorithm module {module.__name__} breaks the contract: it has no SPEC "
                        "(an agents.AlgorithmSpec naming its config, presets, variants, checks "
                        "and Agent)")
    return spec


def algo_names() -> list[str]:
    """Every `--algo` name."""
    if not _ALGOS:
        _ALGOS.update(_variants())
    return list(_ALGOS)


def algo_module(algo: str) -> AlgorithmSpec:
    """The spec of the module implementing `algo` (its `SPEC`); ConfigError naming the known
    algorithms otherwise."""
    names = algo_names()
    if algo not in _ALGOS:
        raise ConfigError(f"unknown algo {algo!r}; choose one of {', '.join(names)}")
    return algorithm_spec(importlib.import_module(f"r2pac_jax.agents.{_ALGOS[algo]}"))


def make_agent(cfg, obs_dim: int, act_dim: int):
    """The agent object (static structure: networks, optimiser) of cfg's algorithm. Its
    `cfg` holds markers in place of the vmappable scalars: inside an agent their one place is
    `hp[name]` (`per_lane.py`)."""
    spec = algo_module(cfg.algo)
    return spec.Agent(lane_view(cfg, spec.HPARAMS), obs_dim, act_dim)

"""The algorithms, each a module behind the protocol of `agents/base.py`.

A module declares its config class (`CONFIG`), presets, variants (the `--algo` names it serves,
as config switches), the generic keys it pins (`FIXED`), its vmappable scalars (`HPARAMS`) and
an `Agent` class with init / update / act. This registry maps every `--algo` name to its module.
"""
from __future__ import annotations

import importlib
from types import ModuleType

# module names under r2pac_jax.agents, in the order `--algo`'s help lists them
MODULES = ("r2pac", "bc_flow", "bc_mlp", "cpq", "bcq_lag", "coptidice", "fisor", "cdt")


def _variants() -> dict[str, str]:
    out = {}
    for m in MODULES:
        for name in importlib.import_module(f"r2pac_jax.agents.{m}").VARIANTS:
            out[name] = m
    return out


_ALGOS: dict[str, str] = {}


def algo_names() -> list[str]:
    """Every `--algo` name."""
    if not _ALGOS:
        _ALGOS.update(_variants())
    return list(_ALGOS)


def algo_module(algo: str) -> ModuleType:
    """The module implementing `algo`; ConfigError naming the known algorithms otherwise."""
    names = algo_names()
    if algo not in _ALGOS:
        from r2pac_jax.config import ConfigError

        raise ConfigError(f"unknown algo {algo!r}; choose one of {', '.join(names)}")
    return importlib.import_module(f"r2pac_jax.agents.{_ALGOS[algo]}")


def make_agent(cfg, obs_dim: int, act_dim: int):
    """The agent object (static structure: networks, optimiser) of cfg's algorithm."""
    return algo_module(cfg.algo).Agent(cfg, obs_dim, act_dim)

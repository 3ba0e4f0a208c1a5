"""The algorithms, each a module behind the protocol of `agents/base.py`.

A module declares what `AlgorithmSpec` lists: its config class (`CONFIG`), presets, variants
(the `--algo` names it serves, as config switches), the generic keys it pins (`FIXED`), its
vmappable scalars (`HPARAMS`), its checks, and an `Agent` class with init / update / act. This
registry maps every `--algo` name to its module and checks the module against the contract.
"""
from __future__ import annotations

import dataclasses
import importlib
from types import ModuleType
from typing import Any, Callable

from r2pac_jax.errors import ConfigError

# module names under r2pac_jax.agents, in the order `--algo`'s help lists them
MODULES = ("r2pac", "bc_flow", "bc_mlp", "cpq", "bcq_lag", "coptidice", "fisor", "cdt",
           "trebi")


def _variants() -> dict[str, str]:
    out = {}
    for m in MODULES:
        for name in importlib.import_module(f"r2pac_jax.agents.{m}").VARIANTS:
            out[name] = m
    return out


_ALGOS: dict[str, str] = {}


@dataclasses.dataclass(frozen=True)
class AlgorithmSpec:
    """The contract of an algorithm module, checked when the module is first looked up (a
    module that misses a name, or holds one of the wrong kind, is refused naming it).

    CONFIG: its config dataclass (the generic keys plus its own); PRESETS: {preset: {key:
    value}, or a function of the task spec giving them (TREBI: its steps by family)}; VARIANTS: {--algo name: {key: value}}, the names it serves as config switches;
    FIXED / FIXED_WHY: generic keys it pins, and why; HPARAMS: its vmappable scalars; Agent: the
    class with init / update / act (`agents/base.py`); check_hparams(values), phases(config),
    task_values(task spec) and validate(config): its checks and per-task defaults."""

    CONFIG: type
    PRESETS: dict
    VARIANTS: dict
    FIXED: dict
    FIXED_WHY: dict
    HPARAMS: tuple
    Agent: type
    check_hparams: Callable[[dict], None]
    phases: Callable[[Any], tuple]
    task_values: Callable[[Any], dict]
    validate: Callable[[Any], None]


def _kind_ok(field: dataclasses.Field, value) -> bool:
    if field.type in ("type", type):
        return isinstance(value, type)
    if field.type in ("dict", dict):
        return isinstance(value, dict)
    if field.type in ("tuple", tuple):
        return isinstance(value, tuple)
    return callable(value)


def algorithm_spec(module: ModuleType) -> AlgorithmSpec:
    """The module's AlgorithmSpec; TypeError naming what is missing or of the wrong kind."""
    fields = dataclasses.fields(AlgorithmSpec)
    missing = [f.name for f in fields if not hasattr(module, f.name)]
    wrong = [f"{f.name} (want {f.type if isinstance(f.type, str) else f.type.__name__})"
             for f in fields
             if hasattr(module, f.name) and not _kind_ok(f, getattr(module, f.name))]
    if missing or wrong:
        raise TypeError(f"algorithm module {module.__name__} breaks the contract "
                        f"(agents.AlgorithmSpec): " + "; ".join(
                            ([f"missing {', '.join(missing)}"] if missing else [])
                            + ([f"wrong kind: {', '.join(wrong)}"] if wrong else [])))
    return AlgorithmSpec(**{f.name: getattr(module, f.name) for f in fields})


_CHECKED: set[str] = set()


def algo_names() -> list[str]:
    """Every `--algo` name."""
    if not _ALGOS:
        _ALGOS.update(_variants())
    return list(_ALGOS)


def algo_module(algo: str) -> ModuleType:
    """The module implementing `algo`; ConfigError naming the known algorithms otherwise."""
    names = algo_names()
    if algo not in _ALGOS:
        raise ConfigError(f"unknown algo {algo!r}; choose one of {', '.join(names)}")
    module = importlib.import_module(f"r2pac_jax.agents.{_ALGOS[algo]}")
    if module.__name__ not in _CHECKED:  # once per module: a broken contract fails loudly
        algorithm_spec(module)
        _CHECKED.add(module.__name__)
    return module


def make_agent(cfg, obs_dim: int, act_dim: int):
    """The agent object (static structure: networks, optimiser) of cfg's algorithm."""
    return algo_module(cfg.algo).Agent(cfg, obs_dim, act_dim)

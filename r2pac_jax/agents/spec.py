"""The contract every algorithm module meets: one `AlgorithmSpec` object, its `SPEC`."""
from __future__ import annotations

import dataclasses
from typing import Any, Callable


@dataclasses.dataclass(frozen=True)
class AlgorithmSpec:
    """The contract of an algorithm module: each module ends with `SPEC = AlgorithmSpec(...)`,
    checked when it is made (a value of the wrong kind is refused, naming it).

    CONFIG: its config dataclass (the generic keys plus its own); PRESETS: {preset: {key:
    value}, or a function of the task spec giving them (TREBI: its steps by family)};
    VARIANTS: {--algo name: {key: value}}, the names it serves as config switches;
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

    def __post_init__(self):
        wrong = [f"{f.name} (want {f.type if isinstance(f.type, str) else f.type.__name__})"
                 for f in dataclasses.fields(self) if not _kind_ok(f, getattr(self, f.name))]
        if wrong:
            raise TypeError(f"AlgorithmSpec: wrong kind: {', '.join(wrong)}")


def _kind_ok(field: dataclasses.Field, value) -> bool:
    if field.type in ("type", type):
        return isinstance(value, type)
    if field.type in ("dict", dict):
        return isinstance(value, dict)
    if field.type in ("tuple", tuple):
        return isinstance(value, tuple)
    return callable(value)

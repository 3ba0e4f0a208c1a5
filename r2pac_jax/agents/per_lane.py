"""An algorithm's vmappable scalars (its HPARAMS) have one place inside an agent: `hp[name]`.

A sweep trains cells with different values side by side in one compiled program, so the number
in the config is only the default cell's (`lanes.Lanes.build` starts from it). An agent is
therefore built with a config whose HPARAMS fields hold `PerLane` markers: reading one as a
number (arithmetic, comparison, float(), an array, formatting) raises, naming `hp[name]`, where
a silent read would train every lane at the default cell's value.
"""
from __future__ import annotations

import dataclasses


class PerLaneValue(TypeError):
    """An agent used a config field that differs per lane instead of `hp[name]`."""


class PerLane:
    """The marker an agent's config holds in place of a per-lane scalar."""

    __slots__ = ("name",)

    def __init__(self, name: str):
        self.name = name

    def __repr__(self) -> str:
        return f"PerLane({self.name!r})"

    def __eq__(self, other) -> bool:
        return isinstance(other, PerLane) and other.name == self.name

    def __hash__(self) -> int:
        return hash(("PerLane", self.name))

    def _refuse(self, *args, **kwargs):
        raise PerLaneValue(
            f"cfg.{self.name} differs per lane (a sweep cell may set another value): inside an "
            f"agent read hp[{self.name!r}], the value of the lane being trained or evaluated")


for _op in ("__float__", "__int__", "__index__", "__bool__", "__format__", "__array__",
            "__jax_array__", "__neg__", "__pos__", "__abs__", "__lt__", "__le__", "__gt__",
            "__ge__", "__add__", "__radd__", "__sub__", "__rsub__", "__mul__", "__rmul__",
            "__truediv__", "__rtruediv__", "__floordiv__", "__rfloordiv__", "__pow__",
            "__rpow__", "__mod__", "__rmod__"):
    setattr(PerLane, _op, PerLane._refuse)


def lane_view(cfg, names: tuple[str, ...]):
    """cfg with the algorithm's per-lane fields `names` replaced by `PerLane` markers (the
    config an agent is built with); cfg itself is unchanged."""
    if not names:
        return cfg
    agent = dataclasses.replace(cfg.agent, **{k: PerLane(k) for k in names})
    return dataclasses.replace(cfg, agent=agent)

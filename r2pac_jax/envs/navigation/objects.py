"""The navigation levels as data: which objects each task holds, in the original's order.

Every constant here is read off Safety-Gymnasium 0.4.0 (`assets/geoms/*.py`,
`assets/free_geoms/*.py`, `assets/mocaps/gremlins.py`, `tasks/{goal,button,push}/*_level*.py`,
`agents/*.py`). Order matters twice and is the same both times: the layout is drawn agent
first, then the objects in the task's `_obstacles` order (geoms in the order added, then free
geoms, then mocaps), and the lidar groups follow that same order in the observation.
"""
from __future__ import annotations

import dataclasses
from typing import Optional

# Object kinds. "static" kinds are immovable collidable geoms in the original (we make them mocap
# bodies so that their position can change at every reset without recompiling the model).
KINDS = ("goal", "hazards", "vases", "pillars", "buttons", "gremlins", "push_box")


@dataclasses.dataclass(frozen=True)
class ObjectGroup:
    """`num` objects of one kind. `size` is the half-size / radius the original uses."""

    kind: str
    num: int
    keepout: float  # placement keepout radius
    size: float
    constrained: bool = False  # contributes to the cost
    density: float = 0.001  # free bodies only
    travel: float = 0.3  # gremlins: radius of the mocap's circle
    height: float = 0.5  # pillars: half height

    @property
    def names(self) -> tuple:
        """Layout names, as the original's placements dict spells them."""
        if self.kind in ("goal", "push_box"):
            return (self.kind,)
        return tuple(f"{self.kind[:-1]}{i}" for i in range(self.num))


@dataclasses.dataclass(frozen=True)
class LevelSpec:
    """One navigation task: agent, placement extents and object groups in `_obstacles` order."""

    name: str  # e.g. "CarGoal2"
    family: str  # "goal" | "button" | "push"
    level: int
    agent: str  # "car" | "point"
    extent: float  # placements are drawn in [-extent, extent]^2 (minus each keepout)
    groups: tuple  # ObjectGroup, in the original's `_obstacles` order
    agent_keepout: float = 0.4
    placement_margin: float = 0.0
    button_delay: int = 10  # Buttons.resampling_delay (steps)

    def group(self, kind: str) -> Optional[ObjectGroup]:
        for g in self.groups:
            if g.kind == kind:
                return g
        return None

    @property
    def layout_names(self) -> tuple:
        return ("agent",) + tuple(n for g in self.groups for n in g.names)

    @property
    def keepouts(self) -> tuple:
        return (self.agent_keepout,) + tuple(g.keepout for g in self.groups for _ in g.names)

    def layout_slice(self, kind: str) -> slice:
        """Rows of the layout array [N, 2] that hold the objects of `kind`."""
        start = 1
        for g in self.groups:
            n = len(g.names)
            if g.kind == kind:
                return slice(start, start + n)
            start += n
        raise KeyError(kind)


def _goal(level: int, agent: str) -> LevelSpec:
    # GoalLevel0: Goal(keepout=0.305); level 1: extents 1.5, Hazards(num=8, keepout=0.18),
    # Vases(num=1, is_constrained=False); level 2: extents 2, 10 hazards, 10 vases (constrained).
    hazards, vases = (8, 1) if level == 1 else (10, 10)
    groups = (ObjectGroup("goal", 1, 0.305, 0.3),
              ObjectGroup("hazards", hazards, 0.18, 0.2, constrained=True),
              ObjectGroup("vases", vases, 0.15, 0.1, constrained=level >= 2, density=0.001))
    return LevelSpec(f"{agent.capitalize()}Goal{level}", "goal", level, agent,
                     1.5 if level == 1 else 2.0, groups)


def _button(level: int, agent: str) -> LevelSpec:
    # ButtonLevel0: Buttons(num=4), Goal(size=2 * button size = 0.2, keepout 0.4); level 1:
    # extents 1.5, buttons constrained, Hazards(num=4, keepout=0.18),
    # Gremlins(num=4, travel=0.35, keepout=0.4); level 2: extents 1.8, 8 hazards, 6 gremlins.
    hazards, gremlins = (4, 4) if level == 1 else (8, 6)
    groups = (ObjectGroup("buttons", 4, 0.2, 0.1, constrained=True),
              ObjectGroup("goal", 1, 0.4, 0.2),
              ObjectGroup("hazards", hazards, 0.18, 0.2, constrained=True),
              ObjectGroup("gremlins", gremlins, 0.4, 0.1, constrained=True, density=0.001,
                          travel=0.35))
    return LevelSpec(f"{agent.capitalize()}Button{level}", "button", level, agent,
                     1.5 if level == 1 else 1.8, groups)


def _push(level: int, agent: str) -> LevelSpec:
    # PushLevel0: Goal() (size 0.3, keepout 0.4), PushBox(null_dist=0) (Car: size 0.125,
    # keepout 0.125, density 0.0005; otherwise 0.2, 0.2, 0.001); level 1: extents 1.5,
    # Hazards(num=2, size=0.3) (keepout 0.4), Pillars(num=1, is_constrained=False) (size 0.2,
    # height 0.5, keepout 0.3); level 2: extents 2, 4 hazards, 4 pillars (constrained).
    hazards, pillars = (2, 1) if level == 1 else (4, 4)
    box = (0.125, 0.125, 0.0005) if agent == "car" else (0.2, 0.2, 0.001)
    groups = (ObjectGroup("goal", 1, 0.4, 0.3),
              ObjectGroup("hazards", hazards, 0.4, 0.3, constrained=True),
              ObjectGroup("pillars", pillars, 0.3, 0.2, constrained=level >= 2),
              ObjectGroup("push_box", 1, box[1], box[0], density=box[2]))
    return LevelSpec(f"{agent.capitalize()}Push{level}", "push", level, agent,
                     1.5 if level == 1 else 2.0, groups)


LEVELS: dict = {}
for _agent in ("car", "point"):
    for _lvl in (1, 2):
        for _make in (_goal, _button, _push):
            _spec = _make(_lvl, _agent)
            LEVELS[_spec.name] = _spec


def level_spec(name: str) -> LevelSpec:
    try:
        return LEVELS[name]
    except KeyError:
        raise KeyError(f"no navigation level {name!r}; known: {', '.join(sorted(LEVELS))}")

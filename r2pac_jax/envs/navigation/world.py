"""One compiled MuJoCo model per task: the agent's XML plus the task's objects.

The original rebuilds and recompiles its MJCF at every reset, writing the new layout into the
bodies' XML positions. We compile once and put everything that a layout changes into the
simulation state instead, so that resets are pure array operations (jittable, vmappable):

- free bodies (vases, push box, gremlin boxes) keep their free joints: the layout goes in qpos,
  and the body order is the original's (agent, free bodies), so qpos / qvel are laid out exactly
  as in the original and can be copied across;
- immovable collidable geoms (buttons, pillars) become mocap bodies, placed through mocap_pos
  (mocap bodies are as immovable as world geoms for the dynamics);
- each gremlin's mocap keeps its weld to the gremlin box, but with an explicit identity
  `relpose`: the original welds at the compiled relative pose (the box's layout position under a
  mocap at the origin) and circles the mocap at (travel sin t, travel cos t, size), so we move
  the mocap to (layout + travel (sin t, cos t), 2 size) with the box's rotation. The weld's
  target pose, residual and Jacobian are the same;
- the goal and hazards have no collision (contype 0) and only exist as positions in the task
  state: they are not in the model.

Contact filtering (contype / conaffinity bits): the floor collides with everything that moves;
the mocap-placed immovable geoms collide with everything that moves but not with the floor or
each other (C MuJoCo skips static-static pairs itself; MJX does not). Everything else keeps the
original's "all collide" rule.

Two variants of the same model:
- "exact" (C MuJoCo): the original's geometry: cylinder pillars, wheels colliding with
  everything, plus one MuJoCo `contact` sensor per cost-relevant object (agent subtree vs that
  body, data "found") so that contact tests come out of sensordata.
- "mjx": MJX's JAX backend (mujoco-mjx 3.17) has no cylinder-box collision (nor cylinder-mesh),
  and the car's body and the vases, push box and gremlins are boxes. So the wheels (cylinders)
  collide with the floor and the immovable geoms only (buttons are spheres: sphere-cylinder;
  pillars are capsules: capsule-cylinder), never with boxes; and pillars are capsules whose
  straight part runs from 0.5 m below the floor to 0.8 m above it: the same lateral surface as
  the original's cylinder (radius 0.2, z in [0, 1]) wherever the car, vases and the box can be
  (below 0.8 m); both ends differ only where nothing reaches. What this costs is measured in
  benchmarks/FIDELITY.md (a wheel that touches a vase, gremlin or the push box passes through
  it). MJX reads contacts directly (`backends.mjx_touch`), so this variant has no contact
  sensors.
"""
from __future__ import annotations

import dataclasses
import functools
import xml.etree.ElementTree as ET

import numpy as np

from r2pac_jax.envs.navigation.agents import AGENTS, AgentSpec
from r2pac_jax.envs.navigation.objects import LevelSpec

# contype / conaffinity bits (see the module docstring)
FLOOR = (1, 0)
STATIC = (2, 0)
MOVING = (4, 7)
WHEEL_MJX = (0, FLOOR[0] | STATIC[0])  # the floor, buttons and pillars; no boxes


@dataclasses.dataclass(frozen=True)
class WorldIndex:
    """Where the task's quantities live in the model's arrays (all static numpy ints)."""

    nq: int
    nv: int
    nu: int
    nmocap: int
    timestep: float
    free_qpos: dict  # kind -> qpos address [num] of each free body's joint
    free_qvel: dict  # kind -> qvel address [num]
    mocap: dict  # kind -> mocap ids [num] ("gremlins", "buttons", "pillars")
    sensor_adr: tuple  # observation sensors: (adr, dim, kind)
    touch_bodies: tuple  # body names tested for contact with the agent, in touch-vector order
    touch_adr: np.ndarray  # sensordata address of each touch sensor ("exact" variant) or empty
    touch_body_ids: np.ndarray  # body ids of touch_bodies
    agent_geoms: np.ndarray  # geom ids of the agent


def touch_bodies(level: LevelSpec) -> tuple:
    """Bodies whose contact with the agent matters: cost (vases, pillars, gremlins, buttons)
    or the goal (buttons). Unconstrained vases / pillars (level 1) are left out."""
    out = []
    for g in level.groups:
        if g.kind == "buttons":
            out += list(g.names)
        elif g.kind == "gremlins" and g.constrained:
            out += [f"{n}obj" for n in g.names]
        elif g.kind in ("vases", "pillars") and g.constrained:
            out += list(g.names)
    return tuple(out)


def _fmt(v) -> str:
    return " ".join(repr(float(x)) for x in np.atleast_1d(v))


def _sub(parent, tag, **attrs):
    return ET.SubElement(parent, tag, {k: (v if isinstance(v, str) else _fmt(v))
                                       for k, v in attrs.items()})


def _col(bits):
    return dict(contype=str(bits[0]), conaffinity=str(bits[1]))


def build_xml(level: LevelSpec, variant: str = "exact") -> str:
    """The task's MJCF (see the module docstring for the two variants)."""
    if variant not in ("exact", "mjx"):
        raise ValueError(f"variant must be 'exact' or 'mjx', got {variant!r}")
    agent: AgentSpec = AGENTS[level.agent]
    root = ET.parse(agent.xml).getroot()
    world = root.find("worldbody")
    for g in world.iter("geom"):
        if g.get("name") == "floor":
            g.attrib.update(_col(FLOOR))
        elif variant == "mjx" and g.get("name") in agent.wheels:
            g.attrib.update(_col(WHEEL_MJX))
        else:
            g.attrib.update(_col(MOVING))
    sensor = root.find("sensor")
    for s in list(sensor):
        if s.get("name") in agent.unused_sensors:
            sensor.remove(s)

    # free bodies, in the original's order (vases / push box / gremlin boxes)
    for g in level.groups:
        s = g.size
        if g.kind == "vases":
            for n in g.names:
                # Vases.get_config: pos z = size - sink (4e-5)
                b = _sub(world, "body", name=n, pos=[0.0, 0.0, s - 4e-5])
                _sub(b, "freejoint", name=n)
                _sub(b, "geom", name=n, type="box", size=[s, s, s], density=g.density,
                     group="4", **_col(MOVING))
        elif g.kind == "push_box":
            b = _sub(world, "body", name="push_box", pos=[0.0, 0.0, s])
            _sub(b, "freejoint", name="push_box")
            _sub(b, "geom", name="push_box", type="box", size=[s, s, s], density=g.density,
                 group="1", **_col(MOVING))
            # the four corner columns of world.py's push_box template
            for i, (sx, sy) in enumerate([(1, 1), (-1, 1), (1, -1), (-1, -1)]):
                _sub(b, "geom", name=f"col{i + 1}", type="box", size=[s / 2, s / 2, s],
                     density=g.density, group="1", pos=[sx * s, sy * s, 0.0], **_col(MOVING))
        elif g.kind == "gremlins":
            for n in g.names:
                b = _sub(world, "body", name=f"{n}obj", pos=[0.0, 0.0, s])
                _sub(b, "freejoint", name=f"{n}obj")
                _sub(b, "geom", name=f"{n}obj", type="box", size=[s, s, s], density=g.density,
                     group="5", **_col(MOVING))
    # mocap bodies: gremlins' drivers, then the immovable collidable geoms
    equality = None
    for g in level.groups:
        if g.kind == "gremlins":
            equality = ET.SubElement(root, "equality")
            for n in g.names:
                _sub(world, "body", name=f"{n}mocap", mocap="true", pos=[0.0, 0.0, 2 * g.size])
                _sub(equality, "weld", name=f"{n}mocap", body1=f"{n}mocap", body2=f"{n}obj",
                     solref=".02 1.5", relpose="0 0 0 1 0 0 0")
    for g in level.groups:
        if g.kind == "buttons":
            for n in g.names:
                b = _sub(world, "body", name=n, mocap="true", pos=[0.0, 0.0, g.size])
                _sub(b, "geom", name=n, type="sphere", size=[g.size], group="1", **_col(STATIC))
        elif g.kind == "pillars":
            for n in g.names:
                b = _sub(world, "body", name=n, mocap="true", pos=[0.0, 0.0, g.height])
                if variant == "exact":
                    _sub(b, "geom", name=n, type="cylinder", size=[g.size, g.height], group="2",
                         **_col(STATIC))
                else:
                    # straight part z in [-0.5, 0.8] (world), caps beyond: see module docstring
                    _sub(b, "geom", name=n, type="capsule", size=[g.size], group="2",
                         fromto=[0.0, 0.0, -2 * g.height, 0.0, 0.0, 0.8 - g.height],
                         **_col(STATIC))
    if variant == "exact":
        for n in touch_bodies(level):
            _sub(sensor, "contact", name=f"touch_{n}", subtree1="agent", body2=n, data="found",
                 num="1")
    del equality
    return ET.tostring(root, encoding="unicode")


@functools.lru_cache(maxsize=None)
def _compiled(level: LevelSpec, variant: str):
    import mujoco

    m = mujoco.MjModel.from_xml_string(build_xml(level, variant))
    return m, _index(level, m, variant)


def build_model(level: LevelSpec, variant: str = "exact"):
    """(mujoco.MjModel, WorldIndex) of the task; compiled once per (level, variant).

    The returned MjModel is shared: copy it before changing it."""
    return _compiled(level, variant)


def _index(level: LevelSpec, m, variant: str) -> WorldIndex:
    import mujoco

    agent = AGENTS[level.agent]

    def body(name):
        return mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name)

    free_qpos, free_qvel, mocap = {}, {}, {}
    for g in level.groups:
        if g.kind in ("vases", "push_box", "gremlins"):
            names = [f"{n}obj" if g.kind == "gremlins" else n for n in g.names]
            jnt = [m.body_jntadr[body(n)] for n in names]
            free_qpos[g.kind] = np.array([m.jnt_qposadr[j] for j in jnt])
            free_qvel[g.kind] = np.array([m.jnt_dofadr[j] for j in jnt])
        if g.kind in ("gremlins", "buttons", "pillars"):
            names = [f"{n}mocap" if g.kind == "gremlins" else n for n in g.names]
            mocap[g.kind] = np.array([m.body_mocapid[body(n)] for n in names])
    sensor_adr = []
    for name, kind in agent.sensors:
        sid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SENSOR, name)
        sensor_adr.append((int(m.sensor_adr[sid]), int(m.sensor_dim[sid]), kind))
    tb = touch_bodies(level)
    if variant == "exact":
        touch_adr = np.array([m.sensor_adr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SENSOR,
                                                              f"touch_{n}")] for n in tb], int)
    else:
        touch_adr = np.zeros(0, int)
    agent_body = body("agent")
    # the agent's subtree: the agent body and its descendants (wheels)
    in_subtree = np.zeros(m.nbody, bool)
    for b in range(m.nbody):
        p = b
        while p > 0:
            if p == agent_body:
                in_subtree[b] = True
                break
            p = m.body_parentid[p]
    agent_geoms = np.nonzero(in_subtree[m.geom_bodyid])[0]
    assert m.nq == agent.nq + 7 * sum(len(v) for v in free_qpos.values()), "unexpected qpos"
    return WorldIndex(nq=m.nq, nv=m.nv, nu=m.nu, nmocap=m.nmocap, timestep=float(m.opt.timestep),
                      free_qpos=free_qpos, free_qvel=free_qvel, mocap=mocap,
                      sensor_adr=tuple(sensor_adr), touch_bodies=tb, touch_adr=touch_adr,
                      touch_body_ids=np.array([body(n) for n in tb], int),
                      agent_geoms=agent_geoms)

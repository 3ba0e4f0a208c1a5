"""Scripted behaviour source for the navigation tasks (Car / Point x Goal / Button / Push, 1-2).

DSRL made these datasets with Lagrangian RL agents whose cost limit was annealed; on a 2-core
CPU that is out of reach, so we drive the robots with a scripted controller that reads the
privileged simulator state and spread the behaviours over the cost/return plane with
per-trajectory knobs:

- RISK in [0, 1]: how much the controller cares about costly things (hazards, constrained
  vases / pillars, gremlins, wrong buttons). 0 keeps a wide berth (margin 0.35 m, strong
  repulsion); 1 ignores them. The mix puts ~1/3 of trajectories above risk 0.75 (unsafe at
  kappa 10 as a rule) and spreads the rest.
- SPEED in [0.15, 1]: the forward-speed target as a fraction of the agent's top speed.
- NOISE in [0, 0.8]: std of Gaussian noise on the normalised commands (forward force, turn).
- GAIN in [1, 4]: how hard the commands are pushed into the actuators' force limits (the
  motors saturate at |ctrl| = 0.02 (Car) / 0.05 (Point forward), so the action scale matters).
- WANDER in [0, 0.7]: the chance, per 50-step stretch, of heading for a random spot instead of
  the target (safe but slow behaviour: the low-return, low-cost corner of the plane).

The controller (`control`, jitted JAX over the batch): a potential field toward the current
target (Goal: the goal; Button: the goal button; Push: a point behind the box on the box-goal
line, then the box itself) with repulsion and a tangential push around every obstacle inside
its influence band, then a steering law: heading error -> turn command, speed error ->
forward force. Car: a differential drive, left = forward + turn, right = forward - turn (left
ahead of right turns it anticlockwise; the car's forward axis is its body -y). Point: action 0
is a forward force along its body x, action 1 the turn-rate command (anticlockwise > 0).

Episodes run batched on the C MuJoCo backend (`mujoco.rollout`), 1000 steps each (DSRL's T),
ending early only when the original would (a goal that cannot be re-placed).
"""
from __future__ import annotations

from typing import NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np

from r2pac_jax.data.factory.batch import episode_keys, in_equal_batches, record_episodes

NAV_TASKS = tuple(f"{a}{f}{lvl}" for a in ("Car", "Point") for f in ("Goal", "Button", "Push")
                  for lvl in (1, 2))

# Default sizes: OVERSAMPLE x this many episodes are simulated, then density-thinned. Chosen
# from each task's measured cost per 1000-step episode at a batch of 200 (0.2 s PointGoal1 to
# 2.2 s CarGoal2 on the shared 2-core CPU, experiments/data_factory/step_cost.py) so that one
# task takes about 10 minutes or less; GENERATION.md has the measurements and full runs.
DEFAULT_TRAJECTORIES = {
    "CarGoal1": 300, "CarGoal2": 120, "CarButton1": 300, "CarButton2": 200, "CarPush1": 200,
    "CarPush2": 200, "PointGoal1": 500, "PointGoal2": 150, "PointButton1": 500,
    "PointButton2": 300, "PointPush1": 200, "PointPush2": 200,
}
OVERSAMPLE = 2
BATCH = 200  # episodes stepped together (mujoco.rollout's threads share them)

AGENT_RADIUS = {"car": 0.2, "point": 0.12}  # reach of the body (Car: bumper corners)
TOP_SPEED = {"car": 0.75, "point": 0.9}  # m/s at full forward force (measured)
FORCE_LIMIT = {"car": (0.02, 0.02), "point": (0.05, 1.0)}  # |ctrl| at which each actuator saturates
MARGIN_MAX = 0.35  # extra clearance at risk 0 (m)
BAND = 0.3  # influence band beyond the clearance (m)
WANDER_PERIOD = 50  # steps between wander decisions
GREMLIN_LOOKAHEAD = (0.4, 0.8)  # s
DISC_RISK = 0.35  # below this risk, gremlins' whole circles are kept out of
# risk-0 margin per kind, as a fraction of MARGIN_MAX (gremlin discs are already wide)
MARGIN_SCALE = {"hazards": 1.0, "vases": 0.6, "pillars": 0.6, "buttons": 0.5, "gremlins": 0.6}


class Knobs(NamedTuple):
    """Per-trajectory behaviour knobs, each [n] float32 (see the module docstring)."""

    risk: jax.Array
    speed: jax.Array
    noise: jax.Array
    gain: jax.Array
    wander: jax.Array
    reverse: jax.Array  # bool: may drive backwards


def sample_knobs(key: jax.Array) -> Knobs:
    """One trajectory's knobs (scalars); vmap for a batch."""
    ks = jax.random.split(key, 8)
    # risk: 35% reckless (0.75-1), 65% careful to middling (0-0.75), so that both sides of
    # kappa appear and the careful ones differ in how much return they give up
    reckless = jax.random.uniform(ks[0]) < 0.35
    risk = jnp.where(reckless, jax.random.uniform(ks[1], minval=0.75, maxval=1.0),
                     jax.random.uniform(ks[2], minval=0.0, maxval=0.75))
    speed = jax.random.uniform(ks[3], minval=0.15, maxval=1.0)
    noise = 0.8 * jax.random.uniform(ks[4]) ** 2  # most trajectories lightly noisy
    gain = jnp.exp(jax.random.uniform(ks[5], minval=0.0, maxval=jnp.log(4.0)))
    # 60% never wander; the rest wander with a chance up to 0.7 per stretch
    u = jax.random.uniform(ks[6])
    wander = jnp.where(u < 0.6, 0.0, (u - 0.6) / 0.4 * 0.7)
    reverse = jax.random.uniform(ks[7]) < 0.5
    return Knobs(risk, speed, noise, gain, wander, reverse)


class Layout(NamedTuple):
    """What `control` needs from the simulator state, batched over n episodes."""

    pos: jax.Array  # [n, 2] agent xy
    heading: jax.Array  # [n] direction of the agent's forward axis (rad)
    vel: jax.Array  # [n, 2] agent xy velocity
    target: jax.Array  # [n, 2] goal (Goal), goal button (Button), goal (Push)
    box: jax.Array  # [n, 2] push box xy (zeros outside Push)
    obstacles: jax.Array  # [n, K, 2] centres
    active: jax.Array  # [n, K] bool: to be avoided at all (the goal button is not)


class NavScene:
    """Reads a navigation env's EnvState into a `Layout` (numpy slicing, no simulation).

    Obstacles, in a fixed order per task: hazards (cost when the agent's centre is inside),
    vases (Goal2: cost on touch), pillars (physical; cost in Push2), buttons (cost when a
    wrong one is pressed), gremlins (cost on touch). Each has a radius (clearance from the
    agent centre at risk 1), whether it is costly and whether it moves. A gremlin circles its
    layout place (travel 0.35 m, 1 rad/s, see task.mocap_positions): it appears as its current
    place plus its places GREMLIN_LOOKAHEAD seconds ahead, repelling from every side; careful
    agents (risk < DISC_RISK) also keep out of the whole disc it sweeps (`disc` rows), where
    standing still is safe: they may get stuck, safe but slow.
    """

    def __init__(self, env):
        import mujoco

        task = env.task
        lv, idx = task.level, env.index
        self.level, self.index, self.agent = lv, idx, task.agent.name
        m = env.mj_model
        spec = int(mujoco.mjtState.mjSTATE_FULLPHYSICS)
        # state vector components appear in bit order: time, qpos, qvel, ...
        t_size = mujoco.mj_stateSize(m, int(mujoco.mjtState.mjSTATE_TIME))
        assert spec & int(mujoco.mjtState.mjSTATE_TIME)
        self._qpos = slice(t_size, t_size + m.nq)
        self._qvel = slice(t_size + m.nq, t_size + m.nq + m.nv)
        ar = AGENT_RADIUS[self.agent]
        rows, radius, costly, kinds, margin, disc = [], [], [], [], [], []
        for g in lv.groups:
            if g.kind in ("goal", "push_box"):
                continue
            if g.kind == "vases" and not g.constrained:
                continue  # Goal1's vase costs nothing; pushing it aside is fine
            if g.kind == "hazards":
                r = g.size  # only the agent's centre counts
            elif g.kind == "gremlins":
                r = g.size * np.sqrt(2) + ar
            else:
                r = g.size + ar
            copies = 1 + len(GREMLIN_LOOKAHEAD) if g.kind == "gremlins" else 1
            kinds += [g.kind] * g.num * copies
            radius += [r] * g.num * copies
            costly += [bool(g.constrained)] * g.num * copies
            margin += [MARGIN_SCALE.get(g.kind, 1.0)] * g.num * copies
            disc += [False] * g.num * copies
            if g.kind == "gremlins":
                kinds += ["gremlin_discs"] * g.num
                radius += [r + g.travel] * g.num
                costly += [bool(g.constrained)] * g.num
                margin += [0.2] * g.num
                disc += [True] * g.num
            rows.append(g.kind)
        self.kinds = tuple(kinds)
        self.radius = np.asarray(radius, np.float32)
        self.costly = np.asarray(costly, bool)
        self.moving = np.asarray([k == "gremlins" for k in kinds], bool)
        self.disc = np.asarray(disc, bool)
        self.margin = np.asarray(margin, np.float32)
        self._groups = rows
        self._time = slice(0, t_size)
        self._travel = lv.group("gremlins").travel if lv.group("gremlins") else 0.0
        self.family = lv.family

    @property
    def num_obstacles(self) -> int:
        return len(self.kinds)

    def read(self, state) -> Layout:
        lv, idx = self.level, self.index
        qpos = np.asarray(state.physics["state"][:, self._qpos], np.float32)
        qvel = np.asarray(state.physics["state"][:, self._qvel], np.float32)
        n = qpos.shape[0]
        pos = qpos[:, :2]
        if self.agent == "car":
            w, x, y, z = (qpos[:, 3 + i] for i in range(4))
            # forward = -(body y axis) = -(R01, R11) of the body's rotation matrix
            fwd = -np.stack([2 * (x * y - w * z), w * w - x * x + y * y - z * z], -1)
            heading = np.arctan2(fwd[:, 1], fwd[:, 0])
        else:
            heading = qpos[:, 2]
        vel = qvel[:, :2]
        layout = np.asarray(state.info["layout"], np.float32)
        goal = np.asarray(state.info["goal"], np.float32)[:, :2]

        def free_xy(kind):
            adr = idx.free_qpos[kind]
            return qpos[:, adr[:, None] + np.arange(2)[None, :]]

        obs, act = [], []
        for kind in self._groups:
            if kind in ("hazards", "pillars", "buttons"):
                xy = layout[:, lv.layout_slice(kind)]
            else:  # vases, gremlins: where they are now
                xy = free_xy(kind)
            if kind == "gremlins":  # and where the gremlins' mocaps will be
                centre = layout[:, lv.layout_slice(kind)]
                t = np.asarray(state.physics["state"][:, self._time], np.float32)[:, :1, None]
                xy = np.concatenate([xy] + [centre + self._travel * np.concatenate(
                    [np.sin(t + dt), np.cos(t + dt)], -1) for dt in GREMLIN_LOOKAHEAD]
                                    + [centre], 1)
            a = np.ones(xy.shape[:2], bool)
            if kind == "buttons":
                gb = np.asarray(state.info["goal_button"])
                a = np.arange(xy.shape[1])[None, :] != gb[:, None]
            obs.append(xy)
            act.append(a)
        if obs:
            obstacles, active = np.concatenate(obs, 1), np.concatenate(act, 1)
        else:
            obstacles, active = np.zeros((n, 0, 2), np.float32), np.zeros((n, 0), bool)
        box = free_xy("push_box")[:, 0] if self.family == "push" else np.zeros_like(pos)
        return Layout(pos=pos, heading=heading.astype(np.float32), vel=vel, target=goal,
                      box=box, obstacles=obstacles, active=active)


def _unit(v, eps=1e-6):
    return v / jnp.maximum(jnp.linalg.norm(v, axis=-1, keepdims=True), eps)


def _perp(v):
    return jnp.stack([-v[..., 1], v[..., 0]], -1)


def avoid_direction(pos, target, obstacles, radius, margin, costly, moving, active, risk):
    """Desired unit heading [2] toward `target`, bent around obstacles; and whether the agent
    is inside some obstacle's clearance (it then heads straight out).

    pos, target [2]; obstacles [K, 2]; radius, margin (scale), costly, moving, active [K].
    Costly ones get a
    clearance margin and weight that fall with `risk` (none at risk >= 0.95); free ones (the
    push box, Push1's pillar) are always skirted with a small margin.
    """
    to_t = target - pos
    dist_t = jnp.linalg.norm(to_t)
    u_t = _unit(to_t)
    care = jnp.clip((0.95 - risk) / 0.95, 0.0, 1.0)
    margin = jnp.where(costly, MARGIN_MAX * care * margin, 0.05)
    weight = jnp.where(costly, 2.5 * care, 1.5)
    v = pos[None, :] - obstacles
    d = jnp.linalg.norm(v, axis=-1)
    n_hat = _unit(v)
    clear = radius + margin
    # 0 outside the band, 1 at the clearance, up to 2 inside it
    x = jnp.clip((clear + BAND - d) / BAND, 0.0, 2.0)
    # static obstacles behind the agent or farther than the target do not matter; moving
    # ones (gremlins) do wherever they are
    ahead = jnp.sum(-n_hat * u_t[None, :], -1) > -0.3
    nearer = d - radius < dist_t
    s = weight * x ** 2 * (((ahead & nearer) | moving) & active)
    tang = _perp(n_hat)
    # go round on the target's side; near a tie prefer anticlockwise (no chattering head-on)
    side = jnp.where(jnp.sum(tang * u_t[None, :], -1) >= -0.3, 1.0, -1.0)
    push = jnp.sum(s[:, None] * (0.6 * n_hat + side[:, None] * tang), 0)
    # inside some clearance: get out first (straight away from what is too close)
    # (half-way into the margin, so that skirting at the clearance stays the normal mode)
    deep = (d < radius + 0.5 * margin) & (weight > 0) & costly & active
    inside = jnp.any(deep)
    escape = jnp.sum(deep[:, None] * weight[:, None] * n_hat, 0)
    return jnp.where(inside, _unit(escape + 0.3 * u_t), _unit(u_t + push)), inside


def _push_target(pos, box, goal, agent):
    """Push: where to head, and whether the agent is in place to push (behind the box, on
    the box-goal line); if not, it heads for a point behind the box (skirting the box)."""
    box_r = 0.125 if agent == "car" else 0.2
    u = _unit(goal - box)
    rel = pos - box
    along = jnp.sum(rel * u)  # < 0 behind the box
    lateral = jnp.sum(rel * _perp(u))
    reach = box_r + AGENT_RADIUS[agent]
    pushing = (along < -0.5 * box_r) & (jnp.abs(lateral) < box_r + 0.05) & (
        jnp.linalg.norm(rel) < reach + 0.3)
    behind = box - u * (reach + 0.1)
    # pushing: aim through the box at a point past it, corrected against the lateral offset
    through = box + u * 0.3 - _perp(u) * lateral
    return jnp.where(pushing, through, behind), pushing


def make_controller(scene: NavScene):
    """A jitted `control(layout, knobs, wander_xy, key) -> actions [n, 2]` for one task."""
    radius = jnp.asarray(scene.radius)
    costly = jnp.asarray(scene.costly)
    moving = jnp.asarray(scene.moving)
    margin = jnp.asarray(scene.margin)
    disc = jnp.asarray(scene.disc)
    agent, family = scene.agent, scene.family
    top = TOP_SPEED[agent]
    lim = jnp.asarray(FORCE_LIMIT[agent], jnp.float32)
    box_r = 0.125 if agent == "car" else 0.2

    def one(pos, heading, vel, target, box, obstacles, active, knobs, wander_xy, wandering, key):
        obst, rad, mar, cst, mov = obstacles, radius, margin, costly, moving
        act = active & (~disc | (knobs.risk < DISC_RISK))
        if family == "push":
            tgt, pushing = _push_target(pos, box, target, agent)
            # skirt the box while getting behind it, not when pushing it
            obst = jnp.concatenate([obst, box[None]], 0)
            rad = jnp.concatenate([rad, jnp.array([box_r + AGENT_RADIUS[agent]])])
            cst = jnp.concatenate([cst, jnp.array([False])])
            mar = jnp.concatenate([mar, jnp.array([1.0])])
            mov = jnp.concatenate([mov, jnp.array([False])])
            act = jnp.concatenate([act, ~pushing[None]])
        else:
            tgt = target
        tgt = jnp.where(wandering, wander_xy, tgt)
        direction, inside = avoid_direction(pos, tgt, obst, rad, mar, cst, mov, act, knobs.risk)
        fwd = jnp.stack([jnp.cos(heading), jnp.sin(heading)])
        err = jnp.arctan2(fwd[0] * direction[1] - fwd[1] * direction[0], jnp.sum(fwd * direction))
        # reversing agents drive backwards when the target is well behind them, and any agent
        # backs out of a clearance it has entered (turning there would sweep the obstacle)
        back = (knobs.reverse | inside) & (jnp.abs(err) > 0.6 * jnp.pi)
        sign = jnp.where(back, -1.0, 1.0)
        err = jnp.where(back, jnp.arctan2(jnp.sin(err - jnp.pi), jnp.cos(err - jnp.pi)), err)
        v_fwd = sign * jnp.sum(vel * fwd)
        v_target = knobs.speed * top * jnp.maximum(jnp.cos(err), 0.0) ** 2
        # feed-forward (force ~ speed at steady state) plus a correction of the speed error
        f = jnp.clip((v_target + 2.0 * (v_target - v_fwd)) / top, -1.0, 1.0)
        w = jnp.clip(2.0 * err, -1.0, 1.0)
        if agent == "car":
            f = jnp.clip(f, -(1.0 - jnp.abs(w)), 1.0 - jnp.abs(w))  # turning first
        f = sign * f
        k1, k2 = jax.random.split(key)
        f = f + knobs.noise * jax.random.normal(k1)
        w = w + knobs.noise * jax.random.normal(k2)
        if agent == "car":
            cmd = jnp.stack([f + w, f - w])
            cmd = cmd / jnp.maximum(jnp.max(jnp.abs(cmd)), 1.0)
        else:
            cmd = jnp.stack([f, w])
        return jnp.clip(cmd * lim * knobs.gain, -1.0, 1.0)

    extent = scene.level.extent

    def step(layout, knobs, wander_xy, wandering, key, t):
        """One episode's action at step t; the wander plan is redrawn every WANDER_PERIOD."""
        k_act, k_wander, k_xy = jax.random.split(jax.random.fold_in(key, t), 3)
        redraw = t % WANDER_PERIOD == 0
        wandering = jnp.where(redraw, jax.random.uniform(k_wander) < knobs.wander, wandering)
        wander_xy = jnp.where(redraw, jax.random.uniform(k_xy, (2,), minval=-extent,
                                                         maxval=extent), wander_xy)
        action = one(layout.pos, layout.heading, layout.vel, layout.target, layout.box,
                     layout.obstacles, layout.active, knobs, wander_xy, wandering, k_act)
        return action, wander_xy, wandering

    @jax.jit
    def control(layout: Layout, knobs: Knobs, wander_xy, wandering, keys, t):
        """actions [n, 2], wander_xy [n, 2], wandering [n] for step t (int32 [])."""
        return jax.vmap(step, in_axes=(0, 0, 0, 0, 0, None))(layout, knobs, wander_xy,
                                                              wandering, keys, t)

    return control


@jax.jit
def _split_keys(keys):
    """Per-episode keys [n] -> reset, knob and step keys (each [n])."""
    return tuple(jax.vmap(lambda k, i=i: jax.random.fold_in(k, i))(keys) for i in range(3))


_sample_knobs_batch = jax.jit(jax.vmap(sample_knobs))


def rollout(env, scene: NavScene, control, keys: jax.Array, progress=None,
            progress_scale: float = 1.0, knobs: Optional[Knobs] = None,
            steps: Optional[int] = None) -> dict:
    """Run one batch of episodes (keys [n]) to the end; DSRL arrays of the real steps.

    `knobs` ([n] each) replaces the sampled ones and `steps` cuts episodes short (tests).
    """
    n = keys.shape[0]
    T = env.episode_len if steps is None else steps
    k_reset, k_knobs, k_steps = _split_keys(keys)
    if knobs is None:
        knobs = _sample_knobs_batch(k_knobs)
    state = env.reset_batch(k_reset)
    carry = dict(wander_xy=jnp.zeros((n, 2), jnp.float32), wandering=jnp.zeros((n,), bool))

    def act(t, state):
        a, carry["wander_xy"], carry["wandering"] = control(
            scene.read(state), knobs, carry["wander_xy"], carry["wandering"], k_steps,
            jnp.int32(t))
        return a

    return record_episodes(env, state, act, T, progress, progress_scale)


def make_generate(task_name: str):
    def generate(n_trajectories: int, seed: int, progress=None) -> dict:
        """`n_trajectories` scripted episodes of `task_name`: DSRL arrays (numpy).

        Trajectory i's randomness comes from fold_in(PRNGKey(seed), i), so the same seed gives
        the same arrays and a smaller n gives a prefix. `progress` is called with counts of
        requested trajectories (generated / OVERSAMPLE), matching the factory's progress bar.
        """
        from r2pac_jax.tasks import get_task

        env = get_task(task_name).make_env(physics="mujoco")
        scene = NavScene(env)
        control = make_controller(scene)
        return in_equal_batches(n_trajectories, BATCH, lambda first, size: rollout(
            env, scene, control, episode_keys(seed, first, size), progress, 1.0 / OVERSAMPLE))

    return generate


def source(task_name: str) -> dict:
    return dict(name="scripted navigation controller (privileged state; risk, speed, noise, "
                     "gain and wander knobs), density-thinned",
                generate=make_generate(task_name),
                default_trajectories=DEFAULT_TRAJECTORIES[task_name], oversample=OVERSAMPLE)


SOURCES = {name: source(name) for name in NAV_TASKS}

"""A navigation task as pure JAX functions shared by both physics backends.

    qpos, qvel, mocap_pos, mocap_quat, extras = task.init(key)      # a fresh layout
    mocap_pos = task.mocap_positions(layout, time, xp)              # before every substep
    obs = task.observe(view, extras)                                # [obs_dim]
    reward, cost, terminated, extras = task.transition(after, extras)

`view` is what the backend read off the simulator after a control step's last substep and a
forward pass (the original calls mj_forward before it observes): `qpos`, `qvel`, `sensordata`
and `touch` [T], the number of contacts between the agent and each body of
`WorldIndex.touch_bodies` (C MuJoCo: contact sensors; MJX: its contact list).

`extras` (the task's own state, a dict of arrays): `layout` [N, 2] (the original's layout dict
as an array in placement order; moving objects' rows are refreshed when a goal is reached, as
`update_layout` does, gremlins excepted), `goal` [3] (goal body position), `last_dist_goal`,
`last_dist_box`, `last_box_goal` (push), `timer`, `goal_button` (button), `rng`.

The rules, from Safety-Gymnasium 0.4.0 (`builder.py` step, `tasks/*/*_level0.py`, the objects'
`cal_cost`):
- Goal: reward = previous XY distance to the goal - current one, +1 when the distance is
  <= goal size (0.3); then a new goal is drawn (keepout sampling against every other object at
  its current place) and the distance is remembered to the new goal. No goal place -> the
  episode ends (`terminate_resample_failure`).
- Button: the same distance reward to the goal button; reached = the agent touches the goal
  button; then a new goal button is drawn uniformly among all buttons (it may be the same one)
  and the 10-step timer starts. While the timer runs the buttons' lidar reads 0 and pressing a
  wrong button costs nothing; the timer counts down after each step's cost.
- Push: reward = (previous - current) 3D agent-box distance (gated by previous > 0) +
  (previous - current) 3D box-goal distance, +1 when box-goal <= goal size; then a new goal.
- Cost (per step, indicator of any violation, `constrain_indicator`): agent XY distance to a
  hazard < hazard size; agent touches a vase, or a vase's speed >= 1e-4 (Goal2); agent touches
  a pillar (Push2), a gremlin (Button), a wrong button while the timer is 0 (Button).
"""
from __future__ import annotations

import chex
import jax
import jax.numpy as jnp
import numpy as np

from r2pac_jax.envs.navigation import agents as agents_lib
from r2pac_jax.envs.navigation.layout import sample_goal, sample_layout
from r2pac_jax.envs.navigation.lidar import NUM_BINS, grouped_lidar
from r2pac_jax.envs.navigation.objects import LevelSpec
from r2pac_jax.envs.navigation.world import build_model

VASE_VELOCITY_THRESHOLD = 1e-4  # Vases.velocity_threshold
EPISODE_LEN = 1000  # BaseTask.num_steps


class NavTask:
    """Safety-Gymnasium Goal / Button / Push task functions for one level (see module doc)."""

    act_dim = 2
    episode_len = EPISODE_LEN

    def __init__(self, level: LevelSpec):
        self.level = level
        self.name = level.name
        self.agent = agents_lib.AGENTS[level.agent]
        self.frame_skip = self.agent.frame_skip
        _, self.index = build_model(level, "exact")
        self.num_groups = len(level.groups)
        self.obs_dim = self.agent.obs_dim + NUM_BINS * self.num_groups
        names = level.layout_names
        self._keepouts = np.array(level.keepouts, np.float32)
        self._is_goal_row = np.array([n == "goal" for n in names])
        self._goal_row = names.index("goal")
        self._timestep = self.index.timestep
        # lidar objects in observation order: (group index, source, rows / addresses)
        self._group_of = np.concatenate([np.full(len(g.names), i)
                                         for i, g in enumerate(level.groups)])
        tb = self.index.touch_bodies
        self._touch_of = {k: np.array([i for i, b in enumerate(tb) if b.startswith(k[:-1])],
                                      int) for k in ("vases", "pillars", "gremlins", "buttons")}

    # ---- helpers --------------------------------------------------------------------------
    def group(self, kind):
        return self.level.group(kind)

    def _rows(self, layout, kind):
        return layout[self.level.layout_slice(kind)]

    def _free_xyz(self, qpos, kind):
        adr = self.index.free_qpos[kind]
        return qpos[adr[:, None] + np.arange(3)[None, :]]

    def _goal_z(self):
        # Goal.get_config: pos z = size / 2 + 1e-2
        return self.group("goal").size / 2 + 1e-2

    # ---- reset ------------------------------------------------------------------------------
    def init(self, key: jax.Array):
        """A fresh episode: qpos [nq], qvel [nv], mocap_pos [m, 3], mocap_quat [m, 4], extras."""
        lv, idx = self.level, self.index
        k_lay, k_rot, k_goal, k_btn, k_rng = jax.random.split(key, 5)
        layout, _ = sample_layout(k_lay, self._keepouts, lv.extent, lv.placement_margin)
        # BaseTask._build_world_config: the agent's rotation, then one per object
        rots = jax.random.uniform(k_rot, (len(self._keepouts),), minval=0.0, maxval=2 * np.pi)
        extras = dict(rng=k_rng)
        if lv.family == "button":
            nb = self.group("buttons").num
            goal_button = jax.random.randint(k_btn, (), 0, nb)
            goal_xy = self._rows(layout, "buttons")[goal_button]
            extras.update(goal_button=goal_button, timer=jnp.zeros((), jnp.int32))
        else:
            goal_xy, _ = sample_goal(k_goal, layout, jnp.asarray(self._keepouts),
                                     jnp.asarray(~self._is_goal_row), self.group("goal").keepout,
                                     lv.extent, lv.placement_margin)
            layout = layout.at[self._goal_row].set(goal_xy)
        goal = jnp.concatenate([goal_xy, jnp.array([self._goal_z()], jnp.float32)])

        qpos = jnp.zeros((idx.nq,), jnp.float32)
        qpos = qpos.at[:self.agent.nq].set(agents_lib.init_qpos(self.agent, layout[0], rots[0]))
        mocap_quat = jnp.tile(jnp.array([1.0, 0.0, 0.0, 0.0], jnp.float32), (idx.nmocap, 1))
        for g in lv.groups:
            sl = lv.layout_slice(g.kind)
            xy, quat = layout[sl], agents_lib.rot2quat(rots[sl])
            if g.kind in idx.free_qpos:
                # Vases sink 4e-5 into the floor (Vases.sink); boxes rest at z = size
                z = g.size - 4e-5 if g.kind == "vases" else g.size
                body = jnp.concatenate([xy, jnp.full((xy.shape[0], 1), z), quat], -1)
                adr = idx.free_qpos[g.kind][:, None] + np.arange(7)[None, :]
                qpos = qpos.at[adr].set(body)
            if g.kind in idx.mocap:
                mocap_quat = mocap_quat.at[idx.mocap[g.kind]].set(quat)
        extras["layout"] = layout
        mocap_pos = self.mocap_positions(layout, jnp.zeros(()), jnp, at_reset=True)
        pos, _ = agents_lib.pose(self.agent, qpos)
        extras["goal"] = goal
        extras["last_dist_goal"] = jnp.linalg.norm(goal[:2] - pos[:2])
        if lv.family == "push":
            box = self._free_xyz(qpos, "push_box")[0]
            extras["last_dist_box"] = jnp.linalg.norm(box - pos)
            extras["last_box_goal"] = jnp.linalg.norm(box - goal)
        return qpos, jnp.zeros((idx.nv,), jnp.float32), mocap_pos, mocap_quat, extras

    def mocap_positions(self, layout, time, xp=jnp, at_reset: bool = False):
        """mocap_pos [m, 3] at simulation time `time` (set before every substep).

        Buttons and pillars stay at their layout place; each gremlin's mocap circles its layout
        place: layout + travel * (sin t, cos t) at height 2 * size (see world.py on the weld).
        At reset the original's mocap is still at its compiled place (weld target = the box's
        start pose): `at_reset` gives that. `xp` is numpy (C MuJoCo, float64) or jax.numpy.
        """
        idx = self.index
        out = xp.zeros(layout.shape[:-2] + (idx.nmocap, 3), dtype=layout.dtype)
        for g in self.level.groups:
            if g.kind not in idx.mocap:
                continue
            xy = layout[..., self.level.layout_slice(g.kind), :]
            if g.kind == "gremlins":
                if at_reset:
                    z = g.size
                else:
                    phase = xp.asarray(time)[..., None]
                    offset = xp.stack([xp.sin(phase), xp.cos(phase)], -1) * g.travel
                    xy = xy + offset
                    z = 2 * g.size
            else:
                z = g.height if g.kind == "pillars" else g.size
            zz = xp.full(xy.shape[:-1] + (1,), z, dtype=layout.dtype)
            val = xp.concatenate([xy, zz], -1)
            if xp is np:
                out[..., idx.mocap[g.kind], :] = val
            else:
                out = out.at[..., idx.mocap[g.kind], :].set(val)
        return out

    def controls(self, action):
        return action

    # ---- observation --------------------------------------------------------------------------
    def observe(self, view: dict, extras: dict) -> jax.Array:
        """Sensors then one 16-bin lidar per object group, in the original's order [obs_dim]."""
        qpos, sens = view["qpos"], view["sensordata"]
        chex.assert_rank(qpos, 1)
        pos, mat = agents_lib.pose(self.agent, qpos)
        parts = []
        for adr, dim, kind in self.index.sensor_adr:
            v = sens[adr:adr + dim]
            parts.append(agents_lib.quat2mat(v).reshape(9) if kind == "quat2mat" else v)
        layout = extras["layout"]
        xy = []
        for g in self.level.groups:
            if g.kind == "goal":
                xy.append(extras["goal"][None, :2])
            elif g.kind in self.index.free_qpos:
                xy.append(self._free_xyz(qpos, g.kind)[:, :2])
            else:  # hazards, buttons, pillars: where the layout put them
                xy.append(self._rows(layout, g.kind))
        lidars = grouped_lidar(pos, mat, jnp.concatenate(xy, 0), self._group_of,
                               self.num_groups)
        if self.level.family == "button":
            # ButtonLevel0.obs: buttons' lidar reads 0 while the timer runs
            b = [g.kind for g in self.level.groups].index("buttons")
            lidars = lidars.at[b].multiply((extras["timer"] == 0).astype(lidars.dtype))
        obs = jnp.concatenate(parts + [lidars.reshape(-1)])
        chex.assert_shape(obs, (self.obs_dim,))
        return obs

    # ---- one control step's outcome ---------------------------------------------------------
    def transition(self, after: dict, extras: dict):
        """(reward [], cost [], terminated [], extras) of the step that led to `after`."""
        lv = self.level
        qpos, qvel, touch = after["qpos"], after["qvel"], after["touch"]
        pos, _ = agents_lib.pose(self.agent, qpos)
        goal = extras["goal"]
        rng, k_goal, k_btn = jax.random.split(extras["rng"], 3)
        new = dict(extras, rng=rng)

        # reward (calculate_reward) and whether the goal is reached (goal_achieved)
        dist_goal = jnp.linalg.norm(goal[:2] - pos[:2])
        if lv.family == "push":
            box = self._free_xyz(qpos, "push_box")[0]
            dist_box = jnp.linalg.norm(box - pos)
            last_box = extras["last_dist_box"]
            reward = (last_box - dist_box) * (last_box > 0.0)  # null_dist = 0
            dist_box_goal = jnp.linalg.norm(box - goal)
            reward = reward + (extras["last_box_goal"] - dist_box_goal)
            achieved = dist_box_goal <= self.group("goal").size
            new.update(last_dist_box=dist_box, last_box_goal=dist_box_goal)
        else:
            reward = extras["last_dist_goal"] - dist_goal
            if lv.family == "goal":
                achieved = dist_goal <= self.group("goal").size
            else:
                achieved = touch[self._touch_of["buttons"]][extras["goal_button"]] > 0
        new["last_dist_goal"] = dist_goal
        reward = reward + achieved.astype(reward.dtype)

        cost = self.cost(pos, qvel, touch, extras)

        terminated = jnp.array(False)
        layout = extras["layout"]
        if lv.family == "button":
            # specific_step: the timer ticks after the cost; then a reached goal re-arms it
            timer = jnp.maximum(0, extras["timer"] - 1)
            nb = self.group("buttons").num
            button = jax.random.randint(k_btn, (), 0, nb)
            new_goal_xy = self._rows(layout, "buttons")[button]
            new["goal_button"] = jnp.where(achieved, button, extras["goal_button"])
            new["timer"] = jnp.where(achieved, lv.button_delay, timer).astype(jnp.int32)
            goal_xy = jnp.where(achieved, new_goal_xy, goal[:2])
        else:
            # update_layout: moving objects' rows take their current place (gremlins do not)
            moved = layout.at[0].set(pos[:2])
            for kind in ("vases", "push_box"):
                if self.group(kind) is not None:
                    moved = moved.at[lv.layout_slice(kind)].set(
                        self._free_xyz(qpos, kind)[:, :2])
            g_xy, ok = sample_goal(k_goal, moved, jnp.asarray(self._keepouts),
                                   jnp.asarray(~self._is_goal_row), self.group("goal").keepout,
                                   lv.extent, lv.placement_margin, need=achieved)
            terminated = achieved & ~ok
            goal_xy = jnp.where(achieved & ok, g_xy, goal[:2])
            moved = moved.at[self._goal_row].set(goal_xy)
            new["layout"] = jnp.where(achieved, moved, layout)
        new_goal = jnp.concatenate([goal_xy, goal[2:]])
        new["goal"] = new_goal
        # update_world remembers the distances to the new goal
        new["last_dist_goal"] = jnp.where(achieved, jnp.linalg.norm(goal_xy - pos[:2]),
                                          dist_goal)
        if lv.family == "push":
            new["last_box_goal"] = jnp.where(achieved, jnp.linalg.norm(box - new_goal),
                                             dist_box_goal)
        return reward, cost, terminated, new

    def cost(self, pos, qvel, touch, extras) -> jax.Array:
        """1.0 if any constraint is violated at this state, else 0.0 (indicator cost)."""
        lv = self.level
        bad = jnp.array(False)
        hz = self.group("hazards")
        if hz is not None and hz.constrained:
            d = jnp.linalg.norm(self._rows(extras["layout"], "hazards") - pos[None, :2], axis=-1)
            bad = bad | jnp.any(d < hz.size)  # cost += size - d for d <= size
        vases = self.group("vases")
        if vases is not None and vases.constrained:
            adr = self.index.free_qvel["vases"]
            speed = jnp.linalg.norm(qvel[adr[:, None] + np.arange(3)[None, :]], axis=-1)
            bad = bad | jnp.any(touch[self._touch_of["vases"]] > 0)
            bad = bad | jnp.any(speed >= VASE_VELOCITY_THRESHOLD)
        for kind in ("pillars", "gremlins"):
            g = self.group(kind)
            if g is not None and g.constrained:
                bad = bad | jnp.any(touch[self._touch_of[kind]] > 0)
        bt = self.group("buttons")
        if bt is not None and bt.constrained:
            pressed = touch[self._touch_of["buttons"]] > 0
            wrong = pressed & (jnp.arange(bt.num) != extras["goal_button"])
            bad = bad | ((extras["timer"] == 0) & jnp.any(wrong))
        del lv
        return bad.astype(jnp.float32)

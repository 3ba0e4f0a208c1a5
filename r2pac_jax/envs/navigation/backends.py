"""The two physics backends of the navigation tasks: MJX (JAX) and C MuJoCo stepped in batch.

They follow `r2pac_jax.envs.physics` (the task is a set of pure JAX functions that both backends
run; `MjxEnv`-style JAX env on one side, `is_jax = False` batch env on the other) with what the
navigation tasks need beyond its `MjTask` protocol:
- mocap bodies: placed at reset (`init` returns mocap_pos / mocap_quat) and moved before every
  substep (the gremlins; `task.mocap_positions(layout, time)`), as the original's `Mocap.move`;
- a forward pass after the last substep, so that sensors (accelerometer, ...) and contacts are
  those of the final state, as the original's `mj_forward` before it observes;
- contacts between the agent and given bodies (`view["touch"]`): MJX reads its contact list,
  C MuJoCo reads `contact` sensors.

C MuJoCo steps all episodes of a batch with `mujoco.rollout` (multi-threaded, no Python loop
over episodes or substeps): control = (ctrl, mocap_pos, mocap_quat) per substep, 11 substeps of
which the 11th only serves its forward pass: the sensordata rollout records at substep k are
computed from the state before substep k's integration, so the 11th's are the final state's.
"""
from __future__ import annotations

import os
from typing import Optional

import jax
import jax.numpy as jnp
import numpy as np

from r2pac_jax.envs.base import EnvState, JaxEnv, check_action
from r2pac_jax.envs.navigation.task import NavTask
from r2pac_jax.envs.navigation.world import build_model


def mjx_touch(model_np, index, data) -> jax.Array:
    """Contacts [T] between the agent's geoms and each touch body, from MJX's contact list.

    Counts active contacts (dist < margin, MJX's own test in its contact sensor), i.e. the
    entries the original iterates in `data.contact[:ncon]`.
    """
    con = data._impl.contact
    active = (con.dist - con.includemargin) < 0
    is_agent = np.zeros(model_np.ngeom, bool)
    is_agent[index.agent_geoms] = True
    touch_of_body = np.full(model_np.nbody, -1, int)
    touch_of_body[index.touch_body_ids] = np.arange(len(index.touch_body_ids))
    touch_of_geom = jnp.asarray(touch_of_body[model_np.geom_bodyid])
    is_agent = jnp.asarray(is_agent)
    g0, g1 = con.geom[:, 0], con.geom[:, 1]
    t = jnp.arange(len(index.touch_body_ids))[:, None]
    hit = ((is_agent[g0] & (touch_of_geom[g1] == t)) | (is_agent[g1] & (touch_of_geom[g0] == t)))
    return jnp.sum(hit & active[None, :], axis=1).astype(jnp.float32)


class NavMjxEnv(JaxEnv):
    """MJX backend: jittable, vmappable, scannable (state.physics is an mjx.Data)."""

    backend = "mjx"

    def __init__(self, task: NavTask):
        from mujoco import mjx

        self._mjx = mjx
        self.task = task
        self.name, self.obs_dim, self.act_dim = task.name, task.obs_dim, task.act_dim
        self.episode_len = task.episode_len
        self.mj_model, self.index = build_model(task.level, "mjx")
        self.model = mjx.put_model(self.mj_model)

    def _view(self, d) -> dict:
        return dict(qpos=d.qpos, qvel=d.qvel, sensordata=d.sensordata,
                    touch=mjx_touch(self.mj_model, self.index, d))

    def reset(self, key: jax.Array) -> EnvState:
        mjx = self._mjx
        key, k = jax.random.split(key)
        qpos, qvel, mocap_pos, mocap_quat, extras = self.task.init(k)
        d = mjx.make_data(self.model).replace(qpos=qpos, qvel=qvel, mocap_pos=mocap_pos,
                                              mocap_quat=mocap_quat)
        d = mjx.forward(self.model, d)
        zero = jnp.zeros((), jnp.float32)
        return EnvState(obs=self.task.observe(self._view(d), extras).astype(jnp.float32),
                        reward=zero, cost=zero, terminated=jnp.array(False),
                        truncated=jnp.array(False), t=jnp.zeros((), jnp.int32), key=key,
                        physics=d, info=extras)

    def step(self, state: EnvState, action: jax.Array) -> EnvState:
        mjx, task = self._mjx, self.task
        action = jnp.clip(action, -1.0, 1.0)
        layout = state.info["layout"]

        def substep(_, d):
            d = d.replace(mocap_pos=task.mocap_positions(layout, d.time, jnp))
            return mjx.step(self.model, d)

        d = state.physics.replace(ctrl=task.controls(action))
        d = jax.lax.fori_loop(0, task.frame_skip, substep, d)
        d = mjx.forward(self.model, d)  # sensors and contacts of the final state
        after = self._view(d)
        reward, cost, terminated, extras = task.transition(after, state.info)
        t = state.t + 1
        return state.replace(obs=task.observe(after, extras).astype(jnp.float32),
                             reward=jnp.asarray(reward, jnp.float32),
                             cost=jnp.asarray(cost, jnp.float32),
                             terminated=jnp.asarray(terminated),
                             truncated=t >= self.episode_len, t=t, physics=d, info=extras)


class NavMujocoEnv:
    """C MuJoCo backend: a batch of episodes stepped with `mujoco.rollout` (is_jax = False).

    `state.physics` holds MuJoCo's full physics state per episode (`state` [n, nstate]), the
    mocap poses (`mocap_pos` [n, m, 3] float64, `mocap_quat` [n, m, 4]) and the last view, so
    stepping the same EnvState twice gives the same result (no hidden simulator state).
    """

    is_jax = False
    backend = "mujoco"

    def __init__(self, task: NavTask, threads: Optional[int] = None):
        import mujoco

        self._mujoco = mujoco
        self.task = task
        self.name, self.obs_dim, self.act_dim = task.name, task.obs_dim, task.act_dim
        self.episode_len = task.episode_len
        m, self.index = build_model(task.level, "exact")
        self.mj_model = m
        self._spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        self._nstate = mujoco.mj_stateSize(m, self._spec)
        self._slices = {}
        for name in ("TIME", "QPOS", "QVEL"):
            bit = int(getattr(mujoco.mjtState, f"mjSTATE_{name}"))
            lower = int(self._spec) & (bit - 1)
            start = mujoco.mj_stateSize(m, lower) if lower else 0
            self._slices[name.lower()] = slice(start, start + mujoco.mj_stateSize(m, bit))
        self._control_spec = int(mujoco.mjtState.mjSTATE_CTRL)
        if m.nmocap:
            self._control_spec |= int(mujoco.mjtState.mjSTATE_MOCAP_POS)
            self._control_spec |= int(mujoco.mjtState.mjSTATE_MOCAP_QUAT)
        threads = threads or min(os.cpu_count() or 1, 8)
        self._datas = [mujoco.MjData(m) for _ in range(threads)]
        self._scratch = mujoco.MjData(m)
        self._init = jax.jit(jax.vmap(task.init))
        self._observe = jax.jit(jax.vmap(task.observe))
        self._outcome = jax.jit(jax.vmap(self._outcome_one))

    def _outcome_one(self, after, extras):
        reward, cost, terminated, extras = self.task.transition(after, extras)
        return reward, cost, terminated, extras, self.task.observe(after, extras)

    def _view(self, qpos, qvel, sensordata) -> dict:
        return dict(qpos=qpos, qvel=qvel, sensordata=sensordata,
                    touch=sensordata[:, self.index.touch_adr].astype(np.float32))

    def _state(self, obs, reward, cost, terminated, t, key, physics, extras) -> EnvState:
        return EnvState(obs=np.asarray(obs, np.float32), reward=np.asarray(reward, np.float32),
                        cost=np.asarray(cost, np.float32), terminated=np.asarray(terminated),
                        truncated=np.asarray(t) >= self.episode_len, t=np.asarray(t), key=key,
                        physics=physics, info=extras)

    def reset_batch(self, keys) -> EnvState:
        keys = jnp.asarray(keys)
        split = jax.vmap(jax.random.split)(keys)
        qpos, qvel, mocap_pos, mocap_quat, extras = self._init(split[:, 1])
        return self.reset_to(np.asarray(qpos, np.float64), np.asarray(qvel, np.float64),
                             np.asarray(mocap_pos, np.float64),
                             np.asarray(mocap_quat, np.float64), extras, split[:, 0])

    def reset_to(self, qpos, qvel, mocap_pos, mocap_quat, extras, keys, time=None,
                 ctrl=None, warmstart=None) -> EnvState:
        """Start episodes [n] from given positions, velocities and mocap poses (float64).

        `time` [n], `ctrl` [n, nu] (the controls the first observation's forward pass sees,
        0 after a reset) and `warmstart` [n, nv] (qacc_warmstart, where the constraint solver
        starts) serve to copy a running episode's state (fidelity checks)."""
        mujoco, m, d = self._mujoco, self.mj_model, self._scratch
        n = qpos.shape[0]
        states = np.empty((n, self._nstate))
        sens = np.empty((n, m.nsensordata))
        for i in range(n):
            mujoco.mj_resetData(m, d)
            d.qpos[:], d.qvel[:] = qpos[i], qvel[i]
            if m.nmocap:
                d.mocap_pos[:], d.mocap_quat[:] = mocap_pos[i], mocap_quat[i]
            if time is not None:
                d.time = time[i]
            if ctrl is not None:
                d.ctrl[:] = ctrl[i]
            if warmstart is not None:
                d.qacc_warmstart[:] = warmstart[i]
            mujoco.mj_forward(m, d)
            mujoco.mj_getState(m, d, states[i], self._spec)
            sens[i] = d.sensordata
        view = self._view(qpos, qvel, sens)
        obs = self._observe(view, extras)
        zeros = np.zeros(n, np.float32)
        physics = dict(state=states, mocap_pos=np.asarray(mocap_pos, np.float64),
                       mocap_quat=np.asarray(mocap_quat, np.float64))
        return self._state(obs, zeros, zeros, np.zeros(n, bool), np.zeros(n, np.int32), keys,
                           physics, extras)

    def _controls(self, actions, state):
        """Per-substep controls [n, frame_skip + 1, ncontrol] for mujoco.rollout, and the mocap
        positions [n, m, 3] the last substep leaves."""
        m, fs = self.mj_model, self.task.frame_skip
        n = actions.shape[0]
        ctrl = np.repeat(np.asarray(self.task.controls(actions), np.float64)[:, None, :],
                         fs + 1, axis=1)
        if not m.nmocap:
            return ctrl, state.physics["mocap_pos"]
        # the simulation clock as mj_step advances it (repeated additions of the timestep)
        t = state.physics["state"][:, self._slices["time"]][:, 0].copy()
        layout = np.asarray(state.info["layout"], np.float64)
        mpos = np.empty((n, fs + 1, m.nmocap, 3))
        for k in range(fs):
            mpos[:, k] = self.task.mocap_positions(layout, t, np)
            t = t + m.opt.timestep
        mpos[:, fs] = mpos[:, fs - 1]  # the final forward pass sees the last substep's mocap
        mquat = np.repeat(state.physics["mocap_quat"][:, None], fs + 1, axis=1)
        return np.concatenate([ctrl, mpos.reshape(n, fs + 1, -1), mquat.reshape(n, fs + 1, -1)],
                              axis=-1), mpos[:, fs]

    def step_batch(self, state: EnvState, actions) -> EnvState:
        from mujoco import rollout

        n = state.obs.shape[0]
        actions = np.clip(check_action(actions, self.act_dim, batch=n), -1.0, 1.0)
        fs = self.task.frame_skip
        control, mocap_pos = self._controls(actions, state)
        datas = self._datas[:max(1, min(n, len(self._datas)))]
        states, sens = rollout.rollout(self.mj_model, datas, state.physics["state"], control,
                                       control_spec=self._control_spec, nstep=fs + 1,
                                       persistent_pool=True)
        final = states[:, fs - 1]
        after = self._view(final[:, self._slices["qpos"]], final[:, self._slices["qvel"]],
                           sens[:, fs])
        reward, cost, terminated, extras, obs = self._outcome(after, state.info)
        physics = dict(state=final, mocap_pos=mocap_pos, mocap_quat=state.physics["mocap_quat"])
        return self._state(obs, reward, cost, terminated, state.t + 1, state.key, physics,
                           extras)

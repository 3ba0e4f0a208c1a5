"""Physics backends for MuJoCo tasks: MJX (JAX, jittable) and C MuJoCo stepped in batch.

A task describes itself once, as pure JAX functions over a *view* of the simulator's data (a
dict of the mjData fields it names in `view_fields`), and both backends run those same
functions:

    class MyTask(MjTask):
        name, obs_dim, act_dim, episode_len, frame_skip = ...
        view_fields = ("qpos", "qvel")                    # mjData fields the task reads
        def model(self) -> mujoco.MjModel                 # the compiled MJCF model
        def init(self, key) -> (qpos, qvel, extras)       # reset distribution
        def observe(self, view, extras) -> obs            # [obs_dim]
        def transition(self, before, after, action, extras)
            -> (reward, cost, terminated, extras)        # one control step's outcome
        def controls(self, action, extras) -> ctrl        # optional: action -> mjData.ctrl
        def inputs(self, before, action, extras) -> dict  # optional: {"ctrl", "xfrc_applied"}

`MjxEnv(task)` is a `JaxEnv` (its state's `physics` is an `mjx.Data`): jit it, vmap it, scan it.
`MujocoEnv(task)` keeps one `mujoco.MjData` per episode and steps them from Python
(`is_jax = False`): `reset_batch(keys)` / `step_batch(state, actions)` run the task functions
jitted and vmapped over the batch, so C MuJoCo and MJX share every line of task code.
`make_physics_env(task, physics)` picks the backend: "mjx" on an accelerator, "mujoco" on a CPU
(where MJX measured ~40x slower than C MuJoCo), or the one named.
"""
from __future__ import annotations

from typing import Optional

import jax
import jax.numpy as jnp
import numpy as np

from r2pac_jax.envs.base import BackendUnavailableError, EnvState, JaxEnv, check_action
from r2pac_jax.envs import mjx_lean

__all__ = ["BackendUnavailableError", "MjTask", "MjxEnv", "MujocoEnv", "make_physics_env",
           "resolve_physics"]


class MjTask:
    """Base class for tasks simulated by MuJoCo (see the module docstring)."""

    name: str
    obs_dim: int
    act_dim: int
    episode_len: int
    frame_skip: int
    view_fields: tuple = ("qpos", "qvel")

    def model(self):  # pragma: no cover - abstract
        raise NotImplementedError

    def init(self, key):  # pragma: no cover - abstract
        raise NotImplementedError

    def observe(self, view: dict, extras: dict) -> jax.Array:  # pragma: no cover - abstract
        raise NotImplementedError

    def transition(self, before: dict, after: dict, action, extras):  # pragma: no cover
        raise NotImplementedError

    def controls(self, action: jax.Array, extras: dict) -> jax.Array:
        return action

    def inputs(self, before: dict, action: jax.Array, extras: dict) -> dict:
        """What a control step holds fixed over its sub-steps: `ctrl` [nu] and, for tasks that
        push bodies directly, `xfrc_applied` [nbody, 6] (world-frame force and torque at each
        body's centre of mass). `before` is the view at the step's start."""
        return {"ctrl": self.controls(action, extras)}

    def mjx_model(self, model):
        """The model given to MJX (a task may simplify it there, e.g. fewer solver iterations)."""
        return model


def _import_mujoco():
    try:
        import mujoco
    except ImportError as e:  # pragma: no cover - mujoco is a dependency
        raise BackendUnavailableError(f"C MuJoCo is unavailable: cannot import mujoco ({e}); "
                                      "pip install mujoco") from e
    return mujoco


def _import_mjx():
    try:
        from mujoco import mjx
    except ImportError as e:  # pragma: no cover
        raise BackendUnavailableError(f"MJX is unavailable: cannot import mujoco.mjx ({e}); "
                                      "pip install mujoco-mjx") from e
    return mjx


def resolve_physics(physics: str) -> str:
    """`auto` -> mjx on an accelerator, mujoco on a CPU; checks the named backend imports."""
    if physics == "auto":
        physics = "mujoco" if jax.default_backend() == "cpu" else "mjx"
    if physics == "mjx":
        _import_mjx()
    elif physics == "mujoco":
        _import_mujoco()
    else:
        raise BackendUnavailableError(f"physics must be auto, mjx or mujoco for MuJoCo tasks, "
                                      f"got {physics!r}")
    return physics


def make_physics_env(task: MjTask, physics: str = "auto"):
    return MjxEnv(task) if resolve_physics(physics) == "mjx" else MujocoEnv(task)


# ---------------------------------------------------------------------------------------------
# MJX


class MjxEnv(JaxEnv):
    """Pure-JAX environment over `mjx.Data`: jittable, vmappable, scannable."""

    backend = "mjx"

    def __init__(self, task: MjTask):
        mjx = _import_mjx()
        self.task = task
        self.name, self.obs_dim, self.act_dim = task.name, task.obs_dim, task.act_dim
        self.episode_len = task.episode_len
        self.mj_model = task.model()
        self.model = mjx.put_model(task.mjx_model(self.mj_model))
        self._mjx = mjx

    def _view(self, data) -> dict:
        return {f: getattr(data, f) for f in self.task.view_fields}

    def reset(self, key: jax.Array) -> EnvState:
        mjx = self._mjx
        key, k = jax.random.split(key)
        qpos, qvel, extras = self.task.init(k)
        data = mjx.make_data(self.model).replace(qpos=qpos, qvel=qvel)
        # only what the view needs (no pass, kinematics or forward): less to compile
        data = mjx_lean.reset_pass(self.model, data, self.task.view_fields)
        zero = jnp.zeros((), jnp.float32)
        return EnvState(obs=self.task.observe(self._view(data), extras).astype(jnp.float32),
                        reward=zero, cost=zero, terminated=jnp.array(False),
                        truncated=jnp.array(False), t=jnp.zeros((), jnp.int32), key=key,
                        physics=data, info=extras)

    def step(self, state: EnvState, action: jax.Array) -> EnvState:
        action = jnp.clip(action, -1.0, 1.0)
        before = self._view(state.physics)
        data = state.physics.replace(**self.task.inputs(before, action, state.info))
        data = jax.lax.fori_loop(0, self.task.frame_skip,  # mjx.step, RK4 rolled (mjx_lean)
                                 lambda _, d: mjx_lean.step(self.model, d), data)
        after = self._view(data)
        reward, cost, terminated, extras = self.task.transition(before, after, action,
                                                                state.info)
        t = state.t + 1
        return state.replace(obs=self.task.observe(after, extras).astype(jnp.float32),
                             reward=jnp.asarray(reward, jnp.float32),
                             cost=jnp.asarray(cost, jnp.float32),
                             terminated=jnp.asarray(terminated), truncated=t >= self.episode_len,
                             t=t, physics=data, info=extras)


# ---------------------------------------------------------------------------------------------
# C MuJoCo in batch

# mjData fields that can be read off MuJoCo's full-physics state vector (plus sensordata, which
# `mujoco.rollout` returns beside it).
STATE_FIELDS = ("time", "qpos", "qvel", "act", "mocap_pos", "mocap_quat")


class MujocoEnv:
    """C MuJoCo stepped in batch with `mujoco.rollout` (multi-threaded), from Python.

    The state's `physics` holds MuJoCo's full physics state vector per episode
    (`physics["state"]`, [n, nstate]) and the view fields, so the env keeps no hidden
    simulator state: stepping the same `EnvState` twice gives the same result (MuJoCo's solver
    warm start is not carried: each control step starts cold; the constraint solver converges
    to its tolerance either way). Tasks whose view needs fields outside `STATE_FIELDS` +
    `sensordata` are stepped one `MjData` at a time. After a step, views are read as `mj_step`
    leaves mjData (as in gymnasium): state fields are the new state, derived fields (sensordata,
    xpos, ...) come from the step's last forward pass; after a reset, from `mj_forward`.
    """

    is_jax = False
    backend = "mujoco"

    def __init__(self, task: MjTask, threads: Optional[int] = None):
        import os

        mujoco = _import_mujoco()
        self._mujoco = mujoco
        self.task = task
        self.name, self.obs_dim, self.act_dim = task.name, task.obs_dim, task.act_dim
        self.episode_len = task.episode_len
        m = self.mj_model = task.model()
        self._spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        self._nstate = mujoco.mj_stateSize(m, self._spec)
        # offsets of each component inside the state vector (components appear in bit order)
        self._slices = {}
        for name in ("TIME", "QPOS", "QVEL", "ACT", "MOCAP_POS", "MOCAP_QUAT"):
            bit = int(getattr(mujoco.mjtState, f"mjSTATE_{name}"))
            lower = int(self._spec) & (bit - 1)
            start = mujoco.mj_stateSize(m, lower) if lower else 0
            self._slices[name.lower()] = slice(start, start + mujoco.mj_stateSize(m, bit))
        self._use_rollout = set(task.view_fields) <= set(STATE_FIELDS) | {"sensordata"}
        threads = threads or min(os.cpu_count() or 1, 8)
        self._datas = [mujoco.MjData(m) for _ in range(threads)]
        self._scratch = mujoco.MjData(m)
        self._init = jax.jit(jax.vmap(task.init))
        # key split and init in one jitted call (split eagerly under vmap costs ~ms per reset)
        self._split_init = jax.jit(jax.vmap(lambda k: (lambda a, b: (a, task.init(b)))(
            *jax.random.split(k))))
        self._observe = jax.jit(jax.vmap(task.observe))
        self._outcome = jax.jit(jax.vmap(self._outcome_one))
        default_inputs = (type(task).controls is MjTask.controls
                          and type(task).inputs is MjTask.inputs)
        self._inputs = None if default_inputs else jax.jit(jax.vmap(task.inputs))

    def _outcome_one(self, before, after, action, extras):
        reward, cost, terminated, extras = self.task.transition(before, after, action, extras)
        return reward, cost, terminated, extras, self.task.observe(after, extras)

    def _view(self, states: np.ndarray, sensordata: Optional[np.ndarray]) -> dict:
        view = {}
        for f in self.task.view_fields:
            if f == "sensordata":
                view[f] = sensordata
            else:
                view[f] = states[:, self._slices[f]]
        return view

    def _forward_states(self, states: np.ndarray):
        """mj_forward each state (resets, or tasks reading derived fields): views and states."""
        mujoco, m, d = self._mujoco, self.mj_model, self._scratch
        n = states.shape[0]
        views = {f: [] for f in self.task.view_fields}
        for i in range(n):
            mujoco.mj_setState(m, d, states[i], self._spec)
            mujoco.mj_forward(m, d)
            for f in views:
                views[f].append(np.array(getattr(d, f)))
        return {f: np.stack(v) for f, v in views.items()}

    def _make_state(self, states, view, extras, obs, reward, cost, terminated, t, key) -> EnvState:
        return EnvState(obs=np.asarray(obs, np.float32), reward=np.asarray(reward, np.float32),
                        cost=np.asarray(cost, np.float32), terminated=np.asarray(terminated),
                        truncated=np.asarray(t) >= self.episode_len, t=np.asarray(t),
                        key=key, physics=dict(view, state=states), info=extras)

    def states_from_qpos_qvel(self, qpos, qvel) -> np.ndarray:
        """Full physics state vectors [n, nstate] for given positions and velocities."""
        mujoco, m, d = self._mujoco, self.mj_model, self._scratch
        qpos, qvel = np.asarray(qpos, np.float64), np.asarray(qvel, np.float64)
        out = np.empty((qpos.shape[0], self._nstate))
        for i in range(qpos.shape[0]):
            mujoco.mj_resetData(m, d)
            d.qpos[:] = qpos[i]
            d.qvel[:] = qvel[i]
            mujoco.mj_getState(m, d, out[i], self._spec)
        return out

    def reset_batch(self, keys) -> EnvState:
        keys, (qpos, qvel, extras) = self._split_init(jnp.asarray(keys))
        return self.reset_to(self.states_from_qpos_qvel(qpos, qvel), extras, keys)

    def reset_to(self, states: np.ndarray, extras, keys) -> EnvState:
        """Start episodes from given physics state vectors [n, nstate]."""
        n = states.shape[0]
        view = self._forward_states(states)
        obs = self._observe(view, extras)
        zeros = np.zeros(n, np.float32)
        return self._make_state(states, view, extras, obs, zeros, zeros, np.zeros(n, bool),
                                np.zeros(n, np.int32), keys)

    def step_batch(self, state: EnvState, actions) -> EnvState:
        from mujoco import rollout

        n = state.obs.shape[0]
        actions = np.clip(check_action(actions, self.act_dim, batch=n), -1.0, 1.0)
        before = {f: state.physics[f] for f in self.task.view_fields}
        xfrc = None
        if self._inputs is None:
            ctrl = actions
        else:
            inputs = self._inputs(before, jnp.asarray(actions), state.info)
            ctrl = np.asarray(inputs.get("ctrl", np.zeros((n, self.mj_model.nu))))
            if "xfrc_applied" in inputs:
                xfrc = np.asarray(inputs["xfrc_applied"], np.float64)
        fs = self.task.frame_skip
        control = np.repeat(np.asarray(ctrl, np.float64)[:, None, :], fs, axis=1)
        if self._use_rollout and xfrc is None:
            states, sens = rollout.rollout(self.mj_model, self._datas[:max(1, min(n, len(
                self._datas)))], state.physics["state"], control, nstep=fs,
                persistent_pool=True)
            states = states[:, -1]
            after = self._view(states, sens[:, -1] if sens.size else sens[:, 0])
        else:
            # views read as mj_step leaves mjData (derived fields such as xpos come from its
            # last forward pass, as gymnasium's envs read them), like sensordata above
            mujoco, m = self._mujoco, self.mj_model
            states = np.empty_like(state.physics["state"])
            after = {f: np.empty((n,) + getattr(self._scratch, f).shape)
                     for f in self.task.view_fields}

            def run(d, lanes):  # one MjData per thread; mj_step releases the GIL
                for i in lanes:
                    mujoco.mj_setState(m, d, state.physics["state"][i], self._spec)
                    d.qacc_warmstart[:] = 0.0  # cold start, as rollout does: no leak
                    d.ctrl[:] = control[i, 0]
                    d.xfrc_applied[:] = 0.0 if xfrc is None else xfrc[i]
                    mujoco.mj_step(m, d, nstep=fs)
                    mujoco.mj_getState(m, d, states[i], self._spec)
                    for f in after:
                        after[f][i] = getattr(d, f)

            k = max(1, min(n, len(self._datas)))
            if k == 1:
                run(self._datas[0], range(n))
            else:
                if getattr(self, "_pool", None) is None:
                    from concurrent.futures import ThreadPoolExecutor

                    self._pool = ThreadPoolExecutor(len(self._datas))
                list(self._pool.map(run, self._datas[:k], np.array_split(np.arange(n), k)))
        reward, cost, terminated, extras, obs = self._outcome(before, after, actions, state.info)
        return self._make_state(states, after, extras, obs, reward, cost, terminated,
                                state.t + 1, state.key)

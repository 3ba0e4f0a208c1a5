"""The `bullet` backend: the original's engine (pybullet 3.2.7), one physics client per episode,
stepped in batch from Python on the CPU (`is_jax = False`). The faithful path for the
Bullet-Safety-Gym tasks: it repeats the original's calls in the original's order (physics
parameters, bodies loaded in the same order, the reset's placement calls and its settling step,
one `stepSimulation` of `frame_skip` sub-steps per control step; every episode starts as the
original's first episode after construction, see `_World.reset`), and runs the tasks' JAX rules
(`tasks.py`) jitted and vmapped over the batch, as `physics.MujocoEnv` does for MuJoCo.

Unlike C MuJoCo, a pybullet world cannot be stepped from a state vector: each episode's
simulation lives in its client. So an `EnvState` of this backend names its clients
(`physics["world"]`) with a stamp per step (`physics["stamp"]`), and stepping a state that is not
the latest of its episode raises `StaleStateError`. A client is recycled by a later reset once
its episode has ended (terminated or truncated) or has been `release`d; stepping an ended
episode further (as the evaluation loop does while other lanes run) is allowed until then. A
state saved and loaded in another process (a resumed data generation) gets its simulations back
by `revive`, which replays each episode's recorded actions from its start.
"""
from __future__ import annotations

import functools
from typing import Optional

import jax
import jax.numpy as jnp
import numpy as np

from r2pac_jax.envs.base import BackendUnavailableError, EnvState, check_action
from r2pac_jax.envs.bullet.robots import ASSETS
from r2pac_jax.errors import R2pacError

INSTALL = "pip install -e '.[bullet]' (or pip install pybullet==3.2.7)"
MIB_PER_CLIENT = 29  # resident memory of one DIRECT client with its world (client_cost.py)
_LIVE = [0]  # clients alive in this process, across envs


def max_clients() -> int:
    """The most pybullet clients (parallel episodes) this process may hold:
    $R2PAC_BULLET_MAX_CLIENTS, default 512 (~15 GiB)."""
    import os

    return int(os.environ.get("R2PAC_BULLET_MAX_CLIENTS", "512"))


BASE_KEYS = ("pos", "quat", "vel", "angvel", "dpos")


class StaleStateError(R2pacError, RuntimeError):
    """An EnvState whose simulation has moved on (stepped, reset or released since)."""


def import_pybullet():
    try:
        import pybullet
    except ImportError as e:
        raise BackendUnavailableError(
            f"the bullet physics backend needs pybullet, which is not installed ({e}): {INSTALL}"
        ) from e
    return pybullet


class _World:
    """One pybullet client holding one episode's world, built as the original builds it."""

    def __init__(self, pb, task):
        self.pb, self.task, self.robot = pb, task, task.robot
        self.cid = pb.connect(pb.DIRECT)
        _LIVE[0] += 1
        self.build()
        self.stamp = 0
        self.free = True

    def build(self) -> None:
        """Physics parameters and bodies as the original's constructor sets them."""
        pb, task, c = self.pb, self.task, self.cid
        pb.setPhysicsEngineParameter(fixedTimeStep=task.time_step * task.frame_skip,
                                     numSolverIterations=task.solver_iterations,
                                     deterministicOverlappingPairs=1,
                                     numSubSteps=task.frame_skip, physicsClientId=c)
        pb.setGravity(0, 0, -9.81, physicsClientId=c)
        pb.setDefaultContactERP(0.9, physicsClientId=c)
        ground = "plane250.urdf" if task.world == "plane250" else "plane15.urdf"
        plane = pb.loadURDF(str(ASSETS / ground), physicsClientId=c)
        pb.changeDynamics(plane, -1, lateralFriction=0.8, restitution=0.5, physicsClientId=c)
        if task.world == "octagon":
            for yaw in np.linspace(0, 7 / 8 * 2 * np.pi, num=8):
                pb.loadURDF(str(ASSETS / "octagon_wall.urdf"), globalScaling=1,
                            useFixedBase=True,
                            baseOrientation=pb.getQuaternionFromEuler([0, 0, yaw]),
                            physicsClientId=c)
        # (the original's visual-only bodies, without collision shapes, are left out)
        self.body = self.robot.load(pb, c)
        self.robot.setup(pb, c, self.body)
        self.stepped = False

    def read(self) -> dict:
        pb, c, b = self.pb, self.cid, self.body
        pos, quat = pb.getBasePositionAndOrientation(b, physicsClientId=c)
        vel, ang = pb.getBaseVelocity(b, physicsClientId=c)
        return dict(pos=np.array(pos), quat=np.array(quat), vel=np.array(vel),
                    angvel=np.array(ang), **self.robot.read(self))

    # the original's Body.set_position / set_orientation: each pybullet call is repeated, since
    # the engine stores what it is given (a pose re-read and set again differs in the last bit,
    # and contact dynamics grow such bits to visible differences within ~100 steps)
    def set_position(self, pos) -> None:
        pb, c = self.pb, self.cid
        _, quat = pb.getBasePositionAndOrientation(self.body, physicsClientId=c)
        quat = pb.getQuaternionFromEuler(pb.getEulerFromQuaternion(quat))
        pb.resetBasePositionAndOrientation(self.body, pos, quat, physicsClientId=c)

    def set_orientation(self, quat) -> None:
        pb, c = self.pb, self.cid
        pos, _ = pb.getBasePositionAndOrientation(self.body, physicsClientId=c)
        pb.resetBasePositionAndOrientation(self.body, pos, quat, physicsClientId=c)

    def reset(self, pose: dict) -> dict:
        """The original's first reset after its construction, on a world built afresh: the
        robot's and the task's placement, one simulation step. `pose`: {pos [3], joints
        [n_joints]} float64, the task's sampled position and the robot's joint positions.

        The original's later resets restore a saved state instead; pybullet's restoreState
        keeps the contact manifolds of the episode before (no manifold existed when the state
        was saved), whose impulses warm-start the next episode's first steps (benchmarks/
        FIDELITY.md): an episode would depend on the one before it in the same client. A world
        rebuilt for every episode (3.5-9 ms, benchmarks/fidelity_bullet/client_cost.py) has no
        history."""
        pb, c = self.pb, self.cid
        if self.stepped:
            pb.resetSimulation(physicsClientId=c)
            self.build()
        self.robot.specific_reset(self, pose)
        pos = np.asarray(pose["pos"], np.float64)
        self.set_position(pos)
        yaw = self.task.yaw(pb.getBasePositionAndOrientation(self.body, physicsClientId=c)[0])
        if yaw is not None:
            self.set_orientation(pb.getQuaternionFromEuler([0.0, 0.0, yaw]))
        before = np.array(pb.getBasePositionAndOrientation(self.body, physicsClientId=c)[0])
        pb.stepSimulation(physicsClientId=c)
        self.stepped = True
        view = self.read()
        view["dpos"] = view["pos"] - before
        self.stamp += 1
        self.free = False
        return view

    def step(self, action: np.ndarray, pos_before: np.ndarray) -> dict:
        """One control step; `action` as the policy gave it (the robot clips it, as the
        original's agents do)."""
        self.robot.apply_action(self.pb, self.cid, self.body, action)
        self.pb.stepSimulation(physicsClientId=self.cid)
        view = self.read()
        view["dpos"] = view["pos"] - pos_before
        self.stamp += 1
        return view

    def close(self):
        try:
            self.pb.disconnect(physicsClientId=self.cid)
            _LIVE[0] -= 1
        except Exception:  # pragma: no cover - already gone at interpreter exit
            pass


def _split_init(task, key):
    key, k = jax.random.split(key)
    return key, task.init(k)


def _start_one(task, view, extras):
    extras = task.after_reset(view, extras)
    return extras, task.observe(view, extras)


def _outcome_one(task, before, after, action, extras):
    reward, cost, terminated, extras = task.transition(before, after, action, extras)
    return reward, cost, terminated, extras, task.observe(after, extras)


class BulletEnv:
    """Batched episodes of one Bullet task on pybullet (see the module docstring)."""

    is_jax = False
    backend = "bullet"

    def __init__(self, task):
        self._pb = import_pybullet()
        self.task = task
        self.name, self.obs_dim, self.act_dim = task.name, task.obs_dim, task.act_dim
        self.episode_len = task.episode_len
        self._worlds: list[_World] = []
        # the jitted rules close over the task only, never over the env: an env that goes out
        # of scope is freed at once and disconnects its clients (~29 MiB each)
        self._split_init = jax.jit(jax.vmap(functools.partial(_split_init, task)))
        self._start = jax.jit(jax.vmap(functools.partial(_start_one, task)))
        self._outcome = jax.jit(jax.vmap(functools.partial(_outcome_one, task)))

    # -- clients ----------------------------------------------------------------------------
    def _acquire(self, n: int) -> list[int]:
        free = [i for i, w in enumerate(self._worlds) if w.free]
        new = n - len(free)
        if new > 0 and _LIVE[0] + new > max_clients():
            raise MemoryError(
                f"{n} parallel episodes of {self.name} need {new} more pybullet clients, "
                f"{_LIVE[0] + new} in all (about {MIB_PER_CLIENT * (_LIVE[0] + new) / 1024:.1f} "
                f"GiB at {MIB_PER_CLIENT} MiB each), over the limit of {max_clients()}: step "
                "fewer episodes at once (fewer lanes x episodes, or --num-envs), or raise "
                "R2PAC_BULLET_MAX_CLIENTS if the memory is there")
        while len(free) < n:
            self._worlds.append(_World(self._pb, self.task))
            free.append(len(self._worlds) - 1)
        return free[:n]

    def release(self, state: EnvState) -> None:
        """Hand the state's clients back for later resets (the state can no longer be stepped)."""
        for i in np.atleast_1d(np.asarray(state.physics["world"])):
            self._worlds[int(i)].free = True
            self._worlds[int(i)].stamp += 1

    def close(self) -> None:
        for w in self._worlds:
            w.close()
        self._worlds = []

    def __del__(self):  # pragma: no cover - best effort
        try:
            self.close()
        except Exception:
            pass

    @property
    def max_parallel(self) -> int:
        """The most episodes this env can run at once: the process's client limit less the
        clients other envs hold (the evaluator splits larger batches of lanes by it)."""
        return max_clients() - (_LIVE[0] - len(self._worlds))

    # -- protocol ---------------------------------------------------------------------------
    @property
    def view_keys(self) -> tuple:
        return BASE_KEYS + tuple(self.task.robot.view_keys)

    def reset_batch(self, keys) -> EnvState:
        """n new episodes from PRNG keys [n, 2]: the task's reset law, then `reset_to`. The
        state's obs is [n, obs_dim] float32; its `physics` holds the float64 view [n, ...]."""
        keys, (pose, extras) = self._split_init(jnp.asarray(keys))
        pose = {k: np.asarray(v, np.float64) for k, v in pose.items()}
        # the robot's height is a constant: exact in float64 (0.17 or 0.2 in float32 is not,
        # and a robot resting on the ground settles differently by such bits)
        pose["pos"][:, 2] = self.task.robot.init_xyz[2]
        return self.reset_to(pose, extras, keys)

    def reset_to(self, poses: dict, extras: Optional[dict] = None, keys=None) -> EnvState:
        """Start episodes from given sampled positions: `pos` [n, 3] float64 and, for robots
        with joints, `joints` [n, n_joints] (the original's `specific_reset` draws them; the
        orientation and the rest follow as it sets them)."""
        n = np.asarray(poses["pos"]).shape[0]
        if "joints" not in poses:
            poses = dict(poses, joints=np.zeros((n, self.task.robot.n_joints)))
        if extras is None:
            extras = jax.vmap(lambda _: self.task.empty_extras())(jnp.arange(n))
        if keys is None:
            keys = jax.random.split(jax.random.PRNGKey(0), n)
        ids = self._acquire(n)
        rows = [self._worlds[w].reset({k: np.asarray(v)[i] for k, v in poses.items()})
                for i, w in enumerate(ids)]
        view = {k: np.stack([r[k] for r in rows]) for k in self.view_keys}
        extras, obs = self._start(self._as_f32(view), extras)
        zeros = np.zeros(n, np.float32)
        record = dict(start=np.asarray(poses["pos"], np.float64),
                      start_joints=np.asarray(poses["joints"], np.float64),
                      actions=np.zeros((n, self.episode_len, self.act_dim), np.float32))
        return self._state(view, ids, obs, zeros, zeros, np.zeros(n, bool), np.zeros(n, np.int32),
                           keys, extras, record)

    def revive(self, state: EnvState) -> EnvState:
        """The state with its simulations rebuilt where they are gone (a generation resumed in
        a new process): each such episode is reset again from its sampled position and joints
        and replays the actions it took (`physics["actions"]`), which gives the same simulation
        bit for bit (checked against the state's view)."""
        gone = self._gone(state)
        if not gone.any():
            return state
        t = np.asarray(state.t)
        if (t[gone] > self.episode_len).any():
            raise StaleStateError("an episode stepped past its end cannot be rebuilt (its "
                                  "actions after the end were not recorded)")
        idx = np.flatnonzero(gone)
        acts = np.asarray(state.physics["actions"])[idx]
        fresh = self.reset_to(dict(pos=np.asarray(state.physics["start"])[idx],
                                   joints=np.asarray(state.physics["start_joints"])[idx]))
        for j, w in enumerate(fresh.physics["world"]):
            world, view = self._worlds[w], None
            for k in range(int(t[idx[j]])):
                pos = fresh.physics["pos"][j] if view is None else view["pos"]
                view = world.step(acts[j, k], pos)
            if view is not None:
                for key in self.view_keys:
                    fresh.physics[key][j] = view[key]
        for key in self.view_keys:
            if not np.array_equal(fresh.physics[key], np.asarray(state.physics[key])[idx]):
                raise RuntimeError(f"a rebuilt bullet episode differs from its record ({key}): "
                                   "the simulation is not reproducible on this machine")
        physics = {k: np.array(v, copy=True) for k, v in state.physics.items()}
        physics["world"][idx] = fresh.physics["world"]
        physics["stamp"][idx] = [self._worlds[w].stamp for w in fresh.physics["world"]]
        return state.replace(physics=physics)

    def step_batch(self, state: EnvState, actions) -> EnvState:
        """`actions` [n, act_dim] as the policy gives them: each robot clips them into [-1, 1]
        for its motors as the original does, and the rules see them as given (the Ant's energy
        terms read the unclipped action, as the original's)."""
        ids = np.asarray(state.physics["world"])
        n = ids.shape[0]
        actions = check_action(actions, self.act_dim, batch=n)
        gone = self._gone(state)
        if gone.any():
            raise StaleStateError(
                f"episode {int(np.flatnonzero(gone)[0])} of this state is not the latest state "
                "of its simulation (it was stepped, reset or released since): the bullet "
                "backend keeps one live simulation per episode; step the state step_batch / "
                "reset_batch returned last")
        before = {k: np.asarray(state.physics[k]) for k in self.view_keys}
        rows = [self._worlds[w].step(actions[i], before["pos"][i]) for i, w in enumerate(ids)]
        after = {k: np.stack([r[k] for r in rows]) for k in self.view_keys}
        reward, cost, terminated, extras, obs = self._outcome(
            self._as_f32(before), self._as_f32(after), actions, state.info)
        t0 = np.asarray(state.t)
        t = t0 + 1
        log = np.array(state.physics["actions"], copy=True)
        inside = t0 < self.episode_len
        log[np.flatnonzero(inside), t0[inside]] = actions[inside]
        terminated = np.asarray(terminated)
        for i, w in enumerate(ids):  # ended episodes' clients may serve the next resets
            if terminated[i] or t[i] >= self.episode_len:
                self._worlds[w].free = True
        record = dict(start=np.asarray(state.physics["start"]),
                      start_joints=np.asarray(state.physics["start_joints"]), actions=log)
        return self._state(after, ids, obs, reward, cost, terminated, t, state.key, extras,
                           record)

    # -- helpers ----------------------------------------------------------------------------
    def _gone(self, state: EnvState) -> np.ndarray:
        """[n] bool: episodes whose simulation this env no longer holds at the state's step."""
        ids, stamps = np.asarray(state.physics["world"]), np.asarray(state.physics["stamp"])
        return np.array([w >= len(self._worlds) or self._worlds[w].stamp != s
                         for w, s in zip(ids, stamps)], bool)

    @staticmethod
    def _as_f32(view: dict) -> dict:
        # numpy's rounding (IEEE, as XLA's convert): an eager jnp conversion per key and step
        # cost more than the physics on a single live episode
        return {k: np.asarray(v, np.float32) for k, v in view.items()}

    def _state(self, view, ids, obs, reward, cost, terminated, t, key, extras,
               record) -> EnvState:
        stamps = np.array([self._worlds[w].stamp for w in ids])
        # record: each episode's sampled position and joints (float64) and its actions so far
        # [n, episode_len, act_dim], from which `revive` rebuilds it
        physics = dict(view, world=np.asarray(ids, np.int64), stamp=stamps, **record)
        return EnvState(obs=np.asarray(obs, np.float32), reward=np.asarray(reward, np.float32),
                        cost=np.asarray(cost, np.float32), terminated=np.asarray(terminated),
                        truncated=np.asarray(t) >= self.episode_len, t=np.asarray(t, np.int32),
                        key=key, physics=physics, info=extras)

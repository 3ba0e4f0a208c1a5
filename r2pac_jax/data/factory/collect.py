"""Learned-behaviour datasets (DSRL's recipe), generated resumably on any backend.

A PPO-Lagrangian agent (`ppo_lagrangian.py`) that sees only the observation trains for the
task's RL budget while its cost limit follows DSRL's schedule (`tasks.CollectionSpec`); every
episode it finishes along training with cost <= the cap (and return >= the floor) goes to a pool
on disk; the pool is evened out on DSRL-style density grids (`thinning.py`) whenever it grows past
1.5 x the target (DSRL's TrajectoryBuffer filter interval), and the final file keeps `target`
trajectories. C MuJoCo envs roll out from Python (`rollout_batch`), JAX envs in one jitted scan
per update (`make_jax_rollout`); both feed the same update, multiplier and schedule.

Partial state lives in `{file}.partial/` (locked while a generation runs):

    spec.json   what is generated (task, seed, size, budget, schedule, PPO values); a resumed
                generation must match it key for key
    state.pkl   learner, environments and bookkeeping at the last checkpoint (an update boundary)
    episodes/   one ep-{index}.npz per pooled episode (DSRL arrays)
    log.jsonl   one row per update (return, cost, limit, multiplier, pool, speed)

A killed generation continues from its last checkpoint and ends with the same arrays as an
uninterrupted one (same machine and backend): episodes written after the checkpoint are
discarded on resume and made again identically. Another machine may not make the same file
(XLA's CPU numerics follow the CPU): given the log of the file it should make (`expect_log`),
a generation compares every update's row with it and stops at the first that differs, an
update in instead of hours, its partial state kept.
"""
from __future__ import annotations

import dataclasses
import json
import os
import pickle
import shutil
import time
from pathlib import Path
from typing import Callable, Optional

import jax
import jax.numpy as jnp
import numpy as np

from r2pac_jax.data.dsrl import DatasetError, LogMismatch
from r2pac_jax.data.factory import ppo_lagrangian as pl
from r2pac_jax.data.factory.thinning import thin_by_density
from r2pac_jax.tasks import TaskSpec

DATA_VERSION = 2  # 1: the scripted controllers; 2: learned behaviour (this module)

# Generation speed measured on the 2-core development CPU (env steps/s, 100 envs x 100 steps,
# policy at initialisation; experiments/data_factory/GENERATION.md): for the ETA printed
# before a generation starts. The progress bar measures the real rate as it goes.
CPU2_STEPS_PER_S = {
    "CarGoal1": 6593, "CarGoal2": 2159, "CarButton1": 4788, "CarButton2": 4684,
    "CarPush1": 4672, "CarPush2": 4056, "PointGoal1": 10563, "PointGoal2": 2002,
    "PointButton1": 7041, "PointButton2": 5663, "PointPush1": 4784, "PointPush2": 4958,
    "AntVelocity": 5331, "HalfCheetahVelocity": 18362, "HopperVelocity": 6756,
    "SwimmerVelocity": 18138, "Walker2dVelocity": 5089,
    # bullet backend, beside other runs (2026-12-02, load 3-4): BallRun 100 x 100, BallCircle
    # 50 x 200, CarRun 50 x 200, CarCircle 33 x 300, AntRun 50 x 200, AntCircle 20 x 500
    "BallRun": 6976, "BallCircle": 4864, "CarRun": 1370, "CarCircle": 752, "AntRun": 1614,
    "AntCircle": 825,
    # bullet, 2026-12-03 at nice 19 beside a generation (load ~2.5): DroneRun 50 x 200,
    # DroneCircle 33 x 300
    "DroneRun": 1710, "DroneCircle": 1532}


# A log row's wall-clock fields: they differ between any two runs; the data never depend on them
TIMING_KEYS = frozenset({"steps_per_s", "t_rollout", "t_physics", "t_pool", "t_update",
                         "t_checkpoint_before"})


def read_log(path) -> list[dict]:
    """The rows of a generation log (`.log.jsonl`, or gzipped `.log.jsonl.gz` as archived)."""
    import gzip

    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"no generation log {path}: give the .log.jsonl(.gz) written beside "
                           "the file to make again (results_v2/TASK archives them)")
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt") as f:
        return [json.loads(x) for x in f if x.strip()]


def log_difference(new: dict, old: dict) -> dict:
    """{key: (new, old)} for the logged quantities of one update that differ, the wall-clock
    fields left out and only the keys both rows have compared (older generators logged fewer
    quantities); {} where the rows agree."""
    keys = (set(new) & set(old)) - TIMING_KEYS
    return {k: (new[k], old[k]) for k in sorted(keys) if new[k] != old[k]}


# A whole generation's mean rate over the rate above (policy at initialisation), in the eight
# full-budget files of GENERATION.md: 0.45-0.77 for the MuJoCo tasks beside other work, 1.0-1.6
# for the Bullet ones (their updates end on episode boundaries). Budgets fitted to a session
# take the MuJoCo end, so that a generation meant to fit usually does.
MEAN_OVER_INIT_RATE = 0.6


def budget_for_hours(task: TaskSpec, hours: float) -> Optional[int]:
    """The RL budget (env steps, whole millions, at most DSRL's) that a generation is expected to
    finish in `hours` on the 2-core CPU beside one other job, or None where the rate was never
    measured. For a machine that does not outlive a session: DSRL's 22-54M steps take 2-18 h
    here, and a partial generation dies with its machine."""
    if not hours > 0:
        raise DatasetError(f"the hours a generation may take must be > 0, got {hours}")
    rate = CPU2_STEPS_PER_S.get(task.name)
    if rate is None or task.collection is None:
        return None
    fit = int(hours * 3600 * rate * MEAN_OVER_INIT_RATE // 1_000_000) * 1_000_000
    return max(1_000_000, min(task.collection.env_steps, fit))


def estimate_hours(task: TaskSpec, env_steps: Optional[int] = None) -> Optional[float]:
    """Hours of generation on a 2-core CPU at the measured rate, or None if not measured."""
    rate = CPU2_STEPS_PER_S.get(task.name)
    if rate is None or task.collection is None:
        return None
    return (env_steps or task.collection.env_steps) / rate / 3600.0
POOL_FACTOR = 1.5  # DSRL's TrajectoryBuffer filter_interval


@dataclasses.dataclass(frozen=True)
class GenSpec:
    task: str
    seed: int
    trajectories: int
    env_steps: int
    physics: str
    schedule: pl.CostSchedule
    cost_cap: float
    reward_min: float
    ppo: pl.PPOLagConfig
    checkpoint_every: int = 10  # updates

    @property
    def steps_per_update(self) -> int:
        return self.ppo.num_envs * self.ppo.rollout_len

    @property
    def updates(self) -> int:
        return max(1, self.env_steps // self.steps_per_update)

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["ppo"] = {k: list(v) if isinstance(v, tuple) else v for k, v in d["ppo"].items()
                    if pl.LATER_DEFAULTS.get(k, object()) != v}
        return json.loads(json.dumps(d))  # the form spec.json holds (lists, not tuples)


def make_spec(task: TaskSpec, trajectories: Optional[int] = None, env_steps: Optional[int] = None,
              seed: int = 0, physics: str = "auto", ppo: Optional[dict] = None,
              checkpoint_every: int = 10) -> GenSpec:
    """The task's DSRL recipe at its sizes, or scaled: a smaller `env_steps` budget moves the
    schedule's start and end by the same fraction of the budget."""
    c = task.collection
    if c is None:
        raise DatasetError(f"task {task.name} has no learned-behaviour recipe (tasks.py: "
                           "set_collection); use --source scripted or pass --dataset")
    budget = int(c.env_steps if env_steps is None else env_steps)
    n = int(c.trajectories if trajectories is None else trajectories)
    if budget < 1 or n < 1:
        raise DatasetError(f"--budget and --trajectories must be >= 1, got {budget}, {n}")
    frac = budget / c.env_steps
    sched = pl.CostSchedule(float(c.cost_start), float(c.cost_end),
                            int(round(c.epoch_start * c.steps_per_epoch * frac)),
                            max(1, int(round(c.epoch_end * c.steps_per_epoch * frac))))
    values = {**dict(c.ppo), **(ppo or {})}
    known = {f.name for f in dataclasses.fields(pl.PPOLagConfig)}
    for k in values:
        if k not in known:
            raise DatasetError(f"{task.name}: the generator has no recipe value {k!r}; known: "
                               f"{', '.join(sorted(known))}")
    cfg = pl.PPOLagConfig(**values)
    cfg.validate()
    if physics == "auto":
        physics = ("auto" if task.family == "demo" else "bullet" if task.family == "bullet"
                   else "mujoco" if jax.default_backend() == "cpu" else "mjx")
    if task.family == "bullet" and physics != "bullet":
        # the file's name does not say which engine made it, and train would evaluate it on
        # the original's: the MuJoCo re-creations serve evaluation only
        raise DatasetError(f"{task.name}: data for the Bullet tasks is made on the original's "
                           f"engine (--physics bullet or auto), not {physics!r}: the MuJoCo "
                           "re-creations (mujoco, mjx) are for evaluation")
    return GenSpec(task.name, int(seed), n, budget, physics, sched, float(c.cost_cap),
                   float(c.reward_min), cfg, int(checkpoint_every))


def _numpy(tree):
    return jax.tree_util.tree_map(np.asarray, tree)


def _atomic_pickle(path: Path, obj) -> None:
    from r2pac_jax.io import writing

    tmp = path.with_name(f".{path.name}.tmp")
    with writing(path, "the generation checkpoint", "the previous checkpoint is kept"):
        with open(tmp, "wb") as f:
            pickle.dump(obj, f, protocol=pickle.HIGHEST_PROTOCOL)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)


EPISODE_KEYS = {"observations": "obs", "next_observations": "nobs", "actions": "act",
                "rewards": "r", "costs": "c", "terminals": "term", "timeouts": "trunc"}


class Generation:
    """One learned-behaviour generation in `partial` (see the module docstring)."""

    def __init__(self, task: TaskSpec, spec: GenSpec, partial: Path,
                 log: Callable[[str], None] = print, progress: bool = True,
                 expected: Optional[tuple] = None):
        self.task, self.spec, self.dir = task, spec, Path(partial)
        self.log, self.progress = log, progress
        # (rows, where they came from): the log of the file this generation is to make again
        self.expected = expected
        self.env = task.make_env(physics=spec.physics)
        self.actor, self.critics, self.opt = pl.networks(task.obs_dim, task.act_dim, spec.ppo)
        self.policy = pl.make_policy_step(self.actor, self.critics)
        self.update = pl.make_update(self.actor, self.critics, self.opt, spec.ppo)
        N, T = spec.ppo.num_envs, spec.ppo.rollout_len
        self.jax_rollout = (pl.make_jax_rollout(self.env, self.policy, N, T)
                            if self.env.is_jax else None)

    # ---- state ------------------------------------------------------------------------------
    def fresh_state(self) -> dict:
        s = self.spec
        key = jax.random.PRNGKey(s.seed)
        k_par, k_env, key = jax.random.split(key, 3)
        params = pl.init_params(k_par, self.task.obs_dim, self.actor, self.critics)
        env_state = self.env.reset_batch(jax.random.split(k_env, s.ppo.num_envs))
        state = dict(update=0, env_steps=0, key=np.asarray(key), params=_numpy(params),
                     opt_state=_numpy(self.opt.init(params)), pid=(0.0, 0.0), lam=0.0,
                     env=_numpy(env_state), partial=[None] * s.ppo.num_envs, pool=[],
                     next_index=0, finished=0, thin_rounds=0, last_cost=0.0, last_return=0.0)
        if s.ppo.stagger_starts:
            n = s.ppo.num_envs
            offsets = (np.arange(n) * self.task.episode_len) // n  # [N] steps already "taken"
            state["env"] = state["env"].replace(t=offsets.astype(np.asarray(state["env"].t).dtype))
            # the shortened first episodes: not pooled, not in the multiplier's episode cost
            state["skip_first"] = [bool(o > 0) for o in offsets]
        return state

    def _check_spec(self) -> None:
        f = self.dir / "spec.json"
        new = self.spec.to_dict()
        if f.exists():
            old = json.loads(f.read_text())
            diff = [f"{k}: {old.get(k)!r} -> {new.get(k)!r}" for k in sorted(set(old) | set(new))
                    if old.get(k) != new.get(k)]
            if diff:
                raise DatasetError(f"{self.dir} holds a generation started with other settings "
                                   f"({'; '.join(diff)}); rerun with the same options to resume "
                                   "it, or pass --force to discard it")
        else:
            from r2pac_jax.io import atomic_write_json

            atomic_write_json(f, new)

    def _restore(self) -> dict:
        st = self.dir / "state.pkl"
        resumed = st.exists()
        if resumed:
            with open(st, "rb") as f:
                state = pickle.load(f)
        else:  # a run killed before its first checkpoint left episodes and log rows: drop them
            state = self.fresh_state()
        # episodes written after the checkpoint, or dropped by the thinning it recorded
        keep = {e[0] for e in state["pool"]}
        for p in (self.dir / "episodes").glob("ep-*.npz"):
            i = int(p.stem[3:])
            if i >= state["next_index"] or i not in keep:
                p.unlink()
        rows = [ln for ln in self._log_file.read_text().splitlines()
                if ln and json.loads(ln)["update"] <= state["update"]] \
            if self._log_file.exists() else []
        self._log_file.write_text("".join(r + "\n" for r in rows))
        for r in rows:  # made before, perhaps without the expected log
            self._check_row(json.loads(r))
        if resumed:
            self.log(f"resuming {self.dir} at update {state['update']} of {self.spec.updates} "
                     f"({state['env_steps']} env steps, {len(state['pool'])} episodes pooled)")
        return state

    @property
    def _log_file(self) -> Path:
        return self.dir / "log.jsonl"

    def _check_row(self, row: dict) -> None:
        """Refuse to go on once an update's row differs from the expected log's."""
        if self.expected is None:
            return
        rows, source = self.expected
        u = row["update"]
        if u > len(rows):
            return  # the expected log is shorter (a generation stopped early): nothing to match
        diff = log_difference(row, rows[u - 1])
        if diff:
            what = "; ".join(f"{k} {a!r} here, {b!r} expected" for k, (a, b) in diff.items())
            raise LogMismatch(
                f"{self.spec.task}: update {u} of the generation differs from {source} ({what}): "
                "this machine does not make that file bit for bit. The partial generation is "
                f"kept in {self.dir}; without the expected log it continues from there")

    def _checkpoint(self, state: dict) -> None:
        s = self.spec
        dropped = []
        if len(state["pool"]) > POOL_FACTOR * s.trajectories:
            pool = state["pool"]
            keep = thin_by_density(np.array([e[1] for e in pool]), np.array([e[2] for e in pool]),
                                   s.trajectories, seed=s.seed * 100_003 + state["thin_rounds"])
            kept = set(keep.tolist())
            dropped = [e[0] for i, e in enumerate(pool) if i not in kept]
            state["pool"] = [pool[i] for i in keep]
            state["thin_rounds"] += 1
        _atomic_pickle(self.dir / "state.pkl", state)
        for i in dropped:  # after the commit: a kill in between is cleaned up on resume
            (self.dir / "episodes" / f"ep-{i:07d}.npz").unlink(missing_ok=True)

    # ---- episodes -------------------------------------------------------------------------------
    def _split_episodes(self, state: dict, traj: dict) -> tuple[list, list]:
        """Finished episodes of the rollout (appending to each env's unfinished one) ->
        (kept [(index, return, cost, length)], all finished [(return, cost)])."""
        s = self.spec
        T, N = traj["done"].shape
        kept, finished = [], []
        for j in range(N):
            ends = np.flatnonzero(traj["done"][:, j])
            start = 0
            for e in list(ends) + [None]:
                stop = T if e is None else e + 1
                seg = {k: traj[v][start:stop, j] for k, v in EPISODE_KEYS.items()}
                prev = state["partial"][j]
                if prev is not None:
                    seg = {k: np.concatenate([prev[k], seg[k]]) for k in seg}
                if e is None:
                    state["partial"][j] = seg if seg["rewards"].size else None
                    break
                state["partial"][j] = None
                start = stop
                if state.get("skip_first", [False] * N)[j]:  # stagger_starts' short first one
                    state["skip_first"][j] = False
                    continue
                ret, cost = float(seg["rewards"].sum()), float(seg["costs"].sum())
                finished.append((ret, cost))
                if cost <= s.cost_cap and ret >= s.reward_min:
                    from r2pac_jax.io import writing

                    i = state["next_index"]
                    state["next_index"] += 1
                    f = self.dir / "episodes" / f"ep-{i:07d}.npz"
                    with writing(f, "a pooled episode", "rerunning continues from the last "
                                 "checkpoint"):
                        np.savez(f, **seg)
                    kept.append((i, ret, cost, int(seg["rewards"].size)))
        return kept, finished

    # ---- the loop ---------------------------------------------------------------------------
    def run(self, stop_after: Optional[int] = None) -> Optional[dict]:
        """Generate (or continue) to the end of the budget; with `stop_after`, stop after that
        many updates of this call (as an interruption would) and return None. Returns the info
        of the finished generation (its pool is in `episodes/`)."""
        from r2pac_jax.io import lock_directory

        (self.dir / "episodes").mkdir(parents=True, exist_ok=True)
        lock = lock_directory(self.dir)
        try:
            self._check_spec()
            return self._run(stop_after)
        finally:
            lock.close()

    def _run(self, stop_after: Optional[int]) -> Optional[dict]:
        s = self.spec
        state = self._restore()
        params = jax.tree_util.tree_map(jnp.asarray, state["params"])
        opt_state = jax.tree_util.tree_map(jnp.asarray, state["opt_state"])
        env_state = state["env"]
        if self.env.is_jax:
            env_state = jax.tree_util.tree_map(jnp.asarray, env_state)
        elif hasattr(self.env, "revive"):  # simulations held outside the state (bullet)
            env_state = self.env.revive(env_state)
        bar = None
        if self.progress:
            from tqdm import tqdm

            bar = tqdm(total=s.updates * s.steps_per_update, initial=state["env_steps"],
                       unit="step", unit_scale=True, desc=f"{s.task} PPO-Lagrangian",
                       dynamic_ncols=True, smoothing=0.05)
        done_here = 0
        t_run = time.time()
        t_checkpoint = None
        try:
            with open(self._log_file, "a") as logf:
                while state["update"] < s.updates:
                    if stop_after is not None and done_here >= stop_after:
                        return None
                    t0 = time.time()
                    # where an update's time goes (profiling; the data do not depend on it)
                    parts: dict = {}
                    key, k_roll, k_upd = jax.random.split(jnp.asarray(state["key"]), 3)
                    if self.jax_rollout is not None:
                        env_state, traj = self.jax_rollout(params, env_state, k_roll)
                        traj = _numpy(traj)
                    else:
                        env_state, traj = pl.rollout_batch(self.env, self.policy, params,
                                                           env_state, k_roll, s.ppo.rollout_len,
                                                           timing=parts)
                    t1 = time.time()
                    kept, finished = self._split_episodes(state, traj)
                    state["pool"].extend(kept)
                    state["finished"] += len(finished)
                    if finished:
                        state["last_return"] = float(np.mean([f[0] for f in finished]))
                        state["last_cost"] = float(np.mean([f[1] for f in finished]))
                    state["env_steps"] += s.steps_per_update
                    limit = s.schedule.limit(state["env_steps"])
                    state["pid"], state["lam"] = pl.pid_multiplier(
                        state["pid"], state["last_cost"], limit, tuple(s.ppo.pid))
                    t2 = time.time()
                    params, opt_state, m = self.update(params, opt_state, pl.as_update_batch(traj),
                                                       jnp.float32(state["lam"]), k_upd)
                    m = jax.block_until_ready(m)
                    t3 = time.time()
                    state["update"] += 1
                    state["key"] = np.asarray(key)
                    row = dict(update=state["update"], env_steps=state["env_steps"],
                               cost_limit=limit, multiplier=state["lam"],
                               episode_return=state["last_return"],
                               episode_cost=state["last_cost"], finished=len(finished),
                               finished_within_last_limit=sum(
                                   f[1] <= s.schedule.end for f in finished),
                               pooled=len(state["pool"]),
                               policy_loss=float(m["policy_loss"]),
                               value_loss=float(m["value_loss"]),
                               # the policy's noise: a task whose cost the noise alone makes
                               # (Swimmer) needs it to fall before the limit can be met
                               log_std=float(np.mean(np.asarray(
                                   params["actor"]["params"]["log_std"]))),
                               steps_per_s=s.steps_per_update / (time.time() - t0),
                               # seconds of this update: the rollout (for a Python-stepped
                               # simulator, t_physics of it is the simulator's), the episode
                               # pool and its files, PPO's GAE and update (t_checkpoint_before:
                               # the checkpoint written after the previous update)
                               t_rollout=t1 - t0, t_pool=t2 - t1, t_update=t3 - t2)
                    if "physics" in parts:
                        row["t_physics"] = parts["physics"]
                    if t_checkpoint is not None:  # the one written after the previous update
                        row["t_checkpoint_before"], t_checkpoint = t_checkpoint, None
                    # the row before the checkpoint: a resume drops rows past its checkpoint
                    logf.write(json.dumps(row) + "\n")
                    logf.flush()
                    self._check_row(row)  # before the checkpoint: a resume makes it again
                    done_here += 1
                    if state["update"] % s.checkpoint_every == 0 or state["update"] == s.updates:
                        t4 = time.time()
                        state["params"], state["opt_state"] = _numpy(params), _numpy(opt_state)
                        state["env"] = _numpy(env_state)
                        self._checkpoint(state)
                        t_checkpoint = time.time() - t4
                    if bar is not None:
                        bar.set_postfix(limit=f"{limit:.0f}", lam=f"{state['lam']:.2f}",
                                        ret=f"{state['last_return']:.1f}",
                                        cost=f"{state['last_cost']:.1f}",
                                        pool=len(state["pool"]), refresh=False)
                        bar.update(s.steps_per_update)
        finally:
            if bar is not None:
                bar.close()
        return dict(updates=state["update"], env_steps=state["env_steps"],
                    finished_episodes=state["finished"], pooled=len(state["pool"]),
                    wall_s_this_call=time.time() - t_run, pool=state["pool"])

    # ---- the file ---------------------------------------------------------------------------
    def assemble(self, pool: list) -> tuple[dict, dict]:
        """The final DSRL arrays: the pool thinned to the target (index order) -> (arrays,
        {thinning info})."""
        s = self.spec
        if not pool:
            raise DatasetError(f"{s.task}: the generation kept no episode (cost <= {s.cost_cap}, "
                               f"return >= {s.reward_min}) within {s.env_steps} env steps")
        rets = np.array([e[1] for e in pool])
        costs = np.array([e[2] for e in pool])
        keep = thin_by_density(rets, costs, s.trajectories, seed=s.seed)
        chosen = sorted((pool[i][0], pool[i][3]) for i in keep)  # (index, length)
        # filled episode by episode into arrays of the final size: one copy of the file in
        # memory, not two (a list of the episodes, then their concatenation)
        total = sum(n for _, n in chosen)
        arrays: dict = {}
        at = 0
        for i, n in chosen:
            with np.load(self.dir / "episodes" / f"ep-{i:07d}.npz") as ep:
                for k in EPISODE_KEYS:
                    a = ep[k]
                    if a.shape[0] != n:
                        raise DatasetError(f"{self.dir}: episode {i} holds {a.shape[0]} steps, "
                                           f"its pool record {n}: the pool is damaged; pass "
                                           "--force to generate again")
                    if k not in arrays:
                        dtype = bool if k in ("terminals", "timeouts") else a.dtype
                        arrays[k] = np.empty((total,) + a.shape[1:], dtype)
                    arrays[k][at:at + n] = a
            at += n
        return arrays, dict(pooled=len(pool), kept=len(chosen), grid="20x20 (cost, return)")

    def plot(self, path: Path) -> None:
        rows = [json.loads(ln) for ln in self._log_file.read_text().splitlines() if ln]
        if not rows:
            return
        from r2pac_jax.report import _plt, _savefig

        plt = _plt()
        x = [r["env_steps"] for r in rows]
        fig, axes = plt.subplots(1, 3, figsize=(13, 3.4))
        axes[0].plot(x, [r["episode_return"] for r in rows], lw=1)
        axes[0].set_title("episode return", fontsize=9)
        axes[1].plot(x, [r["episode_cost"] for r in rows], lw=1, label="episode cost")
        axes[1].plot(x, [r["cost_limit"] for r in rows], lw=1, ls="--", label="cost limit")
        axes[1].legend(fontsize=7)
        axes[1].set_title("episode cost and the scheduled limit", fontsize=9)
        axes[2].plot(x, [r["multiplier"] for r in rows], lw=1)
        axes[2].set_title("Lagrange multiplier (PID)", fontsize=9)
        for ax in axes:
            ax.set_xlabel("env steps")
        fig.suptitle(f"{self.spec.task}: PPO-Lagrangian data generation", fontsize=10)
        _savefig(fig, path)
        plt.close(fig)


def needed_disk_bytes(task: TaskSpec, spec: GenSpec) -> int:
    """Disk for the pool at its largest plus the final file (float32 arrays, both copies)."""
    per_step = 4 * (2 * task.obs_dim + task.act_dim + 2) + 2
    return int(per_step * task.episode_len * spec.trajectories * (POOL_FACTOR + 1.2))


def needed_memory_bytes(task: TaskSpec, spec: GenSpec) -> int:
    """Memory to assemble and write the final file (its arrays about twice over)."""
    per_step = 4 * (2 * task.obs_dim + task.act_dim + 2) + 2
    return int(2 * per_step * task.episode_len * spec.trajectories)


def _available_memory() -> Optional[int]:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except OSError:
        return None
    return None


def check_disk(task: TaskSpec, spec: GenSpec, where: Path) -> None:
    """DatasetError naming the sizes when the disk (pool + file) or the memory (assembling the
    file) cannot hold the requested size."""
    where.mkdir(parents=True, exist_ok=True)
    need = needed_disk_bytes(task, spec)
    free = shutil.disk_usage(where).free
    if free < need:
        raise DatasetError(f"{where}: {free / 2**30:.1f} GiB free, generating {spec.trajectories} "
                           f"{task.name} trajectories needs about {need / 2**30:.1f} GiB; free "
                           "space or pass a smaller --trajectories")
    mem, avail = needed_memory_bytes(task, spec), _available_memory()
    if avail is not None and avail < mem:
        raise DatasetError(f"{avail / 2**30:.1f} GiB of memory available, assembling "
                           f"{spec.trajectories} {task.name} trajectories needs about "
                           f"{mem / 2**30:.1f} GiB; free memory or pass a smaller --trajectories")


def schedule_warning(task: TaskSpec, spec: GenSpec) -> Optional[str]:
    """A line when the budget leaves no whole episode under the schedule's last limit (each
    environment needs episode_len steps, i.e. episode_len / rollout_len updates, after the limit
    arrives): the learner cannot be judged against that limit and the file holds few episodes
    made under it. None when the budget allows one."""
    per_update = spec.steps_per_update
    total = spec.updates * per_update
    after = total - spec.schedule.end_step
    need = task.episode_len * spec.ppo.num_envs  # one whole episode per environment
    if after >= need:
        return None
    c = task.collection
    return (f"{task.name}: a budget of {spec.env_steps:,} env steps reaches the last cost limit "
            f"{spec.schedule.end:g} at step {spec.schedule.end_step:,} and leaves "
            f"{max(after, 0):,} steps under it, fewer than one {task.episode_len}-step episode "
            f"per environment ({need:,}); DSRL's budget of {c.env_steps:,} leaves "
            f"{(c.epochs - c.epoch_end) * c.steps_per_epoch:,}. Episodes under the last limit "
            f"will be few or none: give a larger --budget")


def generate_learned(task: TaskSpec, path: Path, trajectories: Optional[int] = None,
                     env_steps: Optional[int] = None, seed: int = 0, physics: str = "auto",
                     ppo: Optional[dict] = None, checkpoint_every: int = 10,
                     progress: bool = True, log: Callable[[str], None] = print,
                     stop_after: Optional[int] = None,
                     expect_log: Optional[Path] = None) -> Optional[Path]:
    """Make (or continue making) the learned-behaviour file at `path`: generation in
    `{path}.partial/`, then the file, its card, a composition plot, the training log and plot.
    Returns the path, or None when `stop_after` stopped it early (resumable). `expect_log`: the
    log of the file to make again (`read_log`); the first update whose row differs raises
    `LogMismatch`, the partial state kept."""
    import resource

    from r2pac_jax.data.dsrl import validate, write_dsrl
    from r2pac_jax.data.factory.card import card_path, make_card
    from r2pac_jax.io import atomic_write_json
    from r2pac_jax.report import plot_composition

    spec = make_spec(task, trajectories, env_steps, seed, physics, ppo, checkpoint_every)
    expected = None if expect_log is None else (read_log(expect_log), str(expect_log))
    warning = schedule_warning(task, spec)
    if warning:
        log(f"warning: {warning}")
    partial = Path(f"{path}.partial")
    check_disk(task, spec, path.parent)
    gen = Generation(task, spec, partial, log=log, progress=progress, expected=expected)
    t0 = time.time()
    info = gen.run(stop_after)
    if info is None:
        return None
    arrays, thin = gen.assemble(info.pop("pool"))
    ds = validate(arrays, str(path), task.obs_dim, task.act_dim, task.name)
    c = task.collection
    card = make_card(task, ds, seed, spec.trajectories,
                     f"PPO-Lagrangian (observation-based, PID multiplier) under DSRL's cost "
                     f"schedule {spec.schedule.start:g} -> {spec.schedule.end:g}, trajectories "
                     f"kept along training (data v{DATA_VERSION})")
    card.update(
        data_version=DATA_VERSION, source="ppo-lagrangian", physics=spec.physics,
        generation=dict(spec.to_dict(), **info, wall_s_last_call=time.time() - t0,
                        peak_rss_mib=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024),
        thinning=thin, dsrl_env_steps=c.env_steps, dsrl_trajectories=c.trajectories,
        budget_below_dsrl=spec.env_steps < c.env_steps,
        trajectories_below_target=ds.episode_sums()[0].size < spec.trajectories)
    write_dsrl(path, ds, attrs={"task": task.name, "generated": True, "seed": seed,
                                "source": "ppo-lagrangian", "data_version": DATA_VERSION})
    rets, costs = ds.episode_sums()
    plot_composition(rets, costs, task.kappa, path.with_suffix(".png"),
                     f"{task.name} PPO-Lagrangian v{DATA_VERSION} (seed {seed}, {rets.size} "
                     "trajectories)")
    shutil.copyfile(partial / "log.jsonl", path.with_suffix(".log.jsonl"))
    gen.plot(path.with_suffix(".training.png"))
    atomic_write_json(card_path(path), card)  # last: marks the dataset complete
    shutil.rmtree(partial, ignore_errors=True)
    return path

"""The training loop every algorithm shares: pure compiled blocks, and the run that drives them.

The unit of compiled work is a *block*: the agent's `begin_block` (R2PAC refreshes its safety
threshold), then `block_steps` gradient steps in one `jax.lax.scan`, returning the block's
mean metrics. Blocks are vmapped over *lanes* (seeds x scalar-hyperparameter cells, `lanes.py`),
so a grid of seeds and hyperparameters trains as one compiled program. `make_train` chains every
block of every phase into one scan (pure, no I/O); `Run` calls the same vmapped block from
Python between evaluations and checkpoints so that a user gets progress, logs and resumability.
Nothing here knows which algorithm it trains: that is `agents/`'s protocol (`agents/base.py`).
"""
from __future__ import annotations

import functools
import time
from pathlib import Path
from typing import Callable, Optional

import jax
import jax.numpy as jnp
import numpy as np

from r2pac_jax.agents import make_agent
from r2pac_jax.config import Config, default_hparams
from r2pac_jax.data.dsrl import Dataset
from r2pac_jax.divergence import MODES, TrainingDiverged, check_finite, evaluate_lanes
from r2pac_jax.io import sigint_deferred
from r2pac_jax.lanes import Lanes, place
from r2pac_jax.precision import with_matmul_precision
from r2pac_jax.progress import RunProgress
from r2pac_jax.run_dir import RunDirectory
from r2pac_jax.tasks import TaskSpec

__all__ = ["Run", "RunEvaluation", "TrainingDiverged", "compiled", "make_block", "make_data",
           "make_train"]


# ---------------------------------------------------------------------------------------------
# Pure pieces


def make_data(cfg: Config, task: TaskSpec, ds: Dataset):
    """The data view cfg's algorithm trains on (for R2PAC: h-step chunks; bc-safe: safe ones)."""
    agent = make_agent(cfg, task.obs_dim, task.act_dim)
    check_data(agent, task, ds, default_cells(cfg))
    return agent.make_data(task, ds)


chunk_dataset = make_data  # the name of earlier releases


def make_block(agent, phase: str, first_bad: bool = False) -> Callable:
    """block(state, hp, data) -> (state, metrics): begin_block + `block_steps` steps.

    With `first_bad`, also the index (0-based, within the block) of the first step whose
    metrics hold a NaN or inf, or -1: the run names the exact step of a divergence."""
    cfg = agent.cfg

    def block(state, hp: dict, data):
        state = agent.begin_block(state, hp, data)

        def step(s, _):
            key, k_batch = jax.random.split(s.key)
            batch = agent.sample(data, k_batch)
            return agent.update(s.replace(key=key), batch, hp, phase)

        state, metrics = jax.lax.scan(step, state, None, length=cfg.block_steps)
        means = jax.tree_util.tree_map(jnp.mean, metrics)
        if not first_bad:
            return state, means
        ok = jnp.stack([jnp.isfinite(v).reshape(v.shape[0], -1).all(-1)
                        for v in jax.tree_util.tree_leaves(metrics)]).all(0)
        return state, means, jnp.where(ok.all(), -1, jnp.argmin(ok))

    # an agent written against the protocol alone may carry a config without the key
    return with_matmul_precision(block, getattr(cfg, "matmul_precision", "default"))


def time_block(cfg: Config, task: TaskSpec, ds: Dataset, lanes: int, blocks: int = 5,
               phase: Optional[str] = None) -> dict:
    """Training speed of cfg's compiled block with `lanes` seeds vmapped (evaluation excluded):
    compile timed apart, one warm-up block, then the median of `blocks` timed blocks."""
    agent = make_agent(cfg, task.obs_dim, task.act_dim)
    data = make_data(cfg, task, ds)
    ln = Lanes.build(cfg, list(range(lanes)))
    state = jax.jit(jax.vmap(agent.init))(ln.init_keys(), ln.hp)
    fn = jax.jit(jax.vmap(make_block(agent, phase or cfg.phases[0]), in_axes=(0, 0, None)))
    t0 = time.perf_counter()
    comp = fn.lower(state, ln.hp, data).compile()
    compile_s = time.perf_counter() - t0
    state, _ = comp(state, ln.hp, data)
    jax.block_until_ready(state)
    times = []
    for _ in range(blocks):
        t0 = time.perf_counter()
        state, _ = comp(state, ln.hp, data)
        jax.block_until_ready(state)
        times.append(time.perf_counter() - t0)
    dt = float(np.median(times))
    return dict(lanes=lanes, block_steps=cfg.block_steps,
                steps_per_s=cfg.block_steps / dt,
                seed_steps_per_s=lanes * cfg.block_steps / dt, compile_s=compile_s)


def time_policy_step(cfg, task: TaskSpec, lanes: int, episodes: int, calls: int = 3) -> float:
    """Seconds of one evaluation step's policy for `lanes` x `episodes` states (as an evaluation
    calls it: jitted, vmapped over lanes; a memory policy's act and observe), freshly
    initialised networks (the time does not depend on training); the median of `calls` calls
    after a compiling one. The simulator's step comes on top."""
    from r2pac_jax.evaluate import _stepper, policy_of

    agent, init, _, policy_params = compiled(cfg, task.obs_dim, task.act_dim)
    ln = Lanes.build(cfg, list(range(lanes)))
    pp = policy_params(init(ln.init_keys(), ln.hp), ln.hp)
    pol = _stepper(policy_of(agent))
    obs = jnp.zeros((lanes, episodes, task.obs_dim), jnp.float32)
    zeros = jnp.zeros((lanes, episodes), jnp.float32)
    mem = jax.jit(jax.vmap(pol.init))(pp, obs)
    keys = jax.random.split(jax.random.PRNGKey(0), lanes)

    @jax.jit
    def step(pp, obs, keys, mem):
        action, mem, _ = jax.vmap(pol.step)(pp, obs, keys, mem)
        return action, jax.vmap(pol.observe)(pp, mem, zeros, zeros)

    jax.block_until_ready(step(pp, obs, keys, mem))
    times = []
    for _ in range(max(calls, 1)):
        t0 = time.perf_counter()
        jax.block_until_ready(step(pp, obs, keys, mem))
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def make_train(cfg: Config, data, obs_dim: int, act_dim: int):
    """A pure `train(key, hp=None) -> (state, {phase: metrics[n_blocks]})`.

    Every phase runs as one `lax.scan` over blocks; jit it and vmap it over keys and hp (a dict
    of the algorithm's vmappable scalars, `config.default_hparams`) as you like. The dataset is
    passed to the compiled function as an argument, not baked in.
    """
    agent = make_agent(cfg, obs_dim, act_dim)
    blocks = {p: make_block(agent, p) for p in cfg.phases}
    n_blocks = cfg.steps // cfg.block_steps

    def train_with_data(key, hp, data):
        state = agent.init(key, hp)
        metrics = {}
        for phase in cfg.phases:
            state, metrics[phase] = jax.lax.scan(
                lambda s, _: blocks[phase](s, hp, data), state, None, length=n_blocks)
        return state, metrics

    def train(key, hp: Optional[dict] = None):
        hp = default_hparams(cfg) if hp is None else hp
        return train_with_data(key, hp, data)

    train.agent = agent
    train.with_data = train_with_data
    return train


@functools.lru_cache(maxsize=16)
def compiled(cfg: Config, obs_dim: int, act_dim: int):
    """Jitted, lane-vmapped pieces for a config, shared by every `Run` with the same config
    (a resumed run or a sweep's next group reuses the compiled programs)."""
    agent = make_agent(cfg, obs_dim, act_dim)
    blocks = {p: jax.jit(jax.vmap(make_block(agent, p, first_bad=True), in_axes=(0, 0, None)))
              for p in cfg.phases}
    return agent, jax.jit(jax.vmap(agent.init)), blocks, jax.jit(jax.vmap(agent.policy_params))


@functools.lru_cache(maxsize=16)
def lane_evaluator(cfg: Config, task: TaskSpec, episodes: int, physics: str,
                   diagnostics: bool = True):
    from r2pac_jax.evaluate import LaneEvaluator, policy_of

    agent = compiled(cfg, task.obs_dim, task.act_dim)[0]
    return LaneEvaluator(policy_of(agent, diagnostics), task, episodes, physics=physics)


@functools.lru_cache(maxsize=16)
def diagnostic_params(cfg: Config, obs_dim: int, act_dim: int):
    """Jitted, lane-vmapped `diagnostic_params` of cfg's agent (its policy_params where it has
    none): what evaluation with diagnostics acts on."""
    agent = compiled(cfg, obs_dim, act_dim)[0]
    return jax.jit(jax.vmap(getattr(agent, "diagnostic_params", agent.policy_params)))


def check_run(cfg: Config, task: TaskSpec, ds: Dataset) -> None:
    """Everything about (config, dataset) that can be refused before any training starts."""
    check_data(make_agent(cfg, task.obs_dim, task.act_dim), task, ds, default_cells(cfg))


def default_cells(cfg: Config) -> list[dict]:
    """The one cell of a run without a grid: cfg's values of its per-lane scalars."""
    return Lanes.build(cfg, [0]).cell_hparams


def check_data(agent, task: TaskSpec, ds: Dataset, cells: list[dict]) -> None:
    """The agent's checks of the dataset, then of each lane cell's values where it has such
    checks (`check_cells`: CDT's cost targets against the data's episode costs)."""
    agent.check_data(task, ds)
    if hasattr(agent, "check_cells"):
        agent.check_cells(task, ds, cells)


# ---------------------------------------------------------------------------------------------
# The run: blocks between evaluations and checkpoints


def schedule(cfg: Config) -> list[tuple[str, int]]:
    """(phase, step within phase after the block) for every block of a run of cfg."""
    n = cfg.steps // cfg.block_steps
    return [(p, (i + 1) * cfg.block_steps) for p in cfg.phases for i in range(n)]


def evaluation_due(cfg: Config, agent, phase: str, phase_step: int, last: bool) -> bool:
    """An evaluation follows this block: every eval_every steps of an evaluated phase, and
    after the last block."""
    if phase in agent.unevaluated_phases:
        return False
    return last or phase_step % cfg.eval_every == 0


def count_evaluations(cfg: Config, agent) -> int:
    """How many evaluations a run of cfg makes (its evaluation episodes each time)."""
    blocks = schedule(cfg)
    return sum(evaluation_due(cfg, agent, p, s, i == len(blocks) - 1)
               for i, (p, s) in enumerate(blocks))


class RunEvaluation:
    """A run's evaluations: when one falls due, and every lane's scores (diverged lanes: NaN,
    not run). With diagnostics the policy also reports them (R2PAC: its candidates' spread, the
    reward the choice gives up, V_c > l); they consume no random key, so every score is the
    same without them."""

    def __init__(self, cfg: Config, task: TaskSpec, physics: str, diagnostics: bool,
                 log: Callable[[str], None]):
        self.cfg = cfg
        self.agent, _, _, policy_params = compiled(cfg, task.obs_dim, task.act_dim)
        self.evaluator = (lane_evaluator(cfg, task, cfg.eval_episodes, physics, diagnostics)
                          if cfg.eval_episodes > 0 else None)
        self._params = (diagnostic_params(cfg, task.obs_dim, task.act_dim) if diagnostics
                        else policy_params)
        note = getattr(self.agent, "diagnostics_note", lambda: None)()
        if diagnostics and self.evaluator is not None and note:
            log(f"note: {note}")

    @property
    def backend(self) -> Optional[str]:
        """The physics the evaluation ran on (None without evaluation)."""
        return None if self.evaluator is None else getattr(self.evaluator.env, "backend", "jax")

    def due(self, phase: str, phase_step: int, last: bool) -> bool:
        return self.evaluator is not None and evaluation_due(self.cfg, self.agent, phase,
                                                             phase_step, last)

    def __call__(self, state, lanes: Lanes, step: int, diverged: dict) -> dict:
        """Every lane's evaluation at `step`: per-episode [L, episodes] and per-lane [L]."""
        from r2pac_jax.evaluate import eval_keys

        return evaluate_lanes(self.evaluator, self._params(state, lanes.hp),
                              eval_keys(lanes.seeds, step), diverged, lanes.size,
                              self.cfg.eval_episodes)


class Run:
    """Trains all lanes of one config on one dataset: blocks, with evaluations and checkpoints
    between them. Its directory's files and rules are `run_dir.RunDirectory`'s, its logs and
    progress bar `progress.RunProgress`'s, its evaluations `RunEvaluation`'s, non-finite lanes
    `divergence`'s."""

    def __init__(self, cfg: Config, task: TaskSpec, ds: Dataset, out_dir, lanes: Lanes,
                 physics: str = "auto", progress: bool = True, log: Callable[[str], None] = print,
                 dataset_label: str = "", nonfinite: str = "stop", diagnostics: bool = True):
        """nonfinite: "stop" (a block with a NaN/inf metric stops the run) or "mark" (sweeps:
        the diverged lanes are recorded, reported without scores, and the others finish).
        diagnostics: evaluations also log the policy's diagnostics (`RunEvaluation`)."""
        if nonfinite not in MODES:
            raise ValueError(f"nonfinite must be 'stop' or 'mark', got {nonfinite!r}")
        self.cfg, self.task, self.lanes, self.nonfinite = cfg, task, lanes, nonfinite
        self.physics, self.progress, self.log = physics, progress, log
        self.step_reached, self.last_checkpoint = 0, None  # what an interruption reports
        self.diverged: dict[int, dict] = {}  # lane -> {seed, step, terms}
        self.out = Path(out_dir)
        self.dir = RunDirectory(self.out)
        self.dataset_label = dataset_label or ds.source
        self.dataset_path = next((Path(p) for p in (dataset_label, ds.source)
                                  if p and Path(p).is_file()), None)
        self.agent, self._init, self._blocks, self._policy_params = compiled(
            cfg, task.obs_dim, task.act_dim)
        check_data(self.agent, task, ds, lanes.cell_hparams)
        self.data = self.agent.make_data(task, ds)
        self.dataset_info = dict(source=ds.source, sha256=ds.digest(), transitions=int(ds.size))
        self.evaluation = RunEvaluation(cfg, task, physics, diagnostics, log)

    @property
    def schedule(self) -> list[tuple[str, int]]:
        """(phase, step within phase after the block) for every block of the run."""
        return schedule(self.cfg)

    def init_state(self):
        return place(self._init(self.lanes.init_keys(), self.lanes.hp), self.lanes.size)

    def evaluate(self, state, step: int) -> dict:
        """Every lane's evaluation at `step` (diverged lanes: NaN, not run)."""
        return self.evaluation(state, self.lanes, step, self.diverged)

    def run(self, resume: bool = False, stop_after: Optional[int] = None) -> Optional[dict]:
        """Train to the end (or stop after `stop_after` blocks, as an interruption would, and
        return None); with `resume`, continue from the latest checkpoint in the run directory.
        The directory is locked meanwhile: a second live process on it gets DirectoryBusy."""
        with self.dir.held():
            return self._run(resume, stop_after)

    def check_same_run(self) -> None:
        """A resumed run must be the run that was started: same config, seeds and cells."""
        self.dir.check_same_run(self.cfg, self.lanes, self.dataset_info, self.physics)

    def _run(self, resume: bool, stop_after: Optional[int]) -> Optional[dict]:
        cfg, schedule = self.cfg, self.schedule
        ckpt, state, done_blocks, resume_step = self._start(resume)
        shown = RunProgress(self.out, self.lanes, cfg.block_steps, self.agent.progress_metrics,
                            resume_step, self.progress, len(schedule) * cfg.block_steps,
                            done_blocks * cfg.block_steps, f"{self.task.name} {cfg.algo}")
        hp = place(self.lanes.hp, self.lanes.size)
        last_eval, t_start, steps_timed = None, time.time(), 0
        try:
            for i in range(done_blocks, len(schedule)):
                if stop_after is not None and i - done_blocks >= stop_after:
                    return None
                phase, phase_step = schedule[i]
                step, last = (i + 1) * cfg.block_steps, i == len(schedule) - 1
                t0 = time.time()
                state, metrics, first_bad = self._blocks[phase](state, hp, self.data)
                metrics = jax.tree_util.tree_map(np.asarray, metrics)  # waits for the block
                steps_timed += cfg.block_steps
                self.step_reached = step
                shown.block(metrics, step, phase, time.time() - t0)
                check_finite(metrics, step - cfg.block_steps + 1 + np.asarray(first_bad),
                             ckpt.latest_step(), self.diverged, self.nonfinite, self.lanes,
                             f"{self.task.name} {cfg.algo}", self.log)
                if self.evaluation.due(phase, phase_step, last):
                    last_eval = self.evaluate(state, step)
                    shown.evaluation(last_eval, step)
                if last or step % cfg.checkpoint_every == 0:
                    with sigint_deferred():  # Ctrl-C waits for the save and its record here
                        ckpt.save_blocks(step, state, i + 1, self.diverged)
                        self.last_checkpoint = step
                shown.show(phase, metrics, last_eval)
            shown.close_bar()
            return self._finish(state, last_eval, time.time() - t_start, steps_timed,
                                resume_step, shown.logs)
        finally:
            shown.close()
            ckpt.close()

    def _start(self, resume: bool):
        """Checks, then the checkpointer and the starting state: (ckpt, state, blocks done,
        step resumed from). The logs keep rows up to the step training starts from: 0 unless a
        checkpoint is restored, so an attempt that died before its first checkpoint leaves no
        rows behind (they would repeat the steps this run writes again)."""
        from r2pac_jax.checkpoint import Checkpointer
        from r2pac_jax.memory import check_lanes_fit

        if resume:
            # settings are compared whether or not checkpoints remain: a run whose checkpoints
            # are gone must not restart silently under other settings
            self.check_same_run()
        else:
            self.dir.refuse_existing_run()
        # before anything of the run is allocated or created
        check_lanes_fit(self._init, self._blocks, self.lanes.hp, self.data, self.lanes.size,
                        f"{self.task.name} {self.cfg.algo}", self.cfg.batch_size, self.log)
        self.out.mkdir(parents=True, exist_ok=True)
        ckpt = Checkpointer(self.out / "checkpoints")
        state, done_blocks, resume_step = self.init_state(), 0, 0
        self.step_reached, self.last_checkpoint = 0, None
        try:
            restored = ckpt.resume_blocks(state, log=self.log) if resume else None
        except BaseException:  # closed here: _run's finally only holds it once _start returns
            ckpt.close()
            raise
        if restored is not None:
            resume_step, state, done_blocks, self.diverged = restored
            state = place(state, self.lanes.size)
            self.step_reached = self.last_checkpoint = resume_step
            self.log(f"resuming {self.out} from step {resume_step}")
        self.dir.write_identity(self.cfg, self.dataset_info, self.lanes, self.task.name,
                                self.dataset_label, self.physics)
        return ckpt, state, done_blocks, resume_step

    def _finish(self, state, last_eval, wall: float, steps_timed: int, resume_step: int,
                logs) -> dict:
        """The final evaluation (if the last block had none), the policy, results and plots."""
        from r2pac_jax.results import run_results

        if last_eval is None and self.evaluation.evaluator is not None:  # resumed at the end
            last_eval = self.evaluate(state, len(self.schedule) * self.cfg.block_steps)
        self.dir.save_policy(self.cfg.total_steps, self._policy_params(state, self.lanes.hp),
                             {"task": self.task.name, "algo": self.cfg.algo,
                              "lanes": self.lanes.size, "obs_dim": self.task.obs_dim,
                              "act_dim": self.task.act_dim})
        results = run_results(
            self.cfg, self.task.name, self.lanes, self.agent.summary(state), last_eval, wall,
            steps_timed, self.dataset_label, self.physics, self.diverged, resume_step,
            eval_backend=self.evaluation.backend, dataset_path=self.dataset_path,
            provenance=True)
        self.dir.write_results(results)
        self.dir.plot(logs, f"{self.task.name} {self.cfg.algo}", self.agent.plot_metrics)
        return results

"""Training: a pure `train(key, hp)` built from config and dataset, and the CLI around it.

The unit of compiled work is a *block*: refresh the safety threshold, then `threshold_every`
gradient steps in one `jax.lax.scan`, returning the block's mean metrics. Blocks are vmapped
over *lanes* (seeds x scalar-hyperparameter cells), so a grid of seeds, alphas, penalties and
guidance scales trains as one compiled program. `make_train` chains every block of every phase
into one scan (pure, no I/O); `Run` calls the same vmapped block from Python between
evaluations and checkpoints so that a user gets progress, logs and resumability.

    python -m r2pac_jax.train --task ReachAvoid --preset quick --seeds 3
"""
from __future__ import annotations

import argparse
import dataclasses
import functools
import sys
import time
from pathlib import Path
from typing import Callable, Optional, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from r2pac_jax.agents.r2pac import Agent, AgentState
from r2pac_jax.config import (ALGOS, PRESETS, Config, ConfigError, HParams, check_hparams,
                              make_config, resolve_preset)
from r2pac_jax.data.chunks import ChunkedData, build_chunks, sample
from r2pac_jax.data.dsrl import Dataset
from r2pac_jax.io import DirectoryBusy, atomic_write_json, atomic_write_text, lock_directory
from r2pac_jax.tasks import TaskSpec, get_task


# ---------------------------------------------------------------------------------------------
# Pure pieces


def chunk_dataset(cfg: Config, task: TaskSpec, ds: Dataset) -> ChunkedData:
    """The dataset's h-step chunks for this config (BC-safe keeps episodes with cost <= kappa)."""
    keep = None
    if cfg.data_filter == "safe":
        _, costs = ds.episode_sums()
        keep = costs <= task.kappa
        if not keep.any():
            raise ConfigError(f"bc-safe: the dataset {ds.source} has no episode with cost <= "
                              f"kappa={task.kappa}")
    return build_chunks(ds, cfg.chunk_len, cfg.discount, cfg.reward_scale, cfg.cost_scale,
                        keep_episodes=keep, threshold_subset=cfg.threshold_subset)


def make_block(agent: Agent, phase: str) -> Callable:
    """block(state, hp, data) -> (state, metrics): threshold refresh + `threshold_every` steps."""
    cfg = agent.cfg

    def block(state: AgentState, hp: HParams, data: ChunkedData):
        if agent.uses_critics and cfg.threshold_source == "dataset":
            state = state.replace(threshold=agent.dataset_threshold(state.params, data, hp))

        def step(s, _):
            key, k_batch = jax.random.split(s.key)
            batch = sample(data, k_batch, cfg.batch_size)
            return agent.update(s.replace(key=key), batch, hp, phase)

        state, metrics = jax.lax.scan(step, state, None, length=cfg.threshold_every)
        return state, jax.tree_util.tree_map(jnp.mean, metrics)

    return block


def make_train(cfg: Config, data: ChunkedData, obs_dim: int, act_dim: int):
    """A pure `train(key, hp=None) -> (AgentState, {phase: metrics[n_blocks]})`.

    Every phase runs as one `lax.scan` over blocks; jit it and vmap it over keys and `HParams`
    as you like. The dataset is passed to the compiled function as an argument, not baked in.
    """
    agent = Agent(cfg, obs_dim, act_dim)
    blocks = {p: make_block(agent, p) for p in cfg.phases}
    n_blocks = cfg.steps // cfg.threshold_every

    def train_with_data(key, hp, data):
        state = agent.init(key, hp)
        metrics = {}
        for phase in cfg.phases:
            state, metrics[phase] = jax.lax.scan(
                lambda s, _: blocks[phase](s, hp, data), state, None, length=n_blocks)
        return state, metrics

    def train(key, hp: Optional[HParams] = None):
        hp = HParams.from_config(cfg) if hp is None else hp
        return train_with_data(key, hp, data)

    train.agent = agent
    train.with_data = train_with_data
    return train


@functools.lru_cache(maxsize=16)
def compiled(cfg: Config, obs_dim: int, act_dim: int):
    """Jitted, lane-vmapped pieces for a config, shared by every `Run` with the same config
    (a resumed run or a sweep's next group reuses the compiled programs)."""
    agent = Agent(cfg, obs_dim, act_dim)
    blocks = {p: jax.jit(jax.vmap(make_block(agent, p), in_axes=(0, 0, None)))
              for p in cfg.phases}
    return agent, jax.jit(jax.vmap(agent.init)), blocks, jax.jit(jax.vmap(agent.policy_params))


@functools.lru_cache(maxsize=16)
def lane_evaluator(cfg: Config, task: TaskSpec, episodes: int, physics: str):
    from r2pac_jax.evaluate import LaneEvaluator

    agent = compiled(cfg, task.obs_dim, task.act_dim)[0]
    return LaneEvaluator(agent.act, task, episodes, physics=physics)


# ---------------------------------------------------------------------------------------------
# Lanes: seeds x hyperparameter cells


@dataclasses.dataclass
class Lanes:
    seeds: list[int]  # per lane
    cells: list[int]  # per lane: index into `cell_hparams`
    cell_hparams: list[dict]  # per cell: values of HParams fields
    hp: HParams  # arrays [L]

    @property
    def size(self) -> int:
        return len(self.seeds)

    @staticmethod
    def build(cfg: Config, seeds: Sequence[int], cells: Optional[Sequence[dict]] = None) -> "Lanes":
        base = HParams.from_config(cfg)._asdict()
        cells = [dict(c) for c in (cells or [{}])]
        full = []
        for c in cells:
            unknown = set(c) - set(base)
            if unknown:
                raise ConfigError(f"cannot vary {sorted(unknown)} across lanes; vmappable "
                                  f"hyperparameters are {list(base)}")
            merged = {k: float(c.get(k, base[k])) for k in base}
            check_hparams(merged["quantile_alpha"], merged["penalty_c"], merged["guidance_scale"])
            full.append(merged)
        lane_seeds = [s for _ in full for s in seeds]
        lane_cells = [i for i in range(len(full)) for _ in seeds]
        hp = HParams(*(jnp.asarray([full[c][k] for c in lane_cells], jnp.float32)
                       for k in HParams._fields))
        return Lanes(list(lane_seeds), lane_cells, full, hp)


def _stats(per_seed: np.ndarray) -> dict:
    return dict(mean=float(np.mean(per_seed)), std=float(np.std(per_seed)),
                per_seed=[float(x) for x in per_seed])


# ---------------------------------------------------------------------------------------------
# The run: blocks between evaluations and checkpoints


class Run:
    """Trains all lanes of one config on one dataset, with logs, evaluation and checkpoints."""

    def __init__(self, cfg: Config, task: TaskSpec, ds: Dataset, out_dir, lanes: Lanes,
                 physics: str = "auto", progress: bool = True, log: Callable[[str], None] = print,
                 dataset_label: str = ""):
        self.cfg, self.task, self.lanes = cfg, task, lanes
        self.out = Path(out_dir)
        self.physics = physics
        self.progress = progress
        self.log = log
        self.dataset_label = dataset_label or ds.source
        if ds.obs_dim != task.obs_dim or ds.act_dim != task.act_dim:
            raise ConfigError(f"dataset {ds.source} has obs/act sizes {ds.obs_dim}/{ds.act_dim}, "
                              f"task {task.name} needs {task.obs_dim}/{task.act_dim}")
        self.data = chunk_dataset(cfg, task, ds)
        self.agent, self._init, self._blocks, self._policy_params = compiled(
            cfg, task.obs_dim, task.act_dim)
        self.evaluator = (lane_evaluator(cfg, task, cfg.eval_episodes, physics)
                          if cfg.eval_episodes > 0 else None)

    # schedule ---------------------------------------------------------------------------------
    @property
    def schedule(self) -> list[tuple[str, int]]:
        """(phase, step within phase after the block) for every block of the run."""
        n = self.cfg.steps // self.cfg.threshold_every
        return [(p, (i + 1) * self.cfg.threshold_every) for p in self.cfg.phases for i in range(n)]

    def _evaluates(self, phase: str, phase_step: int, last: bool) -> bool:
        if self.evaluator is None or phase == "critic":
            return False
        return last or phase_step % self.cfg.eval_every == 0

    def _place(self, tree):
        """Spread the lane axis over the local devices when it divides evenly (jax.sharding);
        XLA then partitions the vmapped program along lanes. A no-op on one device."""
        devices = jax.local_devices()
        if len(devices) < 2 or self.lanes.size % len(devices):
            return tree
        from jax.sharding import Mesh, NamedSharding, PartitionSpec

        sharding = NamedSharding(Mesh(np.array(devices), ("lanes",)), PartitionSpec("lanes"))
        return jax.device_put(tree, sharding)

    def init_state(self) -> AgentState:
        keys = jnp.stack([jax.random.PRNGKey(s) for s in self.lanes.seeds])
        return self._place(self._init(keys, self.lanes.hp))

    def eval_keys(self, step: int) -> jax.Array:
        return jnp.stack([jax.random.fold_in(jax.random.fold_in(jax.random.PRNGKey(s), 1), step)
                          for s in self.lanes.seeds])

    def evaluate(self, state: AgentState, step: int) -> dict:
        pp = self._policy_params(state, self.lanes.hp)
        return self.evaluator(pp, self.eval_keys(step))

    # main loop ---------------------------------------------------------------------------------
    def run(self, resume: bool = False, stop_after: Optional[int] = None) -> Optional[dict]:
        """Train to the end (or stop after `stop_after` blocks, as an interruption would, and
        return None); with `resume`, continue from the latest checkpoint in the run directory.
        The directory is locked meanwhile: a second live process on it gets DirectoryBusy."""
        lock = lock_directory(self.out)
        try:
            return self._run(resume, stop_after)
        finally:
            lock.close()

    def _run(self, resume: bool, stop_after: Optional[int]) -> Optional[dict]:
        from r2pac_jax.checkpoint import Checkpointer
        from r2pac_jax.metrics_log import MetricsLog

        cfg = self.cfg
        self.out.mkdir(parents=True, exist_ok=True)
        ckpt = Checkpointer(self.out / "checkpoints")
        state = self.init_state()
        done_blocks = 0
        resume_step = None
        if resume:
            latest = ckpt.latest_step()
            if latest is not None:
                state, meta = ckpt.restore(latest, state)
                state = self._place(state)
                done_blocks = int(meta["blocks_done"])
                resume_step = latest
                self.log(f"resuming {self.out} from step {latest}")
            else:
                self.log(f"--resume: no checkpoint in {self.out / 'checkpoints'}; starting afresh")
        elif ckpt.latest_step() is not None:
            raise ConfigError(f"{self.out} already holds a run (checkpoint at step "
                              f"{ckpt.latest_step()}); pass --resume to continue it or choose "
                              "another --out")
        atomic_write_text(self.out / "config.json", cfg.to_json())
        atomic_write_json(self.out / "lanes.json", dict(
            seeds=self.lanes.seeds, cells=self.lanes.cells, cell_hparams=self.lanes.cell_hparams,
            task=self.task.name, dataset=self.dataset_label, physics=self.physics))
        logs = MetricsLog(self.out, resume_step=resume_step)
        hp = self._place(self.lanes.hp)
        schedule = self.schedule
        total = len(schedule) * cfg.threshold_every
        bar = None
        if self.progress:
            from tqdm import tqdm

            bar = tqdm(total=total, initial=done_blocks * cfg.threshold_every, unit="step",
                       desc=f"{self.task.name} {cfg.algo}", dynamic_ncols=True, smoothing=0.1)
        last_eval = None
        t_start = time.time()
        steps_timed = 0
        for i in range(done_blocks, len(schedule)):
            if stop_after is not None and i - done_blocks >= stop_after:
                if bar is not None:
                    bar.close()
                logs.close()
                ckpt.close()
                return None
            phase, phase_step = schedule[i]
            step = (i + 1) * cfg.threshold_every
            t0 = time.time()
            state, metrics = self._blocks[phase](state, hp, self.data)
            metrics = jax.tree_util.tree_map(np.asarray, metrics)  # waits for the block
            dt = time.time() - t0
            steps_timed += cfg.threshold_every
            for lane in range(self.lanes.size):
                row = {k: float(v[lane]) for k, v in metrics.items()}
                row.update(step=step, phase=phase, lane=lane, seed=self.lanes.seeds[lane],
                           steps_per_s=cfg.threshold_every / dt)
                logs.write("metrics", row, tb_prefix=f"train/lane{lane}")
            last = i == len(schedule) - 1
            if self._evaluates(phase, phase_step, last):
                res = self.evaluate(state, step)
                last_eval = res
                for lane in range(self.lanes.size):
                    logs.write("eval", dict(
                        step=step, lane=lane, seed=self.lanes.seeds[lane],
                        normalized_reward=float(res["normalized_reward"][lane]),
                        normalized_cost=float(res["normalized_cost"][lane]),
                        mean_return=float(res["returns"][lane].mean()),
                        mean_cost=float(res["costs"][lane].mean())), tb_prefix=f"eval/lane{lane}")
            if last or step % cfg.checkpoint_every == 0:
                ckpt.save(step, state, {"blocks_done": i + 1, "step": step})
            if bar is not None:
                post = {"phase": phase}
                if "threshold" in metrics:
                    post["l"] = f"{float(np.mean(metrics['threshold'])):.3g}"
                if last_eval is not None:
                    post["rew"] = f"{float(np.mean(last_eval['normalized_reward'])):.2f}"
                    post["cost"] = f"{float(np.mean(last_eval['normalized_cost'])):.2f}"
                bar.set_postfix(post, refresh=False)
                bar.update(cfg.threshold_every)
        if bar is not None:
            bar.close()
        wall = time.time() - t_start
        if last_eval is None and self.evaluator is not None:  # resumed after the last block
            last_eval = self.evaluate(state, total)
        self.save_policy(state)
        results = self.results(state, last_eval, wall, steps_timed)
        atomic_write_json(self.out / "results.json", results)
        self.plot(logs)
        logs.close()
        ckpt.close()
        return results

    def save_policy(self, state: AgentState) -> None:
        """The final policy parameters of every lane (what `load_policy` reads)."""
        from r2pac_jax.checkpoint import Checkpointer

        pol = Checkpointer(self.out / "policy", max_to_keep=1)
        step = self.cfg.total_steps
        if pol.latest_step() != step:  # a resumed finished run already saved this very policy
            pp = self._policy_params(state, self.lanes.hp)
            pol.save(step, pp, {"task": self.task.name, "lanes": self.lanes.size,
                                "obs_dim": self.task.obs_dim, "act_dim": self.task.act_dim})
        pol.close()

    def results(self, state: AgentState, ev: Optional[dict], wall: float, steps: int) -> dict:
        lanes = self.lanes
        out = dict(task=self.task.name, algo=self.cfg.algo, preset=self.cfg.preset,
                   dataset=self.dataset_label, physics=self.physics,
                   total_steps=self.cfg.total_steps, wall_time_s=wall,
                   train_steps_per_s=steps / wall if wall > 0 else None,
                   config=dataclasses.asdict(self.cfg), cells=[])
        thresholds = np.asarray(state.threshold)
        for c, hp in enumerate(lanes.cell_hparams):
            idx = [i for i, ci in enumerate(lanes.cells) if ci == c]
            cell = dict(hparams=hp, seeds=[lanes.seeds[i] for i in idx],
                        threshold=[float(thresholds[i]) for i in idx])
            if ev is not None:
                cell.update(
                    normalized_reward=_stats(ev["normalized_reward"][idx]),
                    normalized_cost=_stats(ev["normalized_cost"][idx]),
                    returns=ev["returns"][idx].tolist(), costs=ev["costs"][idx].tolist(),
                    lengths=ev["lengths"][idx].tolist(),
                    mean_return=_stats(ev["returns"][idx].mean(-1)),
                    mean_cost=_stats(ev["costs"][idx].mean(-1)),
                    episodes=int(ev["returns"].shape[-1]))
                cell["safe"] = bool(cell["normalized_cost"]["mean"] < 1.0)
            out["cells"].append(cell)
        if len(out["cells"]) == 1:
            out.update({k: v for k, v in out["cells"][0].items() if k != "hparams"})
        return out

    def plot(self, logs) -> None:
        from r2pac_jax.report import plot_curves

        rows = logs.read("metrics")
        keys = [k for k in ("loss_qc", "loss_qr", "threshold", "loss_actor") if rows and k in
                {kk for r in rows for kk in r}]
        if keys:
            plot_curves(rows, keys, self.out / "training.png", f"{self.task.name} {self.cfg.algo}")
        ev = logs.read("eval")
        if ev:
            plot_curves(ev, ["normalized_reward", "normalized_cost"], self.out / "eval.png",
                        f"{self.task.name} {self.cfg.algo}: evaluation")


# ---------------------------------------------------------------------------------------------
# CLI


def _parse_set(items: Sequence[str]) -> dict:
    fields = {f.name: f for f in dataclasses.fields(Config)}
    out = {}
    for item in items:
        if "=" not in item:
            raise ConfigError(f"--set takes key=value, got {item!r}")
        k, v = item.split("=", 1)
        k = k.strip().replace("-", "_")
        if k not in fields:
            raise ConfigError(f"--set: unknown config key {k!r}; known keys: {', '.join(fields)}")
        default = getattr(Config(task="x"), k)
        try:
            if isinstance(default, bool):
                if v.lower() not in ("true", "false", "1", "0"):
                    raise ValueError
                out[k] = v.lower() in ("true", "1")
            elif isinstance(default, int):
                out[k] = int(v)
            elif isinstance(default, float):
                out[k] = float(v)
            elif isinstance(default, tuple):
                out[k] = tuple(int(x) for x in v.split(","))
            else:
                out[k] = v
        except ValueError:
            raise ConfigError(f"--set {k}={v!r}: expected a {type(default).__name__}") from None
    return out


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m r2pac_jax.train",
                                 description="Train R2PAC (or a variant/baseline) offline and "
                                             "evaluate it with DSRL's scores.")
    ap.add_argument("--task", required=True, help="task name or DSRL id (e.g. ReachAvoid, CarGoal2)")
    ap.add_argument("--algo", default="r2pac", help=f"one of {', '.join(ALGOS)}")
    ap.add_argument("--baselines", default="bc-all,bc-safe",
                    help="comma-separated algos trained after --algo on the same data for the "
                         "comparison table ('none' to skip)")
    ap.add_argument("--preset", default="auto", help="auto | paper | quick (auto: paper on an "
                                                     "accelerator, quick on a CPU)")
    ap.add_argument("--seeds", type=int, default=None, help="number of seeds (vmapped)")
    ap.add_argument("--seed-offset", type=int, default=0, help="first seed")
    ap.add_argument("--steps", type=int, default=None, help="gradient steps per phase")
    ap.add_argument("--chunk-len", type=int, default=None, help="action chunk length h")
    ap.add_argument("--dataset", default=None, help="a DSRL-format HDF5 file")
    ap.add_argument("--out", default=None, help="run directory (default runs/TASK-ALGO-TIME)")
    ap.add_argument("--resume", action="store_true", help="continue the run in --out")
    ap.add_argument("--physics", default="auto", help="auto | mjx | mujoco | jax")
    ap.add_argument("--eval-episodes", type=int, default=None)
    ap.add_argument("--eval-every", type=int, default=None)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="any config value, e.g. --set quantile_alpha=0.8 (repeatable)")
    ap.add_argument("--no-progress", action="store_true")
    return ap


def fit_blocks_to_steps(overrides: dict, preset: str) -> None:
    """A `--steps` shorter than (or not a multiple of) the preset's block would be refused by
    the config check; shrink the block (threshold refresh, evaluation and checkpoint periods) to
    fit, unless the user set those explicitly. Refreshing the threshold more often is harmless."""
    import math

    steps = overrides.get("steps")
    if steps is None or steps < 1:
        return
    preset_values = PRESETS[resolve_preset(preset)[0]]
    block = overrides.get("threshold_every") or preset_values["threshold_every"]
    if steps % block == 0 or "threshold_every" in overrides:
        return
    block = math.gcd(steps, block)
    overrides["threshold_every"] = block
    for k in ("eval_every", "checkpoint_every"):
        if overrides.get(k) is None:
            period = min(preset_values[k], steps)
            overrides[k] = max(block, period - period % block)


def run_algo(task: TaskSpec, algo: str, args, ds: Dataset, out: Path, log) -> dict:
    overrides = dict(steps=args.steps, chunk_len=args.chunk_len, seeds=args.seeds,
                     eval_episodes=args.eval_episodes, eval_every=args.eval_every)
    overrides.update(_parse_set(args.set))
    fit_blocks_to_steps(overrides, args.preset)
    if not task.has_env and overrides.get("eval_episodes") is None:
        log(f"note: {task.name} has no environment in this install; training without evaluation")
        overrides["eval_episodes"] = 0
    cfg = make_config(task, algo, args.preset, overrides)
    seeds = list(range(args.seed_offset, args.seed_offset + cfg.seeds))
    lanes = Lanes.build(cfg, seeds)
    log(f"{algo}: {cfg.total_steps} steps ({' + '.join(cfg.phases)}), {len(seeds)} seeds "
        f"vmapped, h={cfg.chunk_len}, alpha={cfg.quantile_alpha}, C={cfg.penalty_c} "
        f"({cfg.penalty_mode}), -> {out}")
    run = Run(cfg, task, ds, out, lanes, physics=args.physics, progress=not args.no_progress,
              log=log, dataset_label=ds.source)
    return run.run(resume=args.resume)


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)

    def log(msg):
        print(msg, flush=True)

    from r2pac_jax.data import DatasetError, load_task_dataset
    from r2pac_jax.data.chunks import ChunkError
    from r2pac_jax.tasks import EnvUnavailableError, UnknownTaskError

    try:
        task = get_task(args.task)
        preset, why = resolve_preset(args.preset)
        log(why)
        args.preset = preset
        algos = [args.algo] + [b for b in args.baselines.split(",")
                               if b and b != "none" and b != args.algo]
        for a in algos:
            if a not in ALGOS:
                raise ConfigError(f"unknown algo {a!r}; choose one of {', '.join(ALGOS)}")
        if args.resume and not args.out:
            raise ConfigError("--resume needs --out DIR (the run to continue)")
        out = Path(args.out or f"runs/{task.name}-{args.algo}-{time.strftime('%Y%m%d-%H%M%S')}")
        ds = load_task_dataset(task, args.dataset, announce=log)
        results = {}
        for a in algos:
            sub = out if a == args.algo else out / "baselines" / a
            results[a] = run_algo(task, a, args, ds, sub, log)
    except (ConfigError, DatasetError, ChunkError, UnknownTaskError, EnvUnavailableError,
            DirectoryBusy) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    from r2pac_jax.report import results_table

    if all("normalized_reward" in r for r in results.values()):
        table = results_table({task.name: results})
        atomic_write_text(out / "table.md", table + "\n")
        log("\n" + table)
    log(f"\nresults: {out / 'results.json'}; metrics: {out / 'metrics.jsonl'}; "
        f"policy: r2pac_jax.load_policy({str(out)!r})")
    return 0


if __name__ == "__main__":
    sys.exit(main())

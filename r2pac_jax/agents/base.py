"""The protocol every algorithm implements, and the pieces algorithms on h-step chunks share.

An algorithm is a module under `agents/` with

    CONFIG      frozen dataclass of its own keys (defaults = the quick preset's values)
    PRESETS     {"paper": {...}, "quick": {...}}: its values per preset (its keys or generic ones)
    VARIANTS    {"--algo name": {switches}}: the names it serves, as config values
    FIXED       {generic key: value} it pins (a one-step cloner pins chunk_len=1); FIXED_WHY
    HPARAMS     names of its scalars that may differ between vmapped lanes (sweep cells)
    task_values(spec) -> dict, phases(agent_cfg) -> tuple, validate(agent_cfg),
    check_hparams(values)
    Agent(cfg, obs_dim, act_dim) implementing `Algorithm` below.

The generic loop (`loop.py`) serves every algorithm unchanged: it samples batches through the
agent's data view, vmaps `init` / blocks of `update` over lanes, checkpoints the state pytree,
evaluates `act` on `policy_params`, and writes the same logs and results.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol

import chex
import jax
import jax.numpy as jnp
from flax import struct

from r2pac_jax.data import chunks, transitions
from r2pac_jax.data.dsrl import Dataset
from r2pac_jax.errors import ConfigError
from r2pac_jax.ranges import check_range
from r2pac_jax.tasks import TaskSpec

if TYPE_CHECKING:  # the config sits above the agents: a type only, never imported at run time
    from r2pac_jax.config import Config


class Algorithm(Protocol):
    """What the loop needs of an agent. All methods are pure and jittable except `make_data`
    and `check_data` (host side, once per run). `hp` is a dict of [] float32 scalars named by
    the module's HPARAMS (vmapped to [L] by the loop): their one place, since `cfg` holds
    `per_lane.PerLane` markers there (a sweep's lanes differ in them)."""

    cfg: Config
    plot_metrics: tuple[str, ...]  # metric keys drawn in training.png
    unevaluated_phases: tuple[str, ...]  # phases with no policy yet (R2PAC's "critic")
    progress_metrics: dict  # {label: metric key} shown on the progress bar (R2PAC: l)

    def check_data(self, task: TaskSpec, ds: Dataset) -> None:
        """Raise ConfigError / ChunkError if the dataset cannot serve this algorithm (cheap)."""

    def make_data(self, task: TaskSpec, ds: Dataset) -> Any:
        """The device-side data view (a pytree), built once per run."""

    def sample(self, data: Any, key: jax.Array) -> Any:
        """One training batch from the data view."""

    def init(self, key: jax.Array, hp: dict) -> Any:
        """The training state: a flax struct with at least a `key` field (the loop splits it)."""

    def begin_block(self, state: Any, hp: dict, data: Any) -> Any:
        """Work done once per compiled block before its steps (R2PAC: the safety threshold)."""

    def update(self, state: Any, batch: Any, hp: dict, phase: str) -> tuple[Any, dict]:
        """One gradient step of `phase` -> (state, {name: [] metric})."""

    def policy_params(self, state: Any, hp: dict) -> Any:
        """Exactly what `act` needs (saved as the final policy)."""

    def act(self, pp: Any, obs: jax.Array, key: jax.Array) -> jax.Array:
        """The policy: obs [B, obs_dim] -> action [B, act_dim] in [-1, 1]."""

    def summary(self, state: Any) -> dict:
        """Per-run scalars worth reporting in results.json (e.g. the threshold), or {}."""

    # Optional: check_cells(task, ds, cells: list[{name: value}]): checks of the lane cells'
    # HPARAMS values against the data (host side, once per run; CDT's cost targets).
    # Optional: a policy with memory (CDT's context of returns-/costs-to-go). An agent that
    # defines all three is evaluated through them (`policy.policy_of`); `act` then acts as
    # at an episode's first step.
    #   memory_init(pp, obs[B, o]) -> mem
    #   act_memory(pp, obs[B, o], key, mem) -> (action[B, a], mem)
    #   observe(pp, mem, reward[B], cost[B]) -> mem      (after each environment step)


@struct.dataclass
class ActorState:
    """The state of algorithms that train one actor network (the cloners)."""

    params: dict  # {"actor": ...}
    opt: dict  # {"actor": optimiser state}
    step: jax.Array  # [] int32 gradient steps taken
    key: jax.Array


def check_obs(obs: jax.Array, obs_dim: int) -> None:
    """chex check at the policy's entry: obs [B, obs_dim]."""
    chex.assert_rank(obs, 2)
    chex.assert_axis_dimension(obs, 1, obs_dim)


def check_act(obs: jax.Array, action: jax.Array, obs_dim: int, act_dim: int) -> jax.Array:
    """chex checks at the policy's border: obs [B, obs_dim] in, action [B, act_dim] out."""
    check_obs(obs, obs_dim)
    chex.assert_shape(action, (obs.shape[0], act_dim))
    return action


def check_dataset_sizes(task: TaskSpec, ds: Dataset) -> None:
    """ConfigError unless the dataset's observation and action sizes are the task's."""
    if ds.obs_dim != task.obs_dim or ds.act_dim != task.act_dim:
        raise ConfigError(f"dataset {ds.source} has obs/act sizes {ds.obs_dim}/{ds.act_dim}, "
                          f"task {task.name} needs {task.obs_dim}/{task.act_dim}")


class ChunkAlgorithm:
    """Base of algorithms trained on `data.chunks` (h = cfg.chunk_len; one-step ones pin h = 1).

    Gives the data view (the dataset's h-step chunks, the safe subset when data_filter is safe),
    the batch sampler, and no-op hooks."""

    plot_metrics: tuple[str, ...] = ("loss_actor",)
    unevaluated_phases: tuple[str, ...] = ()
    progress_metrics: dict = {}
    threshold_subset: int = 1  # states kept for a dataset-wide statistic (R2PAC: its quantile)

    def __init__(self, cfg: Config, obs_dim: int, act_dim: int):
        self.cfg = cfg
        self.obs_dim, self.act_dim, self.h = obs_dim, act_dim, cfg.chunk_len
        self.chunk_size = cfg.chunk_len * act_dim

    def keep_episodes(self, task: TaskSpec, ds: Dataset):
        """[E] bool of the episodes trained on (None: all)."""
        if self.cfg.data_filter != "safe":
            return None
        _, costs = ds.episode_sums()
        keep = costs <= task.kappa
        if not keep.any():
            raise ConfigError(f"{self.cfg.algo}: the dataset {ds.source} has no episode with "
                              f"cost <= kappa={task.kappa} (data_filter=safe needs one)")
        return keep

    def check_data(self, task: TaskSpec, ds: Dataset) -> None:
        check_dataset_sizes(task, ds)
        self.keep_episodes(task, ds)
        chunks.check_chunk_len(ds, self.cfg.chunk_len)

    def make_data(self, task: TaskSpec, ds: Dataset) -> chunks.ChunkedData:
        cfg = self.cfg
        return chunks.build_chunks(ds, cfg.chunk_len, cfg.discount, cfg.reward_scale,
                                   cfg.cost_scale, keep_episodes=self.keep_episodes(task, ds),
                                   threshold_subset=self.threshold_subset)

    def sample(self, data: chunks.ChunkedData, key: jax.Array) -> chunks.Batch:
        return chunks.sample(data, key, self.cfg.batch_size)

    def begin_block(self, state, hp: dict, data):
        return state

    def summary(self, state) -> dict:
        return {}


class TransitionAlgorithm(ChunkAlgorithm):
    """Base of the one-step baselines ported from OSRL (CPQ, BCQ-L, COptiDICE): they train on
    `data.transitions` (rows sampled uniformly, OSRL's done rule unless the config's `done_rule`
    says otherwise); chunk_len is pinned to 1 by their modules."""

    def check_data(self, task: TaskSpec, ds: Dataset) -> None:
        check_dataset_sizes(task, ds)
        self.keep_episodes(task, ds)

    def make_data(self, task: TaskSpec, ds: Dataset) -> transitions.TransitionData:
        cfg = self.cfg
        return transitions.build_transitions(ds, cfg.reward_scale, cfg.cost_scale,
                                             cfg.done_rule, self.keep_episodes(task, ds))

    def sample(self, data: transitions.TransitionData, key: jax.Array):
        return transitions.sample(data, key, self.cfg.batch_size)


class TanhMeanPolicy:
    """Mixin of the OSRL ports whose actor is a squashed Gaussian (CPQ, COptiDICE): evaluation
    acts deterministically with tanh of its mean, as OSRL's `act(deterministic=True)` does.
    Needs `self.actor_net` (apply -> (mu, log_std)) and a state with params["actor"]."""

    def policy_params(self, state, hp: dict) -> dict:
        return {"actor": state.params["actor"]}

    def act(self, pp: dict, obs: jax.Array, key: jax.Array) -> jax.Array:
        """Deterministic: obs [B, obs_dim] -> tanh(mu(obs)) [B, act_dim]; key unused."""
        del key
        check_obs(obs, self.obs_dim)
        mu, _ = self.actor_net.apply(pp["actor"], obs)
        return check_act(obs, jnp.tanh(mu), self.obs_dim, self.act_dim)


def check_choice(name: str, value, choices) -> None:
    if value not in choices:
        raise ConfigError(f"{name} must be one of {', '.join(map(str, choices))}; got {value!r}")


def soft_update(target, online, tau):
    """Polyak averaging of parameter pytrees: tau * online + (1 - tau) * target."""
    return jax.tree_util.tree_map(lambda t, o: (1.0 - tau) * t + tau * o, target, online)


def optimizer_step(tx: dict, name: str, params: dict, opt: dict, loss_fn):
    """One step of network `name` on loss_fn(params[name]) -> (loss, aux):
    -> (params, opt, loss, aux) with only that network and its optimiser state changed."""
    import optax

    (loss, aux), g = jax.value_and_grad(loss_fn, has_aux=True)(params[name])
    upd, opt_n = tx[name].update(g, opt[name], params[name])
    return {**params, name: optax.apply_updates(params[name], upd)}, {**opt, name: opt_n}, \
        loss, aux


def osrl_presets(**quick) -> dict:
    """Presets of the OSRL ports: `paper` = OSRL's training values (batch 512, reward scale 0.1,
    cost scale 1, gamma 0.99, 100k steps); `quick` = the same with 10k steps, batch 256 and the
    module's smaller networks (`quick`), fixed for the CPU before any v2 score."""
    osrl = dict(batch_size=512, reward_scale=0.1, cost_scale=1.0, discount=0.99)
    return {"paper": dict(osrl, steps=100_000),
            "quick": dict(osrl, steps=10_000, batch_size=256, **quick)}


def cost_limit_task_values(spec) -> dict:
    """The registry values of the OSRL ports: their cost limit is the task's kappa, their
    threshold's horizon its episode length."""
    return dict(cost_limit=float(spec.kappa), episode_len=int(spec.episode_len))


def check_lane_hparams(values: dict, hparams, positive=()) -> None:
    """Per-lane values of vmappable scalars: known names, finite, >= 0 (> 0 for `positive`)."""
    unknown = set(values) - set(hparams)
    if unknown:
        raise ConfigError(f"cannot vary {sorted(unknown)} across lanes; vmappable "
                          f"hyperparameters are {list(hparams)}")
    for k, v in values.items():
        check_range(k, v, 0, low_open=k in positive)


def check_counts(c, names) -> None:
    """Integer config values that must be >= 1."""
    for k in names:
        if getattr(c, k) < 1:
            raise ConfigError(f"{k} must be >= 1, got {getattr(c, k)}")


def no_hparams(values: dict) -> None:
    """check_hparams of modules without vmappable scalars."""
    if values:
        raise ConfigError(f"this algorithm has no hyperparameters to vary across lanes; got "
                          f"{sorted(values)}")


def check_positive(name: str, value) -> None:
    check_range(name, value, 0, low_open=True)


def check_sizes(name: str, sizes) -> None:
    """Hidden layer sizes: a non-empty tuple of ints >= 1."""
    if not sizes or min(sizes) < 1:
        raise ConfigError(f"{name} must be a non-empty list of sizes >= 1, got {sizes}")


def no_task_values(spec) -> dict:
    """task_values of modules that take nothing from the task registry."""
    return {}


def actor_only(agent_cfg) -> tuple[str, ...]:
    """phases of modules that train one network from the first step."""
    return ("actor",)
